"""Imports every subcommand module so that each attaches itself to the group."""

from . import batch, bench, edit, export, info, render, segment, vectorize  # noqa: F401
