"""Quality and size figures: PSNR, SSIM, bpp and the paper's efficiency w = 1 / (E * C)."""

from __future__ import annotations

import numpy as np


def _as_float(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img.astype(np.float64) / 255.0
    return img.astype(np.float64)


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean squared error of RGB in ``[0, 1]`` over the whole image (the paper's E).

    Both images are quantised to 8 bits first, as a saved PNG would be.
    """
    qa = np.round(np.clip(_as_float(a), 0, 1) * 255.0) / 255.0
    qb = np.round(np.clip(_as_float(b), 0, 1) * 255.0) / 255.0
    if qa.shape != qb.shape:
        raise ValueError(f"shape mismatch {qa.shape} vs {qb.shape}")
    return float(np.mean((qa - qb) ** 2))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of 8-bit RGB over the whole image (inf for identical images)."""
    e = mse(a, b)
    return float("inf") if e == 0 else float(10.0 * np.log10(1.0 / e))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM over the RGB channels (scikit-image, data range 1)."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(_as_float(a), _as_float(b), channel_axis=2, data_range=1.0))


def bpp(nbytes: int, width: int, height: int) -> float:
    """Bits per pixel of a file of ``nbytes`` for a ``width x height`` image."""
    return 8.0 * nbytes / (width * height)


def efficiency(err: float, nbytes: int, width: int, height: int) -> float:
    """The paper's w = 1 / (E * C), with C = file bytes / (W * H * 3)."""
    c = nbytes / (width * height * 3.0)
    return float("inf") if err == 0 else 1.0 / (err * c)
