"""Rasterise solved kernels on a Warp device: the per-pixel blend of localised TPS (float32).

One thread per output pixel: its region, its ``(S, T)``, the at most 2 x 2
covering kernels of the region's grid, the TPS of each in its local frame,
the partition-of-unity blend (``tpsv.tps.blend`` module doc), then Lab ->
sRGB (:func:`tpsv.gpu.color.lab_to_srgb`), clamped to ``[0, 1]``. The
full-frame rasteriser, the dirty-pixel rasteriser (``tpsv.rendering.live``) and
the scattered-point evaluation share one per-pixel body (:func:`_shade`,
:func:`_blend`); the kernels' arrays reach them as one
:class:`tpsv.gpu.device.BlendArrays`.

Range clamp (``clamp=True``, the default of :func:`rasterise`): each
kernel's value is clamped, per Lab channel, to the range of its own
features' colours before blending. A TPS overshoots beside close samples
of very different colour (curvilinear pairs) and extrapolates far from
features; on the bundled samples this clamp raises the PSNR by 4 to 13 dB.
The blend of clamped kernels is still continuous (no seams) but only C0
where a clamp is active; with ``clamp=False`` the result is the plain
localised TPS (what the accuracy tests compare with ``RBFInterpolator``).

On the CPU device launches run in bands of rows (or of listed pixels) from
a few host threads, as many as their work pays for (:func:`_launch_banded`,
:data:`HOST_SECONDS`, :func:`tpsv.gpu.device.split_launch`).
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import warp as wp

from ..errors import TpsvError
from . import resolve_device
from . import warp as _warp
from .color import lab_to_srgb
from .device import BlendArrays, DeviceKernels, bands, split_launch, upload
from .solve import solve
from .transfer import upload as _send

# fast_math only changes CUDA float32 code (approximate log/division in the rasteriser:
# about 25 % faster on an H100, renders agree with the CPU device within 2e-4).
wp.set_module_options({"enable_backward": False, "fast_math": True})

#: Output modes of :func:`rasterise`: clamped sRGB, or Lab.
MODE_SRGB = wp.constant(0)
MODE_LAB = wp.constant(1)

#: Work of each kernel launched in bands, on one core of the 2-core CI machine: seconds per item of
#: the launch (a pixel of the frame or band; a listed pixel, candidate or group of ``_gather``; a
#: big pixel that ``_area`` reads), measured on the samples' default files at scale 1 (the rasteriser's
#: with 16 features a pixel). How far :func:`tpsv.gpu.device.bands` splits a launch depends on it;
#: only its order of magnitude matters.
HOST_SECONDS = {
    "_rasterise": 330e-9, "_rasterise_dirty": 330e-9, "_mix_border": 330e-9, "_add_detail": 34e-9,
    "_add_detail_list": 60e-9, "_map_kernel": 34e-9, "_fill_rows": 2.5e-9, "_fill_pixels": 17e-9,
    "_find_gaps": 7e-9, "_put_gaps": 5e-9, "_candidates": 7e-9, "_gather": 10e-9, "_row_regions": 10e-9,
    "_measure": 640e-9, "_compact": 18e-9, "_tv": 27e-9, "_area": 6e-9, "_cubic": 37e-9, "_to_uint": 4e-9,
}


# --------------------------------------------------------------------------- per-pixel body


@wp.func
def _bump(z: float):
    if wp.abs(z) < 1.0:
        t = 1.0 - z * z
        return t * t
    return 0.0


@wp.func
def _eval_kernel(kb: BlendArrays, k: int, S: float, T: float):
    """Kernel ``k``'s TPS at ``(S, T)``, evaluated in its local frame."""
    fr = kb.frame32[k]
    u = (S - fr[0]) * fr[2]
    v = (T - fr[1]) * fr[3]
    acc = kb.b32[k, 0] + u * kb.b32[k, 1] + v * kb.b32[k, 2]
    for i in range(kb.count[k]):
        p = kb.pos32[k, i]
        du = u - p[0]
        dv = v - p[1]
        r2 = du * du + dv * dv
        if r2 > 0.0:
            acc = acc + (0.5 * r2 * wp.log(r2)) * kb.w32[k, i]
    return acc


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
def _blend(kb: BlendArrays, r: int, S: float, T: float, clamp: int):
    """Lab of region ``r`` at ``(S, T)``: the blend of its covering kernels (or its fill colour)."""
    gx = kb.grid[r, 0]
    gy = kb.grid[r, 1]
    k0 = kb.grid[r, 2]
    if gx <= 0 or gy <= 0:
        return kb.fill[r]
    a = wp.clamp(S, 0.0, 1.0) * float(gx)
    b = wp.clamp(T, 0.0, 1.0) * float(gy)
    acc = wp.vec3f(0.0, 0.0, 0.0)
    wsum = float(0.0)
    for sy in range(2):
        cy, wy = _axis(b, gy, kb.half, sy == 0)
        if cy >= 0:
            for sx in range(2):
                cx, wx = _axis(a, gx, kb.half, sx == 0)
                wgt = wx * wy
                if cx >= 0 and wgt > 0.0:
                    k = k0 + cy * gx + cx
                    val = _eval_kernel(kb, k, S, T)
                    if clamp != 0:
                        val = wp.min(wp.max(val, kb.lo[k]), kb.hi[k])
                    acc = acc + wgt * val
                    wsum = wsum + wgt
    return acc / wsum


