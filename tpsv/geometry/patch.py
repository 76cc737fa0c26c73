"""Bicubic Hermite patches: construction, forward map, Jacobian and inverse.

Parameters and cells
--------------------
A patch has ``M x N`` control points (``Patch.ctrl``, see ``tpsv.model``);
``s`` runs over ``[0, M-1]`` and ``t`` over ``[0, N-1]``. The cell of ``s`` is
``i = clip(floor(s), 0, M-2)`` and the local parameter ``u = s - i``; likewise
``j``, ``v`` for ``t``. Within the cell::

    M(u, v) = H(u)^T G H(v)

with the Hermite basis ``H(u) = (2u^3-3u^2+1, -2u^3+3u^2, u^3-2u^2+u, u^3-u^2)``
(weights of ``P_0, P_1, D_0, D_1``) and the usual 4x4 geometry matrix ``G`` of
positions, ``s``/``t`` derivatives and twists of the cell's four control
points. Derivatives are per unit of ``s`` (one cell).

Outside the domain (``s < 0``, ``s > M-1``, same for ``t``) the border cell's
cubic polynomial is extrapolated: ``u`` is not clamped. For a patch built by
:func:`build_patch` this is the same affine map as inside, so region pixels
that stick out of the surface (possible after ``deform``) still get a
well-defined, continuous parameter; :func:`normalize` then clamps ``S, T`` into
``[0, 1]``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..errors import TpsvError
from ..model import Patch

# --------------------------------------------------------------------------- basis


#: B[p, a]: coefficient of u**p in Hermite basis function a.
_B = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-3.0, 3.0, -2.0, -1.0], [2.0, -2.0, 1.0, 1.0]])


def _cells(patch: Patch, s, t):
    M, N = patch.shape
    s = np.asarray(s, np.float64)
    t = np.asarray(t, np.float64)
    s, t = np.broadcast_arrays(s, t)
    i = np.clip(np.floor(s), 0, M - 2).astype(np.int64)
    j = np.clip(np.floor(t), 0, N - 2).astype(np.int64)
    return s - i, t - j, i, j


def _geometry(ctrl: np.ndarray):
    """Geometry matrices G (M-1, N-1, 4, 4, 2) of all cells.

    Rows: P(u=0), P(u=1), Ds(u=0), Ds(u=1); columns: the same along v with Dt
    (and twists where both are derivatives).
    """
    c00 = ctrl[:-1, :-1]
    c10 = ctrl[1:, :-1]
    c01 = ctrl[:-1, 1:]
    c11 = ctrl[1:, 1:]
    G = np.stack(
        [
            np.stack([c00[..., 0, :], c01[..., 0, :], c00[..., 2, :], c01[..., 2, :]], axis=-2),
            np.stack([c10[..., 0, :], c11[..., 0, :], c10[..., 2, :], c11[..., 2, :]], axis=-2),
            np.stack([c00[..., 1, :], c01[..., 1, :], c00[..., 3, :], c01[..., 3, :]], axis=-2),
            np.stack([c10[..., 1, :], c11[..., 1, :], c10[..., 3, :], c11[..., 3, :]], axis=-2),
        ],
        axis=-3,
    )
    return G


def coefficients(patch: Patch) -> np.ndarray:
    """Power-basis coefficients K (M-1, N-1, 4, 4, 2): ``M(u, v) = sum K[p, q] u^p v^q`` per cell."""
    G = _geometry(np.asarray(patch.ctrl, np.float64))
    # B G B^T per cell and coordinate, as matrix products (an unoptimised einsum took 5x as long;
    # the same numbers for the affine patches of a fresh model, within 1e-15 relative otherwise)
    return np.moveaxis(_B @ np.moveaxis(G, -1, 2) @ _B.T, 2, -1)


def _horner(K, u, v):
    """Evaluate gathered coefficients K (..., 4, 4, 2) at (u, v) (...)."""
    v_ = v[..., None, None]
    Kv = K[..., 0, :] + v_ * (K[..., 1, :] + v_ * (K[..., 2, :] + v_ * K[..., 3, :]))  # (..., 4, 2)
    u_ = u[..., None]
    return Kv[..., 0, :] + u_ * (Kv[..., 1, :] + u_ * (Kv[..., 2, :] + u_ * Kv[..., 3, :]))


def _horner_jac(K, u, v):
    """Value, d/du and d/dv of gathered coefficients."""
    v_ = v[..., None, None]
    Kv = K[..., 0, :] + v_ * (K[..., 1, :] + v_ * (K[..., 2, :] + v_ * K[..., 3, :]))
    Kdv = K[..., 1, :] + v_ * (2 * K[..., 2, :] + 3 * v_ * K[..., 3, :])
    u_ = u[..., None]
    val = Kv[..., 0, :] + u_ * (Kv[..., 1, :] + u_ * (Kv[..., 2, :] + u_ * Kv[..., 3, :]))
    du = Kv[..., 1, :] + u_ * (2 * Kv[..., 2, :] + 3 * u_ * Kv[..., 3, :])
    dv = Kdv[..., 0, :] + u_ * (Kdv[..., 1, :] + u_ * (Kdv[..., 2, :] + u_ * Kdv[..., 3, :]))
    return val, du, dv


def _grid_eval(K, uu, vv):
    """Gathered K (n, 4, 4, 2) at the tensor grid uu (n, a) x vv (n, b) -> (n, a, b, 2)."""
    v_ = vv[:, :, None, None]  # (n, b, 1, 1)
    Kb = K[:, None]  # (n, 1, 4, 4, 2)
    Kv = Kb[..., 0, :] + v_ * (Kb[..., 1, :] + v_ * (Kb[..., 2, :] + v_ * Kb[..., 3, :]))  # (n, b, 4, 2)
    u_ = uu[:, :, None, None]  # (n, a, 1, 1)
    Kv = Kv[:, None]  # (n, 1, b, 4, 2)
    return Kv[..., 0, :] + u_ * (Kv[..., 1, :] + u_ * (Kv[..., 2, :] + u_ * Kv[..., 3, :]))


def _gather(K, i, j):
    n1 = K.shape[1]
    flat = K.reshape(-1, 4, 4, 2)
    return flat[(i * n1 + j)]


def forward(patch: Patch, s, t, coef: np.ndarray | None = None) -> np.ndarray:
    """Surface points ``M(s, t)``, shape ``broadcast(s, t).shape + (2,)`` (x, y)."""
    K = coefficients(patch) if coef is None else coef
    u, v, i, j = _cells(patch, s, t)
    return _horner(_gather(K, i, j), u, v)


def jacobian(patch: Patch, s, t, coef: np.ndarray | None = None) -> np.ndarray:
    """Jacobian ``[[dx/ds, dx/dt], [dy/ds, dy/dt]]``, shape ``(..., 2, 2)``."""
    K = coefficients(patch) if coef is None else coef
    u, v, i, j = _cells(patch, s, t)
    _, du, dv = _horner_jac(_gather(K, i, j), u, v)
    return np.stack([du, dv], axis=-1)


def _det(J):
    return J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]


# --------------------------------------------------------------------------- inverse


def _bilinear_inverse(A, B, C, D, p, iters: int = 5):
    """Local (a, b) of p in the bilinear quad A(0,0) B(1,0) C(0,1) D(1,1) (Newton from the centre)."""
    a = np.full(p.shape[:-1], 0.5)
    b = np.full(p.shape[:-1], 0.5)
    e = B - A
    f = C - A
    g = A - B - C + D
    for _ in range(iters):
        q = A + a[..., None] * e + b[..., None] * f + (a * b)[..., None] * g
        r = q - p
        ja = e + b[..., None] * g
        jb = f + a[..., None] * g
        det = ja[..., 0] * jb[..., 1] - ja[..., 1] * jb[..., 0]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        da = (r[..., 0] * jb[..., 1] - r[..., 1] * jb[..., 0]) / det
        db = (ja[..., 0] * r[..., 1] - ja[..., 1] * r[..., 0]) / det
        a = np.clip(a - da, -4.0, 5.0)
        b = np.clip(b - db, -4.0, 5.0)
    return a, b


def _outside(a, b):
    return np.maximum.reduce([np.zeros_like(a), -a, a - 1, -b, b - 1])


def _locate_cell(patch: Patch, xy: np.ndarray):
    """Cell (i, j) whose control-point quad contains each point (walk from a global guess)."""
    ctrl = patch.ctrl
    M, N = patch.shape
    P = ctrl[..., 0, :]
    if (M - 1) * (N - 1) <= 16:
        # global guess from the four corner control points
        a, b = _bilinear_inverse(P[0, 0], P[M - 1, 0], P[0, N - 1], P[M - 1, N - 1], xy)
        i = np.clip(np.floor(a * (M - 1)), 0, M - 2).astype(np.int64)
        j = np.clip(np.floor(b * (N - 1)), 0, N - 2).astype(np.int64)
    else:
        # start at the nearest cell centre: on a large, bent grid the corner
        # guess can be hundreds of cells off, and each walk step costs a pass
        from scipy.spatial import cKDTree

        centre = 0.25 * (P[:-1, :-1] + P[1:, :-1] + P[:-1, 1:] + P[1:, 1:])
        _, k = cKDTree(centre.reshape(-1, 2)).query(xy)
        i, j = np.divmod(np.asarray(k, np.int64), N - 1)
    # from a near start a walk needs a few steps; one that oscillates between
    # two cells (a point in the sliver between non-convex quads) is cut short,
    # and Newton on the surface finishes it
    steps = M + N if (M - 1) * (N - 1) <= 16 else 16
    act = np.arange(len(xy))
    for _ in range(steps):
        ia, ja, p = i[act], j[act], xy[act]
        a, b = _bilinear_inverse(P[ia, ja], P[ia + 1, ja], P[ia, ja + 1], P[ia + 1, ja + 1], p)
        di = np.where((a < 0) & (ia > 0), -1, np.where((a > 1) & (ia < M - 2), 1, 0))
        dj = np.where((b < 0) & (ja > 0), -1, np.where((b > 1) & (ja < N - 2), 1, 0))
        mv = (di != 0) | (dj != 0)
        if not mv.any():
            break
        act = act[mv]
        i[act] += di[mv]
        j[act] += dj[mv]
    return i, j


def _newton(patch: Patch, xy, s, t, steps: int, tol: float = 1e-10, coef=None):
    """Newton on the global surface; points stop once within ``tol`` px."""
    K = coefficients(patch) if coef is None else coef
    s = np.array(s, np.float64, copy=True)
    t = np.array(t, np.float64, copy=True)
    act = np.flatnonzero(np.ones(s.shape, bool).ravel())
    sf = s.reshape(-1)
    tf = t.reshape(-1)
    xyf = np.broadcast_to(xy, s.shape + (2,)).reshape(-1, 2)
    for _ in range(steps):
        sa, ta = sf[act], tf[act]
        u, v, i, j = _cells(patch, sa, ta)
        val, du, dv = _horner_jac(_gather(K, i, j), u, v)
        r = val - xyf[act]
        keep = np.hypot(r[:, 0], r[:, 1]) >= tol
        if not keep.any():
            break
        act, r, du, dv, sa, ta = act[keep], r[keep], du[keep], dv[keep], sa[keep], ta[keep]
        det = du[:, 0] * dv[:, 1] - dv[:, 0] * du[:, 1]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        ds = (r[:, 0] * dv[:, 1] - r[:, 1] * dv[:, 0]) / det
        dt = (du[:, 0] * r[:, 1] - du[:, 1] * r[:, 0]) / det
        # damp huge steps (far outside the surface the extrapolated cubic may be poor)
        n = np.hypot(ds, dt)
        k = np.minimum(1.0, 2.0 / np.maximum(n, 1e-300))
        sf[act] = sa - k * ds
        tf[act] = ta - k * dt
    return s, t


_CHUNK = 1 << 15


def affine_frame(patch: Patch, tol: float = 1e-9):
    """``(O, A)`` when the patch is exactly the affine map ``O + A (s, t)``, else None.

    Patches fresh from :func:`build_patch` are affine; ``deform`` makes them not.
    """
    ctrl = np.asarray(patch.ctrl, np.float64)
    M, N = patch.shape
    O = ctrl[0, 0, 0]
    a = ctrl[0, 0, 1]
    b = ctrl[0, 0, 2]
    ii, jj = np.meshgrid(np.arange(M, dtype=np.float64), np.arange(N, dtype=np.float64), indexing="ij")
    ref = np.zeros_like(ctrl)
    ref[..., 0, :] = O + ii[..., None] * a + jj[..., None] * b
    ref[..., 1, :] = a
    ref[..., 2, :] = b
    scale = max(1.0, float(np.abs(ctrl[..., 0, :]).max()))
    if np.abs(ctrl - ref).max() > tol * scale:
        return None
    A = np.stack([a, b], axis=1)
    if abs(np.linalg.det(A)) < 1e-12:
        return None
    return O.copy(), A


def inverse(patch: Patch, xy, t_loc: float = 0.001, n_itr: int = 8, newton: int = 12, method: str = "auto") -> np.ndarray:
    """Parameters ``(s, t)`` (unnormalised) of image points ``xy`` (..., 2).

    The paper's 2D binary search, vectorised: the control-point quads locate
    the sub-patch (a walk from the bilinear guess of the four patch corners),
    then the sub-patch's parameter square is halved ``n_itr`` times, each time
    keeping the quadrant whose surface quad (corners, edge midpoints and centre
    evaluated on the surface) contains the point, until the surface point of
    the square's centre is within ``t_loc`` px. At most ``newton`` Newton
    steps on the global surface then polish the result (each point stops once
    within 1e-10 px; the cubic is extrapolated outside the domain, see the
    module docstring). The quads are straight while a bent patch's cell
    borders are cubic, so near a border the search may end in the
    neighbouring cell; Newton crosses cells and corrects that.

    ``method='auto'`` solves an exactly affine patch (as built by
    :func:`build_patch`, before any deformation) in closed form, and searches
    otherwise; ``method='search'`` always searches.
    """
    xy = np.asarray(xy, np.float64)
    shape = xy.shape[:-1]
    xy = xy.reshape(-1, 2)
    if xy.shape[0] == 0:
        return np.zeros(shape + (2,))
    if method not in ("auto", "search"):
        raise ValueError(f"unknown inverse method {method!r}")
    if method == "auto":
        frame = affine_frame(patch)
        if frame is not None:
            O, A = frame
            st = np.linalg.solve(A, (xy - O).T).T
            return st.reshape(shape + (2,))
    if len(xy) > _CHUNK:
        parts = [inverse(patch, xy[k : k + _CHUNK], t_loc, n_itr, newton, method) for k in range(0, len(xy), _CHUNK)]
        return np.concatenate(parts, axis=0).reshape(shape + (2,))
    K = coefficients(patch)
    i, j = _locate_cell(patch, xy)
    Kc = _gather(K, i, j)
    n = len(xy)
    u0 = np.zeros(n)
    v0 = np.zeros(n)
    h = np.ones(n)
    frac = np.array([0.0, 0.5, 1.0])
    done = np.zeros(n, bool)
    for _ in range(n_itr):
        uu = u0[:, None] + h[:, None] * frac  # (n, 3)
        vv = v0[:, None] + h[:, None] * frac
        Q = _grid_eval(Kc, uu, vv)  # (n, 3, 3, 2) surface points of the square
        done |= np.hypot(*(Q[:, 1, 1] - xy).T) < t_loc
        if done.all():
            break
        best = np.zeros(n, np.int64)
        best_out = np.full(n, np.inf)
        for qa in (0, 1):
            for qb in (0, 1):
                a, b = _bilinear_inverse(
                    Q[:, qa, qb], Q[:, qa + 1, qb], Q[:, qa, qb + 1], Q[:, qa + 1, qb + 1], xy, iters=3
                )
                o = _outside(a, b)
                better = o < best_out
                best = np.where(better, qa * 2 + qb, best)
                best_out = np.where(better, o, best_out)
        move = ~done
        h2 = h * 0.5
        u0 = np.where(move, u0 + (best // 2) * h2, u0)
        v0 = np.where(move, v0 + (best % 2) * h2, v0)
        h = np.where(move, h2, h)
    s = i + u0 + 0.5 * h
    t = j + v0 + 0.5 * h
    s, t = _newton(patch, xy, s, t, newton, coef=K)
    return np.stack([s, t], axis=-1).reshape(shape + (2,))


class InverseLUT:
    """Look-up-table inverse: a dense table of ``(s, t)`` over the patch's bounding box.

    The table samples the exact inverse on a lattice of spacing ``step`` px
    covering the surface's bounding box plus ``margin`` px; a query is a
    bilinear look-up (clamped at the table border) followed by at most
    ``newton`` Newton steps, which restores full accuracy (the inverse map is smooth on a
    fold-free patch). Memory: 16 bytes per table node.
    """

    def __init__(self, patch: Patch, step: float = 1.0, margin: float = 2.0, newton: int = 6, max_nodes: int = 4_000_000):
        self.patch = patch
        self.newton = newton
        M, N = patch.shape
        ss, tt = np.meshgrid(np.linspace(0, M - 1, 8 * (M - 1) + 1), np.linspace(0, N - 1, 8 * (N - 1) + 1), indexing="ij")
        pts = forward(patch, ss, tt).reshape(-1, 2)
        lo = pts.min(axis=0) - margin
        hi = pts.max(axis=0) + margin
        span = hi - lo
        step = float(step)
        while (math.ceil(span[0] / step) + 1) * (math.ceil(span[1] / step) + 1) > max_nodes:
            step *= 1.5
        nx = int(math.ceil(span[0] / step)) + 1
        ny = int(math.ceil(span[1] / step)) + 1
        self.origin = lo
        self.step = step
        gx = lo[0] + step * np.arange(nx)
        gy = lo[1] + step * np.arange(ny)
        X, Y = np.meshgrid(gx, gy)
        self.table = inverse(patch, np.stack([X, Y], axis=-1), method="search")  # (ny, nx, 2)

    def __call__(self, xy) -> np.ndarray:
        xy = np.asarray(xy, np.float64)
        ny, nx = self.table.shape[:2]
        fx = np.clip((xy[..., 0] - self.origin[0]) / self.step, 0, nx - 1)
        fy = np.clip((xy[..., 1] - self.origin[1]) / self.step, 0, ny - 1)
        x0 = np.minimum(np.floor(fx).astype(np.int64), nx - 2) if nx > 1 else np.zeros(fx.shape, np.int64)
        y0 = np.minimum(np.floor(fy).astype(np.int64), ny - 2) if ny > 1 else np.zeros(fy.shape, np.int64)
        ax = (fx - x0)[..., None]
        ay = (fy - y0)[..., None]
        T = self.table
        x1 = np.minimum(x0 + 1, nx - 1)
        y1 = np.minimum(y0 + 1, ny - 1)
        st = (T[y0, x0] * (1 - ax) + T[y0, x1] * ax) * (1 - ay) + (T[y1, x0] * (1 - ax) + T[y1, x1] * ax) * ay
        s, t = _newton(self.patch, xy, st[..., 0], st[..., 1], self.newton)
        return np.stack([s, t], axis=-1)


def normalize(patch: Patch, st) -> np.ndarray:
    """``(S, T) = (s / (M-1), t / (N-1))`` clamped to ``[0, 1]``."""
    M, N = patch.shape
    st = np.asarray(st, np.float64)
    return np.clip(st / np.array([M - 1, N - 1], np.float64), 0.0, 1.0)


def denormalize(patch: Patch, ST) -> np.ndarray:
    """``(s, t) = (S (M-1), T (N-1))``."""
    M, N = patch.shape
    return np.asarray(ST, np.float64) * np.array([M - 1, N - 1], np.float64)


#: Pixel scale floor (px per unit of S or T): a degenerate patch still has a finite scale.
MIN_SCALE_PX = 1e-3


def patch_pixel_scale(patch: Patch) -> tuple[float, float]:
    """Pixels per unit of ``S`` and ``T``: mean lengths of the control polygon's s and t lines.

    Parameters
    ----------
    patch : Patch

    Returns
    -------
    (float, float)
        Pixels per unit of ``S`` and of ``T``, at least :data:`MIN_SCALE_PX`.
    """
    pos = np.asarray(patch.ctrl, np.float64)[:, :, 0, :]
    sx = float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).sum(axis=0).mean()) if pos.shape[0] > 1 else 0.0
    sy = float(np.linalg.norm(np.diff(pos, axis=1), axis=-1).sum(axis=1).mean()) if pos.shape[1] > 1 else 0.0
    return max(sx, MIN_SCALE_PX), max(sy, MIN_SCALE_PX)


# --------------------------------------------------------------------------- construction


def adini_twist(ctrl: np.ndarray) -> np.ndarray:
    """Adini twist vectors (M, N, 2) from positions and s/t derivatives of ``ctrl``.

    ``T_ij = dPt/ds + dPs/dt - d2P/dsdt``, each by central differences
    (``(X_{i+1} - X_{i-1}) / 2``) inside and one-sided differences at the
    border, so that bilinear data are reproduced exactly. (The formula printed
    in the paper pairs the s derivative with the i direction and adds the
    position term; we use Adini's formula as published by Barnhill et al.)
    """
    P = ctrl[..., 0, :]
    Ds = ctrl[..., 1, :]
    Dt = ctrl[..., 2, :]
    M, N = P.shape[:2]
    ii = np.arange(M)
    jj = np.arange(N)
    i0 = np.maximum(ii - 1, 0)
    i1 = np.minimum(ii + 1, M - 1)
    j0 = np.maximum(jj - 1, 0)
    j1 = np.minimum(jj + 1, N - 1)
    di = (i1 - i0).astype(np.float64)[:, None, None]
    dj = (j1 - j0).astype(np.float64)[None, :, None]
    a = (Dt[i1, :] - Dt[i0, :]) / di
    b = (Ds[:, j1] - Ds[:, j0]) / dj
    c = (P[i1][:, j1] - P[i1][:, j0] - P[i0][:, j1] + P[i0][:, j0]) / (di * dj)
    return a + b - c


def choose_grid(mask_area: float, rect_w: float, rect_h: float, n_features: int | None = None) -> tuple[int, int]:
    """Control grid ``(M, N)`` for a region.

    ``rect_w`` is the side along ``s`` (the longer one), ``rect_h`` along ``t``.
    The target cell size is 48 px, shrunk for regions that fill little of
    their rectangle (``sqrt(fill)``, so thin curved regions such as a C or a
    spiral get enough control points to be bent into shape later) and, when
    ``n_features`` is given, so that a cell holds about 256 features at most.
    Each side gets ``round(side / cell) + 1`` points, clamped to ``[2, 32]``.
    """
    rect_w = max(float(rect_w), 1.0)
    rect_h = max(float(rect_h), 1.0)
    fill = min(1.0, max(float(mask_area), 1.0) / (rect_w * rect_h))
    cell = 48.0 * max(0.5, math.sqrt(fill))
    if n_features:
        cells_needed = n_features / 256.0
        if cells_needed > 1:
            cell = min(cell, math.sqrt(rect_w * rect_h / cells_needed))
    cell = max(cell, 8.0)
    M = int(min(32, max(2, round(rect_w / cell) + 1)))
    N = int(min(32, max(2, round(rect_h / cell) + 1)))
    return M, N


def _mask_hull(mask: np.ndarray | None) -> np.ndarray:
    """Vertices (k, 2) of the convex hull of all the region's pixel squares (none for no mask).

    Boundary pixels suffice: the squares of interior pixels lie inside their hull.
    """
    if mask is None:
        return np.zeros((0, 2))
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    rr, cc = np.nonzero(mask & (inner == 0))
    if not rr.size:
        return np.zeros((0, 2))
    corners = np.concatenate([np.stack([cc + dx, rr + dy], axis=1) for dx in (0, 1) for dy in (0, 1)], axis=0)
    # whole pixel corners: exact in float32 up to 2^24 px
    return cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(np.float64)


def _min_area_rect(hull: np.ndarray, outline=None):
    """Minimum-area rectangle (centre, unit axes, lengths) of the region's pixel squares (their ``hull``,
    :func:`_mask_hull`) and its outline's outer polygon."""
    if outline is not None and len(outline):
        pts = np.concatenate([np.asarray(outline[0], np.float64), hull], axis=0)
    else:
        pts = hull
    if len(pts) == 0:
        raise TpsvError("cannot build a patch for an empty region")
    (cx, cy), (w, h), ang = cv2.minAreaRect(pts.astype(np.float32))
    th = math.radians(ang)
    e1 = np.array([math.cos(th), math.sin(th)])
    e2 = np.array([-math.sin(th), math.cos(th)])
    if h > w:
        w, h = h, w
        e1, e2 = e2, e1
    # orientation: det[e_s, e_t] > 0 (x right, y down)
    if e1[0] * e2[1] - e1[1] * e2[0] < 0:
        e2 = -e2
    # canonical direction of s: pointing right (or down when vertical)
    if e1[0] < -1e-9 or (abs(e1[0]) <= 1e-9 and e1[1] < 0):
        e1, e2 = -e1, -e2
    # minAreaRect works in float32: verify and enlarge to contain all points exactly
    c = np.array([cx, cy], np.float64)
    d = pts - c
    a1 = d @ e1
    a2 = d @ e2
    lo1, hi1, lo2, hi2 = a1.min(), a1.max(), a2.min(), a2.max()
    c = c + e1 * (lo1 + hi1) / 2 + e2 * (lo2 + hi2) / 2
    return c, e1, e2, float(hi1 - lo1), float(hi2 - lo2)


