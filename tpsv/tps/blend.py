"""Blend weights of the sub-patch kernels (paper VI-C, read as a partition of unity).

A kernel's support is its cell extended by ``overlap`` of a cell on every
side. Along each axis, with ``a = S * gx`` (``S`` clamped to ``[0, 1]``) and
``z = (a - (i + 0.5)) / (0.5 + overlap)`` for cell ``i``, the weight is
``(1 - z^2)^2`` for ``|z| < 1``, else 0: smooth, positive inside the support,
zero with zero slope on its border. A kernel's weight is the product over the
two axes; the weights of the (at most 2 x 2, for ``overlap <= 0.5``) kernels
covering a point are normalised to sum to one. With ``overlap <= 0``, each
point uses only its own cell's kernel (no blending).

The device rasteriser (``tpsv.gpu.tps``) computes the same weights in
float32; :func:`blend_weights` is the numpy version the fit and the tests use.
"""

from __future__ import annotations

import numpy as np


def bump(z: np.ndarray) -> np.ndarray:
    """The blend profile ``(1 - z^2)^2`` for ``|z| < 1``, else 0.

    Parameters
    ----------
    z : array_like
        Offset from a cell centre in units of the support's half-width.

    Returns
    -------
    ndarray, float64
    """
    z = np.asarray(z, np.float64)
    return np.where(np.abs(z) < 1.0, (1.0 - z * z) ** 2, 0.0)


def _axis_cover(a: np.ndarray, g: np.ndarray, overlap: float):
    """Per axis: own cell, neighbour cell and their unnormalised weights.

    ``a`` is the parameter times the cell count ``g`` (``a`` in ``[0, g]``).
    The neighbour is -1 where it does not exist or does not cover ``a``.
    """
    i = np.minimum(np.floor(a), g - 1).astype(np.int64)
    i = np.maximum(i, 0)
    frac = a - i
    j = np.where(frac < 0.5, i - 1, i + 1)
    if overlap <= 0.0:
        return i, np.full_like(i, -1), np.ones_like(a), np.zeros_like(a)
    half = 0.5 + overlap
    wi = bump((a - (i + 0.5)) / half)
    wj = bump((a - (j + 0.5)) / half)
    ok = (j >= 0) & (j < g) & (wj > 0.0)
    return i, np.where(ok, j, -1), wi, np.where(ok, wj, 0.0)


def blend_weights(ks, region, st):
    """Kernels covering each point and their normalised blend weights (numpy).

    Parameters
    ----------
    ks : KernelSet
    region : (n,) int
        Region index per point.
    st : (n, 2) float
        Normalised ``(S, T)``; clamped to ``[0, 1]`` here.

    Returns
    -------
    kid : (n, 4) int64
        Kernel index or -1.
    w : (n, 4) float64
        Weights summing to 1 over the valid entries (0 for -1).
    """
    region = np.asarray(region, np.int64)
    st = np.clip(np.asarray(st, np.float64), 0.0, 1.0)
    gx = ks.grid[region, 0].astype(np.float64)
    gy = ks.grid[region, 1].astype(np.float64)
    k0 = ks.grid[region, 2].astype(np.int64)
    has = ks.grid[region, 0] > 0
    gxs = np.maximum(gx, 1)
    gys = np.maximum(gy, 1)
    ix, jx, wix, wjx = _axis_cover(st[:, 0] * gxs, gxs, ks.overlap)
    iy, jy, wiy, wjy = _axis_cover(st[:, 1] * gys, gys, ks.overlap)
    cx = np.stack([ix, jx], 1)
    cy = np.stack([iy, jy], 1)
    wx = np.stack([wix, wjx], 1)
    wy = np.stack([wiy, wjy], 1)
    kid = np.full((st.shape[0], 4), -1, np.int64)
    w = np.zeros((st.shape[0], 4))
    for a in range(2):
        for b in range(2):
            ok = (cx[:, a] >= 0) & (cy[:, b] >= 0) & has
            col = 2 * b + a
            kid[:, col] = np.where(ok, k0 + cy[:, b] * gx.astype(np.int64) + cx[:, a], -1)
            w[:, col] = np.where(ok, wx[:, a] * wy[:, b], 0.0)
    tot = w.sum(axis=1, keepdims=True)
    w = np.where(tot > 0, w / np.where(tot > 0, tot, 1.0), 0.0)
    kid[w == 0.0] = -1
    return kid, w


__all__ = ["bump", "blend_weights"]
