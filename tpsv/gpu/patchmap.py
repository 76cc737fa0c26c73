"""Pixel -> normalised patch parameters (S, T), as Warp kernels (cpu and cuda).

This is ``tpsv.geometry.patch.inverse`` for every output pixel at once, one thread per
pixel, in float32. Layout (:class:`PatchSet`), all flat device arrays:

* ``coef``: per cell of every patch, the 16 power-basis coefficients
  ``K[p, q]`` (vec2) of ``M(u, v) = sum K[p, q] u^p v^q``
  (``tpsv.geometry.patch.coefficients``), cells in row-major ``(i, j)`` order;
* ``pos``: control-point positions (vec2), row-major ``(i, j)``;
* ``reg_i`` (R, 4) int32: ``M, N, pos offset, coef offset``;
* ``reg_f`` (R, 7) float32: ``affine flag, O (2), A^-1 (4)``; an exactly affine
  patch (fresh from ``build_patch``) is inverted in closed form.

Other patches: the same algorithm as ``tpsv.geometry.patch.inverse``: a walk over the
control-point quads from the bilinear guess of the four patch corners locates
the cell, ``n_itr`` levels of 2D binary search (stopping once the centre of
the square is within ``t_loc`` px), then up to ``newton`` Newton steps on the
global surface (stopping within 1e-4 px)
(the border cell's cubic is extrapolated outside the domain). The result is
normalised, ``S = s / (M-1)``, ``T = t / (N-1)``, clamped to ``[0, 1]``.

Output pixel ``(X, Y)`` of an ``H x W`` index map samples source point
``((X + 0.5) * Ws / W, (Y + 0.5) * Hs / H)`` where ``(Ws, Hs) = src_size``, as
in ``tpsv.geometry.outline.rasterize_regions``. Pixels with a negative index get
``(-1, -1)``.

The kernels take the four arrays as one :class:`PatchArrays` struct and the
stopping rules as one :class:`Search` struct; the full-frame map and the
scattered points share one per-point body (:func:`_inverse`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .. import memo
from ..geometry.patch import affine_frame, coefficients
from . import warp as _warp
from .transfer import upload


@wp.func
def _horner(coef: wp.array(dtype=wp.vec2), base: int, u: float, v: float):
    # value, d/du, d/dv of sum K[p, q] u^p v^q (K row-major p, q at base)
    val = wp.vec2(0.0, 0.0)
    du = wp.vec2(0.0, 0.0)
    dv = wp.vec2(0.0, 0.0)
    for pp in range(4):
        p = 3 - pp
        k0 = coef[base + p * 4 + 0]
        k1 = coef[base + p * 4 + 1]
        k2 = coef[base + p * 4 + 2]
        k3 = coef[base + p * 4 + 3]
        kv = k0 + v * (k1 + v * (k2 + v * k3))
        kdv = k1 + v * (2.0 * k2 + 3.0 * v * k3)
        du = du * u + val
        val = val * u + kv
        dv = dv * u + kdv
    return val, du, dv


@wp.func
def _cell(x: float, n: int):
    return wp.clamp(int(wp.floor(x)), 0, n - 2)


@wp.func
def _surface(coef: wp.array(dtype=wp.vec2), coff: int, M: int, N: int, s: float, t: float):
    i = _cell(s, M)
    j = _cell(t, N)
    return _horner(coef, coff + (i * (N - 1) + j) * 16, s - float(i), t - float(j))


@wp.func
def _bilin(A: wp.vec2, B: wp.vec2, C: wp.vec2, D: wp.vec2, p: wp.vec2, iters: int):
    # local (a, b) of p in the bilinear quad A(0,0) B(1,0) C(0,1) D(1,1)
    e = B - A
    f = C - A
    g = A - B - C + D
    a = float(0.5)
    b = float(0.5)
    for _k in range(iters):
        r = A + a * e + b * f + (a * b) * g - p
        ja = e + b * g
        jb = f + a * g
        det = ja[0] * jb[1] - ja[1] * jb[0]
        if wp.abs(det) < 1.0e-12:
            det = 1.0e-12
        da = (r[0] * jb[1] - r[1] * jb[0]) / det
        db = (ja[0] * r[1] - ja[1] * r[0]) / det
        a = wp.clamp(a - da, -4.0, 5.0)
        b = wp.clamp(b - db, -4.0, 5.0)
    return wp.vec2(a, b)


@wp.func
def _outside(ab: wp.vec2):
    return wp.max(wp.max(wp.max(0.0, -ab[0]), ab[0] - 1.0), wp.max(-ab[1], ab[1] - 1.0))


@wp.struct
class PatchArrays:
    """All patches as flat arrays (see the module docstring)."""

    pos: wp.array(dtype=wp.vec2)
    coef: wp.array(dtype=wp.vec2)
    reg_i: wp.array2d(dtype=wp.int32)
    reg_f: wp.array2d(dtype=wp.float32)


@wp.struct
class Search:
    """Stopping rules of the inverse: ``t_loc`` px, ``n_itr`` bisection levels, ``n_newton`` steps."""

    t_loc: float
    n_itr: int
    n_newton: int


@wp.func
def _locate_cell(pos: wp.array(dtype=wp.vec2), poff: int, M: int, N: int, p: wp.vec2):
    """Cell ``(i, j)`` holding ``p``: bilinear guess from the patch corners, then a walk over quads."""
    fm = float(M - 1)
    fn = float(N - 1)
    g = _bilin(pos[poff], pos[poff + (M - 1) * N], pos[poff + N - 1], pos[poff + M * N - 1], p, 5)
    i = wp.clamp(int(wp.floor(g[0] * fm)), 0, M - 2)
    j = wp.clamp(int(wp.floor(g[1] * fn)), 0, N - 2)
    for _w in range(M + N):
        q = poff + i * N + j
        ab = _bilin(pos[q], pos[q + N], pos[q + 1], pos[q + N + 1], p, 5)
        di = int(0)
        dj = int(0)
        if ab[0] < 0.0 and i > 0:
            di = -1
        if ab[0] > 1.0 and i < M - 2:
            di = 1
        if ab[1] < 0.0 and j > 0:
            dj = -1
        if ab[1] > 1.0 and j < N - 2:
            dj = 1
        if di == 0 and dj == 0:
            break
        i = i + di
        j = j + dj
    return i, j


@wp.func
def _bisect_cell(coef: wp.array(dtype=wp.vec2), base: int, p: wp.vec2, t_loc: float, n_itr: int):
    """2D binary search in one cell: corner ``(u0, v0)`` and side ``h`` of the sub-square holding ``p``."""
    u0 = float(0.0)
    v0 = float(0.0)
    h = float(1.0)
    q00, d0, d1 = _horner(coef, base, 0.0, 0.0)
    q20, d0, d1 = _horner(coef, base, 1.0, 0.0)
    q02, d0, d1 = _horner(coef, base, 0.0, 1.0)
    q22, d0, d1 = _horner(coef, base, 1.0, 1.0)
    for _l in range(n_itr):
        h2 = 0.5 * h
        q10, d0, d1 = _horner(coef, base, u0 + h2, v0)
        q01, d0, d1 = _horner(coef, base, u0, v0 + h2)
        q11, d0, d1 = _horner(coef, base, u0 + h2, v0 + h2)
        q21, d0, d1 = _horner(coef, base, u0 + h, v0 + h2)
        q12, d0, d1 = _horner(coef, base, u0 + h2, v0 + h)
        if wp.length(q11 - p) < t_loc:
            break
        o00 = _outside(_bilin(q00, q10, q01, q11, p, 3))
        o01 = _outside(_bilin(q01, q11, q02, q12, p, 3))
        o10 = _outside(_bilin(q10, q20, q11, q21, p, 3))
        o11 = _outside(_bilin(q11, q21, q12, q22, p, 3))
        best = o00
        qa = int(0)
        qb = int(0)
        if o01 < best:
            best = o01
            qa = 0
            qb = 1
        if o10 < best:
            best = o10
            qa = 1
            qb = 0
        if o11 < best:
            best = o11
            qa = 1
            qb = 1
        if qa == 0 and qb == 0:
            q20 = q10
            q02 = q01
            q22 = q11
        if qa == 0 and qb == 1:
            q00 = q01
            q20 = q11
            q22 = q12
        if qa == 1 and qb == 0:
            q00 = q10
            q02 = q11
            q22 = q21
        if qa == 1 and qb == 1:
            q00 = q11
            q20 = q21
            q02 = q12
        u0 = u0 + float(qa) * h2
        v0 = v0 + float(qb) * h2
        h = h2
    return u0, v0, h


@wp.func
def _newton(coef: wp.array(dtype=wp.vec2), coff: int, M: int, N: int, p: wp.vec2, s: float, t: float, n_newton: int):
    """Newton polish of ``(s, t)`` on the global surface (steps at most 2 cells long)."""
    for _n in range(n_newton):
        val, ds, dt = _surface(coef, coff, M, N, s, t)
        res = val - p
        if wp.length(res) < 1.0e-4:
            break
        det = ds[0] * dt[1] - dt[0] * ds[1]
        if wp.abs(det) < 1.0e-12:
            det = 1.0e-12
        es = (res[0] * dt[1] - res[1] * dt[0]) / det
        et = (ds[0] * res[1] - ds[1] * res[0]) / det
        nrm = wp.sqrt(es * es + et * et)
        k = wp.min(1.0, 2.0 / wp.max(nrm, 1.0e-30))
        s = s - k * es
        t = t - k * et
    return s, t


@wp.func
def _inverse(ps: PatchArrays, opt: Search, r: int, p: wp.vec2):
    """Normalised ``(S, T)`` of point ``p`` in region ``r``'s patch; ``(-1, -1)`` when ``r < 0``."""
    if r < 0:
        return wp.vec2(-1.0, -1.0)
    M = ps.reg_i[r, 0]
    N = ps.reg_i[r, 1]
    fm = float(M - 1)
    fn = float(N - 1)
    if ps.reg_f[r, 0] > 0.5:
        # an exactly affine patch: closed form
        d = p - wp.vec2(ps.reg_f[r, 1], ps.reg_f[r, 2])
        s = ps.reg_f[r, 3] * d[0] + ps.reg_f[r, 4] * d[1]
        t = ps.reg_f[r, 5] * d[0] + ps.reg_f[r, 6] * d[1]
        return wp.vec2(wp.clamp(s / fm, 0.0, 1.0), wp.clamp(t / fn, 0.0, 1.0))
    coff = ps.reg_i[r, 3]
    i, j = _locate_cell(ps.pos, ps.reg_i[r, 2], M, N, p)
    u0, v0, h = _bisect_cell(ps.coef, coff + (i * (N - 1) + j) * 16, p, opt.t_loc, opt.n_itr)
    s, t = _newton(ps.coef, coff, M, N, p, float(i) + u0 + 0.5 * h, float(j) + v0 + 0.5 * h, opt.n_newton)
    return wp.vec2(wp.clamp(s / fm, 0.0, 1.0), wp.clamp(t / fn, 0.0, 1.0))


