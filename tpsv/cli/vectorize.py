"""``tpsv vectorize``: raster photo -> .tpsv."""

from __future__ import annotations

import click

from . import main, progress_enabled, say
from .options import check_json_target, device_for, device_option, emit_json, json_option, output_option
from .. import metrics
from ..fileio import write_bytes_atomic
from ..image import read_image, read_labels, write_image
from ..model import CURVILINEAR, Params


def vectorize_options(f):
    """Options shared by ``vectorize`` and ``magnify`` (for raster input)."""
    opts = [
        click.option("--labels", type=click.Path(dir_okay=False), default=None,
                     help="Label map PNG (one integer per pixel); segmented automatically if absent."),
        click.option("--seed", type=int, default=0, show_default=True, help="Seed of segmentation and search."),
        click.option("--iterations", type=click.IntRange(0, 1000), default=20, show_default=True,
                     help="N_total of the Monte Carlo threshold search."),
        click.option("--canny", "t_canny", type=float, default=None, help="Fix T_canny (0-255 gradient scale)."),
        click.option("--super", "t_super", type=float, default=None, help="Fix T_super (Lab variance)."),
        click.option("--kernel-size", type=click.IntRange(8, 128), default=None,
                     help="Features per TPS kernel (K) [default: 32; 64 with --plain]."),
        click.option("--smoothing", type=click.FloatRange(0.0), default=Params.smoothing, show_default=True,
                     help="TPS smoothing term (0: exact interpolation)."),
        click.option("--plain", is_flag=True, default=False,
                     help="The paper's plain scheme: pairs on every Canny pixel, superpixel-boundary gradation "
                          "features, sampled colours, finest quantisation (default: compact lattice features "
                          "with fitted colours)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing, search, device,
                  plain=False):
    """Read inputs and vectorise; shared by ``vectorize`` and ``magnify``."""
    from ..encode.vectorize import scheme_params, vectorize as vectorize_image

    rgb = read_image(image)
    lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
    params = scheme_params("paper" if plain else "tpsv", kernel_size=kernel_size, smoothing=smoothing)
    bar = None
    if search and progress_enabled(ctx):
        bar = click.progressbar(length=iterations, label="search", file=click.get_text_stream("stderr"))
        bar.__enter__()

    def progress(done, total):
        if bar is not None:
            bar.update(done - bar.pos)

    try:
        result = vectorize_image(
            rgb, lab, t_canny=t_canny, t_super=t_super, search=search, iterations=iterations,
            seed=seed, params=params, device=device, progress=progress,
        )
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    return rgb, result


def summary(rgb, result) -> dict:
    m = result.model
    h, w = rgb.shape[:2]
    n = len(result.data)
    return {
        "width": w,
        "height": h,
        "regions": len(m.regions),
        "features": len(m.features),
        "curvilinear": int((m.features.kind == CURVILINEAR).sum()),
        "bytes": n,
        "bpp": metrics.bpp(n, w, h),
        "psnr": result.psnr,
        "w": metrics.efficiency(result.mse, n, w, h),
        "t_canny": m.params.t_canny,
        "t_super": m.params.t_super,
        "scheme": m.params.extra.get("scheme", "tpsv"),
        "seconds": result.seconds,
    }


@main.command()
@click.argument("image", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout).")
@vectorize_options
@click.option("--search/--no-search", default=True, show_default=True,
              help="Search the thresholds (else keep the gradient-histogram initial guess).")
@click.option("--preview", type=click.Path(dir_okay=False), default=None,
              help="Write patches and features over the photo (like the paper's Fig. 1).")
@device_option
@json_option
@click.pass_context
def vectorize(ctx, image, output, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing, plain,
              search, preview, device, as_json):
    """Vectorise IMAGE into a .tpsv hybrid vector image."""
    check_json_target(as_json, output)
    device = device_for(ctx, device)
    rgb, result = run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size,
                                smoothing, search, device, plain=plain)
    write_bytes_atomic(output, result.data)
    if preview:
        from ..render.preview import draw_preview

        write_image(preview, draw_preview(rgb, result.model))
    s = summary(rgb, result)
    if as_json:
        emit_json(s)
    else:
        say(ctx, f"{output}: {s['regions']} regions, {s['features']} features, {s['bytes']} bytes "
                 f"({s['bpp']:.2f} bpp), PSNR {s['psnr']:.2f} dB, {s['seconds']:.1f} s")