#: Padding (px) added around the minimum-area rectangle on every side.
PAD = 1.0
#: Control vectors of a new patch are multiples of 1 / GRID_QUANTUM px (the codec's quantum).
GRID_QUANTUM = 16


def _covers(hull: np.ndarray, O, a, b, M, N) -> bool:
    """Whether every pixel corner of the region maps inside the affine grid's domain: the domain is
    convex, so the corners of the pixel squares' ``hull`` (:func:`_mask_hull`) tell."""
    if len(hull) == 0:
        return True
    eps = 1e-9
    st = np.linalg.solve(np.stack([a, b], 1), (hull - O).T).T
    return bool((st[:, 0] >= -eps).all() and (st[:, 0] <= M - 1 + eps).all()
                and (st[:, 1] >= -eps).all() and (st[:, 1] <= N - 1 + eps).all())


def build_patch(mask: np.ndarray, outline=None, grid: tuple[int, int] | None = None, n_features: int | None = None) -> Patch:
    """One fold-free Hermite patch covering a region.

    The paper finds four corners on the region outline and fits Hermite
    boundary curves, with RDP plus convex decomposition for non-convex shapes;
    that surface folds on C shapes, rings and spirals (its boundary curves
    follow a non-convex outline, so interior iso-curves cross), and a folded
    map gives some pixels two (s, t) and others none. We keep the Hermite
    representation (M x N control points with position, s and t derivatives
    and Adini twist) but place it on the region's minimum-area rotated
    rectangle (``cv2.minAreaRect`` of all the region's pixel squares, padded
    by :data:`PAD` px on every side), corners = the rectangle's corners:

    * control point ``(i, j) = O + i a + j b`` with ``a = (L_s / (M-1)) e_s``,
      ``b = (L_t / (N-1)) e_t``; derivatives ``Ds = a``, ``Dt = b`` (the
      spacing, per unit of s and t); twists from :func:`adini_twist`, which
      gives exactly zero on this grid.
    * A cubic Hermite segment with ``P1 - P0 = D0 = D1`` is the linear
      segment, so each bicubic cell with zero twist is exactly the affine map
      ``O + s a + t b``: the Jacobian is the constant ``det[a, b] =
      L_s L_t / ((M-1)(N-1)) > 0`` everywhere, the map is one-to-one, and
      since the rectangle contains every pixel square of the region (with a
      1 px margin) every pixel of any shape (holes, thin parts, spirals,
      single pixels) gets exactly one (s, t) inside the domain.
    * ``s`` runs along the longer side and points right (or down), and
      ``det[e_s, e_t] > 0`` with x right and y down.

    The result is a genuine Hermite patch that ``deform`` can bend by moving
    control vectors; :func:`fold_free` checks a deformed patch.

    Parameters
    ----------
    mask : ndarray (H, W) bool
        The region's pixels.
    outline : list of ndarray, optional
        The region's outline (its outer polygon is included in the rectangle).
    grid : (M, N), optional
        Control grid; default :func:`choose_grid`.
    n_features : int, optional
        Passed to :func:`choose_grid`.
    """
    mask = None if mask is None else np.asarray(mask, bool)
    hull = _mask_hull(mask)
    c, e1, e2, L1, L2 = _min_area_rect(hull, outline)
    L1 += 2 * PAD
    L2 += 2 * PAD
    area = float(mask.sum()) if mask is not None else L1 * L2
    if grid is None:
        M, N = choose_grid(area, L1, L2, n_features)
    else:
        M, N = int(grid[0]), int(grid[1])
        if M < 2 or N < 2:
            raise TpsvError(f"patch grid {M}x{N} is too small (at least 2x2)")
    # Snap the grid to the file's control-vector quantum (1/16 px) so that the
    # patch a decoder reads back is still exactly affine (closed-form inverse);
    # grow the rectangle until every pixel square of the region is inside.
    q = float(GRID_QUANTUM)
    for _ in range(8):
        a = np.round(e1 * (L1 / (M - 1)) * q) / q
        b = np.round(e2 * (L2 / (N - 1)) * q) / q
        O = np.round((c - a * (M - 1) / 2 - b * (N - 1) / 2) * q) / q
        if _covers(hull, O, a, b, M, N):
            break
        L1 += 1.0
        L2 += 1.0
    ii, jj = np.meshgrid(np.arange(M, dtype=np.float64), np.arange(N, dtype=np.float64), indexing="ij")
    ctrl = np.zeros((M, N, 4, 2), np.float64)
    ctrl[..., 0, :] = O + ii[..., None] * a + jj[..., None] * b
    ctrl[..., 1, :] = a
    ctrl[..., 2, :] = b
    ctrl[..., 3, :] = adini_twist(ctrl)
    return Patch(ctrl=ctrl)


