"""``tpsv segment``: a label map, automatic or from strokes."""

from __future__ import annotations

import time

import click
import cv2
import numpy as np

from . import main, say
from .options import check_json_target, emit_json, json_option, output_option
from ..geometry import segment as seg
from ..image import read_image, write_image, write_labels


@main.command()
@click.argument("image", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("Label map PNG to write (8- or 16-bit, values 0..n-1).")
@click.option("--regions", type=click.IntRange(1, 10000), default=None, help="Number of regions (automatic mode).")
@click.option("--strokes", type=click.Path(dir_okay=False), default=None,
              help="Stroke PNG: each distinct non-black colour is one label.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the automatic segmentation.")
@click.option("--preview", type=click.Path(dir_okay=False), default=None, help="Write the regions over the photo.")
@json_option
@click.pass_context
def segment(ctx, image, output, regions, strokes, seed, preview, as_json):
    """Label map of IMAGE: automatic object regions, or a fill of user strokes."""
    check_json_target(as_json, output)
    t0 = time.perf_counter()
    rgb = read_image(image)
    if strokes:
        if regions is not None:
            raise click.UsageError("--regions and --strokes cannot both be used")
        raw = cv2.imread(strokes, cv2.IMREAD_COLOR)
        if raw is None:
            from ..errors import TpsvError

            raise TpsvError(f"{strokes}: not an image OpenCV can decode")
        labels = seg.segment_strokes(rgb, np.ascontiguousarray(raw[:, :, ::-1]))
    else:
        labels = seg.segment_auto(rgb, n_regions=regions, seed=seed)
    seconds = time.perf_counter() - t0
    write_labels(output, labels)
    if preview:
        write_image(preview, seg.overlay_regions(rgb, labels))
    n = int(labels.max()) + 1
    if as_json:
        emit_json({"width": rgb.shape[1], "height": rgb.shape[0], "regions": n, "seconds": seconds})
    else:
        say(ctx, f"{output}: {n} regions ({seconds:.2f} s)")
