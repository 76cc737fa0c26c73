"""Build and solve every sub-patch TPS on a Warp device (Eq. (4) of the paper, float64).

Eq. (4), ``[Phi + lambda I, P; P^T, 0] [w; b] = [h; 0]``, is solved in the
null space of ``P^T``. With the kernel's anchors ``a0, a1, a2`` (slots 0-2,
chosen by :func:`tpsv.tps.group_kernels`) and ``L_j`` the barycentric
coordinates of feature ``j`` w.r.t. the anchors, ``Q = [-L^T; I]`` spans
``null(P^T)``; ``w = Q gamma`` and

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
inactive slots are identity rows with a zero right-hand side. On the CPU the
kernels other than the tile solve run in bands from host threads
(:func:`tpsv.gpu.device.split_launch`). The tile solve is one launch: Warp's
CPU tile kernels share one static scratch block, so two must never run at
once.

A degenerate kernel (see ``tpsv.tps.grouping``) and any kernel whose solve is
not finite (which should not happen) get the affine fallback
(:func:`_affine_fallback`): least squares along the line through anchors 0
and 1, constant across it (``w = 0``); ``tpsv.encode.fit.cardinal_matrices``
is its numpy twin, pinned by ``tests/test_gpu_pinning.py``.

Coefficients are kept in float64 (for tests) and float32 (for rendering).
Local feature positions are rounded to float32 *before* the solve, so the
float64 solution is exact for the very positions the rasteriser uses (a shift
of about 1e-7 of a kernel's size); otherwise that rounding, multiplied by the
large weights of rough data, dominates the float32 error.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import replace

import numpy as np
import warp as wp

from ..errors import TpsvError
from . import resolve_device
from .device import DeviceKernels, Solution, Systems, split_launch, upload

# fast_math only changes CUDA float32 code; the float64 solve and the CPU device are unaffected.
wp.set_module_options({"enable_backward": False, "fast_math": True})

#: Columns of A per thread of ``_build`` (threads per kernel: K x ceil(K / BUILD_CHUNK)).
BUILD_CHUNK = 16

#: Work of the banded build and finish on one core of the CI machine, seconds per kernel of 32 features
#: (it grows as K^2): how far :func:`tpsv.gpu.device.split_launch` splits them.
_BUILD_SECONDS = 37e-6
_FINISH_SECONDS = 19e-6

#: :func:`solve_reusing` solves everything when more than this fraction of the kernels changed.
FULL_SOLVE_FRACTION = 0.6


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


@wp.func
def _f32(v: wp.vec3d):
    return wp.vec3f(wp.float32(v[0]), wp.float32(v[1]), wp.float32(v[2]))


@wp.func
def _slot_point(sy: Systems, k: int, j: int):
    return _round32(_local64(sy.st[sy.index[k, j]], sy.frame64[k]))


# --------------------------------------------------------------------------- build


@wp.kernel
def _prep(k_off: int, sy: Systems, sol: Solution, rhs: wp.array3d(dtype=wp.float64)):
    """Per slot: local point, value, barycentric coordinates, anchor row of Phi, projected rhs."""
    kk, j = wp.tid()
    k = kk + k_off
    m = sy.count[k]
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    rhs[k, j, 0] = zero
    rhs[k, j, 1] = zero
    rhs[k, j, 2] = zero
    sy.bary[k, j] = z3
    sy.pa[k, j] = z3
    if j >= m:
        sol.pts[k, j] = wp.vec2d(zero, zero)
        sy.vals[k, j] = z3
        sol.pos32[k, j] = wp.vec2f(0.0, 0.0)
        return
    p = _slot_point(sy, k, j)
    c = sy.lab[sy.index[k, j]]
    h = wp.vec3d(wp.float64(c[0]), wp.float64(c[1]), wp.float64(c[2]))
    sol.pts[k, j] = p
    sy.vals[k, j] = h
    sol.pos32[k, j] = wp.vec2f(wp.float32(p[0]), wp.float32(p[1]))
    if sy.degen[k] != 0:
        return
    q0 = _slot_point(sy, k, 0)
    q1 = _slot_point(sy, k, 1)
    q2 = _slot_point(sy, k, 2)
    sy.pa[k, j] = wp.vec3d(_phi64(_d2(q0, p)), _phi64(_d2(q1, p)), _phi64(_d2(q2, p)))
    if j < 3:
        return
    e1 = q1 - q0
    e2 = q2 - q0
    d = p - q0
    det = e1[0] * e2[1] - e1[1] * e2[0]
    l1 = (d[0] * e2[1] - d[1] * e2[0]) / det
    l2 = (e1[0] * d[1] - e1[1] * d[0]) / det
    l0 = wp.float64(1.0) - l1 - l2
    sy.bary[k, j] = wp.vec3d(l0, l1, l2)
    h0 = sy.lab[sy.index[k, 0]]
    h1 = sy.lab[sy.index[k, 1]]
    h2 = sy.lab[sy.index[k, 2]]
    for ch in range(3):
        rhs[k, j, ch] = h[ch] - l0 * wp.float64(h0[ch]) - l1 * wp.float64(h1[ch]) - l2 * wp.float64(h2[ch])


@wp.kernel
def _build(k_off: int, sy: Systems, sol: Solution, chunk: int, A: wp.array3d(dtype=wp.float64)):
    """Columns [c*chunk, (c+1)*chunk) of row j of the lower triangle of A = Q^T (Phi + lambda I) Q.

    Anchor rows/columns and inactive slots are identity. With G = Phi among
    the anchors, ``A_jl = phi_jl - L_j . pa_l - L_l . pa_j + L_j^T G L_l
    + lambda (delta_jl + L_j . L_l)``.
    """
    kk, j, c = wp.tid()
    k = kk + k_off
    l0 = c * chunk
    l1 = wp.min(l0 + chunk, j + 1)
    m = sy.count[k]
    zero = wp.float64(0.0)
    if sy.degen[k] != 0 or j < 3 or j >= m:
        for l in range(l0, l1):
            A[k, j, l] = zero
        if j >= l0 and j < l0 + chunk:
            A[k, j, j] = wp.float64(1.0)
        return
    Lj = sy.bary[k, j]
    pj = sol.pts[k, j]
    t = Lj[0] * sy.pa[k, 0] + Lj[1] * sy.pa[k, 1] + Lj[2] * sy.pa[k, 2] - sy.pa[k, j]
    for l in range(l0, l1):
        if l < 3:
            A[k, j, l] = zero
        else:
            Ll = sy.bary[k, l]
            reg = wp.dot(Lj, Ll)
            if l == j:
                reg = reg + wp.float64(1.0)
            A[k, j, l] = _phi64(_d2(pj, sol.pts[k, l])) - wp.dot(Lj, sy.pa[k, l]) + wp.dot(Ll, t) + sy.lam[k] * reg


_SOLVE_KERNELS: dict = {}

#: Held while a tile kernel is made and while one runs on the CPU device: Warp's CPU tile kernels share one
#: static scratch block, so two threads of a process solving at once (a caller rendering from several
#: threads) corrupted each other's tiles (a segmentation fault in 6 of 8 processes rendering on 4 threads).
_TILE_LOCK = threading.Lock()


def _solve_kernel(K: int):
    """The tile Cholesky kernel for ``K`` slots (tile shapes are compile-time; compiled once per K)."""
    with _TILE_LOCK:
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


# --------------------------------------------------------------------------- finish


@wp.func
def _slot_w(k: int, i: int, w0: wp.vec3d, w1: wp.vec3d, w2: wp.vec3d, gamma: wp.array3d(dtype=wp.float64)):
    if i == 0:
        return w0
    if i == 1:
        return w1
    if i == 2:
        return w2
    return wp.vec3d(gamma[k, i, 0], gamma[k, i, 1], gamma[k, i, 2])


@wp.func
def _value_range(sy: Systems, k: int, m: int):
    """Per Lab channel, the float32 range of the kernel's feature colours."""
    vmin = wp.vec3f(1.0e30, 1.0e30, 1.0e30)
    vmax = wp.vec3f(-1.0e30, -1.0e30, -1.0e30)
    for i in range(m):
        vf = _f32(sy.vals[k, i])
        vmin = wp.min(vmin, vf)
        vmax = wp.max(vmax, vf)
    return vmin, vmax


