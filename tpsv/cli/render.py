"""``tpsv render`` and ``tpsv magnify``: pixels from a .tpsv at any size.

The image format is the output's extension's (``tpsv.image.output_format``):
PNG (8- or 16-bit), JPEG, WebP, TIFF (8- or 16-bit); ``-`` (stdout) is PNG
unless ``--format`` says otherwise. PNG is streamed band by band at any size;
JPEG, WebP and TIFF are encoded whole, so they are refused above
``tpsv.rendering.raster.MAX_ARRAY_PIXELS`` with a line pointing to PNG.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import click

from . import advance, main, progress_bar, say
from .options import (IMAGE_HELP, SCALE, SIZE, check_json_target, device_for, device_option, emit_json,
                      image_format, image_options, is_tpsv, json_option, output_option, scale_option)
from .outputs import claim_outputs, encode_model
from .. import codec
from ..encode.alpha import has_transparency
from ..errors import TpsvError
from ..image import OutputFormat, encode_image, read_image, read_labels
from ..png import png_chunks
from ..rendering.raster import (MAX_ARRAY_PIXELS, TILE_PIXELS, output_size, render as render_raster, render_bands,
                                render_png)


def render_file(model, width: int, height: int, fmt: OutputFormat = OutputFormat(), device: str = "cpu",
                antialias: bool = True, max_pixels: int | None = None):
    """The image file of ``model`` rendered at ``width x height`` in ``fmt``, piece by piece.

    PNG of more than ``max_pixels`` pixels is rendered in bands and streamed
    (8-bit: ``tpsv.rendering.raster.render_png``; 16-bit: the bands of
    ``render_bands(..., depth=16)``), so memory stays bounded at any
    size; smaller outputs and the other formats are encoded whole
    (``tpsv.image.encode_image``), the latter at most
    ``tpsv.rendering.raster.MAX_ARRAY_PIXELS`` pixels. A model with transparent
    regions gives RGBA (straight alpha) in PNG, WebP and TIFF, and is
    composited over white in a JPEG.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size (``tpsv.rendering.raster.output_size``).
    fmt : OutputFormat
        Default: 8-bit PNG.
    device : str
        Warp device.
    antialias : bool
        As ``tpsv.rendering.raster.render``.
    max_pixels : int, optional
        Pixels a band of a streamed PNG (default ``tpsv.rendering.raster.TILE_PIXELS``).

    Returns
    -------
    iterable of bytes
        Consecutive pieces of the file.

    Raises
    ------
    TpsvError
        A size the format cannot hold (checked before anything is rendered).
    """
    fmt.check_size(width, height)
    alpha = has_transparency(model)
    if fmt.name == "PNG" and fmt.depth == 8:
        bands = {} if max_pixels is None else {"max_pixels": max_pixels}
        return render_png(model, width, height, device=device, antialias=antialias, alpha=alpha, **bands)
    if fmt.name == "PNG":
        return _png16(model, width, height, device, antialias, TILE_PIXELS if max_pixels is None else max_pixels,
                      alpha)
    if width * height > MAX_ARRAY_PIXELS:
        raise TpsvError(f"a {width}x{height} px {fmt.name} is encoded whole, and tpsv holds at most "
                        f"{MAX_ARRAY_PIXELS:,} px in memory; write a PNG, which is streamed at any size")
    return _whole(model, width, height, fmt, device, antialias, alpha)


def _whole(model, W, H, fmt, device, antialias, alpha):
    yield encode_image(render_raster(model, W, H, device=device, antialias=antialias, alpha=alpha), fmt)


def _png16(model, W, H, device, antialias, max_pixels, alpha):
    """16-bit PNG pieces: one OpenCV encode when small, else the float bands streamed."""
    fmt = OutputFormat("PNG", 16)
    if W * H <= max_pixels:
        yield encode_image(render_raster(model, W, H, device=device, antialias=antialias, alpha=alpha), fmt)
        return
    bands = render_bands(model, W, H, device=device, max_pixels=max_pixels, antialias=antialias, alpha=alpha, depth=16)
    yield from png_chunks(W, H, bands, depth=16, channels=4 if alpha else 3)


def _render_image(out, model, output, size, scale, fmt, device, antialias: bool = True) -> dict:
    """Render ``model`` at ``size`` (W, H) or else at ``scale`` and stage the image; returns the summary.

    Large PNG outputs are rendered in bands and streamed into the staged file,
    so memory stays bounded at any size (:func:`render_file`).
    """
    t0 = time.perf_counter()
    w, h = size if size is not None else (None, None)
    W, H = output_size(model, w, h, None if size is not None else scale)
    out.write(output, render_file(model, W, H, fmt, device=device, antialias=antialias))
    seconds = time.perf_counter() - t0
    return {"width": W, "height": H, "seconds": seconds, "device": device}


def _magnify_file(ctx, out, model, output, factor, refine_iterations, fmt, device) -> dict:
    """``model`` magnified by ``factor`` and refined (:func:`magnify_model`), staged as ``output``; the
    summary. Without refinement steps it is rendered as ``tpsv render`` renders it (bands at any size)."""
    from ..rendering.magnify import magnify_model, refine_steps

    W, H = output_size(model, scale=factor)
    steps = refine_steps((model.width, model.height), (W, H), refine_iterations)
    if not steps:
        return _render_image(out, model, output, None, factor, fmt, device)
    t0 = time.perf_counter()
    fmt.check_size(W, H)
    with progress_bar(ctx, steps, "magnify") as bar:
        big = magnify_model(model, (W, H), device=device, refine_iterations=steps,
                            alpha=has_transparency(model), progress=advance(bar))
    out.write(output, encode_image(big, fmt))
    return {"width": W, "height": H, "seconds": time.perf_counter() - t0, "device": device}


def _report(ctx, output, info: dict, as_json: bool) -> None:
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {info['width']}x{info['height']} on {info['device']} in {info['seconds']:.3f} s")


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(f"Image to write: {IMAGE_HELP} ('-': stdout).")
@scale_option("Output scale (default 1).", default=None)
@click.option("--size", type=SIZE, default=None, help="Output size in pixels (instead of --scale).")
@click.option("--antialias/--no-antialias", default=True, show_default=True,
              help="Blend the pixels a region border crosses (off: one region per pixel, its centre's).")
@image_options()
@device_option
@json_option
@click.pass_context
def render(ctx, path, output, scale, size, antialias, format_name, quality, depth, device, as_json):
    """Render a .tpsv file to an image (PNG, JPEG, WebP, TIFF) at any scale or size."""
    check_json_target(as_json, output)
    if scale is not None and size is not None:
        raise click.UsageError("--scale and --size cannot both be used")
    with claim_outputs([path], ("-o", output)) as out:
        fmt = image_format(output, format_name, quality, depth)
        device = device_for(ctx, device)
        info = _render_image(out, codec.load(path), output, size, scale or 1.0, fmt, device, antialias)
    _report(ctx, output, info, as_json)


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(f"Image to write: {IMAGE_HELP} ('-': stdout).")
@click.option("--factor", type=SCALE, required=True, help="Magnification factor.")
@click.option("--labels", type=click.Path(dir_okay=False), default=None,
              help="For raster input: label map whose region borders stay sharp (default: one region; a "
                   "flat-colour graphic: its patches of one colour).")
@click.option("--fit-iterations", type=click.IntRange(0, 50), default=6, show_default=True,
              help="For raster input: back-projection steps fitting the colours to the input.")
@click.option("--refine-iterations", type=click.IntRange(0, 200), default=40, show_default=True,
              help="Steps sharpening the edges of the written picture while keeping its area average equal "
                   "to the input (a raster), or to the file's own render at its size (a .tpsv); least total "
                   "variation; 0: the render as it is.")
@click.option("--save-model", type=click.Path(dir_okay=False), default=None,
              help="For raster input: also write the fitted dense model as .tpsv (its render is the picture "
                   "before the refinement).")
@image_options()
@device_option
@json_option
@click.pass_context
def magnify(ctx, path, output, factor, labels, fit_iterations, refine_iterations, save_model, format_name, quality,
            depth, device, as_json):
    """Magnify PATH by --factor.

    PATH is a .tpsv: rendered at the scale, then its edges sharpened while its
    area average stays the file's own render at its size. Or a raster photo:
    every pixel becomes a colour feature, the colours are fitted so that the
    magnified render, area-averaged back, reproduces the photo, and the
    render's edges are sharpened under the same constraint
    (tpsv.rendering.magnify, .refine). `tpsv render` draws a .tpsv as it is.
    """
    # (the dense fit's modules, imported here: `tpsv render` needs none of them)
    from ..rendering.magnify import magnify_raster, picture_kind, refine_steps

    check_json_target(as_json, output)
    if is_tpsv(path):
        if labels or save_model:
            raise click.UsageError("--labels and --save-model apply to raster input only")
        with claim_outputs([path], ("-o", output)) as out:
            fmt = image_format(output, format_name, quality, depth)
            device = device_for(ctx, device)
            info = _magnify_file(ctx, out, codec.load(path), output, factor, refine_iterations, fmt, device)
        _report(ctx, output, info, as_json)
        return
    t0 = time.perf_counter()
    with claim_outputs([path, labels], ("-o", output), ("--save-model", save_model)) as out:
        fmt = image_format(output, format_name, quality, depth)
        device = device_for(ctx, device)
        rgb = read_image(path)
        lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
        h, w = rgb.shape[:2]
        size = (max(1, round(w * factor)), max(1, round(h * factor)))
        # the renderer's size limits, checked before the fit rather than at its final render
        output_size(SimpleNamespace(width=w, height=h), width=size[0], height=size[1])
        fmt.check_size(*size)
        # a flat-colour graphic is drawn by fitted outlines (without a label map, of its own patches), unrefined
        graphic, flat = picture_kind(rgb)
        lab = flat if lab is None else lab
        steps = refine_steps((w, h), size, refine_iterations, graphic)
        with progress_bar(ctx, fit_iterations + steps, "magnify") as bar:
            model, big = magnify_raster(rgb, size, labels=lab, iterations=fit_iterations, device=device,
                                        progress=advance(bar), refine_iterations=refine_iterations, graphic=graphic)
        seconds = time.perf_counter() - t0
        if save_model:
            out.write(save_model, encode_model(model))
        out.write(output, encode_image(big, fmt))
    info = {"width": size[0], "height": size[1], "seconds": seconds, "device": device,
            "features": len(model.features), "regions": len(model.regions)}
    if as_json:
        emit_json(info)
    else:
        say(ctx, f"{output}: {size[0]}x{size[1]} from {w}x{h} ({info['features']} features) in {seconds:.2f} s")
