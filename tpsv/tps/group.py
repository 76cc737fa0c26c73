"""Thin-plate splines: numpy reference, sub-patch grouping and packing.

TPS (paper Eq. (3)-(4))
-----------------------
``f(p) = b0 + b1 x + b2 y + sum_i w_i phi(|p - p_i|)`` with
``phi(r) = r^2 log r`` (``phi(0) = 0``) and ``sum w_i = sum w_i x_i =
sum w_i y_i = 0``. :func:`tps_fit` / :func:`tps_eval` are the float64 numpy
reference (one dense solve of Eq. (4)); the renderer solves the same system
per kernel on the device (``tpsv.gpu.tps``).

Grouping and packing (paper V-B, VI-B)
--------------------------------------
:func:`group_kernels` splits each region's ``(S, T)`` square into a uniform
grid of ``gx x gy`` sub-patch cells. Distances are measured isotropically in
pixels: ``S`` and ``T`` are scaled by the region's patch side lengths
(:func:`patch_pixel_scale`), so a cell is roughly square on screen. The grid
is chosen so that a cell holds about ``cell_features`` features on average
(default ``K / 2``: on the bundled samples ``K / 3`` costs 25-50 % more
kernels for a PSNR within 0.15 dB) and is refined (cell side / 1.25 per step) while the
densest cell holds more than ``K`` features, down to cells of
``min_cell_px`` pixels and up to ``max_refine`` times the initial cell
count (a uniform grid refined for one dense spot multiplies the kernels, and
the solve time, of the whole region; beyond the cap a dense cell's kernel
keeps the ``K`` features nearest its centre). A region with at
most ``K`` features is one cell whose kernel holds all its features.

Each cell's kernel holds the ``K`` features of the same region nearest to
the cell centre (packing: every kernel has exactly ``K`` slots). "Nearest" is
the Chebyshev (L-infinity) distance in pixels, because a kernel's support is
a square: the ``K`` nearest in that metric are the contents of the largest
square around the centre that holds ``K`` features, so whenever the extended
cell (the support) holds at most ``K`` features they are all in the kernel.
Regions with fewer than ``K`` features leave the remaining slots inactive
(index ``-1``).

Features at exactly the same ``(S, T)`` in one region are merged: the first
one stands for the group, with the group's mean colour (a TPS through two
colours at one point does not exist). With ``merge_px > 0`` (default 0),
features in the same ``merge_px``-pixel square of a region are merged too,
at their mean position.

Solve (anchors and degenerate kernels)
--------------------------------------
Slots 0, 1, 2 of a kernel are its anchors: three well-spread active features
(the one farthest from the centroid, the one farthest from it, and the one
farthest from the line through those two), used by the device solver for
an explicit null-space basis of ``P^T`` (see ``tpsv.gpu.tps``). A kernel
with fewer than 3 active features, or whose features are collinear (the
anchor triangle's height below ``1e-3`` of its base), is *degenerate*: it
gets no TPS but the least-squares affine function that is linear along the
line through its first two anchors and constant across it (one feature: a
constant).

Local frames
------------
TPS with this ``phi`` is invariant under translation and uniform scaling of
the coordinates, so each kernel works in its own frame for float
conditioning: ``u = (S - cS) * ax``, ``v = (T - cT) * ay`` where
``(cS, cT)`` is the cell centre and ``(ax, ay) = (sx, sy) / scale`` with
``(sx, sy)`` the region's pixel scale and ``scale`` the larger of the
kernel's feature extent and the support's half-size (in pixels), so that
local coordinates are ``O(1)``. The smoothing term ``lambda``
(``Params.smoothing``) is meant for distances in pixels, as
``RBFInterpolator(smoothing=lambda)`` on pixel coordinates; each kernel
applies it scaled to its local units (``tpsv.gpu.tps.kernel_lambda``).

Blending (paper VI-C, read as a partition of unity)
---------------------------------------------------
A kernel's support is its cell extended by ``overlap`` of a cell on every
side. Along each axis, with ``a = S * gx`` (``S`` clamped to ``[0, 1]``) and
``z = (a - (i + 0.5)) / (0.5 + overlap)`` for cell ``i``, the weight is
``(1 - z^2)^2`` for ``|z| < 1``, else 0: smooth, positive inside the support,
zero with zero slope on its border. A kernel's weight is the product over the
two axes; the weights of the (at most 2 x 2, for ``overlap <= 0.5``) kernels
covering a point are normalised to sum to one. With ``overlap <= 0``, each
point uses only its own cell's kernel (no blending).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import TpsvError

#: Largest K: the solver keeps a K x K float64 tile in shared memory (about
#: 128 KiB at 128; CUDA blocks have at most about 227 KiB, Warp's CPU tiles 256 KiB).
MAX_KERNEL_SIZE = 128
#: Smallest sub-patch cell side, in pixels.
MIN_CELL_PX = 4.0
#: Refinement for dense spots may multiply a region's cell count by at most this.
MAX_REFINE = 3.0
#: Collinearity tolerance: anchor triangle height / base below this is degenerate.
COLLINEAR_TOL = 1e-3
#: Pixel scale floor (px per unit of S or T).
MIN_SCALE_PX = 1e-3


# --------------------------------------------------------------------------- numpy reference


def tps_phi(r2: np.ndarray) -> np.ndarray:
    """``phi(r) = r^2 log r`` given ``r^2`` (``0`` at ``0``), float64."""
    r2 = np.asarray(r2, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 0.5 * r2 * np.log(np.where(r2 > 0.0, r2, 1.0))
    return out


def _sqdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a[:, None, :] - b[None, :, :]
    return np.einsum("ijk,ijk->ij", d, d)


def tps_fit(points, values, smoothing: float = 0.0) -> np.ndarray:
    """Solve Eq. (4) for the TPS through ``points`` (n, 2) with ``values`` (n, c).

    ``smoothing`` (lambda) is added to the diagonal of the kernel block, as in
    ``scipy.interpolate.RBFInterpolator``. Needs ``n >= 3`` non-collinear points.

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
    """Evaluate the TPS of :func:`tps_fit` at ``query`` (m, 2); returns (m, c) float64."""
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


