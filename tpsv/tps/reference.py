"""The numpy TPS reference (paper Eq. (3)-(4)), float64.

``f(p) = b0 + b1 x + b2 y + sum_i w_i phi(|p - p_i|)`` with
``phi(r) = r^2 log r`` (``phi(0) = 0``) and ``sum w_i = sum w_i x_i =
sum w_i y_i = 0``. :func:`tps_fit` / :func:`tps_eval` solve and evaluate one
dense system; :func:`blend_reference` blends given kernel coefficients as the
device rasteriser does. The renderer solves the same system per kernel on the
device (``tpsv.gpu.tps``); the tests pin the device to these functions.
"""

from __future__ import annotations

import numpy as np

from .blend import blend_weights


def tps_phi(r2: np.ndarray) -> np.ndarray:
    """``phi(r) = r^2 log r`` given ``r^2`` (``0`` at ``0``).

    Parameters
    ----------
    r2 : array_like
        Squared distances.

    Returns
    -------
    ndarray, float64, the shape of ``r2``.
    """
    r2 = np.asarray(r2, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 0.5 * r2 * np.log(np.where(r2 > 0.0, r2, 1.0))
    return out


def _sqdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a[:, None, :] - b[None, :, :]
    return np.einsum("ijk,ijk->ij", d, d)


def tps_fit(points, values, smoothing: float = 0.0) -> np.ndarray:
    """Solve Eq. (4) for the TPS through ``points`` with ``values``.

    ``smoothing`` (lambda) is added to the diagonal of the kernel block, as in
    ``scipy.interpolate.RBFInterpolator``. Needs ``n >= 3`` non-collinear points.

    Parameters
    ----------
    points : (n, 2) array_like
    values : (n, c) or (n,) array_like
    smoothing : float

    Returns
    -------
    coef : ndarray, shape (n + 3, c), float64 (``c = 1`` for 1-D ``values``)
        ``w_1..w_n`` then ``b0, b1, b2`` (constant, x and y coefficients) in
        the coordinates of ``points``.
    """
    p = np.asarray(points, np.float64)
    h = np.asarray(values, np.float64)
    if h.ndim == 1:
        h = h[:, None]
    n = p.shape[0]
    if p.ndim != 2 or p.shape[1] != 2 or h.shape[0] != n:
        raise ValueError("points must be (n, 2) and values (n, c)")
    if n < 3:
        raise ValueError("a TPS needs at least 3 points")
    c = p.mean(axis=0)
    q = p - c  # translation invariant; conditions the affine block
    A = np.zeros((n + 3, n + 3))
    A[:n, :n] = tps_phi(_sqdist(q, q)) + float(smoothing) * np.eye(n)
    P = np.column_stack([np.ones(n), q])
    A[:n, n:] = P
    A[n:, :n] = P.T
    rhs = np.zeros((n + 3, h.shape[1]))
    rhs[:n] = h
    coef = np.linalg.solve(A, rhs)
    # back to the caller's coordinates: b0 + b1 (x - cx) + b2 (y - cy)
    coef[n] -= coef[n + 1] * c[0] + coef[n + 2] * c[1]
    return coef


def tps_eval(coef: np.ndarray, points, query) -> np.ndarray:
    """Evaluate the TPS of :func:`tps_fit` at ``query``.

    Parameters
    ----------
    coef : (n + 3, c) ndarray
        From :func:`tps_fit`.
    points : (n, 2) array_like
        The points ``coef`` was fitted through.
    query : (m, 2) array_like

    Returns
    -------
    ndarray (m, c) float64
    """
    p = np.asarray(points, np.float64)
    q = np.asarray(query, np.float64)
    coef = np.asarray(coef, np.float64)
    n = p.shape[0]
    out = np.empty((q.shape[0], coef.shape[1]))
    for s in range(0, q.shape[0], 4096):  # bounded memory
        qq = q[s : s + 4096]
        out[s : s + 4096] = (
            tps_phi(_sqdist(qq, p)) @ coef[:n] + coef[n] + qq[:, 0:1] * coef[n + 1] + qq[:, 1:2] * coef[n + 2]
        )
    return out


def blend_reference(ks, pts, w, b, region, st) -> np.ndarray:
    """Blended Lab at points in float64 numpy, from given kernel coefficients.

    The reference for the device rasteriser (which evaluates in float32).

    Parameters
    ----------
    ks : KernelSet
    pts : (n_k, K, 2) ndarray
        Local points of every kernel (``tpsv.gpu.tps.coefficients``).
    w : (n_k, K, 3) ndarray
        TPS weights.
    b : (n_k, 3, 3) ndarray
        Affine part ``b0, b_u, b_v``.
    region : (n,) int
        Region of each query point.
    st : (n, 2) float
        ``(S, T)`` of each query point.

    Returns
    -------
    ndarray (n, 3) float64
        Lab; regions without kernels get their ``ks.fill`` colour.
    """
    region = np.asarray(region, np.int64).reshape(-1)
    st = np.asarray(st, np.float64).reshape(-1, 2)
    kid, wt = blend_weights(ks, region, st)
    out = np.zeros((st.shape[0], 3))
    for c in range(4):
        for k in np.unique(kid[:, c][kid[:, c] >= 0]):
            sel = kid[:, c] == k
            loc = ks.local(int(k), st[sel])
            m = int(ks.count[k])
            val = tps_phi(_sqdist(loc, pts[k, :m])) @ w[k, :m] + b[k, 0] + loc[:, :1] * b[k, 1] + loc[:, 1:] * b[k, 2]
            out[sel] += wt[sel, c : c + 1] * val
    nofeat = ks.grid[region, 0] == 0
    out[nofeat] = ks.fill[region[nofeat]]
    return out


__all__ = ["tps_phi", "tps_fit", "tps_eval", "blend_reference"]
