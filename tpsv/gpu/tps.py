"""Warp kernels: build and solve every sub-patch TPS, then rasterise with blending.

One code path for the ``cpu`` and ``cuda`` devices. Data live in ``wp.array``
objects on the device; every launch is explicit.

Solve (per kernel, float64)
---------------------------
Eq. (4) of the paper, ``[Phi + lambda I, P; P^T, 0] [w; b] = [h; 0]``, is
solved in the null space of ``P^T``. With the kernel's anchors ``a0, a1, a2``
(slots 0-2, chosen by :func:`tpsv.tps.group.group_kernels`) and ``L_j`` the
barycentric coordinates of feature ``j`` w.r.t. the anchors,
``Q = [-L^T; I]`` spans ``null(P^T)``; ``w = Q gamma`` and

    ``A gamma = Q^T h``,   ``A = Q^T (Phi + lambda I) Q``

where ``A`` is symmetric positive definite (``phi = r^2 log r`` is
conditionally positive definite of order 2). The affine part follows from
the anchor rows: ``[1 x_a y_a] b = h_a - ((Phi + lambda I) w)_a``.

Launches: ``_prep`` (one thread per kernel slot: local coordinates,
barycentric coordinates, anchor rows of ``Phi``, projected right-hand side),
``_build`` (one thread per 16 columns of a row of the lower triangle of
``A``), a tile kernel per ``K`` (one block per kernel: ``tile_cholesky`` +
``tile_cholesky_solve``; cuSolverDx on CUDA when Warp has it, Warp's
cooperative fallback on the CPU), ``_finish`` (one thread per kernel: anchor
weights, ``b``, fallbacks, colour range) and ``_write_w`` (one thread per
slot: the other weights). ``A`` is padded to ``K x K``: the anchor rows and
inactive slots are identity rows with a zero right-hand side.

On the CPU device the kernels other than the tile solve, and the
rasteriser's pixel rows, are split into bands launched from a few host
threads (Warp's CPU launches run one thread each and release the GIL);
results do not depend on the split. The tile solve is one launch: Warp's CPU
tile kernels share one static scratch block, so two must never run at once.

A degenerate kernel (see ``tpsv.tps.group``) and any kernel whose solve is not
finite (which should not happen) get the affine fallback: least squares
along the line through anchors 0 and 1, constant across it (``w = 0``).

Coefficients are kept in float64 (for tests) and float32 (for rendering);
rasterisation evaluates in float32 in each kernel's local frame. Local
feature positions are rounded to float32 *before* the solve, so the float64
solution is exact for the very positions the rasteriser uses (a shift of
about 1e-7 of a kernel's size); otherwise that rounding, multiplied by the
large weights of rough data, dominates the float32 error.

Rasterise
---------
One thread per output pixel: its region, its ``(S, T)``, the at most 2 x 2
covering kernels of the region's grid, the TPS of each in its local frame,
the partition-of-unity blend (``tpsv.tps.group`` module doc), then Lab -> sRGB with
the formulas of ``tpsv.color``, clamped to ``[0, 1]``.

Range clamp (``clamp=True``, the default of :func:`rasterise`): each
kernel's value is clamped, per Lab channel, to the range of its own
features' colours before blending. A TPS overshoots beside close samples
of very different colour (curvilinear pairs) and extrapolates far from
features; on the bundled samples this clamp raises the PSNR by 4 to 13 dB.
The blend of clamped kernels is still continuous (no seams) but only C0
where a clamp is active; with ``clamp=False`` the result is the plain
localised TPS (what the accuracy tests compare with ``RBFInterpolator``).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..color import _WHITE, _XYZ2RGB
from ..errors import TpsvError
from . import resolve_device
from . import warp as _warp

# fast_math only changes CUDA float32 code (approximate log/division in the rasteriser:
# about 25 % faster on an H100, renders agree with the CPU device within 2e-4);
# the float64 solve and the CPU device are unaffected.
wp.set_module_options({"enable_backward": False, "fast_math": True})

_XYZ2RGB_W = wp.constant(wp.mat33(*[float(v) for v in np.asarray(_XYZ2RGB).ravel()]))
_WHITE_W = wp.constant(wp.vec3(*[float(v) for v in _WHITE]))

#: Output modes of :func:`rasterise`.
MODE_SRGB = 0
MODE_LAB = 1


# --------------------------------------------------------------------------- helpers


@wp.func
def _phi64(r2: wp.float64):
    if r2 > wp.float64(0.0):
        return wp.float64(0.5) * r2 * wp.log(r2)
    return wp.float64(0.0)


@wp.func
def _local64(st: wp.vec2d, fr: wp.vec4d):
    return wp.vec2d((st[0] - fr[0]) * fr[2], (st[1] - fr[1]) * fr[3])


@wp.func
def _round32(p: wp.vec2d):
    """Round to float32 and back: the solve uses exactly the positions the rasteriser sees."""
    return wp.vec2d(wp.float64(wp.float32(p[0])), wp.float64(wp.float32(p[1])))


@wp.func
def _d2(p: wp.vec2d, q: wp.vec2d):
    dx = p[0] - q[0]
    dy = p[1] - q[1]
    return dx * dx + dy * dy


@wp.func
def _finite3(v: wp.vec3d):
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])


# --------------------------------------------------------------------------- build + solve


@wp.kernel
def _prep(
    k_off: int,
    index: wp.array2d(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    degen: wp.array(dtype=wp.int32),
    frame: wp.array(dtype=wp.vec4d),
    st: wp.array(dtype=wp.vec2d),
    lab: wp.array(dtype=wp.vec3f),
    pts: wp.array2d(dtype=wp.vec2d),
    vals: wp.array2d(dtype=wp.vec3d),
    bary: wp.array2d(dtype=wp.vec3d),
    pa: wp.array2d(dtype=wp.vec3d),
    rhs: wp.array3d(dtype=wp.float64),
    pos32: wp.array2d(dtype=wp.vec2f),
):
    """Per slot: local point, value, barycentric coordinates, anchor row of Phi, projected rhs."""
    kk, j = wp.tid()
    k = kk + k_off
    m = count[k]
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    rhs[k, j, 0] = zero
    rhs[k, j, 1] = zero
    rhs[k, j, 2] = zero
    bary[k, j] = z3
    pa[k, j] = z3
    if j >= m:
        pts[k, j] = wp.vec2d(zero, zero)
        vals[k, j] = z3
        pos32[k, j] = wp.vec2f(0.0, 0.0)
        return
    fr = frame[k]
    p = _round32(_local64(st[index[k, j]], fr))
    c = lab[index[k, j]]
    h = wp.vec3d(wp.float64(c[0]), wp.float64(c[1]), wp.float64(c[2]))
    pts[k, j] = p
    vals[k, j] = h
    pos32[k, j] = wp.vec2f(wp.float32(p[0]), wp.float32(p[1]))
    if degen[k] != 0:
        return
    q0 = _round32(_local64(st[index[k, 0]], fr))
    q1 = _round32(_local64(st[index[k, 1]], fr))
    q2 = _round32(_local64(st[index[k, 2]], fr))
    pa[k, j] = wp.vec3d(_phi64(_d2(q0, p)), _phi64(_d2(q1, p)), _phi64(_d2(q2, p)))
    if j < 3:
        return
    e1 = q1 - q0
    e2 = q2 - q0
    d = p - q0
    det = e1[0] * e2[1] - e1[1] * e2[0]
    l1 = (d[0] * e2[1] - d[1] * e2[0]) / det
    l2 = (e1[0] * d[1] - e1[1] * d[0]) / det
    l0 = wp.float64(1.0) - l1 - l2
    bary[k, j] = wp.vec3d(l0, l1, l2)
    h0 = lab[index[k, 0]]
    h1 = lab[index[k, 1]]
    h2 = lab[index[k, 2]]
    for ch in range(3):
        rhs[k, j, ch] = h[ch] - l0 * wp.float64(h0[ch]) - l1 * wp.float64(h1[ch]) - l2 * wp.float64(h2[ch])


#: Columns of A per thread of ``_build`` (threads per kernel: K x ceil(K / BUILD_CHUNK)).
BUILD_CHUNK = 16


@wp.kernel
def _build(
    k_off: int,
    count: wp.array(dtype=wp.int32),
    degen: wp.array(dtype=wp.int32),
    pts: wp.array2d(dtype=wp.vec2d),
    bary: wp.array2d(dtype=wp.vec3d),
    pa: wp.array2d(dtype=wp.vec3d),
    lam: wp.array(dtype=wp.float64),
    chunk: int,
    A: wp.array3d(dtype=wp.float64),
):
    """Columns [c*chunk, (c+1)*chunk) of row j of the lower triangle of A = Q^T (Phi + lambda I) Q.

    Anchor rows/columns and inactive slots are identity. With G = Phi among
    the anchors, ``A_jl = phi_jl - L_j . pa_l - L_l . pa_j + L_j^T G L_l
    + lambda (delta_jl + L_j . L_l)``.
    """
    kk, j, c = wp.tid()
    k = kk + k_off
    l0 = c * chunk
    l1 = wp.min(l0 + chunk, j + 1)
    m = count[k]
    zero = wp.float64(0.0)
    if degen[k] != 0 or j < 3 or j >= m:
        for l in range(l0, l1):
            A[k, j, l] = zero
        if j >= l0 and j < l0 + chunk:
            A[k, j, j] = wp.float64(1.0)
        return
    Lj = bary[k, j]
    pj = pts[k, j]
    t = Lj[0] * pa[k, 0] + Lj[1] * pa[k, 1] + Lj[2] * pa[k, 2] - pa[k, j]
    for l in range(l0, l1):
        if l < 3:
            A[k, j, l] = zero
        else:
            Ll = bary[k, l]
            reg = wp.dot(Lj, Ll)
            if l == j:
                reg = reg + wp.float64(1.0)
            A[k, j, l] = _phi64(_d2(pj, pts[k, l])) - wp.dot(Lj, pa[k, l]) + wp.dot(Ll, t) + lam[k] * reg


_SOLVE_KERNELS: dict = {}


def _solve_kernel(K: int):
    """The tile Cholesky kernel for ``K`` slots (tile shapes are compile-time; compiled once per K)."""
    kern = _SOLVE_KERNELS.get(K)
    if kern is None:

        @wp.kernel(module="unique", enable_backward=False)
        def _solve_tile(k_off: int, A: wp.array3d(dtype=wp.float64), B: wp.array3d(dtype=wp.float64)):
            k = wp.tid() + k_off
            a = wp.tile_load(A[k], shape=(K, K))
            b = wp.tile_load(B[k], shape=(K, 3))
            wp.tile_cholesky_inplace(a)
            wp.tile_cholesky_solve_inplace(a, b)
            wp.tile_store(B[k], b)

        kern = _SOLVE_KERNELS[K] = _solve_tile
    return kern


@wp.func
def _slot_w(k: int, i: int, w0: wp.vec3d, w1: wp.vec3d, w2: wp.vec3d, gamma: wp.array3d(dtype=wp.float64)):
    if i == 0:
        return w0
    if i == 1:
        return w1
    if i == 2:
        return w2
    return wp.vec3d(gamma[k, i, 0], gamma[k, i, 1], gamma[k, i, 2])


@wp.kernel
def _finish(
    k_off: int,
    count: wp.array(dtype=wp.int32),
    degen: wp.array(dtype=wp.int32),
    pts: wp.array2d(dtype=wp.vec2d),
    vals: wp.array2d(dtype=wp.vec3d),
    bary: wp.array2d(dtype=wp.vec3d),
    pa: wp.array2d(dtype=wp.vec3d),
    gamma: wp.array3d(dtype=wp.float64),
    lam: wp.array(dtype=wp.float64),
    K: int,
    w64: wp.array2d(dtype=wp.vec3d),
    b64: wp.array2d(dtype=wp.vec3d),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
    status: wp.array(dtype=wp.int32),
    lo: wp.array(dtype=wp.vec3f),
    hi: wp.array(dtype=wp.vec3f),
):
    """Per kernel: w = Q gamma, the affine part from the anchor rows, fallbacks, float32 copies."""
    k = wp.tid() + k_off
    m = count[k]
    vmin = wp.vec3f(1.0e30, 1.0e30, 1.0e30)
    vmax = wp.vec3f(-1.0e30, -1.0e30, -1.0e30)
    for i in range(m):
        vi = vals[k, i]
        vf = wp.vec3f(wp.float32(vi[0]), wp.float32(vi[1]), wp.float32(vi[2]))
        vmin = wp.min(vmin, vf)
        vmax = wp.max(vmax, vf)
    lo[k] = vmin
    hi[k] = vmax
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    ok = degen[k] == 0
    st = int(0)
    if not ok:
        st = 1
    w0 = z3
    w1 = z3
    w2 = z3
    bb0 = z3
    bb1 = z3
    bb2 = z3
    if ok:
        fin = bool(True)
        for j in range(3, m):
            g = wp.vec3d(gamma[k, j, 0], gamma[k, j, 1], gamma[k, j, 2])
            fin = fin and _finite3(g)
            Lj = bary[k, j]
            w0 = w0 - Lj[0] * g
            w1 = w1 - Lj[1] * g
            w2 = w2 - Lj[2] * g
        r0 = vals[k, 0] - lam[k] * w0
        r1 = vals[k, 1] - lam[k] * w1
        r2 = vals[k, 2] - lam[k] * w2
        for i in range(m):
            wi = _slot_w(k, i, w0, w1, w2, gamma)
            pai = pa[k, i]
            r0 = r0 - pai[0] * wi
            r1 = r1 - pai[1] * wi
            r2 = r2 - pai[2] * wi
        q0 = pts[k, 0]
        q1 = pts[k, 1]
        q2 = pts[k, 2]
        one = wp.float64(1.0)
        M = wp.mat33d(one, q0[0], q0[1], one, q1[0], q1[1], one, q2[0], q2[1])
        Mi = wp.inverse(M)
        # b_row = sum_a Mi[row, a] r_a   (rows: constant, u, v; vec3 over channels)
        bb0 = Mi[0, 0] * r0 + Mi[0, 1] * r1 + Mi[0, 2] * r2
        bb1 = Mi[1, 0] * r0 + Mi[1, 1] * r1 + Mi[1, 2] * r2
        bb2 = Mi[2, 0] * r0 + Mi[2, 1] * r1 + Mi[2, 2] * r2
        fin = fin and _finite3(bb0) and _finite3(bb1) and _finite3(bb2)
        fin = fin and _finite3(w0) and _finite3(w1) and _finite3(w2)
        if not fin:
            ok = False
            st = 2
    if ok:
        # anchor slots here; slots 3.. are written by _write_w (one thread per slot)
        w64[k, 0] = w0
        w64[k, 1] = w1
        w64[k, 2] = w2
        w32[k, 0] = wp.vec3f(wp.float32(w0[0]), wp.float32(w0[1]), wp.float32(w0[2]))
        w32[k, 1] = wp.vec3f(wp.float32(w1[0]), wp.float32(w1[1]), wp.float32(w1[2]))
        w32[k, 2] = wp.vec3f(wp.float32(w2[0]), wp.float32(w2[1]), wp.float32(w2[2]))
    else:
        # affine fallback: least squares along anchors 0 -> 1, constant across
        cen = wp.vec2d(zero, zero)
        hm = z3
        for i in range(m):
            cen = cen + pts[k, i]
            hm = hm + vals[k, i]
        fm = wp.float64(wp.max(m, 1))
        cen = cen / fm
        hm = hm / fm
        dvec = wp.vec2d(wp.float64(1.0), zero)
        if m >= 2:
            e = pts[k, 1] - pts[k, 0]
            ln = wp.length(e)
            if ln > zero:
                dvec = e / ln
        stt = zero
        sth = z3
        for i in range(m):
            t = wp.dot(pts[k, i] - cen, dvec)
            stt = stt + t * t
            sth = sth + t * (vals[k, i] - hm)
        beta = z3
        if stt > zero:
            beta = sth / stt
        bb0 = hm - wp.dot(cen, dvec) * beta
        bb1 = dvec[0] * beta
        bb2 = dvec[1] * beta
        for i in range(3):
            w64[k, i] = z3
            w32[k, i] = wp.vec3f(0.0, 0.0, 0.0)
    b64[k, 0] = bb0
    b64[k, 1] = bb1
    b64[k, 2] = bb2
    b32[k, 0] = wp.vec3f(wp.float32(bb0[0]), wp.float32(bb0[1]), wp.float32(bb0[2]))
    b32[k, 1] = wp.vec3f(wp.float32(bb1[0]), wp.float32(bb1[1]), wp.float32(bb1[2]))
    b32[k, 2] = wp.vec3f(wp.float32(bb2[0]), wp.float32(bb2[1]), wp.float32(bb2[2]))
    status[k] = st


@wp.kernel
def _write_w(
    k_off: int,
    count: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    gamma: wp.array3d(dtype=wp.float64),
    w64: wp.array2d(dtype=wp.vec3d),
    w32: wp.array2d(dtype=wp.vec3f),
):
    """Slots 3..K-1: w = gamma for active slots of solved kernels, else 0."""
    kk, j = wp.tid()
    k = kk + k_off
    i = j + 3
    wi = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if status[k] == 0 and i < count[k]:
        wi = wp.vec3d(gamma[k, i, 0], gamma[k, i, 1], gamma[k, i, 2])
    w64[k, i] = wi
    w32[k, i] = wp.vec3f(wp.float32(wi[0]), wp.float32(wi[1]), wp.float32(wi[2]))


# --------------------------------------------------------------------------- rasterise


@wp.func
def _bump(z: float):
    if wp.abs(z) < 1.0:
        t = 1.0 - z * z
        return t * t
    return 0.0


@wp.func
def _eval_kernel(
    k: int,
    S: float,
    T: float,
    count: wp.array(dtype=wp.int32),
    frame32: wp.array(dtype=wp.vec4f),
    pos32: wp.array2d(dtype=wp.vec2f),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
):
    fr = frame32[k]
    u = (S - fr[0]) * fr[2]
    v = (T - fr[1]) * fr[3]
    acc = b32[k, 0] + u * b32[k, 1] + v * b32[k, 2]
    for i in range(count[k]):
        p = pos32[k, i]
        du = u - p[0]
        dv = v - p[1]
        r2 = du * du + dv * dv
        if r2 > 0.0:
            acc = acc + (0.5 * r2 * wp.log(r2)) * w32[k, i]
    return acc


@wp.func
def _lab_f_inv(f: float):
    if f > 0.206893:
        return f * f * f
    return (f - 16.0 / 116.0) / 7.787


@wp.func
def _gamma(c: float):
    c = wp.max(c, 0.0)
    s = float(0.0)
    if c > 0.0031308:
        s = 1.055 * wp.pow(c, 1.0 / 2.4) - 0.055
    else:
        s = 12.92 * c
    return wp.clamp(s, 0.0, 1.0)


@wp.func
def lab_to_srgb(lab: wp.vec3f):
    """Lab -> sRGB in [0, 1], the formulas of ``tpsv.color.lab_to_srgb``."""
    fy = (lab[0] + 16.0) / 116.0
    fx = fy + lab[1] / 500.0
    fz = fy - lab[2] / 200.0
    xyz = wp.vec3(
        _lab_f_inv(fx) * _WHITE_W[0],
        _lab_f_inv(fy) * _WHITE_W[1],
        _lab_f_inv(fz) * _WHITE_W[2],
    )
    lin = _XYZ2RGB_W * xyz
    return wp.vec3(_gamma(lin[0]), _gamma(lin[1]), _gamma(lin[2]))


@wp.func
def _axis(a: float, g: int, half: float, own: bool):
    """Cell index (own cell, or its covering neighbour; -1 if none) and weight along one axis."""
    i = wp.min(int(wp.floor(a)), g - 1)
    i = wp.max(i, 0)
    if own:
        if half <= 0.5:
            return i, 1.0
        return i, _bump((a - (float(i) + 0.5)) / half)
    if half <= 0.5:
        return -1, 0.0
    j = i + 1
    if a - float(i) < 0.5:
        j = i - 1
    if j < 0 or j >= g:
        return -1, 0.0
    w = _bump((a - (float(j) + 0.5)) / half)
    if w <= 0.0:
        return -1, 0.0
    return j, w


@wp.func
def _blend(
    r: int,
    S: float,
    T: float,
    grid: wp.array2d(dtype=wp.int32),
    fill: wp.array(dtype=wp.vec3f),
    half: float,
    count: wp.array(dtype=wp.int32),
    frame32: wp.array(dtype=wp.vec4f),
    pos32: wp.array2d(dtype=wp.vec2f),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
    lo: wp.array(dtype=wp.vec3f),
    hi: wp.array(dtype=wp.vec3f),
    clamp: int,
):
    gx = grid[r, 0]
    gy = grid[r, 1]
    k0 = grid[r, 2]
    if gx <= 0 or gy <= 0:
        return fill[r]
    a = wp.clamp(S, 0.0, 1.0) * float(gx)
    b = wp.clamp(T, 0.0, 1.0) * float(gy)
    acc = wp.vec3f(0.0, 0.0, 0.0)
    wsum = float(0.0)
    for sy in range(2):
        cy, wy = _axis(b, gy, half, sy == 0)
        if cy >= 0:
            for sx in range(2):
                cx, wx = _axis(a, gx, half, sx == 0)
                wgt = wx * wy
                if cx >= 0 and wgt > 0.0:
                    k = k0 + cy * gx + cx
                    val = _eval_kernel(k, S, T, count, frame32, pos32, w32, b32)
                    if clamp != 0:
                        val = wp.min(wp.max(val, lo[k]), hi[k])
                    acc = acc + wgt * val
                    wsum = wsum + wgt
    return acc / wsum


@wp.kernel
def _rasterise(
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    y0: int,
    grid: wp.array2d(dtype=wp.int32),
    fill: wp.array(dtype=wp.vec3f),
    background: wp.vec3f,
    half: float,
    count: wp.array(dtype=wp.int32),
    frame32: wp.array(dtype=wp.vec4f),
    pos32: wp.array2d(dtype=wp.vec2f),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
    lo: wp.array(dtype=wp.vec3f),
    hi: wp.array(dtype=wp.vec3f),
    clamp: int,
    mode: int,
    out: wp.array2d(dtype=wp.vec3f),
):
    yy, x = wp.tid()
    y = yy + y0
    r = region[y, x]
    lab = background
    if r >= 0:
        st = stmap[y, x]
        lab = _blend(r, st[0], st[1], grid, fill, half, count, frame32, pos32, w32, b32, lo, hi, clamp)
    if mode == 0:
        out[y, x] = lab_to_srgb(lab)
    else:
        out[y, x] = lab


@wp.kernel
def _eval_points(
    region: wp.array(dtype=wp.int32),
    st: wp.array(dtype=wp.vec2f),
    grid: wp.array2d(dtype=wp.int32),
    fill: wp.array(dtype=wp.vec3f),
    half: float,
    count: wp.array(dtype=wp.int32),
    frame32: wp.array(dtype=wp.vec4f),
    pos32: wp.array2d(dtype=wp.vec2f),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
    lo: wp.array(dtype=wp.vec3f),
    hi: wp.array(dtype=wp.vec3f),
    clamp: int,
    kernel: int,
    out: wp.array(dtype=wp.vec3f),
):
    """Blended Lab at scattered points; or, with ``kernel >= 0``, that one kernel's TPS."""
    i = wp.tid()
    p = st[i]
    if kernel >= 0:
        out[i] = _eval_kernel(kernel, p[0], p[1], count, frame32, pos32, w32, b32)
    else:
        out[i] = _blend(region[i], p[0], p[1], grid, fill, half, count, frame32, pos32, w32, b32, lo, hi, clamp)