# --------------------------------------------------------------------------- blending weights


def bump(z: np.ndarray) -> np.ndarray:
    """``(1 - z^2)^2`` for ``|z| < 1``, else 0."""
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


def blend_weights(ks: "KernelSet", region, st):
    """Kernels covering each point and their normalised blend weights (numpy).

    Parameters
    ----------
    ks : KernelSet
    region : (n,) int region index per point
    st : (n, 2) float normalised ``(S, T)``; clamped to ``[0, 1]`` here.

    Returns
    -------
    kid : (n, 4) int64, kernel index or -1
    w : (n, 4) float64, weights summing to 1 over the valid entries (0 for -1)
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


# --------------------------------------------------------------------------- grouping


@dataclass
class KernelSet:
    """Sub-patch TPS kernels of a model (derived data, not stored in files).

    Attributes
    ----------
    kernel_size : int
        K, slots per kernel.
    overlap : float
        Support extension per side, as a fraction of a cell.
    smoothing : float
        lambda added to the kernel diagonal, for distances in pixels
        (0 = interpolation).
    st : (F, 2) float64
        Feature ``(S, T)`` (a copy of the model's).
    lab : (F, 3) float32
        Feature colours (Lab); a merged duplicate's representative carries
        its group's mean.
    index : (n_kernels, K) int32
        Feature index per slot, ``-1`` for inactive slots (always last).
        Slots 0-2 are the anchors of a non-degenerate kernel.
    count : (n_kernels,) int32
        Active slots.
    degenerate : (n_kernels,) bool
        Fewer than 3 active features, or collinear ones (affine fallback).
    region : (n_kernels,) int32
        Region of each kernel.
    cell : (n_kernels, 4) float64
        Cell bounds ``S0, S1, T0, T1`` (without the overlap).
    frame : (n_kernels, 4) float64
        Local frame ``cS, cT, ax, ay``: ``u = (S - cS) ax``, ``v = (T - cT) ay``.
    grid : (n_regions, 3) int32
        ``gx, gy, first kernel``; the kernel of cell ``(ix, iy)`` is
        ``first + iy * gx + ix``. ``gx = gy = 0`` for a region without
        features.
    scale : (n_regions, 2) float64
        Pixels per unit of ``S`` and of ``T`` (patch side lengths).
    fill : (n_regions, 3) float32
        Lab colour of regions without kernels: the mean colour of all the
        model's features (mid grey, Lab (50, 0, 0), when there are none).
    """

    kernel_size: int
    overlap: float
    smoothing: float
    st: np.ndarray
    lab: np.ndarray
    index: np.ndarray
    count: np.ndarray
    degenerate: np.ndarray
    region: np.ndarray
    cell: np.ndarray
    frame: np.ndarray
    grid: np.ndarray
    scale: np.ndarray
    fill: np.ndarray

    @property
    def n_kernels(self) -> int:
        return int(self.index.shape[0])

    def local(self, k: int, st) -> np.ndarray:
        """Coordinates of ``st`` (n, 2) in kernel ``k``'s local frame."""
        cS, cT, ax, ay = self.frame[k]
        st = np.asarray(st, np.float64)
        return np.column_stack([(st[:, 0] - cS) * ax, (st[:, 1] - cT) * ay])


def patch_pixel_scale(patch) -> tuple[float, float]:
    """Pixels per unit of ``S`` and ``T``: mean lengths of the control polygon's s and t lines."""
    pos = np.asarray(patch.ctrl, np.float64)[:, :, 0, :]
    sx = float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).sum(axis=0).mean()) if pos.shape[0] > 1 else 0.0
    sy = float(np.linalg.norm(np.diff(pos, axis=1), axis=-1).sum(axis=1).mean()) if pos.shape[1] > 1 else 0.0
    return max(sx, MIN_SCALE_PX), max(sy, MIN_SCALE_PX)


