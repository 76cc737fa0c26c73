"""Imports every subcommand module, so that each attaches itself to the group (``tpsv.cli`` imports
one when it is first looked up: :func:`tpsv.cli.command`)."""

from . import batch, bench, edit, export, info, render, segment, vectorize  # noqa: F401