@wp.kernel
def _weights(
    region: wp.array(dtype=wp.int32),
    st: wp.array(dtype=wp.vec2f),
    grid: wp.array2d(dtype=wp.int32),
    half: float,
    kid: wp.array2d(dtype=wp.int32),
    wout: wp.array2d(dtype=wp.float32),
):
    """The device's blend weights (normalised), for tests: 4 slots (sx + 2 sy), kernel -1 if unused."""
    i = wp.tid()
    r = region[i]
    gx = grid[r, 0]
    gy = grid[r, 1]
    k0 = grid[r, 2]
    for s in range(4):
        kid[i, s] = -1
        wout[i, s] = 0.0
    if gx <= 0:
        return
    p = st[i]
    a = wp.clamp(p[0], 0.0, 1.0) * float(gx)
    b = wp.clamp(p[1], 0.0, 1.0) * float(gy)
    wsum = float(0.0)
    for sy in range(2):
        cy, wy = _axis(b, gy, half, sy == 0)
        for sx in range(2):
            cx, wx = _axis(a, gx, half, sx == 0)
            if cx >= 0 and cy >= 0 and wx * wy > 0.0:
                kid[i, sy * 2 + sx] = k0 + cy * gx + cx
                wout[i, sy * 2 + sx] = wx * wy
                wsum = wsum + wx * wy
    for s in range(4):
        wout[i, s] = wout[i, s] / wsum