def _choose_grid(xy: np.ndarray, sx: float, sy: float, K: int, cell_features: float, min_cell_px: float, max_refine: float):
    n = xy.shape[0]
    if n <= K:
        return 1, 1
    c = max(np.sqrt(sx * sy * cell_features / n), min_cell_px)

    def dims(c):
        return int(max(1, min(round(sx / c), n))), int(max(1, min(round(sy / c), n)))

    gx, gy = dims(c)
    budget = max(gx * gy * max_refine, 1.0)
    while True:
        ix = np.clip((xy[:, 0] * (gx / sx)).astype(np.int64), 0, gx - 1)
        iy = np.clip((xy[:, 1] * (gy / sy)).astype(np.int64), 0, gy - 1)
        if np.bincount(iy * gx + ix, minlength=gx * gy).max() <= K or c <= min_cell_px:
            return gx, gy
        c2 = max(c / 1.25, min_cell_px)
        gx2, gy2 = dims(c2)
        if gx2 * gy2 > budget or gx2 * gy2 >= n:
            return gx, gy
        c, gx, gy = c2, gx2, gy2


def _anchors(P: np.ndarray, mask: np.ndarray):
    """Choose 3 well-spread anchor slots per kernel (vectorised).

    Returns (a0, a1, a2) slot indices (n_k,) and the degenerate flag.
    """
    nk, K, _ = P.shape
    cnt = mask.sum(1)
    big = -np.inf
    cen = (P * mask[..., None]).sum(1) / np.maximum(cnt, 1)[:, None]
    d0 = np.where(mask, ((P - cen[:, None]) ** 2).sum(-1), big)
    a0 = d0.argmax(1)
    r = np.arange(nk)
    p0 = P[r, a0]
    d1 = np.where(mask, ((P - p0[:, None]) ** 2).sum(-1), big)
    a1 = d1.argmax(1)
    p1 = P[r, a1]
    e = p1 - p0
    cr = np.where(mask, np.abs(e[:, None, 0] * (P[..., 1] - p0[:, None, 1]) - e[:, None, 1] * (P[..., 0] - p0[:, None, 0])), big)
    a2 = cr.argmax(1)
    base = np.sqrt((e**2).sum(-1))
    height = cr[r, a2] / np.where(base > 0, base, 1.0)
    degenerate = (cnt < 3) | (base <= 0) | ~(height > COLLINEAR_TOL * base)
    return a0, a1, a2, degenerate


