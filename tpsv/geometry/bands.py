"""Per-pixel work on a whole image, band of rows by band of rows.

A per-pixel formula in float64 over a whole photo makes several temporaries
of 24 bytes a pixel (``tpsv.color.srgb_to_lab`` holds about 150 bytes a pixel
at its peak); run over bands of :data:`BAND_PIXELS` pixels, the same formula
gives the same values with temporaries of a few megabytes.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from ..color import srgb_to_lab
from ..threads import map_ordered

#: Pixels per band (whole rows; at least one row).
BAND_PIXELS = 1 << 16
#: Most host threads :func:`for_bands` runs bands on (each holds a band's temporaries).
BAND_THREADS = 8


def row_bands(height: int, width: int, pixels: int = BAND_PIXELS) -> Iterator[tuple[int, int]]:
    """``(a, b)`` row ranges covering ``0 .. height``, each about ``pixels`` pixels (one row at least).

    Parameters
    ----------
    height, width : int
        Image size.
    pixels : int
        Pixels per band.

    Yields
    ------
    (int, int)
        Rows ``a <= y < b``.
    """
    rows = max(1, int(pixels) // max(int(width), 1))
    for a in range(0, int(height), rows):
        yield a, min(a + rows, int(height))


def lab_image(rgb: np.ndarray, clip: bool = False) -> np.ndarray:
    """``tpsv.color.srgb_to_lab`` of an (H, W, 3) image, computed in bands of rows (the same values).

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float
        sRGB in ``[0, 1]``.
    clip : bool
        Clip to ``[0, 1]`` first (as ``srgb_to_lab(np.clip(rgb, 0, 1))``).

    Returns
    -------
    ndarray (H, W, 3) float32
    """
    h, w = rgb.shape[:2]
    out = np.empty((h, w, 3), np.float32)

    def band(rows: tuple[int, int]) -> None:
        a, b = rows
        out[a:b] = srgb_to_lab(np.clip(rgb[a:b], 0, 1) if clip else rgb[a:b])

    for_bands(band, h, w)
    return out


def map_bands(fn, height: int, width: int, pixels: int = BAND_PIXELS) -> list:
    """What ``fn((a, b))`` returns for every band of :func:`row_bands`, in band order, the calls
    made on up to :data:`BAND_THREADS` host threads (:func:`tpsv.threads.map_ordered`: each band's
    values are what one thread computes)."""
    return map_ordered("bands", fn, row_bands(height, width, pixels), BAND_THREADS)


def for_bands(fn, height: int, width: int, pixels: int = BAND_PIXELS) -> None:
    """``fn((a, b))`` for every band of :func:`row_bands`, on a few host threads (:func:`map_bands`)."""
    map_bands(fn, height, width, pixels)


__all__ = ["BAND_PIXELS", "BAND_THREADS", "for_bands", "lab_image", "map_bands", "row_bands"]