# --------------------------------------------------------------------------- host side


@dataclass
class DeviceKernels:
    """A :class:`tpsv.tps.group.KernelSet` on a device, with scratch and coefficients.

    After :func:`solve`: ``w64`` (n, K) vec3d and ``b64`` (n, 3) vec3d hold the
    float64 coefficients in each kernel's local frame (rows of ``b``:
    constant, u, v), ``w32``/``b32``/``pos32`` the float32 copies used by the
    rasteriser, ``status`` 0 (TPS), 1 (degenerate, affine) or 2 (solve not
    finite, affine).
    """

    device: str
    K: int
    n_kernels: int
    smoothing: float
    half: float
    lam: wp.array
    index: wp.array
    count: wp.array
    degen: wp.array
    frame64: wp.array
    frame32: wp.array
    st: wp.array
    lab: wp.array
    grid: wp.array
    fill: wp.array
    pts: wp.array
    vals: wp.array
    bary: wp.array
    pa: wp.array
    A: wp.array | None
    rhs: wp.array
    pos32: wp.array
    w64: wp.array
    b64: wp.array
    w32: wp.array
    b32: wp.array
    status: wp.array
    lo: wp.array
    hi: wp.array
    solved: bool = False

    def release_scratch(self):
        """Free the K x K matrices (kept otherwise for a re-solve after edits)."""
        self.A = None


