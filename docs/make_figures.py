"""Regenerate the pictures under docs/img with the tool itself.

Run from the repository root: ``.venv/bin/python docs/make_figures.py``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tpsv.image import read_image, write_image
from tpsv.render.raster import render
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
    rgb = read_image(ROOT / "samples" / "chelsea.png")
    crop = np.ascontiguousarray(rgb[90:186, 150:278])  # the left eye, 128x96
    result = vectorize(crop, search=True, iterations=8, seed=0)
    flat = render(result.model)
    big = render(result.model, scale=4)
    write_image(IMG / "hero.png", side_by_side([crop, flat, big], height=384))
    print(f"hero: {len(result.model.features)} features, {len(result.data)} bytes, PSNR {result.psnr:.2f} dB")


if __name__ == "__main__":
    IMG.mkdir(parents=True, exist_ok=True)
    hero()
