"""Each region's colour as a mesh of bicubic patches with bilinear colours (PDF shading types 6 and 7).

Geometry is exact. Within one Hermite cell the patch is a bicubic polynomial
(``tpsv.geometry.patch``), and so is its restriction to any parameter
rectangle ``[s0, s1] x [t0, t1]``: sampled on a 4 x 4 tensor grid it gives
the 16 Bezier control points of that piece (the inverse Bernstein matrix on
each side), which is what a PDF tensor-product patch holds. For a cell with
zero twist and straight sides (every patch fresh from ``vectorize`` is
affine) these are the Hermite rule ``P0, P0 + D0/3, P1 - D1/3, P1`` along
each side, and the interior points follow from the twist.

Colour is approximated. A PDF viewer interpolates the four corner colours of
a patch bilinearly in its ``(u, v)``; the TPS colour is not bilinear, so every
cell is split (in parameter space) until the bilinear colour matches the
renderer's colour within a tolerance at a 5 x 5 grid of test points of each
piece. Colours come from the library's own renderer (``tpsv.gpu.tps``: the
kernels are solved once, then evaluated at every level's corners and test
points in one launch), clamped as ``tpsv.rendering.raster.render`` clamps them.

Beyond the patch. A region is painted a little beyond its outline (the
anti-aliased and soft borders mix the colour of the region across, which the
renderer evaluates beyond that region's outline; ``tpsv.export.pdf``). The
renderer clamps ``(S, T)`` to ``[0, 1]`` there, so the mesh gets a skirt of
cells outside the parameter square: their geometry extrapolates the border
cell's polynomial (as ``tpsv.geometry.patch.forward`` does) and their colour
is the clamped one, constant across the skirt.

Only pieces that reach the region's paint zone (its pixels, grown by the
reach the export needs, plus a margin) are kept, and only test points in that
zone count: the rest of the patch rectangle never shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.patch import affine_frame, coefficients, patch_pixel_scale

#: Test points per side of a piece (corners included).
GRID = 5
#: Pieces whose longer side is at most this many pixels are not split further.
MIN_PIECE_PX = 0.25
#: Extra pixels of paint zone and skirt beyond the reach asked for (culling is done on pixels).
MARGIN_PX = 2.0

# Bernstein basis at 0, 1/3, 2/3, 1 (rows: sample, columns: control point) and its inverse.
_T = np.arange(4) / 3.0
_BERN = np.stack([np.array([1, 3, 3, 1])[k] * _T**k * (1 - _T) ** (3 - k) for k in range(4)], axis=1)
_BERN_INV = np.linalg.inv(_BERN)


@dataclass
class RegionMesh:
    """The patch mesh of one region.

    Attributes
    ----------
    points : ndarray (n, 4, 4, 2) float64
        Bezier control points ``p[i, j]`` of each piece (``i`` along ``s``,
        ``j`` along ``t``), model pixel coordinates.
    colors : ndarray (n, 2, 2, 3) float32
        sRGB in ``[0, 1]`` at the corners ``(i, j)`` in ``{0, 1}^2`` (``i``
        along ``s``).
    affine : bool
        The region's patch is exactly affine: every piece is a parallelogram,
        and a Coons patch (12 points, type 6) holds it exactly.
    """

    points: np.ndarray
    colors: np.ndarray
    affine: bool


@dataclass
class MeshStats:
    """What the subdivision did: ``pieces`` kept, ``levels`` run, ``points`` evaluated, ``max_error`` left (sRGB)."""

    pieces: int = 0
    levels: int = 0
    points: int = 0
    max_error: float = 0.0


class ColorField:
    """The renderer's vector colour (no detail layer) at any region and ``(S, T)``, solved once.

    Parameters
    ----------
    model : Model
    device : str
        Warp device.
    """

    def __init__(self, model, device: str = "cpu"):
        from .. import tps
        from ..gpu import resolve_device
        from ..gpu import tps as gtps

        self.device = resolve_device(device)
        self._gtps = gtps
        self._dk = gtps.solve(gtps.upload(tps.group_kernels(model), self.device))

    def __call__(self, region: np.ndarray, st: np.ndarray) -> np.ndarray:
        """sRGB (n, 3) float32 in ``[0, 1]`` at ``(S, T)`` (n, 2) (clamped to ``[0, 1]``) of ``region`` (n,)."""
        n = int(np.shape(region)[0])
        if n == 0:
            return np.zeros((0, 3), np.float32)
        reg = np.ascontiguousarray(region, np.int32).reshape(1, n)
        st = np.clip(np.asarray(st, np.float32), 0.0, 1.0).reshape(1, n, 2)
        out = self._gtps.rasterise(self._dk, reg, np.ascontiguousarray(st), clamp=True)
        return out.numpy().reshape(n, 3)


class PaintZone:
    """Where a region can show: its pixels grown by ``reach`` pixels, as a summed-area table.

    Parameters
    ----------
    index : ndarray (H, W) int32
        Region of every pixel at scale 1 (``tpsv.rendering.pixelmap.region_index``).
    region : int
    reach : float
        Pixels beyond the region's own pixels that must stay painted.
    """

    def __init__(self, index: np.ndarray, region: int, reach: float):
        H, W = index.shape
        grow = int(np.ceil(reach + MARGIN_PX))
        ys, xs = np.nonzero(index == region)
        if ys.size == 0:
            self.x0 = self.y0 = 0
            self.mask = np.zeros((1, 1), bool)
        else:
            self.x0, self.y0 = max(0, xs.min() - grow), max(0, ys.min() - grow)
            x1, y1 = min(W, xs.max() + 1 + grow), min(H, ys.max() + 1 + grow)
            own = (index[self.y0:y1, self.x0:x1] == region).astype(np.uint8)
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
            self.mask = cv2.dilate(own, disc).astype(bool)
        h, w = self.mask.shape
        self.sat = np.zeros((h + 1, w + 1), np.int64)
        self.sat[1:, 1:] = self.mask.cumsum(0).cumsum(1)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point (..., 2) lies on a zone pixel."""
        h, w = self.mask.shape
        x = np.floor(xy[..., 0] - self.x0).astype(np.int64)
        y = np.floor(xy[..., 1] - self.y0).astype(np.int64)
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        out = np.zeros(x.shape, bool)
        out[ok] = self.mask[y[ok], x[ok]]
        return out

    def touches(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Whether each box ``[lo, hi]`` (n, 2) holds a zone pixel."""
        h, w = self.mask.shape
        x0 = np.clip(np.floor(lo[:, 0] - self.x0).astype(np.int64), 0, w)
        y0 = np.clip(np.floor(lo[:, 1] - self.y0).astype(np.int64), 0, h)
        x1 = np.clip(np.floor(hi[:, 0] - self.x0).astype(np.int64) + 1, 0, w)
        y1 = np.clip(np.floor(hi[:, 1] - self.y0).astype(np.int64) + 1, 0, h)
        s = self.sat
        n = s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]
        return (n > 0) & (x1 > x0) & (y1 > y0)


def _breaks(n: int, ext: float) -> np.ndarray:
    """Cell boundaries along one parameter: the skirt ``[-ext, 0]``, the cells, ``[n - 1, n - 1 + ext]``."""
    inner = np.arange(n, dtype=np.float64)
    return np.concatenate([[-ext], inner, [n - 1 + ext]]) if ext > 0 else inner


def _grid_points(K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Polynomials K (n, 4, 4, 2) at the tensor grid u (n, a) x v (n, b) -> (n, a, b, 2)."""
    up = u[..., None] ** np.arange(4)  # (n, a, 4)
    vp = v[..., None] ** np.arange(4)  # (n, b, 4)
    return np.einsum("nap,npqk,nbq->nabk", up, K, vp)


class _Pieces:
    """Pieces of all regions at one level: region, Hermite cell and global ``(s, t)`` rectangle."""

    def __init__(self, region, ci, cj, s0, s1, t0, t1):
        self.region, self.ci, self.cj = region, ci, cj
        self.s0, self.s1, self.t0, self.t1 = s0, s1, t0, t1

    def __len__(self):
        return int(self.region.size)

    def take(self, keep):
        return _Pieces(*(a[keep] for a in (self.region, self.ci, self.cj, self.s0, self.s1, self.t0, self.t1)))

    @staticmethod
    def concat(parts):
        parts = [p for p in parts if len(p)]
        if not parts:
            z = np.zeros(0)
            return _Pieces(z.astype(np.int64), z.astype(np.int64), z.astype(np.int64), z, z, z, z)
        return _Pieces(*(np.concatenate([getattr(p, k) for p in parts])
                         for k in ("region", "ci", "cj", "s0", "s1", "t0", "t1")))


def build_meshes(model, tolerance: float, reach: np.ndarray, device: str = "cpu",
                 index: np.ndarray | None = None) -> tuple[list[RegionMesh], MeshStats]:
    """The patch mesh of every region, subdivided until its bilinear colour is within ``tolerance``.

    Parameters
    ----------
    model : Model
    tolerance : float
        Largest difference allowed (8-bit sRGB levels, any channel) between a
        piece's bilinear colour and the renderer's at its test points inside
        the region's paint zone.
    reach : ndarray (R,) float
        Pixels beyond its outline each region must stay painted.
    device : str
        Warp device for the colour evaluations.
    index : ndarray (H, W) int32, optional
        Region of every pixel at scale 1 (default: computed).

    Returns
    -------
    meshes : list of RegionMesh
        One per region (possibly with no pieces).
    stats : MeshStats
    """
    from ..rendering.pixelmap import region_index

    R = len(model.regions)
    if index is None:
        index = region_index(model, model.width, model.height)
    field = ColorField(model, device)
    coef, dims, zones, affine = [], [], [], []
    parts = []
    for r, region in enumerate(model.regions):
        patch = region.patch
        M, N = patch.shape
        K = coefficients(patch)
        coef.append(K.reshape(-1, 4, 4, 2))
        dims.append((M, N))
        affine.append(affine_frame(patch) is not None)
        zones.append(PaintZone(index, r, float(reach[r])))
        # skirt width in parameter units: the reach plus a margin, at the patch's smallest pixel scale
        px_s, px_t = patch_pixel_scale(patch)
        ext = float(reach[r]) + 2.0 * MARGIN_PX
        bs = _breaks(M, ext * (M - 1) / px_s)
        bt = _breaks(N, ext * (N - 1) / px_t)
        s0, t0 = np.meshgrid(bs[:-1], bt[:-1], indexing="ij")
        s1, t1 = np.meshgrid(bs[1:], bt[1:], indexing="ij")
        ci = np.clip(np.floor(0.5 * (s0 + s1)), 0, M - 2).astype(np.int64)
        cj = np.clip(np.floor(0.5 * (t0 + t1)), 0, N - 2).astype(np.int64)
        parts.append(_Pieces(np.full(ci.size, r, np.int64), ci.ravel(), cj.ravel(), s0.ravel(), s1.ravel(),
                             t0.ravel(), t1.ravel()))
    cell_off = np.cumsum([0] + [c.shape[0] for c in coef])
    allK = np.concatenate(coef) if coef else np.zeros((0, 4, 4, 2))
    Ndim = np.array([d[1] for d in dims] or [2], np.int64)
    Mdim = np.array([d[0] for d in dims] or [2], np.int64)

    todo = _Pieces.concat(parts)
    done_pts, done_col, done_reg = [], [], []
    stats = MeshStats()
    g = np.linspace(0.0, 1.0, GRID)
    tol = float(tolerance) / 255.0
    while len(todo):
        stats.levels += 1
        n = len(todo)
        reg = todo.region
        K = allK[cell_off[reg] + todo.ci * (Ndim[reg] - 1) + todo.cj]
        # the 4 x 4 Bezier points (exact) and the GRID x GRID test points of every piece
        u = todo.s0[:, None] + (todo.s1 - todo.s0)[:, None] * _T - todo.ci[:, None]
        v = todo.t0[:, None] + (todo.t1 - todo.t0)[:, None] * _T - todo.cj[:, None]
        pts = np.einsum("ia,nabk,jb->nijk", _BERN_INV, _grid_points(K, u, v), _BERN_INV)
        lo = pts.reshape(n, 16, 2).min(axis=1)
        hi = pts.reshape(n, 16, 2).max(axis=1)
        seen = np.zeros(n, bool)
        for r in np.unique(reg):
            sel = np.flatnonzero(reg == r)
            seen[sel] = zones[r].touches(lo[sel], hi[sel])
        todo = todo.take(seen)
        pts, K, reg = pts[seen], K[seen], reg[seen]
        n = len(todo)
        if n == 0:
            break
        ss = todo.s0[:, None] + (todo.s1 - todo.s0)[:, None] * g  # (n, G)
        tt = todo.t0[:, None] + (todo.t1 - todo.t0)[:, None] * g
        xy = _grid_points(K, ss - todo.ci[:, None], tt - todo.cj[:, None])  # (n, G, G, 2)
        S = np.broadcast_to((ss / (Mdim[reg] - 1)[:, None])[:, :, None], (n, GRID, GRID))
        T = np.broadcast_to((tt / (Ndim[reg] - 1)[:, None])[:, None, :], (n, GRID, GRID))
        st = np.stack([S, T], axis=-1).reshape(-1, 2)
        col = field(np.repeat(reg, GRID * GRID), st).reshape(n, GRID, GRID, 3)
        stats.points += n * GRID * GRID
        c00, c10, c01, c11 = col[:, 0, 0], col[:, -1, 0], col[:, 0, -1], col[:, -1, -1]
        a = g[None, :, None, None]
        b = g[None, None, :, None]
        bil = ((1 - a) * (1 - b) * c00[:, None, None] + a * (1 - b) * c10[:, None, None]
               + (1 - a) * b * c01[:, None, None] + a * b * c11[:, None, None])
        diff = np.abs(bil - col).max(axis=-1)  # (n, G, G)
        inside = np.zeros(diff.shape, bool)
        for r in np.unique(reg):
            sel = np.flatnonzero(reg == r)
            inside[sel] = zones[r].contains(xy[sel])
        err = np.where(inside, diff, 0.0).max(axis=(1, 2))
        # side lengths in pixels (control polygon), to stop at MIN_PIECE_PX and pick the split
        len_s = np.linalg.norm(np.diff(pts, axis=1), axis=-1).sum(axis=1).max(axis=1)
        len_t = np.linalg.norm(np.diff(pts, axis=2), axis=-1).sum(axis=2).max(axis=1)
        split = (err > tol) & (np.maximum(len_s, len_t) > MIN_PIECE_PX)
        ok = ~split
        stats.max_error = max(stats.max_error, float(err[ok].max(initial=0.0)) * 255.0)
        done_pts.append(pts[ok])
        done_col.append(np.stack([np.stack([c00[ok], c01[ok]], 1), np.stack([c10[ok], c11[ok]], 1)], 1))
        done_reg.append(reg[ok])
        todo = _split(todo.take(split), len_s[split], len_t[split])
    pts = np.concatenate(done_pts) if done_pts else np.zeros((0, 4, 4, 2))
    col = np.concatenate(done_col).astype(np.float32) if done_col else np.zeros((0, 2, 2, 3), np.float32)
    reg = np.concatenate(done_reg) if done_reg else np.zeros(0, np.int64)
    order = np.argsort(reg, kind="stable")
    pts, col, reg = pts[order], col[order], reg[order]
    bounds = np.searchsorted(reg, np.arange(R + 1))
    meshes = [RegionMesh(points=pts[bounds[r]:bounds[r + 1]], colors=col[bounds[r]:bounds[r + 1]], affine=affine[r])
              for r in range(R)]
    stats.pieces = int(reg.size)
    return meshes, stats


def _split(p: _Pieces, len_s: np.ndarray, len_t: np.ndarray) -> _Pieces:
    """Each piece in two along its much longer side, else in four."""
    along_s = len_s > 2.0 * len_t
    along_t = len_t > 2.0 * len_s
    sm = 0.5 * (p.s0 + p.s1)
    tm = 0.5 * (p.t0 + p.t1)
    cut_s = ~along_t
    cut_t = ~along_s
    out = []
    for hs in (0, 1):
        for ht in (0, 1):
            keep = (cut_s | (hs == 0)) & (cut_t | (ht == 0))
            s0 = np.where(cut_s & (hs == 1), sm, p.s0)
            s1 = np.where(cut_s & (hs == 0), sm, p.s1)
            t0 = np.where(cut_t & (ht == 1), tm, p.t0)
            t1 = np.where(cut_t & (ht == 0), tm, p.t1)
            out.append(_Pieces(p.region, p.ci, p.cj, s0, s1, t0, t1).take(keep))
    return _Pieces.concat(out)


__all__ = ["ColorField", "MeshStats", "PaintZone", "RegionMesh", "build_meshes"]
