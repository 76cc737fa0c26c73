"""Regenerate the pictures under docs/img with the tool itself.

Run from the repository root: ``.venv/bin/python docs/make_figures.py``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tpsv.image import read_image, write_image
from tpsv.rendering.raster import render
from tpsv.encode.rate import DEFAULT_QUALITY, encode_quality
from tpsv.encode.vectorize import vectorize

ROOT = Path(__file__).resolve().parent.parent
IMG = ROOT / "docs" / "img"


def side_by_side(images: list[np.ndarray], height: int, gap: int = 6) -> np.ndarray:
    """Images scaled (nearest neighbour, so pixels stay visible) to one height, with white gaps."""
    tiles = []
    for im in images:
        h, w = im.shape[:2]
        tiles.append(cv2.resize(im, (round(w * height / h), height), interpolation=cv2.INTER_NEAREST))
        tiles.append(np.ones((height, gap, 3), np.float32))
    return np.concatenate(tiles[:-1], axis=1)


def hero() -> None:
    """Input crop, its .tpsv at the default quality at scale 1 and at 4x."""
    rgb = read_image(ROOT / "samples" / "chelsea.png")
    crop = np.ascontiguousarray(rgb[90:186, 150:278])  # the left eye, 128x96
    result = encode_quality(crop)
    flat = render(result.model)
    big = render(result.model, scale=4)
    write_image(IMG / "hero.png", side_by_side([crop, flat, big], height=384))
    print(f"hero: quality {result.quality}, {len(result.data)} bytes "
          f"({8 * len(result.data) / crop.shape[0] / crop.shape[1]:.2f} bpp), PSNR {result.psnr:.2f} dB")


def detail() -> None:
    """chelsea: input, the pure vector image of the paper's search, the default quality; 1x and a 4x crop."""
    from tpsv.image import read_labels

    rgb = read_image(ROOT / "samples" / "chelsea.png")
    lab = read_labels(ROOT / "samples" / "chelsea-labels.png")
    searched = vectorize(rgb, lab, iterations=20, seed=0)
    default = encode_quality(rgb, lab)
    rows = []
    y0, x0, h, w = 60, 120, 60, 100  # the left eye
    for im in (rgb, render(searched.model), render(default.model)):
        rows.append(im)
    crops = [cv2.resize(rgb[y0:y0 + h, x0:x0 + w], (4 * w, 4 * h), interpolation=cv2.INTER_CUBIC),
             render(searched.model, scale=4)[4 * y0:4 * (y0 + h), 4 * x0:4 * (x0 + w)],
             render(default.model, scale=4)[4 * y0:4 * (y0 + h), 4 * x0:4 * (x0 + w)]]
    write_image(IMG / "detail.png", side_by_side(rows, height=300))
    write_image(IMG / "detail-4x.png", side_by_side(crops, height=240))
    px = rgb.shape[0] * rgb.shape[1]
    print(f"detail: search {len(searched.data)} B ({8 * len(searched.data) / px:.2f} bpp) {searched.psnr:.2f} dB; "
          f"quality {DEFAULT_QUALITY} {len(default.data)} B ({8 * len(default.data) / px:.2f} bpp) {default.psnr:.2f} dB")


def vector_ladder() -> None:
    """astronaut's face, 4x: bicubic of the pixels, the pure vector image at quality 60 (4 px lattices)
    and at quality 85 (2 px lattices)."""
    from tpsv.image import read_labels

    rgb = read_image(ROOT / "samples" / "astronaut.png")
    lab = read_labels(ROOT / "samples" / "astronaut-labels.png")
    y0, x0, h, w = 60, 190, 90, 82
    crops = [cv2.resize(rgb[y0:y0 + h, x0:x0 + w], (4 * w, 4 * h), interpolation=cv2.INTER_CUBIC)]
    notes = []
    for q in (60, 85):
        result = encode_quality(rgb, lab, quality=q, detail=False)
        crops.append(render(result.model, scale=4)[4 * y0:4 * (y0 + h), 4 * x0:4 * (x0 + w)])
        notes.append(f"quality {q} {len(result.data)} B ({8 * len(result.data) / rgb.shape[0] / rgb.shape[1]:.2f} bpp) "
                     f"{result.psnr:.2f} dB")
    write_image(IMG / "vector-4x.png", side_by_side(crops, height=360))
    print("vector-4x: --no-detail " + "; ".join(notes))