@wp.func
def _shade(
    kb: BlendArrays,
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    y: int,
    x: int,
    background: wp.vec3f,
    clamp: int,
    mode: int,
):
    """Output pixel ``(x, y)``: the blend at its region and ``(S, T)`` (or ``background``), in ``mode``."""
    r = region[y, x]
    lab = background
    if r >= 0:
        st = stmap[y, x]
        lab = _blend(kb, r, st[0], st[1], clamp)
    if mode == MODE_SRGB:
        return lab_to_srgb(lab)
    return lab


# --------------------------------------------------------------------------- kernels


@wp.kernel
def _rasterise(
    kb: BlendArrays,
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    y0: int,
    background: wp.vec3f,
    clamp: int,
    mode: int,
    out: wp.array2d(dtype=wp.vec3f),
):
    """Every pixel of rows ``y0 ..``."""
    yy, x = wp.tid()
    y = yy + y0
    out[y, x] = _shade(kb, region, stmap, y, x, background, clamp, mode)


@wp.kernel
def _rasterise_dirty(
    kb: BlendArrays,
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    y0: int,
    changed: wp.array(dtype=wp.uint8),
    stale: wp.array(dtype=wp.uint8),
    near: wp.array(dtype=wp.uint8),
    background: wp.vec3f,
    clamp: int,
    mode: int,
    out: wp.array2d(dtype=wp.vec3f),
    counts: wp.array(dtype=wp.int32),
):
    """The dirty pixels of rows ``y0 ..`` (see :func:`rasterise_dirty`); ``counts[y]`` += pixels drawn."""
    yy, x = wp.tid()
    y = yy + y0
    W = region.shape[1]
    dirty = False
    if changed.shape[0] > 0:
        dirty = changed[y * W + x] != wp.uint8(0)
    r = region[y, x]
    if not dirty and r >= 0:
        if stale[r] != wp.uint8(0):
            dirty = True
        else:
            gx = kb.grid[r, 0]
            gy = kb.grid[r, 1]
            if gx != 0 and near.shape[0] > 0:
                # the pixel's own cell, as _blend finds it
                st = stmap[y, x]
                a = wp.clamp(st[0], 0.0, 1.0) * float(gx)
                b = wp.clamp(st[1], 0.0, 1.0) * float(gy)
                ix = wp.min(wp.max(int(wp.floor(a)), 0), gx - 1)
                iy = wp.min(wp.max(int(wp.floor(b)), 0), gy - 1)
                dirty = near[kb.grid[r, 2] + iy * gx + ix] != wp.uint8(0)
    if dirty:
        out[y, x] = _shade(kb, region, stmap, y, x, background, clamp, mode)
        wp.atomic_add(counts, y, 1)