@wp.kernel
def _map_kernel(ps: PatchArrays, opt: Search, index: wp.array2d(dtype=wp.int32), sx: float, sy: float, y0: int,
                out: wp.array2d(dtype=wp.vec2)):
    """Every output pixel of rows ``y0 ..``: its source point ``((x + 0.5) sx, (y0 + y + 0.5) sy)`` in its region.

    A band of rows and the whole frame run this same kernel, so their pixels
    are bit-identical on every device (a separate kernel may be compiled with
    other floating-point contractions on CUDA).
    """
    y, x = wp.tid()
    p = wp.vec2((float(x) + 0.5) * sx, (float(y + y0) + 0.5) * sy)
    out[y, x] = _inverse(ps, opt, index[y, x], p)


@wp.kernel
def _points_kernel(ps: PatchArrays, opt: Search, region: wp.array(dtype=wp.int32), xy: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec2)):
    """Scattered points ``xy`` in regions ``region`` (``(0, 0)`` for region -1: none)."""
    k = wp.tid()
    r = region[k]
    if r >= 0:
        out[k] = _inverse(ps, opt, r, xy[k])
    else:
        out[k] = wp.vec2(0.0, 0.0)


@dataclass
class PatchSet:
    """All patches of a model as flat device arrays (see the module docstring).

    ``arrays`` is the :class:`PatchArrays` struct the kernels take.
    """

    arrays: PatchArrays
    device: str

    @classmethod
    def build(cls, patches, device: str = "cpu", cache: dict | None = None) -> "PatchSet":
        """Flatten ``patches`` (one per region) onto ``device``.

        Parameters
        ----------
        patches : list of Patch
        device : str
            Warp device (``cpu``, ``cuda``, ``cuda:N``).
        cache : dict, optional
            Flattened patches of an earlier build, by their control points:
            an editor that moves one region flattens only that patch again.
            It is left holding this build's patches only.

        Returns
        -------
        PatchSet
        """
        _warp()
        pos_l, coef_l = [], []
        R = len(patches)
        reg_i = np.zeros((max(R, 1), 4), np.int32)
        reg_f = np.zeros((max(R, 1), 7), np.float32)
        po = co = 0
        if cache is None:
            flat = [_flatten(p) for p in patches]
        else:
            keys = [np.asarray(p.ctrl, np.float64).tobytes() for p in patches]
            flat = memo.refresh(cache, keys, lambda idx: [_flatten(patches[i]) for i in idx])
        for r, (patch, (P, K, f)) in enumerate(zip(patches, flat)):
            M, N = patch.shape
            reg_i[r] = (M, N, po, co)
            reg_f[r] = f
            pos_l.append(P)
            coef_l.append(K)
            po += P.shape[0]
            co += K.shape[0]
        pos = np.concatenate(pos_l, axis=0) if pos_l else np.zeros((1, 2))
        coef = np.concatenate(coef_l, axis=0) if coef_l else np.zeros((1, 2))
        arrays = PatchArrays()
        arrays.pos, arrays.coef, arrays.reg_i, arrays.reg_f = upload(
            device, (pos, wp.vec2), (coef, wp.vec2), (reg_i, wp.int32), (reg_f, wp.float32))
        return cls(arrays=arrays, device=device)


