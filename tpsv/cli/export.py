"""``tpsv export``: a .tpsv as a resolution-independent PDF (``tpsv.export.export_pdf``, docs/PDF.md)."""

from __future__ import annotations

import click

from . import main, say
from .options import POSITIVE, check_json_target, device_for, device_option, emit_json, json_option, output_option
from .outputs import claim_outputs
from .. import codec
from ..export import DEFAULT_DETAIL_QUALITY, DEFAULT_TOLERANCE, ExportStats, export_pdf


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PDF to write ('-': stdout).")
@click.option("--tolerance", type=click.FloatRange(0.05, 255.0), default=DEFAULT_TOLERANCE, show_default=True,
              help="Largest colour error of a patch's bilinear colour, in 8-bit sRGB levels "
                   "(smaller: more patches, a closer match).")
@click.option("--detail/--no-detail", default=True, show_default=True,
              help="Include the model's texture detail layer (an image blended over the vector colours).")
@click.option("--detail-quality", type=click.IntRange(0, 100), default=DEFAULT_DETAIL_QUALITY, show_default=True,
              help="JPEG quality of the detail image (0: lossless, Flate).")
@click.option("--dpi", type=POSITIVE, default=72.0, show_default=True,
              help="Model pixels per inch of the page (72: one pixel per point).")
@device_option
@json_option
@click.pass_context
def export(ctx, path, output, tolerance, detail, detail_quality, dpi, device, as_json):
    """Export a .tpsv file as a PDF: patch-mesh shadings clipped by the region outlines."""
    check_json_target(as_json, output)
    stats = ExportStats()
    with claim_outputs([path], ("-o", output)) as out:
        device = device_for(ctx, device)
        data = export_pdf(codec.load(path), tolerance=tolerance, detail=detail,
                          detail_quality=detail_quality or None, dpi=dpi, device=device, stats=stats)
        out.write(output, data)
    info = {"bytes": len(data), "regions": stats.regions, "patches": stats.pieces, "soft_edges": stats.soft_edges,
            "detail": stats.detail, "tolerance": tolerance, "seconds": stats.seconds, "device": device}
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {len(data)} bytes, {stats.regions} regions, {stats.pieces} patches"
                 f"{', detail image' if stats.detail else ''} in {stats.seconds:.2f} s")