@wp.kernel
def _eval_points(
    kb: BlendArrays,
    region: wp.array(dtype=wp.int32),
    st: wp.array(dtype=wp.vec2f),
    clamp: int,
    kernel: int,
    out: wp.array(dtype=wp.vec3f),
):
    """Blended Lab at scattered points; or, with ``kernel >= 0``, that one kernel's TPS."""
    i = wp.tid()
    p = st[i]
    if kernel >= 0:
        out[i] = _eval_kernel(kb, kernel, p[0], p[1])
    else:
        out[i] = _blend(kb, region[i], p[0], p[1], clamp)


@wp.kernel
def _mix_border(
    kb: BlendArrays,
    pixels: wp.array(dtype=wp.int32),
    other: wp.array(dtype=wp.int32),
    st: wp.array(dtype=wp.vec2f),
    alpha: wp.array(dtype=wp.float32),
    other2: wp.array(dtype=wp.int32),
    st2: wp.array(dtype=wp.vec2f),
    alpha2: wp.array(dtype=wp.float32),
    width: int,
    clamp: int,
    out: wp.array2d(dtype=wp.vec3f),
):
    """Anti-aliased border pixels: ``alpha`` of the pixel's own colour, the rest the region across's; then
    ``alpha2`` of that, the rest the region across a second border's (where ``other2`` is one)."""
    i = wp.tid()
    p = pixels[i]
    y = p / width
    x = p - y * width
    q = st[i]
    across = lab_to_srgb(_blend(kb, other[i], q[0], q[1], clamp))
    a = alpha[i]
    c = a * out[y, x] + (1.0 - a) * across
    o2 = other2[i]
    if o2 >= 0:
        q2 = st2[i]
        a2 = alpha2[i]
        c = a2 * c + (1.0 - a2) * lab_to_srgb(_blend(kb, o2, q2[0], q2[1], clamp))
    out[y, x] = c


@wp.kernel
def _weights(
    kb: BlendArrays,
    region: wp.array(dtype=wp.int32),
    st: wp.array(dtype=wp.vec2f),
    kid: wp.array2d(dtype=wp.int32),
    wout: wp.array2d(dtype=wp.float32),
):
    """The device's blend weights (normalised), for tests: 4 slots (sx + 2 sy), kernel -1 if unused."""
    i = wp.tid()
    r = region[i]
    gx = kb.grid[r, 0]
    gy = kb.grid[r, 1]
    k0 = kb.grid[r, 2]
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
        cy, wy = _axis(b, gy, kb.half, sy == 0)
        for sx in range(2):
            cx, wx = _axis(a, gx, kb.half, sx == 0)
            if cx >= 0 and cy >= 0 and wx * wy > 0.0:
                kid[i, sy * 2 + sx] = k0 + cy * gx + cx
                wout[i, sy * 2 + sx] = wx * wy
                wsum = wsum + wx * wy
    for s in range(4):
        wout[i, s] = wout[i, s] / wsum


# --------------------------------------------------------------------------- host side


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


def _pixel_maps(dk: DeviceKernels, region, st):
    """The region and ``(S, T)`` maps on ``dk``'s device, once ``dk`` is solved."""
    if not dk.solved:
        raise TpsvError("kernels are not solved yet")
    return _as_region_map(region, dk.device), _as_st_map(st, dk.device)


