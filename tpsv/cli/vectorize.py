"""``tpsv vectorize``: raster photo -> .tpsv."""

from __future__ import annotations

import click

from . import advance, main, progress_bar, say
from .options import (FINITE_NON_NEGATIVE, IMAGE_HELP, KERNEL_SIZE, SEED, check_json_target, device_for,
                      device_option, emit_json, image_format, json_option, output_option)
from .outputs import claim_outputs
from .. import codec, metrics
from ..encode.rate import DEFAULT_QUALITY, encode_quality, progress_steps
from ..encode.vectorize import scheme_params, vectorize as vectorize_image
from ..errors import TpsvError
from ..image import encode_image, read_image_alpha, read_labels
from ..model import CURVILINEAR, Params
from ..rendering.preview import draw_preview


def vectorize_options(f):
    """The encoder's options of ``vectorize``: labels, seed, search and model parameters."""
    opts = [
        click.option("--labels", type=click.Path(dir_okay=False), default=None,
                     help="Label map PNG (one integer per pixel); segmented automatically if absent."),
        click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of segmentation and search."),
        click.option("--quality", "-q", type=click.IntRange(1, 100), default=None,
                     help=f"Quality 1-100, like JPEG's: bytes and PSNR rise with it [default: {DEFAULT_QUALITY}].",
                     ),
        click.option("--target-psnr", type=FINITE_NON_NEGATIVE, default=None,
                     help="The lowest quality whose PSNR reaches this (dB); the highest when none does."),
        click.option("--max-bytes", type=click.IntRange(1, None), default=None,
                     help="The highest quality whose file fits in this many bytes."),
        click.option("--detail/--no-detail", default=True, show_default=True,
                     help="Texture detail layer over the vector image (--no-detail: the pure vector image, "
                          "quality sets its features)."),
        click.option("--search/--no-search", default=None,
                     help="Instead of a quality: the paper's Monte Carlo search of the thresholds for the best "
                          "efficiency w (--no-search: keep their gradient-histogram guess). Pure vector."),
        click.option("--iterations", type=click.IntRange(1, 1000), default=20, show_default=True,
                     help="N_total of the Monte Carlo threshold search (--search)."),
        click.option("--canny", "t_canny", type=FINITE_NON_NEGATIVE, default=None,
                     help="Fix T_canny (0-255 gradient scale; a threshold mode like --search)."),
        click.option("--super", "t_super", type=FINITE_NON_NEGATIVE, default=None,
                     help="Fix T_super (Lab variance; a threshold mode like --search)."),
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
                          "with fitted colours); a threshold mode like --search."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def threshold_mode(search, t_canny, t_super, plain) -> bool:
    """Whether the options ask for the paper's threshold modes rather than a quality."""
    return search is not None or t_canny is not None or t_super is not None or plain


def run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size, smoothing, search, device,
                  plain=False, outlines="fitted", quality=None, target_psnr=None, max_bytes=None, detail=True):
    """Read the inputs and vectorise: at a quality (default), or by the paper's threshold modes."""
    rated = (quality, target_psnr, max_bytes)
    if sum(v is not None for v in rated) > 1:
        raise TpsvError("give one of --quality, --target-psnr and --max-bytes")
    thresholds = threshold_mode(search, t_canny, t_super, plain)
    if thresholds and any(v is not None for v in rated):
        raise TpsvError("--quality, --target-psnr and --max-bytes choose a quality; they do not go with "
                        "--search, --no-search, --canny, --super or --plain")
    rgb, alpha = read_image_alpha(image)  # a transparent part becomes transparent regions
    lab = read_labels(labels, shape=rgb.shape[:2]) if labels else None
    params = scheme_params("paper" if plain else "tpsv", kernel_size=kernel_size, smoothing=smoothing)
    if not thresholds:
        with progress_bar(ctx, progress_steps(target_psnr, max_bytes), "vectorize") as bar:
            return rgb, encode_quality(rgb, lab, quality=quality, target_psnr=target_psnr, max_bytes=max_bytes,
                                       detail=detail, seed=seed, params=params, device=device, outlines=outlines,
                                       alpha=alpha, progress=advance(bar))
    search = True if search is None else search
    with progress_bar(ctx, iterations, "search", enabled=search) as bar:
        result = vectorize_image(
            rgb, lab, t_canny=t_canny, t_super=t_super, search=search, iterations=iterations,
            seed=seed, params=params, device=device, progress=advance(bar), outlines=outlines, alpha=alpha,
        )
    return rgb, result


def summary(rgb, result) -> dict:
    """The JSON summary of a vectorisation: size, counts, bytes, quality, thresholds, time."""
    m = result.model
    h, w = rgb.shape[:2]
    n = len(result.data)
    detail = m.detail
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
        "quality": result.quality,
        "reached": result.reached,
        "detail_bytes": codec.section_sizes(result.data).get("detail", 0),
        "detail_quality": None if detail is None else detail.quality,
        "seconds": result.seconds,
    }


@main.command()
@click.argument("image", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout).")
@vectorize_options
@click.option("--preview", type=click.Path(dir_okay=False), default=None,
              help=f"Write patches and features over the photo (like the paper's Fig. 1): {IMAGE_HELP}.")
@device_option
@json_option
@click.pass_context
def vectorize(ctx, image, output, labels, seed, quality, target_psnr, max_bytes, detail, search, iterations, t_canny,
              t_super, kernel_size, smoothing, outlines, plain, preview, device, as_json):
    """Vectorise IMAGE into a .tpsv hybrid vector image.

    By default at a quality (--quality, --target-psnr or --max-bytes): a vector
    image plus a texture detail layer. --search, --no-search, --canny, --super
    and --plain select the paper's threshold modes instead (pure vector).
    """
    check_json_target(as_json, output)
    with claim_outputs([image, labels], ("-o", output), ("--preview", preview)) as out:
        preview_format = image_format(preview, option="--preview")  # JPEG and WebP at tpsv.image.OUTPUT_QUALITY
        device = device_for(ctx, device)
        rgb, result = run_vectorize(ctx, image, labels, seed, iterations, t_canny, t_super, kernel_size,
                                    smoothing, search, device, plain=plain, outlines=outlines, quality=quality,
                                    target_psnr=target_psnr, max_bytes=max_bytes, detail=detail)
        out.write(output, result.data)
        if preview:
            out.write(preview, encode_image(draw_preview(rgb, result.model), preview_format))
    s = summary(rgb, result)
    if as_json:
        emit_json(s)
    else:
        q = "" if s["quality"] is None else f"quality {s['quality']}, "
        d = f" ({s['detail_bytes']} detail)" if s["detail_bytes"] else ""
        say(ctx, f"{output}: {q}{s['regions']} regions, {s['features']} features, {s['bytes']} bytes{d} "
                 f"({s['bpp']:.2f} bpp), PSNR {s['psnr']:.2f} dB, {s['seconds']:.1f} s")
        if not s["reached"]:
            say(ctx, f"target PSNR {target_psnr} dB not reached: the highest quality gives {s['psnr']:.2f} dB")
