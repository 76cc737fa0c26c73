"""Sub-patch grouping and packing: each region's features into equal-size TPS kernels.

Grouping and packing (paper V-B, VI-B)
--------------------------------------
:func:`group_kernels` splits each region's ``(S, T)`` square into a uniform
grid of ``gx x gy`` sub-patch cells. Distances are measured isotropically in
pixels: ``S`` and ``T`` are scaled by the region's patch side lengths
(``tpsv.geometry.patch.patch_pixel_scale``), so a cell is roughly square on screen. The grid
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

Features at exactly the same ``(S, T)`` in one region are merged
(:class:`tpsv.tps.duplicates.Duplicates`): the first one stands for the
group, with the group's mean colour (a TPS through two colours at one point
does not exist). With ``merge_px > 0`` (default 0), features in the same
``merge_px``-pixel square of a region are merged too, at their mean position.

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
TPS with ``phi(r) = r^2 log r`` is invariant under translation and uniform
scaling of the coordinates, so each kernel works in its own frame for float
conditioning: ``u = (S - cS) * ax``, ``v = (T - cT) * ay`` where
``(cS, cT)`` is the cell centre and ``(ax, ay) = (sx, sy) / scale`` with
``(sx, sy)`` the region's pixel scale and ``scale`` the larger of the
kernel's feature extent and the support's half-size (in pixels), so that
local coordinates are ``O(1)``. The smoothing term ``lambda``
(``Params.smoothing``) is meant for distances in pixels, as
``RBFInterpolator(smoothing=lambda)`` on pixel coordinates; each kernel
applies it scaled to its local units (:func:`kernel_lambda`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..codec.layout import SUPPORTED_KERNEL_SIZES
from ..errors import TpsvError
from ..geometry.patch import MIN_SCALE_PX
from .duplicates import Duplicates

#: Largest K: the solver keeps a K x K float64 tile in shared memory (about
#: 128 KiB at 128; CUDA blocks have at most about 227 KiB, Warp's CPU tiles 256 KiB).
#: The kernel sizes rendered are ``tpsv.codec.layout.SUPPORTED_KERNEL_SIZES``
#: (each one a Warp kernel compiled once), which the decoder also enforces.
MAX_KERNEL_SIZE = 128
#: Smallest sub-patch cell side, in pixels.
MIN_CELL_PX = 4.0
#: Refinement for dense spots may multiply a region's cell count by at most this.
MAX_REFINE = 3.0
#: Collinearity tolerance: anchor triangle height / base below this is degenerate.
COLLINEAR_TOL = 1e-3


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
        """Number of kernels."""
        return int(self.index.shape[0])

    def local(self, k: int, st) -> np.ndarray:
        """Coordinates of ``st`` (n, 2) in kernel ``k``'s local frame; (n, 2) float64."""
        cS, cT, ax, ay = self.frame[k]
        st = np.asarray(st, np.float64)
        return np.column_stack([(st[:, 0] - cS) * ax, (st[:, 1] - cT) * ay])


def recolor(ks: KernelSet, features, duplicates: Duplicates | None = None) -> KernelSet:
    """``ks`` with the colours of ``features``, merged as :func:`group_kernels` merges them.

    Equal to ``group_kernels`` of a model with these features when ``ks`` was
    grouped (``merge_px = 0``) from the same positions, regions, patches and
    parameters: the grouping depends on nothing else.

    Parameters
    ----------
    ks : KernelSet
    features : Features
        The new colours (``features.lab``) at the positions ``ks`` was grouped from.
    duplicates : Duplicates, optional
        ``Duplicates.of_features(features)`` when the caller keeps it across
        colour edits (it depends on positions only).

    Returns
    -------
    KernelSet
        A shallow copy sharing everything but ``lab`` and ``fill``.
    """
    dup = duplicates if duplicates is not None else Duplicates.of_features(features)
    lab = dup.merge_lab(features.lab)
    fill = np.broadcast_to(dup.fill(lab).astype(np.float32), ks.fill.shape).copy()
    return replace(ks, lab=lab, fill=fill)


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


# --------------------------------------------------------------------------- group_kernels, step by step


def pixel_scales(patches) -> np.ndarray:
    """``tpsv.geometry.patch.patch_pixel_scale`` of every patch, patches of one shape at once.

    The same arithmetic in the same order (the reductions run along the same
    axes), so the values are identical (``tests/test_tps.py`` pins it); a
    model may have thousands of regions.

    Returns
    -------
    ndarray (len(patches), 2) float64
    """
    out = np.zeros((len(patches), 2), np.float64)
    shapes: dict = {}
    for i, p in enumerate(patches):
        shapes.setdefault(np.shape(p.ctrl)[:2], []).append(i)
    for (M, N), idx in shapes.items():
        pos = np.stack([np.asarray(patches[i].ctrl, np.float64)[:, :, 0, :] for i in idx])
        if M > 1:
            out[idx, 0] = np.linalg.norm(np.diff(pos, axis=1), axis=-1).sum(axis=1).mean(axis=-1)
        if N > 1:
            out[idx, 1] = np.linalg.norm(np.diff(pos, axis=2), axis=-1).sum(axis=2).mean(axis=-1)
    return np.maximum(out, MIN_SCALE_PX)