def _launch_banded(kernel, n: int, items: int, dev: str, threads: int | None, launch) -> None:
    """``launch(lo, hi)`` over ``[0, n)``; on the CPU device in as many bands from host threads as the
    work of its ``items`` (:data:`HOST_SECONDS`) pays for."""
    if dev.startswith("cpu"):
        seconds = items * HOST_SECONDS[kernel.key]
        if bands(dev, n, threads, seconds) > 1:
            wp.load_module(module=kernel.module, device=dev)
            split_launch(dev, n, threads, launch, seconds)
            return
    launch(0, n)


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
    """Blend the solved kernels at every pixel.

    Parameters
    ----------
    dk : DeviceKernels
        Solved (:func:`tpsv.gpu.solve.solve`).
    region : ndarray or wp.array (H, W) int32
        Region index (``-1``: outside every region, painted ``background``).
    st : ndarray or wp.array (H, W, 2)
        Normalised ``(S, T)`` of the pixel in its region's patch.
    mode : int
        :data:`MODE_SRGB` (clamped sRGB) or :data:`MODE_LAB`.
    background : 3 floats
        Lab of pixels outside every region.
    out : wp.array2d(vec3f), optional
        Written in place when given.
    threads : int, optional
        Host threads on the CPU device.
    clamp : bool
        Clamp each kernel's TPS to its features' Lab range before blending
        (see the module docstring).

    Returns
    -------
    wp.array2d(dtype=vec3f), shape (H, W)
    """
    reg, stm = _pixel_maps(dk, region, st)
    dev = dk.device
    H, W = reg.shape
    if tuple(stm.shape) != (H, W):
        raise TpsvError(f"(S, T) map {tuple(stm.shape)} does not match region map {(H, W)}")
    if out is None:
        out = wp.empty((H, W), dtype=wp.vec3f, device=dev)
    bg = wp.vec3f(*[float(v) for v in background])

    def launch(r0, r1):
        wp.launch(_rasterise, dim=(r1 - r0, W), inputs=[dk.blend, reg, stm, r0, bg, int(clamp), int(mode), out], device=dev)

    _launch_banded(_rasterise, H, H * W, dev, threads, launch)  # bands of rows
    return out


@wp.kernel
def _changed(a_reg: wp.array2d(dtype=wp.int32), b_reg: wp.array2d(dtype=wp.int32), a_st: wp.array2d(dtype=wp.vec2f),
             b_st: wp.array2d(dtype=wp.vec2f), out: wp.array(dtype=wp.uint8)):
    y, x = wp.tid()
    W = a_reg.shape[1]
    sa = a_st[y, x]
    sb = b_st[y, x]
    flag = wp.uint8(0)
    if a_reg[y, x] != b_reg[y, x] or sa[0] != sb[0] or sa[1] != sb[1]:
        flag = wp.uint8(1)
    out[y * W + x] = flag


def changed_pixels(old_region, new_region, old_st, new_st) -> wp.array:
    """Pixels whose region or ``(S, T)`` differ between two pixel maps on one device (``changed`` of
    :func:`rasterise_dirty`): a flat ``wp.array`` of uint8, made and kept on the device."""
    H, W = old_region.shape
    if tuple(new_region.shape) != (H, W) or tuple(old_st.shape) != (H, W) or tuple(new_st.shape) != (H, W):
        raise TpsvError("the pixel maps to compare differ in size")
    dev = old_region.device
    out = wp.empty(H * W, dtype=wp.uint8, device=dev)
    wp.launch(_changed, dim=(H, W), inputs=[old_region, new_region, old_st, new_st, out], device=dev)
    return out


