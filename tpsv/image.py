"""Reading and writing raster images and label maps, with clear errors."""

from __future__ import annotations

import os

import cv2
import numpy as np

from .errors import TpsvError
from .fileio import read_bytes, write_bytes_atomic

#: Largest raster we accept (pixels); decoding more is a likely mistake or attack.
MAX_PIXELS = 64 * 1024 * 1024


def _decode(path: str | os.PathLike, flags: int) -> np.ndarray:
    try:
        data = read_bytes(path)
    except OSError as exc:
        raise TpsvError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise TpsvError(f"{path}: empty file")
    buf = np.frombuffer(data, np.uint8)
    img = cv2.imdecode(buf, flags)
    if img is None:
        raise TpsvError(f"{path}: not an image OpenCV can decode")
    if img.shape[0] * img.shape[1] > MAX_PIXELS:
        raise TpsvError(f"{path}: image of {img.shape[1]}x{img.shape[0]} is too large")
    return img


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit grey or RGB photo.

    Parameters
    ----------
    path : str or path-like
        Image file (any format OpenCV decodes); ``-`` reads stdin.

    Returns
    -------
    rgb : ndarray, shape (H, W, 3), float32
        Colours in ``[0, 1]``.

    Raises
    ------
    TpsvError
        Not an image, 16-bit, with transparency, or smaller than 2x2.
    """
    img = _decode(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise TpsvError(f"{path}: {img.dtype.itemsize * 8}-bit image; tpsv reads 8-bit images only")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        if np.any(img[:, :, 3] != 255):
            raise TpsvError(f"{path}: image has transparency (RGBA); flatten it onto a background first")
        img = img[:, :, :3]
    elif img.shape[2] != 3:
        raise TpsvError(f"{path}: image with {img.shape[2]} channels; expected grey or RGB")
    h, w = img.shape[:2]
    if h < 2 or w < 2:
        raise TpsvError(f"{path}: image of {w}x{h} is too small (at least 2x2)")
    return np.ascontiguousarray(img[:, :, ::-1]).astype(np.float32) / 255.0


def read_labels(path: str | os.PathLike, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a label map (8- or 16-bit single-channel PNG, one integer a pixel).

    Parameters
    ----------
    path : str or path-like
    shape : (H, W), optional
        Required size; a map of another size is an error.

    Returns
    -------
    labels : ndarray, shape (H, W), int32
    """
    img = _decode(path, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        if img.shape[2] >= 3 and np.array_equal(img[:, :, 0], img[:, :, 1]) and np.array_equal(img[:, :, 1], img[:, :, 2]):
            img = img[:, :, 0]
        else:
            raise TpsvError(f"{path}: label map must have one channel (got {img.shape[2]})")
    if img.dtype not in (np.uint8, np.uint16):
        raise TpsvError(f"{path}: label map must be 8- or 16-bit")
    if shape is not None and img.shape[:2] != tuple(shape):
        raise TpsvError(
            f"{path}: label map is {img.shape[1]}x{img.shape[0]} but the image is {shape[1]}x{shape[0]}"
        )
    return img.astype(np.int32)


def encode_png(rgb: np.ndarray) -> bytes:
    """PNG bytes of an RGB image given as float in ``[0, 1]`` or uint8."""
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.rint(np.asarray(rgb, np.float64) * 255.0), 0, 255).astype(np.uint8)
    if rgb.ndim == 3:
        rgb = np.ascontiguousarray(rgb[:, :, ::-1])
    ok, buf = cv2.imencode(".png", rgb)
    if not ok:
        raise TpsvError("PNG encoding failed")
    return buf.tobytes()


def write_image(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write an RGB image as PNG atomically (``-``: stdout)."""
    write_bytes_atomic(path, encode_png(rgb))


def write_labels(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write a label map as an 8-bit PNG, or 16-bit when there are over 256 labels."""
    if labels.min(initial=0) < 0 or labels.max(initial=0) > 65535:
        raise TpsvError("label values must lie in 0..65535")
    dtype = np.uint8 if labels.max(initial=0) < 256 else np.uint16
    ok, buf = cv2.imencode(".png", labels.astype(dtype))
    if not ok:
        raise TpsvError("PNG encoding failed")
    write_bytes_atomic(path, buf.tobytes())
