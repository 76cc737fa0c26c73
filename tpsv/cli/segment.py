"""``tpsv segment``: a label map, automatic or from strokes."""

from __future__ import annotations

import time

import click

from . import main, say
from .options import IMAGE_HELP, SEED, check_json_target, emit_json, image_format, json_option, output_option
from .outputs import claim_outputs
from ..geometry import segment as seg
from ..image import encode_image, encode_labels, read_image, read_strokes


@main.command()
@click.argument("image", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("Label map PNG to write (8- or 16-bit, values 0..n-1).")
@click.option("--regions", type=click.IntRange(1, 10000), default=None, help="Number of regions (automatic mode).")
@click.option("--strokes", type=click.Path(dir_okay=False), default=None,
              help="Stroke PNG: each distinct non-black colour is one label.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the automatic segmentation.")
@click.option("--preview", type=click.Path(dir_okay=False), default=None,
              help=f"Write the regions over the photo: {IMAGE_HELP}.")
@json_option
@click.pass_context
def segment(ctx, image, output, regions, strokes, seed, preview, as_json):
    """Label map of IMAGE: automatic object regions, or a fill of user strokes."""
    check_json_target(as_json, output)
    if strokes and regions is not None:
        raise click.UsageError("--regions and --strokes cannot both be used")
    t0 = time.perf_counter()
    with claim_outputs([image, strokes], ("-o", output), ("--preview", preview)) as out:
        preview_format = image_format(preview, option="--preview")
        rgb = read_image(image)
        if strokes:
            labels = seg.segment_strokes(rgb, read_strokes(strokes))
        else:
            labels = seg.segment_auto(rgb, n_regions=regions, seed=seed)
        seconds = time.perf_counter() - t0
        out.write(output, encode_labels(labels))
        if preview:
            out.write(preview, encode_image(seg.overlay_regions(rgb, labels), preview_format))
    n = int(labels.max()) + 1
    if as_json:
        emit_json({"width": rgb.shape[1], "height": rgb.shape[0], "regions": n, "seconds": seconds})
    else:
        say(ctx, f"{output}: {n} regions ({seconds:.2f} s)")