def rasterise_dirty(
    dk: DeviceKernels,
    region,
    st,
    out: wp.array,
    stale,
    near,
    changed=None,
    mode: int = MODE_SRGB,
    background=(50.0, 0.0, 0.0),
    threads: int | None = None,
    clamp: bool = True,
) -> int:
    """:func:`rasterise` for the dirty pixels only, found on the device; returns how many were drawn.

    A pixel is dirty when it is flagged in ``changed``, or lies in a region
    flagged ``stale``, or lies in a cell (of its region's grid, as the blend
    finds its own cell) whose kernel is flagged ``near``. Only per-region
    and per-kernel flags cross from the host; the pixel maps stay on the
    device. Other pixels of ``out`` are left as they are; dirty ones get
    exactly the values :func:`rasterise` gives them.

    Parameters
    ----------
    dk : DeviceKernels
        Solved.
    region, st, out, mode, background, threads, clamp
        As :func:`rasterise`; ``out`` (H, W) is required.
    stale : array_like (R,) bool
        Regions whose every pixel is dirty.
    near : array_like (n_kernels,) bool
        Kernels whose cell's pixels are dirty (ignored in regions without features).
    changed : array_like (H * W,) bool or wp.array(uint8), optional
        Pixels dirty in any case (flat ``y * W + x``).

    Returns
    -------
    int
        Pixels drawn.
    """
    reg, stm = _pixel_maps(dk, region, st)
    dev = dk.device
    H, W = reg.shape
    if tuple(stm.shape) != (H, W) or tuple(out.shape) != (H, W):
        raise TpsvError("region map, (S, T) map and output differ in size")

    def flags(v, n=None):
        if isinstance(v, wp.array):
            return v
        a = np.ascontiguousarray(np.asarray(v, bool).reshape(-1), np.uint8)
        if n is not None and a.shape[0] != n:
            raise TpsvError(f"{a.shape[0]} flags for {n} entries")
        return wp.array(a, dtype=wp.uint8, device=dev)

    stale_d = flags(stale, int(dk.blend.grid.shape[0]))
    near_d = flags(near, dk.n_kernels)
    changed_d = flags(np.zeros(0, bool) if changed is None else changed)
    if changed_d.shape[0] not in (0, H * W):
        raise TpsvError(f"{changed_d.shape[0]} changed-pixel flags for {H * W} pixels")
    counts = wp.zeros(H, dtype=wp.int32, device=dev)
    bg = wp.vec3f(*[float(v) for v in background])

    def launch(r0, r1):
        wp.launch(_rasterise_dirty, dim=(r1 - r0, W), inputs=[dk.blend, reg, stm, r0, changed_d, stale_d, near_d, bg,
                                                              int(clamp), int(mode), out, counts], device=dev)

    # bands of rows: a row's count is written by one band only
    _launch_banded(_rasterise_dirty, H, H * W, dev, threads, launch)
    return int(counts.numpy().sum())


def mix_border(dk: DeviceKernels, out: wp.array, mix, st, st2, threads: int | None = None,
               clamp: bool = True) -> wp.array:
    """Mix the regions across borders into border pixels of a rasterised frame, in place (sRGB).

    Parameters
    ----------
    dk : DeviceKernels
        Solved.
    out : wp.array2d(vec3f) (H, W)
        The frame from :func:`rasterise` (``MODE_SRGB``).
    mix : BorderMix
        The border pixels (flat indices ``y * W + x``), the regions across
        and the shares (:class:`tpsv.rendering.borders.BorderMix`).
    st, st2 : array_like (n, 2)
        Normalised ``(S, T)`` of each pixel in ``mix.other``'s and ``mix.other2``'s
        patch (``st2`` read only where ``other2`` is a region).
    threads, clamp
        As :func:`rasterise`.

    Returns
    -------
    wp.array2d(dtype=vec3f)
        ``out``.
    """
    if int(np.size(mix.pixels)) == 0:
        return out
    pixels, other, st_d, alpha, other2, st2_d, alpha2 = _send(
        dk.device, (mix.pixels, wp.int32), (mix.other, wp.int32), (np.reshape(st, (-1, 2)), wp.vec2f),
        (mix.alpha, wp.float32), (mix.other2, wp.int32), (np.reshape(st2, (-1, 2)), wp.vec2f), (mix.alpha2, wp.float32))
    on_device = SimpleNamespace(pixels=pixels, other=other, alpha=alpha, other2=other2, alpha2=alpha2)
    return mix_border_device(dk, out, on_device, st_d, st2_d, threads, clamp)