def group_kernels(
    model,
    kernel_size: int | None = None,
    overlap: float | None = None,
    smoothing: float | None = None,
    cell_features: float | None = None,
    min_cell_px: float = MIN_CELL_PX,
    max_refine: float = MAX_REFINE,
    merge_px: float = 0.0,
) -> KernelSet:
    """Group each region's features into equal-size sub-patch kernels (see module doc).

    ``kernel_size``, ``overlap`` and ``smoothing`` default to ``model.params``;
    ``cell_features`` (target mean features per cell) to ``K / 2``;
    ``merge_px > 0`` also merges features of a region that fall in the same
    ``merge_px``-pixel square (mean position and colour).
    """
    params = model.params
    K = int(kernel_size if kernel_size is not None else params.kernel_size)
    if K < 3 or K > MAX_KERNEL_SIZE:
        raise TpsvError(f"kernel size {K} is out of range (3..{MAX_KERNEL_SIZE})")
    ov = float(overlap if overlap is not None else params.overlap)
    if not np.isfinite(ov) or ov > 0.5:
        raise TpsvError(f"overlap {ov} is out of range (0..0.5)")
    ov = max(ov, 0.0)
    lam = float(smoothing if smoothing is not None else params.smoothing)
    if not np.isfinite(lam) or lam < 0:
        raise TpsvError(f"smoothing {lam} must be >= 0")
    cf = float(cell_features) if cell_features is not None else K / 2.0
    cf = min(max(cf, 1.0), float(K))

    feats = model.features
    F = len(feats)
    R = len(model.regions)
    st_all = np.array(feats.st, np.float64).reshape(F, 2)
    lab_all = np.asarray(feats.lab, np.float32).reshape(F, 3).copy()
    reg_all = np.asarray(feats.region, np.int64).reshape(F)
    if F and (reg_all.min() < 0 or reg_all.max() >= R):
        raise TpsvError("a feature refers to a region that does not exist")

    # merge duplicates: same region and same (S, T), or the same merge_px cell in pixels
    keep = np.ones(F, bool)
    if F > 1:
        if merge_px > 0:
            sc = np.array([patch_pixel_scale(r.patch) for r in model.regions], np.float64).reshape(R, 2)
            key = np.floor(st_all * sc[reg_all] / merge_px)
        else:
            key = st_all
        o = np.lexsort((key[:, 1], key[:, 0], reg_all))  # stable: first occurrence first
        a, b = o[1:], o[:-1]
        same = (reg_all[a] == reg_all[b]) & (key[a, 0] == key[b, 0]) & (key[a, 1] == key[b, 1])
        if same.any():
            gid = np.concatenate([[0], np.cumsum(~same)])
            first = o[np.concatenate([[True], ~same])]
            cnt = np.bincount(gid)[:, None]
            lab_sum = np.zeros((first.size, 3))
            np.add.at(lab_sum, gid, lab_all[o].astype(np.float64))
            lab_all[first] = (lab_sum / cnt).astype(np.float32)
            if merge_px > 0:
                st_all = st_all.copy()
                st_sum = np.zeros((first.size, 2))
                np.add.at(st_sum, gid, st_all[o])
                st_all[first] = st_sum / cnt
            keep[:] = False
            keep[first] = True

    fill_lab = lab_all[keep].astype(np.float64).mean(0) if F else np.array([50.0, 0.0, 0.0])
    scale = np.array([patch_pixel_scale(r.patch) for r in model.regions], np.float64).reshape(R, 2)
    grid = np.zeros((R, 3), np.int32)

    order = np.argsort(reg_all, kind="stable")
    order = order[keep[order]]
    bounds = np.searchsorted(reg_all[order], np.arange(R + 1))

    idx_list, reg_list, cell_list, cen_list = [], [], [], []
    k_total = 0
    for r in range(R):
        fi = order[bounds[r] : bounds[r + 1]]
        n = fi.size
        grid[r, 2] = k_total
        if n == 0:
            continue
        sx, sy = scale[r]
        xy = st_all[fi] * (sx, sy)
        gx, gy = _choose_grid(xy, sx, sy, K, cf, min_cell_px, max_refine)
        grid[r, 0], grid[r, 1] = gx, gy
        ix, iy = np.meshgrid(np.arange(gx), np.arange(gy))  # (gy, gx): row-major iy * gx + ix
        ix = ix.ravel()
        iy = iy.ravel()
        centres = np.column_stack([(ix + 0.5) * (sx / gx), (iy + 0.5) * (sy / gy)])
        if n <= K:
            sel = np.full((gx * gy, K), -1, np.int64)
            sel[:, :n] = fi[None, :]
        else:
            tree = cKDTree(xy)
            _, nn = tree.query(centres, k=K, p=np.inf)
            sel = fi[nn]
        idx_list.append(sel)
        reg_list.append(np.full(gx * gy, r, np.int32))
        cell_list.append(np.column_stack([ix / gx, (ix + 1) / gx, iy / gy, (iy + 1) / gy]))
        cen_list.append(np.column_stack([(ix + 0.5) / gx, (iy + 0.5) / gy]))
        k_total += gx * gy

    if k_total:
        index = np.concatenate(idx_list).astype(np.int64)
        region = np.concatenate(reg_list)
        cell = np.concatenate(cell_list).astype(np.float64)
        cen = np.concatenate(cen_list).astype(np.float64)
    else:
        index = np.zeros((0, K), np.int64)
        region = np.zeros(0, np.int32)
        cell = np.zeros((0, 4))
        cen = np.zeros((0, 2))

    nk = index.shape[0]
    mask = index >= 0
    count = mask.sum(1).astype(np.int32)
    sxy = scale[region]  # (nk, 2)
    P = np.where(mask[..., None], (st_all[np.maximum(index, 0)] - cen[:, None, :]) * sxy[:, None, :], 0.0)

    # local frame scale: the feature extent, at least the support's half size (px)
    ext = np.abs(P).max(axis=(1, 2)) if nk else np.zeros(0)
    cw = (cell[:, 1] - cell[:, 0]) * sxy[:, 0]
    ch = (cell[:, 3] - cell[:, 2]) * sxy[:, 1]
    sup = (0.5 + ov) * np.maximum(cw, ch)
    kscale = np.maximum(np.maximum(ext, sup), 1e-9)
    frame = np.column_stack([cen, sxy / kscale[:, None]]) if nk else np.zeros((0, 4))

    # anchors first
    if nk:
        a0, a1, a2, degenerate = _anchors(P, mask)
        slot = np.broadcast_to(np.arange(K), (nk, K))
        is_anchor = (slot == a0[:, None]) | (slot == a1[:, None]) | (slot == a2[:, None])
        # order: a0, a1, a2, other active slots (original distance order), inactive
        rank = np.where(mask, np.where(is_anchor, 0, 1), 2) * (K + 1) + slot
        rank[np.arange(nk), a0] = -3
        rank[np.arange(nk), a1] = np.where(a1 != a0, -2, rank[np.arange(nk), a1])
        rank[np.arange(nk), a2] = np.where((a2 != a0) & (a2 != a1), -1, rank[np.arange(nk), a2])
        perm = np.argsort(rank, axis=1, kind="stable")
        index = np.take_along_axis(index, perm, 1)
    else:
        degenerate = np.zeros(0, bool)

    fill = np.broadcast_to(fill_lab.astype(np.float32), (R, 3)).copy()
    return KernelSet(
        kernel_size=K,
        overlap=ov,
        smoothing=lam,
        st=st_all,
        lab=lab_all,
        index=index.astype(np.int32),
        count=count,
        degenerate=np.asarray(degenerate, bool),
        region=region.astype(np.int32),
        cell=cell,
        frame=frame.astype(np.float64),
        grid=grid,
        scale=scale,
        fill=fill,
    )


def kernel_points(ks: KernelSet, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Active features of kernel ``k``: local coordinates (m, 2) and Lab values (m, 3), float64."""
    idx = ks.index[k, : ks.count[k]]
    return ks.local(k, ks.st[idx]), ks.lab[idx].astype(np.float64)


def blend_reference(ks: KernelSet, pts, w, b, region, st) -> np.ndarray:
    """Blended Lab at points in float64 numpy, from given kernel coefficients.

    ``pts`` (n_k, K, 2), ``w`` (n_k, K, 3), ``b`` (n_k, 3, 3) are local
    points and coefficients (``tpsv.gpu.tps.coefficients``); ``region`` (n,)
    and ``st`` (n, 2) the query points. The reference for the device
    rasteriser (which evaluates in float32).
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
