"""sRGB <-> CIE Lab (D65): the numpy formulas, their constants, and the Jacobian of Lab -> sRGB.

The render kernel's Warp twin (``tpsv.gpu.color.lab_to_srgb``) takes its
matrix and white point from here, and a test pins the two together.
"""

from __future__ import annotations

import numpy as np

#: Linear sRGB -> XYZ (D65).
RGB2XYZ = np.array(
    [[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169], [0.019334, 0.119193, 0.950227]]
)
#: XYZ -> linear sRGB (D65), the inverse of :data:`RGB2XYZ`.
XYZ2RGB = np.linalg.inv(RGB2XYZ)
#: The D65 white point (XYZ) that Lab is relative to.
WHITE = np.array([0.950456, 1.0, 1.088754])


def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """Convert sRGB to CIE Lab.

    Parameters
    ----------
    rgb : array_like (..., 3)
        sRGB in ``[0, 1]``.

    Returns
    -------
    ndarray (..., 3) float32
        Lab (D65).
    """
    c = np.asarray(rgb, np.float64)
    lin = np.where(c > 0.04045, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = lin @ RGB2XYZ.T / WHITE
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16.0 / 116.0)
    L = 116.0 * f[..., 1] - 16.0
    a = 500.0 * (f[..., 0] - f[..., 1])
    b = 200.0 * (f[..., 1] - f[..., 2])
    return np.stack([L, a, b], axis=-1).astype(np.float32)


def _lab_f(lab: np.ndarray) -> np.ndarray:
    """``(f_x, f_y, f_z)`` (..., 3) of Lab: the cube roots of XYZ / white on the cubic branch."""
    fy = (lab[..., 0] + 16.0) / 116.0
    return np.stack([fy + lab[..., 1] / 500.0, fy, fy - lab[..., 2] / 200.0], axis=-1)


def _lab_linear(lab: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lab (float64) -> ``f``, the cubic-branch mask of ``f`` and linear sRGB (not yet clipped at 0)."""
    f = _lab_f(lab)
    cube = f > 0.206893
    xyz = np.where(cube, f**3, (f - 16.0 / 116.0) / 7.787) * WHITE
    return f, cube, xyz @ XYZ2RGB.T


def _gamma(c: np.ndarray) -> np.ndarray:
    """sRGB transfer curve of linear values ``c >= 0``."""
    return np.where(c > 0.0031308, 1.055 * np.power(c, 1.0 / 2.4) - 0.055, 12.92 * c)


def lab_to_srgb(lab: np.ndarray, clip: bool = True) -> np.ndarray:
    """Convert CIE Lab to sRGB.

    Parameters
    ----------
    lab : array_like (..., 3)
        Lab (D65).
    clip : bool
        Clip out-of-gamut colours to the cube ``[0, 1]^3``.

    Returns
    -------
    ndarray (..., 3) float32
        sRGB (linear values below 0 are taken as 0 before the transfer curve).
    """
    _, _, lin = _lab_linear(np.asarray(lab, np.float64))
    c = _gamma(np.maximum(lin, 0.0))
    if clip:
        c = np.clip(c, 0.0, 1.0)
    return c.astype(np.float32)


def lab_to_srgb_jacobian(lab: np.ndarray) -> np.ndarray:
    """Jacobian ``d sRGB / d Lab`` of :func:`lab_to_srgb`.

    Parameters
    ----------
    lab : array_like (..., 3)
        Lab colours (flattened to ``n`` rows).

    Returns
    -------
    ndarray (n, 3, 3) float64
        ``J[n, i, j] = d sRGB_i / d Lab_j``; rows of channels that clip (linear
        value below 0, or sRGB above 1) are 0, as the clipped function is flat there.
    """
    lab = np.asarray(lab, np.float64).reshape(-1, 3)
    f, cube, lin = _lab_linear(lab)
    dxyz_df = np.where(cube, 3.0 * f * f, 1.0 / 7.787) * WHITE  # (n, 3)
    # df / dLab: rows fx, fy, fz; columns L, a, b
    df = np.array([[1 / 116.0, 1 / 500.0, 0.0], [1 / 116.0, 0.0, 0.0], [1 / 116.0, 0.0, -1 / 200.0]])
    c = np.maximum(lin, 0.0)
    srgb = _gamma(c)
    # the derivative of c^(1/2.4) is infinite at 0; that branch is never taken below 0.0031308
    dg = np.where(c > 0.0031308, 1.055 / 2.4 * np.power(np.maximum(c, 1e-12), 1.0 / 2.4 - 1.0), 12.92)
    dg = np.where((lin < 0.0) | (srgb > 1.0), 0.0, dg)
    # J = diag(dg) XYZ2RGB diag(dxyz_df) df
    return np.einsum("ni,ij,nj,jk->nik", dg, XYZ2RGB, dxyz_df, df)