def edges() -> None:
    """8x crops: a synthetic shape's border (analytic, Lanczos, tpsv) and a photo's region border."""
    from tpsv import metrics
    from tpsv.bench import baseline
    from tpsv.bench.shapes import shapes
    from tpsv.image import read_labels

    rgb, labels = shapes(96, 1, 0)
    rgb = np.round(rgb * 255.0).astype(np.float32) / 255.0
    ref, _ = shapes(96, 8, 0)
    model = vectorize(rgb, labels, iterations=20, seed=0).model
    out = render(model, scale=8)
    lz = baseline.upscale(rgb, 8, "lanczos")
    y, x = 150, 150
    crops = [im[y:y + 200, x:x + 200] for im in (ref, lz, out)]
    write_image(IMG / "edges-shape-8x.png", side_by_side(crops, height=300))
    print(f"edges-shape-8x: tpsv {metrics.psnr(ref, out):.2f} dB, Lanczos {metrics.psnr(ref, lz):.2f} dB")

    photo = read_image(ROOT / "samples" / "chelsea.png")
    lab = read_labels(ROOT / "samples" / "chelsea-labels.png")
    model = vectorize(photo, lab, iterations=8, seed=0).model
    y0, x0, h, w = 127, 263, 32, 40  # where a region border follows a strong edge
    big = render(model, scale=8)[8 * y0:8 * (y0 + h), 8 * x0:8 * (x0 + w)]
    bic = baseline.upscale(np.ascontiguousarray(photo[y0:y0 + h, x0:x0 + w]), 8, "bicubic")
    write_image(IMG / "edges-photo-8x.png", side_by_side([photo[y0:y0 + h, x0:x0 + w], bic, big], height=256))


def soft_edges() -> None:
    """8x around chelsea's eye: bicubic, every border sharp, the fitted edge widths."""
    import dataclasses

    from tpsv.bench import baseline
    from tpsv.image import read_labels

    photo = read_image(ROOT / "samples" / "chelsea.png")
    lab = read_labels(ROOT / "samples" / "chelsea-labels.png")
    model = vectorize(photo, lab, iterations=8, seed=0).model
    y0, x0, h, w = 60, 150, 60, 60
    crop = (slice(8 * y0, 8 * (y0 + h)), slice(8 * x0, 8 * (x0 + w)))
    soft = render(model, scale=8)[crop]
    sharp = render(dataclasses.replace(model, blur=np.zeros((0, 3))), scale=8)[crop]
    bic = baseline.upscale(np.ascontiguousarray(photo[y0:y0 + h, x0:x0 + w]), 8, "bicubic")
    write_image(IMG / "edges-soft-8x.png", side_by_side([bic, sharp, soft], height=300))
    print("edges-soft-8x: edge widths", model.blur[:, 2].tolist())


def magnify() -> None:
    """chelsea area-downscaled 4x, magnified 8x around the eye: bicubic, the dense TPS fit, refined."""
    from tpsv import metrics
    from tpsv.bench import baseline
    from tpsv.rendering.magnify import magnify_raster
    from tpsv.rendering.refine import refine_magnified

    photo = read_image(ROOT / "samples" / "chelsea.png")[:296, :448]
    small = baseline.downscale_area(photo, 4)
    size = (8 * small.shape[1], 8 * small.shape[0])
    _, fit = magnify_raster(small, size, refine_iterations=0)
    sharp = refine_magnified(fit, small)
    bic = baseline.upscale(small, 8, "bicubic")
    y0, x0, h, w = 200, 560, 300, 300
    crops = [im[y0:y0 + h, x0:x0 + w] for im in (bic, fit, sharp)]
    write_image(IMG / "magnify-8x.png", side_by_side(crops, height=300))
    truth = cv2.resize(photo, size, interpolation=cv2.INTER_CUBIC)
    print("magnify-8x: PSNR against the photo at 2x, bicubic / fit / refined",
          [round(metrics.psnr(truth, im), 2) for im in (bic, fit, sharp)])


if __name__ == "__main__":
    IMG.mkdir(parents=True, exist_ok=True)
    hero()
    detail()
    vector_ladder()
    edges()
    soft_edges()
    magnify()
