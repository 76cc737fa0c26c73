"""``tpsv render`` and ``tpsv magnify``: pixels from a .tpsv at any size."""

from __future__ import annotations

import time

import click

from . import main, say
from .options import (check_json_target, device_for, device_option, emit_json, is_tpsv, json_option,
                      output_option, parse_size, positive)
from .. import codec
from ..errors import TpsvError
from ..image import write_image


def _render_and_write(ctx, model, output, size, scale, device, as_json, extra=None):
    from ..render.raster import render

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
@click.option("--labels", type=click.Path(dir_okay=False), default=None,
              help="For raster input: label map whose region borders stay sharp (default: one region).")
@click.option("--fit-iterations", type=click.IntRange(0, 50), default=6, show_default=True,
              help="For raster input: back-projection steps fitting the colours to the input.")
@click.option("--save-model", type=click.Path(dir_okay=False), default=None,
              help="For raster input: also write the fitted dense model as .tpsv.")
@device_option
@json_option
@click.pass_context
def magnify(ctx, path, output, factor, labels, fit_iterations, save_model, device, as_json):
    """Magnify PATH by --factor.

    PATH is a .tpsv (rendered at the scale), or a raster photo: then every pixel
    becomes a colour feature, the colours are fitted so that the magnified
    render, area-averaged back, reproduces the photo, and the result is
    rendered (tpsv.render.magnify).
    """
    check_json_target(as_json, output)
    positive("--factor", factor)
    device = device_for(ctx, device)
    if is_tpsv(path):
        if labels or save_model:
            raise click.UsageError("--labels and --save-model apply to raster input only")
        model = codec.load(path)
        _render_and_write(ctx, model, output, None, factor, device, as_json)
        return
    from ..image import read_image, read_labels
    from ..render.magnify import magnify_raster
    from ..render.raster import MAX_PIXELS, MAX_SIDE

    t0 = time.perf_counter()
    rgb = read_image(path)
    lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
    h, w = rgb.shape[:2]
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    if max(size) > MAX_SIDE or size[0] * size[1] > MAX_PIXELS:
        raise TpsvError(f"output size {size[0]}x{size[1]} is too large (at most {MAX_SIDE} px per side)")
    model, big = magnify_raster(rgb, size, labels=lab, iterations=fit_iterations, device=device)
    seconds = time.perf_counter() - t0
    if save_model:
        codec.save(model, save_model)
    write_image(output, big)
    info = {"width": size[0], "height": size[1], "seconds": seconds, "device": device,
            "features": len(model.features), "regions": len(model.regions)}
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {size[0]}x{size[1]} from {w}x{h} ({info['features']} features) in {seconds:.2f} s")