def min_jacobian(patch: Patch, samples: int = 8) -> float:
    """Smallest Jacobian determinant over ``samples`` x ``samples`` points per cell (cell borders included).

    Each cell's own polynomial is evaluated on the closed cell, so an interior
    cell border is sampled from both sides (the Hermite patch is only C1
    there). The derivative polynomials are evaluated on the per-cell tensor
    grid by matrix products, a batch of cell rows at a time, so a 256 x 256
    grid (4 million samples) takes well under a second and bounded memory.
    """
    K = coefficients(patch)  # (M-1, N-1, 4, 4, 2): M(u, v) = sum K[p, q] u^p v^q in each cell
    x = np.linspace(0.0, 1.0, int(samples) + 1)
    p = np.arange(4)
    P = x[:, None] ** p  # (a, 4)
    dP = p * x[:, None] ** np.maximum(p - 1, 0)  # d/du of u^p
    rows = max(1, 4096 // K.shape[1])
    low = np.inf
    for r in range(0, K.shape[0], rows):
        Kr = K[r:r + rows]
        du = np.einsum("ijpqk,ap,bq->ijabk", Kr, dP, P, optimize=True)
        dv = np.einsum("ijpqk,ap,bq->ijabk", Kr, P, dP, optimize=True)
        det = du[..., 0] * dv[..., 1] - dv[..., 0] * du[..., 1]
        low = min(low, float(det.min()))
    return low


def fold_free(patch: Patch, samples: int = 8) -> bool:
    """True when the sampled Jacobian determinant is positive everywhere."""
    return min_jacobian(patch, samples) > 0.0