def mix_border_device(dk: DeviceKernels, out: wp.array, mix, st, st2, threads: int | None = None,
                      clamp: bool = True) -> wp.array:
    """:func:`mix_border` of border pixels already on the device: ``mix`` a
    :class:`tpsv.gpu.coverage.DeviceBorderMix` (its ``pixels``, ``other``, ``alpha``, ``other2``, ``alpha2``),
    ``st`` and ``st2`` ``vec2f`` arrays."""
    n = int(mix.pixels.shape[0])
    if n == 0:
        return out
    dev = dk.device
    W = out.shape[1]

    def launch(a, b):
        wp.launch(_mix_border, dim=b - a, inputs=[dk.blend, mix.pixels[a:b], mix.other[a:b], st[a:b], mix.alpha[a:b],
                                                  mix.other2[a:b], st2[a:b], mix.alpha2[a:b], int(W), int(clamp), out],
                  device=dev)

    _launch_banded(_mix_border, n, n, dev, threads, launch)
    return out


def _points(dk: DeviceKernels, region, st):
    """Scattered points on the device: region (n,) int32 (broadcast) and ``(S, T)`` (n,) vec2f."""
    st = np.ascontiguousarray(st, np.float32).reshape(-1, 2)
    region = np.broadcast_to(np.asarray(region, np.int32), (st.shape[0],)).copy()
    dev = dk.device
    return wp.array(region, dtype=wp.int32, device=dev), wp.array(st, dtype=wp.vec2f, device=dev)


def eval_points(dk: DeviceKernels, region, st, kernel: int = -1, clamp: bool = False) -> np.ndarray:
    """Lab at scattered points: the blend, or one kernel's TPS.

    Parameters
    ----------
    dk : DeviceKernels
        Solved.
    region : int or array_like (n,)
        Region of each point.
    st : array_like (n, 2)
        Normalised ``(S, T)``.
    kernel : int
        ``-1``: the blended value; else kernel ``kernel``'s TPS alone.
    clamp : bool
        Range clamp, as in :func:`rasterise`.

    Returns
    -------
    ndarray (n, 3) float64
    """
    reg, pts = _points(dk, region, st)
    out = wp.empty(pts.shape[0], dtype=wp.vec3f, device=dk.device)
    wp.launch(_eval_points, dim=pts.shape[0], inputs=[dk.blend, reg, pts, int(clamp), int(kernel), out], device=dk.device)
    return out.numpy().astype(np.float64)


def device_weights(dk: DeviceKernels, region, st):
    """The device's blend weights at points.

    Returns
    -------
    kid : ndarray (n, 4) int32
        Covering kernels (slot ``sx + 2 sy``), -1 where unused.
    w : ndarray (n, 4) float32
        Normalised weights.
    """
    reg, pts = _points(dk, region, st)
    n = pts.shape[0]
    kid = wp.empty((n, 4), dtype=wp.int32, device=dk.device)
    w = wp.empty((n, 4), dtype=wp.float32, device=dk.device)
    wp.launch(_weights, dim=n, inputs=[dk.blend, reg, pts, kid, w], device=dk.device)
    return kid.numpy(), w.numpy()


def render_arrays(ks, region, st, device: str = "cpu", mode: int = MODE_SRGB, threads: int | None = None, clamp: bool = True) -> np.ndarray:
    """The whole TPS stage from host arrays: upload, solve, rasterise.

    Returns
    -------
    ndarray (H, W, 3) float32
    """
    dk = solve(upload(ks, device), threads=threads)
    out = rasterise(dk, region, st, mode=mode, threads=threads, clamp=clamp)
    return out.numpy().reshape(out.shape[0], out.shape[1], 3)


def render_timed(ks, region, st, device: str = "cpu", repeat: int = 1, threads: int | None = None, clamp: bool = True):
    """Like :func:`render_arrays` with the maps kept on the device.

    Returns
    -------
    image : ndarray (H, W, 3) float32
    timings : dict
        Seconds, best of ``repeat``, each stage closed by
        ``wp.synchronize_device``: ``upload`` (kernel set to the device),
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