@wp.func
def _anchor_part(sy: Systems, sol: Solution, gamma: wp.array3d(dtype=wp.float64), k: int, m: int):
    """From the solved ``gamma``: the anchors' weights ``w = Q gamma`` and ``b`` from the anchor rows.

    Returns ``(finite, w0, w1, w2, b0, b1, b2)`` (``b`` rows: constant, u, v).
    """
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    w0 = z3
    w1 = z3
    w2 = z3
    fin = bool(True)
    for j in range(3, m):
        g = wp.vec3d(gamma[k, j, 0], gamma[k, j, 1], gamma[k, j, 2])
        fin = fin and _finite3(g)
        Lj = sy.bary[k, j]
        w0 = w0 - Lj[0] * g
        w1 = w1 - Lj[1] * g
        w2 = w2 - Lj[2] * g
    r0 = sy.vals[k, 0] - sy.lam[k] * w0
    r1 = sy.vals[k, 1] - sy.lam[k] * w1
    r2 = sy.vals[k, 2] - sy.lam[k] * w2
    for i in range(m):
        wi = _slot_w(k, i, w0, w1, w2, gamma)
        pai = sy.pa[k, i]
        r0 = r0 - pai[0] * wi
        r1 = r1 - pai[1] * wi
        r2 = r2 - pai[2] * wi
    q0 = sol.pts[k, 0]
    q1 = sol.pts[k, 1]
    q2 = sol.pts[k, 2]
    one = wp.float64(1.0)
    M = wp.mat33d(one, q0[0], q0[1], one, q1[0], q1[1], one, q2[0], q2[1])
    Mi = wp.inverse(M)
    # b_row = sum_a Mi[row, a] r_a   (rows: constant, u, v; vec3 over channels)
    bb0 = Mi[0, 0] * r0 + Mi[0, 1] * r1 + Mi[0, 2] * r2
    bb1 = Mi[1, 0] * r0 + Mi[1, 1] * r1 + Mi[1, 2] * r2
    bb2 = Mi[2, 0] * r0 + Mi[2, 1] * r1 + Mi[2, 2] * r2
    fin = fin and _finite3(bb0) and _finite3(bb1) and _finite3(bb2)
    fin = fin and _finite3(w0) and _finite3(w1) and _finite3(w2)
    return fin, w0, w1, w2, bb0, bb1, bb2