def _settings(params, kernel_size, overlap, smoothing, cell_features) -> tuple[int, float, float, float]:
    """``K, overlap, lambda, cell_features`` from the arguments or ``params``, validated."""
    K = int(kernel_size if kernel_size is not None else params.kernel_size)
    if K not in SUPPORTED_KERNEL_SIZES:
        # each K is a separately compiled Warp solve kernel: the decoder accepts the same set
        sizes = ", ".join(str(k) for k in SUPPORTED_KERNEL_SIZES)
        raise TpsvError(f"kernel size {K} is not one tpsv renders ({sizes})")
    ov = float(overlap if overlap is not None else params.overlap)
    if not np.isfinite(ov) or ov > 0.5:
        raise TpsvError(f"overlap {ov} is out of range (0..0.5)")
    ov = max(ov, 0.0)
    lam = float(smoothing if smoothing is not None else params.smoothing)
    if not np.isfinite(lam) or lam < 0:
        raise TpsvError(f"smoothing {lam} must be >= 0")
    cf = float(cell_features) if cell_features is not None else K / 2.0
    cf = min(max(cf, 1.0), float(K))
    return K, ov, lam, cf


def _merged_features(model, scale: np.ndarray, merge_px: float):
    """Features' ``(S, T)``, Lab and region with duplicates merged; plus the representatives.

    Returns
    -------
    st (F, 2) float64, lab (F, 3) float32, region (F,) int64, dup : Duplicates
    """
    feats = model.features
    F = len(feats)
    st = np.array(feats.st, np.float64).reshape(F, 2)
    reg = np.asarray(feats.region, np.int64).reshape(F)
    if F and (reg.min() < 0 or reg.max() >= len(model.regions)):
        raise TpsvError("a feature refers to a region that does not exist")
    key = np.floor(st * scale[reg] / merge_px) if merge_px > 0 else st
    dup = Duplicates.find(reg, key)
    lab = dup.merge_lab(feats.lab)
    if merge_px > 0:
        st = dup.merge_st(st)
    return st, lab, reg, dup


def _cells(st, reg, keep, scale, K, cf, min_cell_px, max_refine):
    """Each region's cell grid and each cell's ``K`` nearest features (packing).

    A region with at most ``K`` features is one cell holding them all; those
    are laid out all at once (a model may have thousands of tiny regions),
    the others region by region.

    Returns
    -------
    index (n_k, K) int64, region (n_k,) int32, cell (n_k, 4), centre (n_k, 2), grid (R, 3) int32
    """
    R = scale.shape[0]
    grid = np.zeros((R, 3), np.int32)
    order = np.argsort(reg, kind="stable")
    order = order[keep[order]]
    bounds = np.searchsorted(reg[order], np.arange(R + 1))
    n = np.diff(bounds)
    small = (n > 0) & (n <= K)
    grid[small, 0] = grid[small, 1] = 1
    blocks = {}
    for r in np.flatnonzero(n > K):
        # (imported here: SciPy's spatial package takes a third of a second, which a model whose regions
        # each fit one kernel, the default files' vector part, need not pay)
        from scipy.spatial import cKDTree

        fi = order[bounds[r] : bounds[r + 1]]
        sx, sy = scale[r]
        xy = st[fi] * (sx, sy)
        gx, gy = _choose_grid(xy, sx, sy, K, cf, min_cell_px, max_refine)
        grid[r, 0], grid[r, 1] = gx, gy
        ix, iy = np.meshgrid(np.arange(gx), np.arange(gy))  # (gy, gx): row-major iy * gx + ix
        ix = ix.ravel()
        iy = iy.ravel()
        centres = np.column_stack([(ix + 0.5) * (sx / gx), (iy + 0.5) * (sy / gy)])
        _, nn = cKDTree(xy).query(centres, k=K, p=np.inf)
        blocks[r] = (fi[nn], np.column_stack([ix / gx, (ix + 1) / gx, iy / gy, (iy + 1) / gy]),
                     np.column_stack([(ix + 0.5) / gx, (iy + 0.5) / gy]))
    per = grid[:, 0].astype(np.int64) * grid[:, 1]
    first = np.cumsum(per) - per
    grid[:, 2] = first
    k_total = int(per.sum())
    if not k_total:
        return np.zeros((0, K), np.int64), np.zeros(0, np.int32), np.zeros((0, 4)), np.zeros((0, 2)), grid
    index = np.full((k_total, K), -1, np.int64)
    region = np.repeat(np.arange(R, dtype=np.int32), per)
    cell = np.empty((k_total, 4), np.float64)
    cen = np.empty((k_total, 2), np.float64)
    # one cell per small region: every feature of the region, in feature order, then -1
    rs = np.flatnonzero(small)
    cell[first[rs]] = (0.0, 1.0, 0.0, 1.0)
    cen[first[rs]] = (0.5, 0.5)
    fs = np.flatnonzero(small[reg[order]])
    fr = reg[order[fs]]
    index[first[fr], fs - bounds[fr]] = order[fs]
    for r, (sel, c, ce) in blocks.items():
        k = slice(first[r], first[r] + per[r])
        index[k], cell[k], cen[k] = sel, c, ce
    return index, region, cell, cen, grid


