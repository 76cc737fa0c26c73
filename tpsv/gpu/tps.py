"""The TPS stage on a Warp device, one namespace for its callers: upload, solve, rasterise.

``from tpsv.gpu import tps as gtps`` gives the whole stage:
``gtps.rasterise(gtps.solve(gtps.upload(kernel_set, device)), region, st)``.
The code lives by step, one code path for the ``cpu`` and ``cuda`` devices:

* :mod:`tpsv.gpu.device`: a kernel set's device arrays (three ``@wp.struct``
  bundles), :func:`upload`, the CPU host-thread bands;
* :mod:`tpsv.gpu.solve`: Eq. (4) per kernel in float64 (null-space
  Cholesky, affine fallback), :func:`solve`, :func:`solve_reusing`;
* :mod:`tpsv.gpu.rasterise`: the per-pixel blend in float32,
  :func:`rasterise`, :func:`rasterise_dirty`, :func:`eval_points`;
* :mod:`tpsv.gpu.color`: Lab -> sRGB, the twin of :mod:`tpsv.color`.
"""

from __future__ import annotations

from .device import DeviceKernels, upload
from .rasterise import (
    MODE_LAB,
    MODE_SRGB,
    device_weights,
    eval_points,
    mix_border,
    mix_border_device,
    rasterise,
    rasterise_dirty,
    render_arrays,
    render_timed,
)
from .solve import FULL_SOLVE_FRACTION, coefficients, solve, solve_reusing, subset_kernels

__all__ = [
    "DeviceKernels", "upload",
    "solve", "solve_reusing", "subset_kernels", "coefficients", "FULL_SOLVE_FRACTION",
    "rasterise", "rasterise_dirty", "mix_border", "mix_border_device", "eval_points", "device_weights", "render_arrays", "render_timed",
    "MODE_SRGB", "MODE_LAB",
]
