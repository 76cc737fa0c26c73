"""A :class:`tpsv.tps.KernelSet` on a Warp device: its arrays, the structs the kernels take, host threads.

The device arrays of one kernel set are grouped in three ``@wp.struct``
types, each passed to the kernels as one parameter:

* :class:`Systems`: what the solve reads (features, kernel slots, frames,
  smoothing) and its float64 per-slot scratch;
* :class:`Solution`: what the solve writes (local points, TPS weights ``w``
  and affine part ``b`` in float64 and float32, status, colour range);
* :class:`BlendArrays`: what the rasteriser reads (the region grids, fill
  colours and the float32 half of the solution).

Several structs share an array (``count``, ``pos32`` ...): they hold
references, never copies.

CPU bands: Warp's CPU launches run one thread each and release the GIL, so
on the CPU device the solve kernels (other than the tile solve) and the
rasteriser's pixel rows are split into bands launched from a few host
threads (:func:`split_launch`); results do not depend on the split. A band
costs its launch (20-50 us of Python packing the arguments, under the GIL)
and a hand-off between threads, so a launch is split only as far as its
work pays for that (:func:`bands`).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..threads import pool as host_pool
from ..tps import kernel_lambda
from . import resolve_device
from . import warp as _warp
from .transfer import upload as _send


@wp.struct
class Systems:
    """Per kernel slot: what the solve reads, and its float64 scratch."""

    index: wp.array2d(dtype=wp.int32)  # (n, K) feature of each slot; anchors in slots 0-2
    count: wp.array(dtype=wp.int32)  # (n,) active slots
    degen: wp.array(dtype=wp.int32)  # (n,) 1: degenerate kernel (affine fallback)
    frame64: wp.array(dtype=wp.vec4d)  # (n,) (cS, cT, ax, ay): local = ((S - cS) ax, (T - cT) ay)
    st: wp.array(dtype=wp.vec2d)  # (F,) feature (S, T)
    lab: wp.array(dtype=wp.vec3f)  # (F,) feature Lab
    lam: wp.array(dtype=wp.float64)  # (n,) smoothing in local units
    vals: wp.array2d(dtype=wp.vec3d)  # (n, K) scratch: slot values
    bary: wp.array2d(dtype=wp.vec3d)  # (n, K) scratch: barycentric coordinates w.r.t. the anchors
    pa: wp.array2d(dtype=wp.vec3d)  # (n, K) scratch: anchor rows of Phi


@wp.struct
class Solution:
    """Per kernel: the solved coefficients in its local frame."""

    pts: wp.array2d(dtype=wp.vec2d)  # (n, K) local points (float32-rounded)
    pos32: wp.array2d(dtype=wp.vec2f)  # (n, K) the same in float32
    w64: wp.array2d(dtype=wp.vec3d)  # (n, K) TPS weights
    w32: wp.array2d(dtype=wp.vec3f)
    b64: wp.array2d(dtype=wp.vec3d)  # (n, 3) affine part: rows constant, u, v
    b32: wp.array2d(dtype=wp.vec3f)
    status: wp.array(dtype=wp.int32)  # (n,) 0 TPS, 1 degenerate (affine), 2 not finite (affine)
    lo: wp.array(dtype=wp.vec3f)  # (n,) Lab range of the kernel's features
    hi: wp.array(dtype=wp.vec3f)


@wp.struct
class BlendArrays:
    """What the rasteriser reads: region grids, fill colours, blend half-width, float32 coefficients."""

    grid: wp.array2d(dtype=wp.int32)  # (R, 3) cells along S, along T, first kernel
    fill: wp.array(dtype=wp.vec3f)  # (R,) Lab of a region without features
    half: float  # half-width of a kernel's support, in cells (0.5 + overlap)
    count: wp.array(dtype=wp.int32)
    frame32: wp.array(dtype=wp.vec4f)
    pos32: wp.array2d(dtype=wp.vec2f)
    w32: wp.array2d(dtype=wp.vec3f)
    b32: wp.array2d(dtype=wp.vec3f)
    lo: wp.array(dtype=wp.vec3f)
    hi: wp.array(dtype=wp.vec3f)


@dataclass
class DeviceKernels:
    """A :class:`tpsv.tps.KernelSet` on a device, with scratch and coefficients.

    After :func:`tpsv.gpu.solve.solve`: ``solution.w64`` (n, K) vec3d and
    ``solution.b64`` (n, 3) vec3d hold the float64 coefficients in each
    kernel's local frame (rows of ``b``: constant, u, v), ``w32``/``b32``/
    ``pos32`` the float32 copies used by the rasteriser, ``status`` 0 (TPS),
    1 (degenerate, affine) or 2 (solve not finite, affine).
    """

    device: str
    K: int
    n_kernels: int
    systems: Systems
    solution: Solution
    blend: BlendArrays
    A: wp.array | None  # (n, K, K) float64: the projected systems (lower triangle), then their factors
    rhs: wp.array  # (n, K, 3) float64: right-hand sides, then the solutions gamma
    solved: bool = False


def _struct(cls, **fields):
    s = cls()
    for name, value in fields.items():
        setattr(s, name, value)
    return s


def upload(ks, device: str = "cpu") -> DeviceKernels:
    """Copy a kernel set to ``device`` and allocate the solver's arrays.

    Parameters
    ----------
    ks : tpsv.tps.KernelSet
    device : str
        Warp device (``cpu``, ``cuda``, ``cuda:N``).

    Returns
    -------
    DeviceKernels
        Not yet solved.
    """
    _warp()
    device = resolve_device(device)
    K = int(ks.kernel_size)
    n = int(ks.n_kernels)
    R = int(ks.grid.shape[0])
    F = int(ks.st.shape[0])

    def empty(shape, dtype):  # every entry the solver reads is written first
        return wp.empty(shape, dtype=dtype, device=device)

    # the kernel set's arrays in one transfer
    count, frame32, index, degen, frame64, st, lab, lam, grid, fill = _send(
        device,
        (ks.count, wp.int32), (ks.frame.reshape(n, 4), wp.vec4f), (ks.index.reshape(n, K), wp.int32),
        (ks.degenerate, wp.int32), (ks.frame.reshape(n, 4), wp.vec4d), (ks.st.reshape(F, 2), wp.vec2d),
        (ks.lab.reshape(F, 3), wp.vec3f), (kernel_lambda(ks), wp.float64), (ks.grid.reshape(R, 3), wp.int32),
        (ks.fill.reshape(R, 3), wp.vec3f))
    sol = _struct(
        Solution,
        pts=empty((n, K), wp.vec2d), pos32=empty((n, K), wp.vec2f),
        w64=empty((n, K), wp.vec3d), w32=empty((n, K), wp.vec3f),
        b64=empty((n, 3), wp.vec3d), b32=empty((n, 3), wp.vec3f),
        status=empty(n, wp.int32), lo=empty(n, wp.vec3f), hi=empty(n, wp.vec3f),
    )
    systems = _struct(
        Systems,
        index=index,
        count=count,
        degen=degen,
        frame64=frame64,
        st=st,
        lab=lab,
        lam=lam,
        vals=empty((n, K), wp.vec3d), bary=empty((n, K), wp.vec3d), pa=empty((n, K), wp.vec3d),
    )
    blend = _struct(
        BlendArrays,
        grid=grid,
        fill=fill,
        half=0.5 + float(ks.overlap),
        count=count, frame32=frame32,
        pos32=sol.pos32, w32=sol.w32, b32=sol.b32, lo=sol.lo, hi=sol.hi,
    )
    return DeviceKernels(
        device=device, K=K, n_kernels=n, systems=systems, solution=sol, blend=blend,
        A=empty((n, K, K), wp.float64), rhs=empty((n, K, 3), wp.float64),
    )


#: Least work (seconds on one core) of a band of a CPU launch: a launch with less than twice this runs
#: whole on the calling thread. On the 2-core CI machine, launches of 0.1-1 ms of work took 2-8 times
#: as long in 8 bands on 2 threads (a 512 x 512 render spent 8 ms so); launches of 5 ms and more gain
#: from bands.
BAND_SECONDS = 2e-3


@functools.cache
def _cores() -> int:
    return os.cpu_count() or 1


def host_threads(device: str, threads: int | None) -> int:
    """Host threads that launch bands on ``device``: 1 on CUDA; ``threads`` or every core on the CPU."""
    if not device.startswith("cpu"):
        return 1
    if threads is None:
        threads = _cores()
    return max(1, int(threads))


def bands(device: str, n: int, threads: int | None, seconds: float | None = None) -> int:
    """Bands :func:`split_launch` cuts a launch of extent ``n`` into: at most 4 per host thread, and
    (when the launch's work on one core, ``seconds``, is given) at least :data:`BAND_SECONDS` of work
    each; 1 on CUDA."""
    nt = min(host_threads(device, threads), n)
    if nt <= 1:
        return 1
    nb = min(4 * nt, n)
    if seconds is not None:
        nb = min(nb, int(seconds / BAND_SECONDS))
    return max(nb, 1)


def split_launch(device: str, n: int, threads: int | None, launch, seconds: float | None = None) -> None:
    """Call ``launch(lo, hi)`` over ``[0, n)``: once on CUDA; in bands from host threads on the CPU.

    Parameters
    ----------
    device : str
    n : int
        Extent of the launch's first dimension.
    threads : int or None
        Host threads on the CPU device (None: every core).
    launch : callable
        ``launch(lo, hi)`` launches the band ``[lo, hi)``; the kernel's
        module must be loaded first (``wp.load_module``), so that no two
        threads compile it.
    seconds : float, optional
        The launch's work on one core (an estimate): how many bands it pays
        for (:func:`bands`; default: 4 a thread).
    """
    nb = bands(device, n, threads, seconds)
    if nb <= 1:
        launch(0, n)
        return
    nt = min(host_threads(device, threads), nb)
    edges = np.linspace(0, n, nb + 1).astype(int)
    spans = [(int(edges[i]), int(edges[i + 1])) for i in range(nb) if edges[i + 1] > edges[i]]
    list(host_pool("launch", nt).map(lambda b: launch(*b), spans))
