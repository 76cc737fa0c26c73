"""Raster baselines the benchmark compares against: JPEG (OpenCV), bicubic, Lanczos."""

from __future__ import annotations

import cv2
import numpy as np


def _bgr8(rgb: np.ndarray) -> np.ndarray:
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(rgb[:, :, ::-1])


def jpeg(rgb: np.ndarray, quality: int) -> tuple[int, np.ndarray]:
    """Encode with OpenCV's JPEG at ``quality``; return (bytes, decoded RGB float32)."""
    ok, buf = cv2.imencode(".jpg", _bgr8(rgb), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].astype(np.float32) / 255.0
    return int(buf.size), dec


def jpeg_at_bytes(rgb: np.ndarray, target_bytes: int) -> tuple[int, int, np.ndarray]:
    """JPEG at the highest quality whose file is not larger than ``target_bytes``.

    When even quality 1 is larger, quality 1 is returned.

    Returns
    -------
    quality, nbytes, decoded
    """
    lo, hi = 1, 100
    best = (1, *jpeg(rgb, 1))
    while lo <= hi:
        q = (lo + hi) // 2
        n, dec = jpeg(rgb, q)
        if n <= target_bytes:
            best = (q, n, dec)
            lo = q + 1
        else:
            hi = q - 1
    return best


def upscale(rgb: np.ndarray, factor: float, method: str) -> np.ndarray:
    """Upscale with OpenCV ``bicubic`` or ``lanczos`` interpolation (float32 RGB in [0,1])."""
    interp = {"bicubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4}[method]
    h, w = rgb.shape[:2]
    out = cv2.resize(rgb.astype(np.float32), (round(w * factor), round(h * factor)), interpolation=interp)
    return np.clip(out, 0.0, 1.0)


def downscale_area(rgb: np.ndarray, factor: int) -> np.ndarray:
    """Area-average downscale by an integer factor (the magnification benchmark's input)."""
    h, w = rgb.shape[:2]
    return cv2.resize(rgb.astype(np.float32), (w // factor, h // factor), interpolation=cv2.INTER_AREA)