@wp.func
def _affine_fallback(sy: Systems, sol: Solution, k: int, m: int):
    """Least squares along anchors 0 -> 1 (the x axis if they coincide), constant across: ``b`` rows."""
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    cen = wp.vec2d(zero, zero)
    hm = z3
    for i in range(m):
        cen = cen + sol.pts[k, i]
        hm = hm + sy.vals[k, i]
    fm = wp.float64(wp.max(m, 1))
    cen = cen / fm
    hm = hm / fm
    dvec = wp.vec2d(wp.float64(1.0), zero)
    if m >= 2:
        e = sol.pts[k, 1] - sol.pts[k, 0]
        ln = wp.length(e)
        if ln > zero:
            dvec = e / ln
    stt = zero
    sth = z3
    for i in range(m):
        t = wp.dot(sol.pts[k, i] - cen, dvec)
        stt = stt + t * t
        sth = sth + t * (sy.vals[k, i] - hm)
    beta = z3
    if stt > zero:
        beta = sth / stt
    return hm - wp.dot(cen, dvec) * beta, dvec[0] * beta, dvec[1] * beta


@wp.kernel
def _finish(k_off: int, sy: Systems, gamma: wp.array3d(dtype=wp.float64), sol: Solution):
    """Per kernel: w = Q gamma, the affine part from the anchor rows, fallbacks, float32 copies."""
    k = wp.tid() + k_off
    m = sy.count[k]
    vmin, vmax = _value_range(sy, k, m)
    sol.lo[k] = vmin
    sol.hi[k] = vmax
    zero = wp.float64(0.0)
    z3 = wp.vec3d(zero, zero, zero)
    status = int(1)
    w0 = z3
    w1 = z3
    w2 = z3
    bb0 = z3
    bb1 = z3
    bb2 = z3
    if sy.degen[k] == 0:
        fin, w0, w1, w2, bb0, bb1, bb2 = _anchor_part(sy, sol, gamma, k, m)
        status = 0
        if not fin:
            status = 2
    if status != 0:
        bb0, bb1, bb2 = _affine_fallback(sy, sol, k, m)
        w0 = z3
        w1 = z3
        w2 = z3
    # anchor slots here; slots 3.. are written by _write_w (one thread per slot)
    sol.w64[k, 0] = w0
    sol.w64[k, 1] = w1
    sol.w64[k, 2] = w2
    sol.w32[k, 0] = _f32(w0)
    sol.w32[k, 1] = _f32(w1)
    sol.w32[k, 2] = _f32(w2)
    sol.b64[k, 0] = bb0
    sol.b64[k, 1] = bb1
    sol.b64[k, 2] = bb2
    sol.b32[k, 0] = _f32(bb0)
    sol.b32[k, 1] = _f32(bb1)
    sol.b32[k, 2] = _f32(bb2)
    sol.status[k] = status


