"""``tpsv render`` and ``tpsv magnify``: pixels from a .tpsv at any size."""

from __future__ import annotations

import time

import click

from . import main, say
from .options import (check_json_target, device_for, device_option, emit_json, is_tpsv, json_option,
                      output_option, parse_size, positive)
from .vectorize import run_vectorize, vectorize_options
from .. import codec
from ..image import write_image


def _render_and_write(ctx, model, output, size, scale, device, as_json, extra=None):
    from ..render import render

    t0 = time.perf_counter()
    if size is not None:
        rgb = render(model, width=size[0], height=size[1], device=device)
    else:
        rgb = render(model, scale=scale, device=device)
    seconds = time.perf_counter() - t0
    write_image(output, rgb)
    info = {"width": rgb.shape[1], "height": rgb.shape[0], "seconds": seconds, "device": device, **(extra or {})}
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {info['width']}x{info['height']} on {device} in {seconds:.3f} s")


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PNG to write ('-': stdout).")
@click.option("--scale", type=float, default=None, help="Output scale (default 1).")
@click.option("--size", default=None, help="Output size WIDTHxHEIGHT (instead of --scale).")
@device_option
@json_option
@click.pass_context
def render(ctx, path, output, scale, size, device, as_json):
    """Render a .tpsv file to a PNG at any scale or size."""
    check_json_target(as_json, output)
    if scale is not None and size is not None:
        raise click.UsageError("--scale and --size cannot both be used")
    positive("--scale", scale)
    wh = parse_size(size)
    device = device_for(ctx, device)
    model = codec.load(path)
    _render_and_write(ctx, model, output, wh, scale or 1.0, device, as_json)


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PNG to write ('-': stdout).")
@click.option("--factor", type=float, required=True, help="Magnification factor.")
@vectorize_options
@click.option("--search/--no-search", default=False, show_default=True,
              help="For raster input: search the thresholds before magnifying.")
@device_option
@json_option
@click.pass_context
def magnify(ctx, path, output, factor, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing,
            search, device, as_json):
    """Magnify PATH (a .tpsv, or a raster photo that is vectorised first) by --factor."""
    check_json_target(as_json, output)
    positive("--factor", factor)
    device = device_for(ctx, device)
    extra = {}
    if is_tpsv(path):
        model = codec.load(path)
    else:
        _, result = run_vectorize(ctx, path, labels, seed, iterations, t_canny, t_super, kernel_size,
                                  smoothing, search, device)
        model = result.model
        extra = {"vectorize_seconds": result.seconds, "bytes": len(result.data)}
    _render_and_write(ctx, model, output, None, factor, device, as_json, extra)