def _host_threads(device: str, threads: int | None) -> int:
    if not device.startswith("cpu"):
        return 1
    if threads is None:
        threads = os.cpu_count() or 1
    return max(1, int(threads))


def kernel_lambda(ks) -> np.ndarray:
    """Per-kernel smoothing in local units: ``lambda_px * c^2`` for local = ``c`` * pixels.

    On the null space of ``P^T`` scaling the coordinates by ``c`` scales
    ``Phi`` by ``c^2``, so this gives every kernel the TPS that
    ``RBFInterpolator(smoothing=lambda_px)`` gives on pixel coordinates.
    """
    if ks.n_kernels == 0:
        return np.zeros(0)
    c = ks.frame[:, 2] / ks.scale[ks.region, 0]  # ax = sx / scale_k  ->  c = 1 / scale_k
    return float(ks.smoothing) * c * c


def upload(ks, device: str = "cpu") -> DeviceKernels:
    """Copy a :class:`tpsv.tps.group.KernelSet` to ``device`` and allocate the solver's arrays."""
    _warp()
    device = resolve_device(device)
    K = int(ks.kernel_size)
    n = int(ks.n_kernels)
    R = int(ks.grid.shape[0])
    F = int(ks.st.shape[0])

    def arr(a, dtype):
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)

    def empty(shape, dtype):  # every entry the solver reads is written first
        return wp.empty(shape, dtype=dtype, device=device)

    return DeviceKernels(
        device=device,
        K=K,
        n_kernels=n,
        smoothing=float(ks.smoothing),
        half=0.5 + float(ks.overlap),
        lam=arr(kernel_lambda(ks), wp.float64),
        index=arr(ks.index.astype(np.int32).reshape(n, K), wp.int32),
        count=arr(ks.count.astype(np.int32), wp.int32),
        degen=arr(ks.degenerate.astype(np.int32), wp.int32),
        frame64=arr(ks.frame.astype(np.float64).reshape(n, 4), wp.vec4d),
        frame32=arr(ks.frame.astype(np.float32).reshape(n, 4), wp.vec4f),
        st=arr(ks.st.astype(np.float64).reshape(F, 2), wp.vec2d),
        lab=arr(ks.lab.astype(np.float32).reshape(F, 3), wp.vec3f),
        grid=arr(ks.grid.astype(np.int32).reshape(R, 3), wp.int32),
        fill=arr(ks.fill.astype(np.float32).reshape(R, 3), wp.vec3f),
        pts=empty((n, K), wp.vec2d),
        vals=empty((n, K), wp.vec3d),
        bary=empty((n, K), wp.vec3d),
        pa=empty((n, K), wp.vec3d),
        A=empty((n, K, K), wp.float64),
        rhs=empty((n, K, 3), wp.float64),
        pos32=empty((n, K), wp.vec2f),
        w64=empty((n, K), wp.vec3d),
        b64=empty((n, 3), wp.vec3d),
        w32=empty((n, K), wp.vec3f),
        b32=empty((n, 3), wp.vec3f),
        status=empty(n, wp.int32),
        lo=empty(n, wp.vec3f),
        hi=empty(n, wp.vec3f),
    )


