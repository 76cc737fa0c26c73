"""Exports of a model to other vector formats: ``export_pdf`` (docs/PDF.md)."""

from .pdf import DEFAULT_DETAIL_QUALITY, DEFAULT_TOLERANCE, ExportStats, export_pdf

__all__ = ["DEFAULT_DETAIL_QUALITY", "DEFAULT_TOLERANCE", "ExportStats", "export_pdf"]
