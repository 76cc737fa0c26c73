"""The refinement of a magnified picture on a Warp device (:mod:`tpsv.rendering.refine`).

Three kernels per step, each a thread a pixel:

1. :func:`_tv`: ``x + step eps div(grad x / |grad x|_eps)``, forward
   differences for the gradient and backward ones for the divergence, zero
   flux through the picture's border, the three channels sharing one
   gradient magnitude (the host's :func:`tpsv.rendering.refine._tv_step`);
2. :func:`_area`: the residual ``small - area average of x``, the area average
   as OpenCV's ``INTER_AREA`` takes it (each small pixel the mean of the big
   pixels it covers, the partly covered ones weighted by their share: a table
   of taps per axis made on the host);
3. :func:`_cubic`: the residual upsampled as OpenCV's ``INTER_CUBIC`` does
   (:func:`tpsv.gpu.cubic.sample`: Keys, ``a = -0.75``, pixel centres
   aligned, border replicated) and added.

The sums run in float32 in another order than OpenCV's, so the picture
differs from the host's by rounding (within 1e-5 on the tests' pictures).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .cubic import sample
from .rasterise import _launch_banded
from .transfer import upload

wp.set_module_options({"enable_backward": False})


@wp.func
def _flux(x: wp.array2d(dtype=wp.vec3f), y: int, i: int, eps2: float):
    """The normalised forward gradient at ``(y, i)``: ``(gx, gy) / |(gx, gy)|_eps``, zero past the last
    column or row."""
    c = x[y, i]
    gx = wp.vec3f(0.0, 0.0, 0.0)
    gy = wp.vec3f(0.0, 0.0, 0.0)
    if i + 1 < x.shape[1]:
        gx = x[y, i + 1] - c
    if y + 1 < x.shape[0]:
        gy = x[y + 1, i] - c
    n = wp.sqrt(wp.dot(gx, gx) + wp.dot(gy, gy) + eps2)
    return gx / n, gy / n


@wp.kernel
def _tv(x: wp.array2d(dtype=wp.vec3f), y0: int, eps2: float, k: float, out: wp.array2d(dtype=wp.vec3f)):
    yy, i = wp.tid()
    y = yy + y0
    gx, gy = _flux(x, y, i, eps2)
    div = gx + gy
    if i > 0:
        lx, ly = _flux(x, y, i - 1, eps2)
        div = div - lx
    if y > 0:
        ux, uy = _flux(x, y - 1, i, eps2)
        div = div - uy
    out[y, i] = x[y, i] + k * div


@wp.kernel
def _area(x: wp.array2d(dtype=wp.vec3f), small: wp.array2d(dtype=wp.vec3f), rstart: wp.array(dtype=wp.int32),
          rtap: wp.array(dtype=wp.int32), rw: wp.array(dtype=wp.float32), cstart: wp.array(dtype=wp.int32),
          ctap: wp.array(dtype=wp.int32), cw: wp.array(dtype=wp.float32), y0: int,
          res: wp.array2d(dtype=wp.vec3f)):
    yy, j = wp.tid()
    i = yy + y0
    acc = wp.vec3f(0.0, 0.0, 0.0)
    for a in range(rstart[i], rstart[i + 1]):
        row = wp.vec3f(0.0, 0.0, 0.0)
        r = rtap[a]
        for b in range(cstart[j], cstart[j + 1]):
            row = row + cw[b] * x[r, ctap[b]]
        acc = acc + rw[a] * row
    res[i, j] = small[i, j] - acc


@wp.kernel
def _cubic(res: wp.array2d(dtype=wp.vec3f), sy: float, sx: float, y0: int, x: wp.array2d(dtype=wp.vec3f)):
    yy, i = wp.tid()
    y = yy + y0
    x[y, i] = x[y, i] + sample(res, (float(i) + 0.5) * sx, (float(y) + 0.5) * sy)


def area_taps(big: int, small: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per small pixel along one axis, the big pixels it averages and their weights, as OpenCV's
    ``INTER_AREA`` takes them for a reduction from ``big`` to ``small`` pixels.

    Returns
    -------
    start : (small + 1,) int32
        Taps of pixel ``i``: ``start[i]`` to ``start[i + 1]``.
    tap : int32, weight : float32
        Big pixel and weight of each tap (a pixel's weights sum to 1).
    """
    scale = big / small
    taps, weights, start = [], [], [0]
    for i in range(small):
        f0 = i * scale
        f1 = f0 + scale
        c0, c1 = int(np.ceil(f0)), int(np.floor(f1))
        cell = min(scale, big - f0)
        if c0 - f0 > 1e-3 and c0 >= 1:
            taps.append(c0 - 1)
            weights.append((c0 - f0) / cell)
        for k in range(c0, min(c1, big)):
            taps.append(k)
            weights.append(1.0 / cell)
        if c1 < big and f1 - c1 > 1e-3:
            taps.append(c1)
            weights.append(min(min(f1 - c1, 1.0), cell) / cell)
        start.append(len(taps))
    return np.array(start, np.int32), np.array(taps, np.int32), np.array(weights, np.float32)


def refine_device(big: np.ndarray, small: np.ndarray, iterations: int, eps: float, step: float, device: str,
                  threads: int | None = None, progress=None) -> np.ndarray:
    """:func:`tpsv.rendering.refine.refine_magnified` on ``device``; returns float32 (H, W, 3) clipped to [0, 1]."""
    H, W = big.shape[:2]
    h, w = small.shape[:2]
    x = wp.array(np.ascontiguousarray(big, np.float32).reshape(H, W, 3), dtype=wp.vec3f, device=device)
    y = wp.array(np.ascontiguousarray(small, np.float32).reshape(h, w, 3), dtype=wp.vec3f, device=device)
    nxt = wp.empty_like(x)
    res = wp.empty_like(y)
    (r0, r1, r2), (c0, c1, c2) = area_taps(H, h), area_taps(W, w)
    rows_cols = upload(device, (r0, wp.int32), (r1, wp.int32), (r2, wp.float32), (c0, wp.int32), (c1, wp.int32),
                       (c2, wp.float32))
    eps2, k = float(eps) ** 2, float(step) * float(eps)
    for it in range(iterations):
        src, dst = x, nxt
        _launch_banded(_tv, H, H * W, device, threads, lambda a, b: wp.launch(
            _tv, dim=(b - a, W), inputs=[src, a, eps2, k, dst], device=device))
        x, nxt = nxt, x
        cur = x
        _launch_banded(_area, h, H * W, device, threads, lambda a, b: wp.launch(
            _area, dim=(b - a, w), inputs=[cur, y, *rows_cols, a, res], device=device))
        _launch_banded(_cubic, H, H * W, device, threads, lambda a, b: wp.launch(
            _cubic, dim=(b - a, W), inputs=[res, h / H, w / W, a, cur], device=device))
        if progress is not None:
            progress(it + 1, iterations)
    return np.clip(x.numpy().reshape(H, W, 3), 0.0, 1.0)


__all__ = ["area_taps", "refine_device"]