def _flatten(patch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A patch's corner points (k, 2), its cells' coefficients (cells * 16, 2) row-major
    ``(i, j, p, q)``, and its ``reg_f`` row (1, origin, inverse of the affine map; zeros: not affine)."""
    P = np.asarray(patch.ctrl, np.float64)[..., 0, :].reshape(-1, 2)
    K = coefficients(patch).reshape(-1, 2)
    f = np.zeros(7, np.float32)
    frame = affine_frame(patch)
    if frame is not None:
        O, A = frame
        f[:] = (1.0, O[0], O[1], *np.linalg.inv(A).ravel())
    return P, K, f


def _search(t_loc: float, n_itr: int, newton: int) -> Search:
    opt = Search()
    opt.t_loc = float(t_loc)
    opt.n_itr = int(n_itr)
    opt.n_newton = int(newton)
    return opt


def inverse_map(
    patches,
    index,
    src_size: tuple[int, int],
    device: str = "cpu",
    t_loc: float = 0.001,
    n_itr: int = 8,
    newton: int = 12,
    patch_set: PatchSet | None = None,
    out_size: tuple[int, int] | None = None,
    row0: int = 0,
    threads: int | None = None,
):
    """Normalised ``(S, T)`` of every output pixel, as a device array.

    Parameters
    ----------
    patches : list of Patch
        One per region (``Model.regions[k].patch``); ignored when
        ``patch_set`` is given.
    index : ndarray (H, W) int32 or wp.array2d(int32)
        Region of every output pixel (``tpsv.geometry.outline.rasterize_regions``).
    src_size : (Ws, Hs)
        Model size; output pixel (X, Y) samples ``((X+0.5) Ws/W, (Y+0.5) Hs/H)``.
    device : str
        Warp device (``cpu``, ``cuda``, ``cuda:N``).
    t_loc, n_itr, newton
        Stopping rules (module docstring).
    patch_set : PatchSet, optional
        The patches already on the device (then ``device`` is its device).
    out_size : (W, H), optional
        Size of the whole output when ``index`` holds only a band of its rows
        (default: ``index``'s own shape).
    row0 : int
        Output row of ``index``'s first row (a band's offset).
    threads : int, optional
        Host threads on the CPU device (None: every core).

    Returns
    -------
    wp.array2d(dtype=wp.vec2), shape of ``index``, on ``device``.
    """
    from .rasterise import _launch_banded

    ps = patch_set if patch_set is not None else PatchSet.build(patches, device)
    device = ps.device
    if not isinstance(index, wp.array):
        index = wp.array(np.ascontiguousarray(index, np.int32), dtype=wp.int32, device=device)
    H, W = index.shape
    out = wp.empty((H, W), dtype=wp.vec2, device=device)
    W_out, H_out = out_size if out_size is not None else (W, H)
    sx = float(src_size[0]) / float(W_out)
    sy = float(src_size[1]) / float(H_out)
    opt = _search(t_loc, n_itr, newton)

    def launch(a, b):  # bands of rows run the same kernel as the whole frame: the same pixels
        wp.launch(_map_kernel, dim=(b - a, W), inputs=[ps.arrays, opt, index[a:b], sx, sy, int(row0) + a, out[a:b]],
                  device=device)

    _launch_banded(_map_kernel, H, H * W, device, threads, launch)
    return out


def inverse_map_numpy(patches, index, src_size, device: str = "cpu", **kw) -> np.ndarray:
    """:func:`inverse_map` copied to the host.

    Returns
    -------
    ndarray (H, W, 2) float32
    """
    return inverse_map(patches, index, src_size, device=device, **kw).numpy().reshape(np.shape(index) + (2,))


def inverse_points(patches, region, xy, device: str = "cpu", t_loc: float = 0.001, n_itr: int = 8, newton: int = 12,
                   patch_set: PatchSet | None = None) -> np.ndarray:
    """Normalised ``(S, T)`` of arbitrary points.

    Parameters
    ----------
    patches : list of Patch
    region : array_like (n,) int
        Region of each point (negative: ``(-1, -1)``).
    xy : array_like (n, 2)
        Points in model pixels.
    device, t_loc, n_itr, newton, patch_set
        As :func:`inverse_map`.

    Returns
    -------
    ndarray (n, 2) float32
    """
    ps = patch_set if patch_set is not None else PatchSet.build(patches, device)
    device = ps.device
    xy = np.ascontiguousarray(xy, np.float32).reshape(-1, 2)
    region = np.ascontiguousarray(region, np.int32).reshape(-1)
    n = xy.shape[0]
    if n == 0:
        return np.zeros((0, 2), np.float32)
    reg_d = wp.array(region, dtype=wp.int32, device=device)
    xy_d = wp.array(xy, dtype=wp.vec2, device=device)
    return inverse_points_device(ps, reg_d, xy_d, t_loc, n_itr, newton).numpy().reshape(n, 2)


@wp.kernel
def _to_vec2f(src: wp.array(dtype=wp.vec2d), dst: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    dst[i] = wp.vec2(wp.float32(src[i][0]), wp.float32(src[i][1]))


def inverse_points_device(patch_set: PatchSet, region, xy, t_loc: float = 0.001, n_itr: int = 8,
                          newton: int = 12) -> wp.array:
    """:func:`inverse_points` of points already on the device; the result stays there.

    Parameters
    ----------
    patch_set : PatchSet
    region : wp.array (n,) int32
    xy : wp.array (n,) vec2 or vec2d
        Points in model pixels (float64 points are rounded to float32, as
        :func:`inverse_points` rounds them).
    t_loc, n_itr, newton
        As :func:`inverse_map`.

    Returns
    -------
    wp.array (n,) vec2
    """
    device = patch_set.device
    n = int(region.shape[0])
    if xy.dtype == wp.vec2d:
        single = wp.empty(n, dtype=wp.vec2, device=device)
        if n:
            wp.launch(_to_vec2f, dim=n, inputs=[xy, single], device=device)
        xy = single
    out = wp.empty(n, dtype=wp.vec2, device=device)
    if n:
        wp.launch(_points_kernel, dim=n, inputs=[patch_set.arrays, _search(t_loc, n_itr, newton), region, xy, out],
                  device=device)
    return out
