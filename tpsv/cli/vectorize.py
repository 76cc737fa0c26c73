"""``tpsv vectorize``: raster photo -> .tpsv."""

from __future__ import annotations

import click

from . import main, progress_bar, say
from .options import (FINITE_NON_NEGATIVE, KERNEL_SIZE, SEED, check_json_target, device_for, device_option,
                      emit_json, json_option, output_option)
from .outputs import claim_outputs
from .. import metrics
from ..encode.vectorize import scheme_params, vectorize as vectorize_image
from ..image import encode_png, read_image, read_labels
from ..model import CURVILINEAR, Params
from ..render.preview import draw_preview


def vectorize_options(f):
    """The encoder's options of ``vectorize``: labels, seed, search and model parameters."""
    opts = [
        click.option("--labels", type=click.Path(dir_okay=False), default=None,
                     help="Label map PNG (one integer per pixel); segmented automatically if absent."),
        click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of segmentation and search."),
        click.option("--iterations", type=click.IntRange(1, 1000), default=20, show_default=True,
                     help="N_total of the Monte Carlo threshold search (--no-search: none)."),
        click.option("--canny", "t_canny", type=FINITE_NON_NEGATIVE, default=None,
                     help="Fix T_canny (0-255 gradient scale)."),
        click.option("--super", "t_super", type=FINITE_NON_NEGATIVE, default=None,
                     help="Fix T_super (Lab variance)."),
        click.option("--kernel-size", type=KERNEL_SIZE, default=None,
                     help="Features per TPS kernel (K) [default: 32; 64 with --plain]."),
        click.option("--smoothing", type=FINITE_NON_NEGATIVE, default=Params.smoothing, show_default=True,
                     help="TPS smoothing term (0: exact interpolation)."),
        click.option("--outlines", type=click.Choice(["fitted", "traced"]), default="fitted", show_default=True,
                     help="Region borders fitted to the image's edges at sub-pixel precision (crisp when "
                          "magnified), or traced along the label map's pixels (smaller files)."),
        click.option("--plain", is_flag=True, default=False,
                     help="The paper's plain scheme: pairs on every Canny pixel, superpixel-boundary gradation "
                          "features, sampled colours, finest quantisation (default: compact lattice features "
                          "with fitted colours)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing, search, device,
                  plain=False, outlines="fitted"):
    """Read the inputs and vectorise, with a progress bar for the search on a terminal."""
    rgb = read_image(image)
    lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
    params = scheme_params("paper" if plain else "tpsv", kernel_size=kernel_size, smoothing=smoothing)
    with progress_bar(ctx, iterations, "search", enabled=search) as bar:

        def progress(done, total):
            if bar is not None:
                bar.update(done - bar.pos)

        result = vectorize_image(
            rgb, lab, t_canny=t_canny, t_super=t_super, search=search, iterations=iterations,
            seed=seed, params=params, device=device, progress=progress, outlines=outlines,
        )
    return rgb, result


def summary(rgb, result) -> dict:
    """The JSON summary of a vectorisation: size, counts, bytes, quality, thresholds, time."""
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
def vectorize(ctx, image, output, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing, outlines, plain,
              search, preview, device, as_json):
    """Vectorise IMAGE into a .tpsv hybrid vector image."""
    check_json_target(as_json, output)
    with claim_outputs([image, labels], ("-o", output), ("--preview", preview)) as out:
        device = device_for(ctx, device)
        rgb, result = run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size,
                                    smoothing, search, device, plain=plain, outlines=outlines)
        out.write(output, result.data)
        if preview:
            out.write(preview, encode_png(draw_preview(rgb, result.model)))
    s = summary(rgb, result)
    if as_json:
        emit_json(s)
    else:
        say(ctx, f"{output}: {s['regions']} regions, {s['features']} features, {s['bytes']} bytes "
                 f"({s['bpp']:.2f} bpp), PSNR {s['psnr']:.2f} dB, {s['seconds']:.1f} s")