def _frames(st, index, region, cell, cen, scale, ov):
    """Local frames ``cS, cT, ax, ay`` (n_k, 4) and the slots' offsets from the centre in pixels (n_k, K, 2)."""
    mask = index >= 0
    sxy = scale[region]  # (nk, 2)
    P = np.where(mask[..., None], (st[np.maximum(index, 0)] - cen[:, None, :]) * sxy[:, None, :], 0.0)
    if not index.shape[0]:
        return np.zeros((0, 4)), P
    # local frame scale: the feature extent, at least the support's half size (px)
    ext = np.abs(P).max(axis=(1, 2))
    cw = (cell[:, 1] - cell[:, 0]) * sxy[:, 0]
    ch = (cell[:, 3] - cell[:, 2]) * sxy[:, 1]
    sup = (0.5 + ov) * np.maximum(cw, ch)
    kscale = np.maximum(np.maximum(ext, sup), 1e-9)
    return np.column_stack([cen, sxy / kscale[:, None]]), P


def _anchors_first(index: np.ndarray, P: np.ndarray):
    """Slots reordered as: the 3 anchors, other active slots (distance order), inactive; and the degenerate flags."""
    nk, K = index.shape
    if not nk:
        return index, np.zeros(0, bool)
    mask = index >= 0
    a0, a1, a2, degenerate = _anchors(P, mask)
    slot = np.broadcast_to(np.arange(K), (nk, K))
    is_anchor = (slot == a0[:, None]) | (slot == a1[:, None]) | (slot == a2[:, None])
    rank = np.where(mask, np.where(is_anchor, 0, 1), 2) * (K + 1) + slot
    rows = np.arange(nk)
    rank[rows, a0] = -3
    rank[rows, a1] = np.where(a1 != a0, -2, rank[rows, a1])
    rank[rows, a2] = np.where((a2 != a0) & (a2 != a1), -1, rank[rows, a2])
    perm = np.argsort(rank, axis=1, kind="stable")
    return np.take_along_axis(index, perm, 1), np.asarray(degenerate, bool)


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
    """Group each region's features into equal-size sub-patch kernels (see the module doc).

    Parameters
    ----------
    model : Model
    kernel_size, overlap, smoothing : optional
        K, the support extension and lambda; default ``model.params``.
    cell_features : float, optional
        Target mean features per cell; default ``K / 2``.
    min_cell_px : float
        Smallest cell side in pixels.
    max_refine : float
        Largest factor by which refinement may multiply a region's cells.
    merge_px : float
        When > 0, features of a region in the same ``merge_px``-pixel square
        are merged too (mean position and colour).

    Returns
    -------
    KernelSet
    """
    K, ov, lam, cf = _settings(model.params, kernel_size, overlap, smoothing, cell_features)
    R = len(model.regions)
    scale = pixel_scales([r.patch for r in model.regions])
    st, lab, reg, dup = _merged_features(model, scale, merge_px)
    index, region, cell, cen, grid = _cells(st, reg, dup.keep, scale, K, cf, min_cell_px, max_refine)
    frame, P = _frames(st, index, region, cell, cen, scale, ov)
    count = (index >= 0).sum(1).astype(np.int32)
    index, degenerate = _anchors_first(index, P)
    fill = np.broadcast_to(dup.fill(lab).astype(np.float32), (R, 3)).copy()
    return KernelSet(
        kernel_size=K,
        overlap=ov,
        smoothing=lam,
        st=st,
        lab=lab,
        index=index.astype(np.int32),
        count=count,
        degenerate=degenerate,
        region=region.astype(np.int32),
        cell=cell,
        frame=frame.astype(np.float64),
        grid=grid,
        scale=scale,
        fill=fill,
    )


def kernel_lambda(ks: KernelSet) -> np.ndarray:
    """Per-kernel smoothing in local units: ``lambda_px * c^2`` for local = ``c`` * pixels.

    On the null space of ``P^T`` scaling the coordinates by ``c`` scales
    ``Phi`` by ``c^2``, so this gives every kernel the TPS that
    ``RBFInterpolator(smoothing=lambda_px)`` gives on pixel coordinates.

    Parameters
    ----------
    ks : KernelSet

    Returns
    -------
    ndarray (n_kernels,) float64
    """
    if ks.n_kernels == 0:
        return np.zeros(0)
    c = ks.frame[:, 2] / ks.scale[ks.region, 0]  # ax = sx / scale_k  ->  c = 1 / scale_k
    return float(ks.smoothing) * c * c


__all__ = ["KernelSet", "group_kernels", "recolor", "kernel_lambda", "pixel_scales", "MAX_KERNEL_SIZE", "MIN_CELL_PX", "MAX_REFINE", "COLLINEAR_TOL"]
