"""sRGB <-> CIE Lab (D65), the same formulas as the render kernel uses."""

from __future__ import annotations

import numpy as np

# sRGB (linear) -> XYZ, D65, and its inverse.
_RGB2XYZ = np.array(
    [[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169], [0.019334, 0.119193, 0.950227]]
)
_XYZ2RGB = np.linalg.inv(_RGB2XYZ)
_WHITE = np.array([0.950456, 1.0, 1.088754])


def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """Convert sRGB in ``[0, 1]`` (shape ``(..., 3)``) to Lab (float32)."""
    c = np.asarray(rgb, np.float64)
    lin = np.where(c > 0.04045, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = lin @ _RGB2XYZ.T / _WHITE
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16.0 / 116.0)
    L = 116.0 * f[..., 1] - 16.0
    a = 500.0 * (f[..., 0] - f[..., 1])
    b = 200.0 * (f[..., 1] - f[..., 2])
    return np.stack([L, a, b], axis=-1).astype(np.float32)


def lab_to_srgb(lab: np.ndarray, clip: bool = True) -> np.ndarray:
    """Convert Lab (shape ``(..., 3)``) to sRGB in ``[0, 1]`` (float32).

    Out-of-gamut colours are clipped to the cube when ``clip`` is true.
    """
    lab = np.asarray(lab, np.float64)
    fy = (lab[..., 0] + 16.0) / 116.0
    fx = fy + lab[..., 1] / 500.0
    fz = fy - lab[..., 2] / 200.0
    f = np.stack([fx, fy, fz], axis=-1)
    xyz = np.where(f > 0.206893, f**3, (f - 16.0 / 116.0) / 7.787) * _WHITE
    lin = xyz @ _XYZ2RGB.T
    lin = np.maximum(lin, 0.0)
    c = np.where(lin > 0.0031308, 1.055 * np.power(lin, 1.0 / 2.4) - 0.055, 12.92 * lin)
    if clip:
        c = np.clip(c, 0.0, 1.0)
    return c.astype(np.float32)