@wp.kernel
def _write_w(k_off: int, sy: Systems, gamma: wp.array3d(dtype=wp.float64), sol: Solution):
    """Slots 3..K-1: w = gamma for active slots of solved kernels, else 0."""
    kk, j = wp.tid()
    k = kk + k_off
    i = j + 3
    wi = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if sol.status[k] == 0 and i < sy.count[k]:
        wi = wp.vec3d(gamma[k, i, 0], gamma[k, i, 1], gamma[k, i, 2])
    sol.w64[k, i] = wi
    sol.w32[k, i] = _f32(wi)


# --------------------------------------------------------------------------- host side


def solve(dk: DeviceKernels, block_dim: int | None = None, threads: int | None = None) -> DeviceKernels:
    """Build and solve every kernel's system on its device (asynchronous on CUDA).

    Parameters
    ----------
    dk : DeviceKernels
        From :func:`tpsv.gpu.device.upload`; solved in place.
    block_dim : int, optional
        Threads per block of the tile solve (default 1 on the CPU, 32 on CUDA).
    threads : int, optional
        Host threads launching bands on the CPU device (default: every core).

    Returns
    -------
    DeviceKernels
        ``dk``, solved.
    """
    n, K, dev = dk.n_kernels, dk.K, dk.device
    if n == 0:
        dk.solved = True
        return dk
    if dk.A is None:
        dk.A = wp.empty((n, K, K), dtype=wp.float64, device=dev)
    if block_dim is None:
        block_dim = 1 if dev.startswith("cpu") else 32
    tile = _solve_kernel(K)
    if dev.startswith("cpu"):
        for kern in (_prep, _build, _finish, _write_w, tile):
            wp.load_module(module=kern.module, device=dev)
    sy, sol = dk.systems, dk.solution

    def build(lo, hi):
        wp.launch(_prep, dim=(hi - lo, K), inputs=[lo, sy, sol, dk.rhs], device=dev)
        wp.launch(_build, dim=(hi - lo, K, (K + BUILD_CHUNK - 1) // BUILD_CHUNK), inputs=[lo, sy, sol, BUILD_CHUNK, dk.A], device=dev)

    def finish(lo, hi):
        wp.launch(_finish, dim=hi - lo, inputs=[lo, sy, dk.rhs, sol], device=dev)
        if K > 3:
            wp.launch(_write_w, dim=(hi - lo, K - 3), inputs=[lo, sy, dk.rhs, sol], device=dev)

    size = (K / 32.0) ** 2
    split_launch(dev, n, threads, build, n * size * _BUILD_SECONDS)
    # Warp's CPU tile kernels share one static scratch block: never launch them concurrently (not even
    # from two callers' threads)
    with _TILE_LOCK if dev.startswith("cpu") else contextlib.nullcontext():
        wp.launch_tiled(tile, dim=n, inputs=[0, dk.A, dk.rhs], block_dim=block_dim, device=dev)
    split_launch(dev, n, threads, finish, n * size * _FINISH_SECONDS)
    dk.solved = True
    return dk


def coefficients(dk: DeviceKernels):
    """float64 coefficients on the host.

    Returns
    -------
    pts : ndarray (n, K, 2)
        Local points.
    w : ndarray (n, K, 3)
    b : ndarray (n, 3, 3)
        Rows constant, u, v.
    status : ndarray (n,) int32
        0 TPS, 1 degenerate (affine), 2 solve not finite (affine).
    """
    sol = dk.solution
    return sol.pts.numpy(), sol.w64.numpy(), sol.b64.numpy(), sol.status.numpy()


# --------------------------------------------------------------------------- incremental rebuild (tpsv.rendering.live)


@wp.kernel
def _copy_solution(src_row: wp.array(dtype=wp.int32), src: Solution, dst: Solution):
    """Kernel k of the destination takes row src_row[k] of the source (skipped when -1)."""
    k, j = wp.tid()
    s = src_row[k]
    if s < 0:
        return
    dst.pts[k, j] = src.pts[s, j]
    dst.pos32[k, j] = src.pos32[s, j]
    dst.w64[k, j] = src.w64[s, j]
    dst.w32[k, j] = src.w32[s, j]
    if j < 3:
        dst.b64[k, j] = src.b64[s, j]
        dst.b32[k, j] = src.b32[s, j]
    if j == 0:
        dst.status[k] = src.status[s]
        dst.lo[k] = src.lo[s]
        dst.hi[k] = src.hi[s]


def subset_kernels(ks, kernels):
    """A :class:`tpsv.tps.KernelSet` holding only the kernels ``kernels`` (int array), for solving.

    The features (``st``, ``lab``), region scales and fill colours are shared
    with ``ks``; the grid is emptied (the subset is solved, never rasterised).
    Each kernel's system is exactly the one it has in ``ks``, so its solution
    is bit-identical.

    Parameters
    ----------
    ks : KernelSet
    kernels : array_like of int
        Kernels of ``ks`` to keep, in the order of the subset.

    Returns
    -------
    KernelSet
    """
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
    wp.launch(_copy_solution, dim=(dst.n_kernels, dst.K), inputs=[rows, src.solution, dst.solution], device=dev)


def solve_reusing(ks, prev: DeviceKernels | None, reuse, device: str = "cpu", threads: int | None = None):
    """Upload ``ks`` and solve only the kernels that cannot reuse an earlier solution (on the CPU;
    a GPU solves them all, which costs it less than the copies).

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
    device : str
    threads : int, optional
        Host threads on the CPU device.

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
    # Solving all in place is cheaper than a subset and two copies when most changed, and always on
    # a GPU: it solves thousands of kernels in one pass (H100: 10 000 kernels in 2.9 ms, one of them
    # as a subset in 4.8 ms; 4 kernels in 0.7 ms, one in 1.3 ms).
    if n == 0 or todo.size > FULL_SOLVE_FRACTION * n or not wp.get_device(device).is_cpu:
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
