"""``tpsv render`` and ``tpsv magnify``: pixels from a .tpsv at any size."""

from __future__ import annotations

import time
from types import SimpleNamespace

import click

from . import main, say
from .options import (SCALE, SIZE, check_json_target, device_for, device_option, emit_json, is_tpsv, json_option,
                      output_option, scale_option)
from .outputs import claim_outputs, encode_model
from .. import codec
from ..image import encode_png, read_image, read_labels
from ..render.magnify import magnify_raster
from ..render.raster import output_size, render_png


def _render_png(out, model, output, size, scale, device, antialias: bool = True) -> dict:
    """Render ``model`` at ``size`` (W, H) or else at ``scale`` and stage the PNG; returns the summary.

    Large outputs are rendered in bands and streamed into the staged file, so
    memory stays bounded at any size (``tpsv.render.raster.render_png``).
    """
    t0 = time.perf_counter()
    w, h = size if size is not None else (None, None)
    W, H = output_size(model, w, h, None if size is not None else scale)
    out.write(output, render_png(model, W, H, device=device, antialias=antialias))
    seconds = time.perf_counter() - t0
    return {"width": W, "height": H, "seconds": seconds, "device": device}


def _report(ctx, output, info: dict, as_json: bool) -> None:
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {info['width']}x{info['height']} on {info['device']} in {info['seconds']:.3f} s")


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PNG to write ('-': stdout).")
@scale_option("Output scale (default 1).", default=None)
@click.option("--size", type=SIZE, default=None, help="Output size in pixels (instead of --scale).")
@click.option("--antialias/--no-antialias", default=True, show_default=True,
              help="Blend the pixels a region border crosses (off: one region per pixel, its centre's).")
@device_option
@json_option
@click.pass_context
def render(ctx, path, output, scale, size, antialias, device, as_json):
    """Render a .tpsv file to a PNG at any scale or size."""
    check_json_target(as_json, output)
    if scale is not None and size is not None:
        raise click.UsageError("--scale and --size cannot both be used")
    with claim_outputs([path], ("-o", output)) as out:
        device = device_for(ctx, device)
        info = _render_png(out, codec.load(path), output, size, scale or 1.0, device, antialias)
    _report(ctx, output, info, as_json)


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PNG to write ('-': stdout).")
@click.option("--factor", type=SCALE, required=True, help="Magnification factor.")
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
    if is_tpsv(path):
        if labels or save_model:
            raise click.UsageError("--labels and --save-model apply to raster input only")
        with claim_outputs([path], ("-o", output)) as out:
            device = device_for(ctx, device)
            info = _render_png(out, codec.load(path), output, None, factor, device)
        _report(ctx, output, info, as_json)
        return
    t0 = time.perf_counter()
    with claim_outputs([path, labels], ("-o", output), ("--save-model", save_model)) as out:
        device = device_for(ctx, device)
        rgb = read_image(path)
        lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
        h, w = rgb.shape[:2]
        size = (max(1, round(w * factor)), max(1, round(h * factor)))
        # the renderer's size limits, checked before the fit rather than at its final render
        output_size(SimpleNamespace(width=w, height=h), width=size[0], height=size[1])
        model, big = magnify_raster(rgb, size, labels=lab, iterations=fit_iterations, device=device)
        seconds = time.perf_counter() - t0
        if save_model:
            out.write(save_model, encode_model(model))
        out.write(output, encode_png(big))
    info = {"width": size[0], "height": size[1], "seconds": seconds, "device": device,
            "features": len(model.features), "regions": len(model.regions)}
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {size[0]}x{size[1]} from {w}x{h} ({info['features']} features) in {seconds:.2f} s")