def _split(device: str, n: int, threads: int | None, launch) -> None:
    """Call ``launch(lo, hi)`` over ``[0, n)``: once on CUDA; in bands from host threads on the CPU."""
    nt = min(_host_threads(device, threads), n)
    if nt <= 1:
        launch(0, n)
        return
    nb = nt * 4
    edges = np.linspace(0, n, nb + 1).astype(int)
    bands = [(int(edges[i]), int(edges[i + 1])) for i in range(nb) if edges[i + 1] > edges[i]]
    with ThreadPoolExecutor(max_workers=nt) as pool:
        list(pool.map(lambda b: launch(*b), bands))


def solve(dk: DeviceKernels, block_dim: int | None = None, threads: int | None = None) -> DeviceKernels:
    """Build and solve every kernel's system on its device (asynchronous on CUDA)."""
    n, K, dev = dk.n_kernels, dk.K, dk.device
    if n == 0:
        dk.solved = True
        return dk
    if dk.A is None:
        dk.A = wp.empty((n, K, K), dtype=wp.float64, device=dev)
    lam = dk.lam
    if block_dim is None:
        block_dim = 1 if dev.startswith("cpu") else 32
    tile = _solve_kernel(K)
    if dev.startswith("cpu"):
        for kern in (_prep, _build, _finish, _write_w, tile):
            wp.load_module(module=kern.module, device=dev)

    def build(lo, hi):
        wp.launch(
            _prep,
            dim=(hi - lo, K),
            inputs=[lo, dk.index, dk.count, dk.degen, dk.frame64, dk.st, dk.lab],
            outputs=[dk.pts, dk.vals, dk.bary, dk.pa, dk.rhs, dk.pos32],
            device=dev,
        )
        wp.launch(
            _build,
            dim=(hi - lo, K, (K + BUILD_CHUNK - 1) // BUILD_CHUNK),
            inputs=[lo, dk.count, dk.degen, dk.pts, dk.bary, dk.pa, lam, BUILD_CHUNK],
            outputs=[dk.A],
            device=dev,
        )

    def finish(lo, hi):
        wp.launch(
            _finish,
            dim=hi - lo,
            inputs=[lo, dk.count, dk.degen, dk.pts, dk.vals, dk.bary, dk.pa, dk.rhs, lam, K],
            outputs=[dk.w64, dk.b64, dk.w32, dk.b32, dk.status, dk.lo, dk.hi],
            device=dev,
        )
        if K > 3:
            wp.launch(_write_w, dim=(hi - lo, K - 3), inputs=[lo, dk.count, dk.status, dk.rhs], outputs=[dk.w64, dk.w32], device=dev)

    _split(dev, n, threads, build)
    # Warp's CPU tile kernels share one static scratch block: never launch them concurrently
    wp.launch_tiled(tile, dim=n, inputs=[0, dk.A, dk.rhs], block_dim=block_dim, device=dev)
    _split(dev, n, threads, finish)
    dk.solved = True
    return dk


def _as_region_map(region, device):
    if isinstance(region, wp.array):
        return region
    return wp.array(np.ascontiguousarray(region, np.int32), dtype=wp.int32, device=device)


def _as_st_map(st, device):
    if isinstance(st, wp.array):
        if st.dtype == wp.vec2f and st.ndim == 2:
            return st
        if st.dtype == wp.float32 and st.ndim == 3 and st.shape[2] == 2 and st.is_contiguous:
            return wp.array(ptr=st.ptr, dtype=wp.vec2f, shape=st.shape[:2], device=st.device, copy=False)
        st = st.numpy()
    st = np.ascontiguousarray(st, np.float32)
    if st.ndim != 3 or st.shape[2] != 2:
        raise TpsvError("the (S, T) map must have shape (H, W, 2)")
    return wp.array(st, dtype=wp.vec2f, device=device)


def rasterise(
    dk: DeviceKernels,
    region,
    st,
    mode: int = MODE_SRGB,
    background=(50.0, 0.0, 0.0),
    out: wp.array | None = None,
    threads: int | None = None,
    clamp: bool = True,
) -> wp.array:
    """Blend the solved kernels at every pixel; returns ``wp.array2d(vec3f)`` (H, W).

    ``region`` (H, W) int32 region index (``-1``: outside every region,
    painted ``background`` Lab); ``st`` (H, W, 2) normalised ``(S, T)`` of the
    pixel in its region's patch. Either may be a numpy array or a device
    array. ``mode``: :data:`MODE_SRGB` (clamped sRGB) or :data:`MODE_LAB`.
    ``clamp``: clamp each kernel's TPS to its features' Lab range before
    blending (see the module docstring).
    """
    if not dk.solved:
        raise TpsvError("kernels are not solved yet")
    dev = dk.device
    reg = _as_region_map(region, dev)
    stm = _as_st_map(st, dev)
    H, W = reg.shape
    if tuple(stm.shape) != (H, W):
        raise TpsvError(f"(S, T) map {tuple(stm.shape)} does not match region map {(H, W)}")
    if out is None:
        out = wp.empty((H, W), dtype=wp.vec3f, device=dev)
    bg = wp.vec3f(*[float(v) for v in background])

    def launch(r0, r1):
        wp.launch(
            _rasterise,
            dim=(r1 - r0, W),
            inputs=[reg, stm, r0, dk.grid, dk.fill, bg, float(dk.half), dk.count, dk.frame32, dk.pos32, dk.w32, dk.b32, dk.lo, dk.hi, int(clamp), int(mode)],
            outputs=[out],
            device=dev,
        )

    if dev.startswith("cpu") and H * W >= 4096:
        wp.load_module(module=_rasterise.module, device=dev)
        _split(dev, H, threads, launch)
    else:
        launch(0, H)
    return out


def eval_points(dk: DeviceKernels, region, st, kernel: int = -1, clamp: bool = False) -> np.ndarray:
    """Lab at scattered points (n,) region / (n, 2) ``(S, T)`` (blended; or one kernel's TPS)."""
    dev = dk.device
    st = np.ascontiguousarray(st, np.float32).reshape(-1, 2)
    region = np.broadcast_to(np.asarray(region, np.int32), (st.shape[0],)).copy()
    out = wp.empty(st.shape[0], dtype=wp.vec3f, device=dev)
    wp.launch(
        _eval_points,
        dim=st.shape[0],
        inputs=[
            wp.array(region, dtype=wp.int32, device=dev),
            wp.array(st, dtype=wp.vec2f, device=dev),
            dk.grid,
            dk.fill,
            float(dk.half),
            dk.count,
            dk.frame32,
            dk.pos32,
            dk.w32,
            dk.b32,
            dk.lo,
            dk.hi,
            int(clamp),
            int(kernel),
        ],
        outputs=[out],
        device=dev,
    )
    return out.numpy().astype(np.float64)


def device_weights(dk: DeviceKernels, region, st):
    """The device's blend weights at points: kernel ids (n, 4) int32 and weights (n, 4) float32."""
    dev = dk.device
    st = np.ascontiguousarray(st, np.float32).reshape(-1, 2)
    region = np.broadcast_to(np.asarray(region, np.int32), (st.shape[0],)).copy()
    kid = wp.empty((st.shape[0], 4), dtype=wp.int32, device=dev)
    w = wp.empty((st.shape[0], 4), dtype=wp.float32, device=dev)
    wp.launch(
        _weights,
        dim=st.shape[0],
        inputs=[wp.array(region, dtype=wp.int32, device=dev), wp.array(st, dtype=wp.vec2f, device=dev), dk.grid, float(dk.half)],
        outputs=[kid, w],
        device=dev,
    )
    return kid.numpy(), w.numpy()


def coefficients(dk: DeviceKernels):
    """float64 coefficients on the host: local points (n, K, 2), w (n, K, 3), b (n, 3, 3), status (n,)."""
    return dk.pts.numpy(), dk.w64.numpy(), dk.b64.numpy(), dk.status.numpy()


def render_arrays(ks, region, st, device: str = "cpu", mode: int = MODE_SRGB, threads: int | None = None, clamp: bool = True) -> np.ndarray:
    """The whole TPS stage from host arrays: upload, solve, rasterise; returns (H, W, 3) float32."""
    dk = solve(upload(ks, device), threads=threads)
    out = rasterise(dk, region, st, mode=mode, threads=threads, clamp=clamp)
    return out.numpy().reshape(out.shape[0], out.shape[1], 3)


def render_timed(ks, region, st, device: str = "cpu", repeat: int = 1, threads: int | None = None, clamp: bool = True):
    """Like :func:`render_arrays` with the maps kept on the device; returns (image, timings).

    Timings (seconds, best of ``repeat``, each stage closed by
    ``wp.synchronize_device``): ``upload`` (kernel set to the device),
    ``solve`` (build + solve), ``rasterise``; ``download`` (image to host).
    """
    _warp()
    device = resolve_device(device)
    reg = _as_region_map(region, device)
    stm = _as_st_map(st, device)
    best: dict = {}

    def tick(name, t0):
        wp.synchronize_device(device)
        dt = time.perf_counter() - t0
        best[name] = min(best.get(name, np.inf), dt)

    img = None
    for _ in range(max(1, int(repeat))):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        dk = upload(ks, device)
        tick("upload", t0)
        t0 = time.perf_counter()
        solve(dk, threads=threads)
        tick("solve", t0)
        t0 = time.perf_counter()
        out = rasterise(dk, reg, stm, threads=threads, clamp=clamp)
        tick("rasterise", t0)
        t0 = time.perf_counter()
        img = out.numpy().reshape(out.shape[0], out.shape[1], 3)
        tick("download", t0)
    return img, best


# --------------------------------------------------------------------------- incremental rebuild (tpsv.render.live)


@wp.kernel
def _copy_solution(
    src_row: wp.array(dtype=wp.int32),
    s_pts: wp.array2d(dtype=wp.vec2d),
    s_pos32: wp.array2d(dtype=wp.vec2f),
    s_w64: wp.array2d(dtype=wp.vec3d),
    s_w32: wp.array2d(dtype=wp.vec3f),
    s_b64: wp.array2d(dtype=wp.vec3d),
    s_b32: wp.array2d(dtype=wp.vec3f),
    s_status: wp.array(dtype=wp.int32),
    s_lo: wp.array(dtype=wp.vec3f),
    s_hi: wp.array(dtype=wp.vec3f),
    d_pts: wp.array2d(dtype=wp.vec2d),
    d_pos32: wp.array2d(dtype=wp.vec2f),
    d_w64: wp.array2d(dtype=wp.vec3d),
    d_w32: wp.array2d(dtype=wp.vec3f),
    d_b64: wp.array2d(dtype=wp.vec3d),
    d_b32: wp.array2d(dtype=wp.vec3f),
    d_status: wp.array(dtype=wp.int32),
    d_lo: wp.array(dtype=wp.vec3f),
    d_hi: wp.array(dtype=wp.vec3f),
):
    """Kernel k of the destination takes row src_row[k] of the source (skipped when -1)."""
    k, j = wp.tid()
    s = src_row[k]
    if s < 0:
        return
    d_pts[k, j] = s_pts[s, j]
    d_pos32[k, j] = s_pos32[s, j]
    d_w64[k, j] = s_w64[s, j]
    d_w32[k, j] = s_w32[s, j]
    if j < 3:
        d_b64[k, j] = s_b64[s, j]
        d_b32[k, j] = s_b32[s, j]
    if j == 0:
        d_status[k] = s_status[s]
        d_lo[k] = s_lo[s]
        d_hi[k] = s_hi[s]


def subset_kernels(ks, kernels):
    """A :class:`tpsv.tps.group.KernelSet` holding only the kernels ``kernels`` (int array), for solving.

    The features (``st``, ``lab``), region scales and fill colours are shared
    with ``ks``; the grid is emptied (the subset is solved, never rasterised).
    Each kernel's system is exactly the one it has in ``ks``, so its solution
    is bit-identical.
    """
    from dataclasses import replace

    sel = np.asarray(kernels, np.int64).reshape(-1)
    return replace(
        ks,
        index=ks.index[sel],
        count=ks.count[sel],
        degenerate=ks.degenerate[sel],
        region=ks.region[sel],
        cell=ks.cell[sel],
        frame=ks.frame[sel],
        grid=np.zeros_like(ks.grid),
    )


def _copy_rows(dst: DeviceKernels, src: DeviceKernels, src_row: np.ndarray) -> None:
    dev = dst.device
    rows = wp.array(np.ascontiguousarray(src_row, np.int32), dtype=wp.int32, device=dev)
    wp.launch(
        _copy_solution,
        dim=(dst.n_kernels, dst.K),
        inputs=[rows, src.pts, src.pos32, src.w64, src.w32, src.b64, src.b32, src.status, src.lo, src.hi],
        outputs=[dst.pts, dst.pos32, dst.w64, dst.w32, dst.b64, dst.b32, dst.status, dst.lo, dst.hi],
        device=dev,
    )


#: :func:`solve_reusing` solves everything when more than this fraction of the kernels changed.
FULL_SOLVE_FRACTION = 0.6


def solve_reusing(ks, prev: DeviceKernels | None, reuse, device: str = "cpu", threads: int | None = None):
    """Upload ``ks`` and solve only the kernels that cannot reuse an earlier solution.

    Parameters
    ----------
    ks : KernelSet
        The new kernel set.
    prev : DeviceKernels or None
        Solved kernels of an earlier kernel set (same device and ``K``).
    reuse : (n_kernels,) int array
        For each kernel of ``ks``, the row of ``prev`` whose system is
        identical (same local points, colours, frame, count and smoothing),
        or -1 to solve it.

    Returns
    -------
    (DeviceKernels, int)
        The solved kernels of ``ks`` (bit-identical to ``solve(upload(ks))``)
        and the number of kernels solved.
    """
    device = resolve_device(device)
    reuse = np.asarray(reuse, np.int64).reshape(-1)
    n = int(ks.n_kernels)
    if reuse.shape[0] != n:
        raise TpsvError("reuse map does not match the kernel set")
    if prev is None or not prev.solved or prev.K != int(ks.kernel_size) or prev.device != device:
        reuse = np.full(n, -1, np.int64)
    todo = np.flatnonzero(reuse < 0)
    dk = upload(ks, device)
    if n == 0 or todo.size > FULL_SOLVE_FRACTION * n:
        # most kernels changed: solving all of them in place is cheaper than a subset and a copy
        return solve(dk, threads=threads), n
    dk.A = None  # the full scratch matrix is not needed: only the subset is solved
    if todo.size < n:
        _copy_rows(dk, prev, reuse)
    if todo.size:
        sub = solve(upload(subset_kernels(ks, todo), device), threads=threads)
        row = np.full(n, -1, np.int64)
        row[todo] = np.arange(todo.size)
        _copy_rows(dk, sub, row)
    dk.solved = True
    return dk, int(todo.size)


@wp.kernel
def _rasterise_list(
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    pixels: wp.array(dtype=wp.int32),
    grid: wp.array2d(dtype=wp.int32),
    fill: wp.array(dtype=wp.vec3f),
    background: wp.vec3f,
    half: float,
    count: wp.array(dtype=wp.int32),
    frame32: wp.array(dtype=wp.vec4f),
    pos32: wp.array2d(dtype=wp.vec2f),
    w32: wp.array2d(dtype=wp.vec3f),
    b32: wp.array2d(dtype=wp.vec3f),
    lo: wp.array(dtype=wp.vec3f),
    hi: wp.array(dtype=wp.vec3f),
    clamp: int,
    mode: int,
    width: int,
    out: wp.array2d(dtype=wp.vec3f),
):
    """``_rasterise`` for the listed pixels (flat indices ``y * width + x``) only."""
    i = wp.tid()
    p = pixels[i]
    y = p / width
    x = p - y * width
    r = region[y, x]
    lab = background
    if r >= 0:
        st = stmap[y, x]
        lab = _blend(r, st[0], st[1], grid, fill, half, count, frame32, pos32, w32, b32, lo, hi, clamp)
    if mode == 0:
        out[y, x] = lab_to_srgb(lab)
    else:
        out[y, x] = lab


def rasterise_pixels(
    dk: DeviceKernels,
    region,
    st,
    pixels,
    out: wp.array,
    mode: int = MODE_SRGB,
    background=(50.0, 0.0, 0.0),
    threads: int | None = None,
    clamp: bool = True,
) -> wp.array:
    """:func:`rasterise` for the pixels ``pixels`` (flat indices ``y * W + x``) only, into ``out``.

    Other pixels of ``out`` are left as they are; the listed ones get exactly
    the values :func:`rasterise` gives them.
    """
    if not dk.solved:
        raise TpsvError("kernels are not solved yet")
    dev = dk.device
    reg = _as_region_map(region, dev)
    stm = _as_st_map(st, dev)
    H, W = reg.shape
    if tuple(stm.shape) != (H, W) or tuple(out.shape) != (H, W):
        raise TpsvError("region map, (S, T) map and output differ in size")
    pix = np.ascontiguousarray(pixels, np.int32).reshape(-1)
    n = pix.shape[0]
    if n == 0:
        return out
    pix_d = wp.array(pix, dtype=wp.int32, device=dev)
    bg = wp.vec3f(*[float(v) for v in background])

    def launch(a, b):
        wp.launch(
            _rasterise_list,
            dim=b - a,
            inputs=[reg, stm, pix_d[a:b], dk.grid, dk.fill, bg, float(dk.half), dk.count, dk.frame32, dk.pos32,
                    dk.w32, dk.b32, dk.lo, dk.hi, int(clamp), int(mode), int(W)],
            outputs=[out],
            device=dev,
        )

    if dev.startswith("cpu") and n >= 4096:
        wp.load_module(module=_rasterise_list.module, device=dev)
        _split(dev, n, threads, launch)
    else:
        launch(0, n)
    return out
