"""Imports every subcommand module so that each attaches itself to the group."""

from . import bench, edit, info, render, segment, vectorize  # noqa: F401
