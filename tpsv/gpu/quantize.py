"""A rendered frame rounded to 8 or 16 bits on its Warp device, before it is copied to the host.

The rule is :func:`tpsv.image.to_uint8` / :func:`tpsv.image.to_uint16`, value
for value: the float32 sample widened to float64, times 255 (65535), rounded
half to even, clipped to ``0..top``. A band of a large render then crosses to
the host as 3 (6) bytes a pixel instead of 12, and the host does not round it
(on an H100 the download and the rounding were 5 of the 10-12 s of a
16384 x 16384 PNG).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from .rasterise import _launch_banded

# exact float64 arithmetic: the host's rounding, bit for bit
wp.set_module_options({"enable_backward": False, "fast_math": False})


@wp.kernel
def _to_uint(frame: wp.array2d(dtype=wp.vec3f), row0: int, top: wp.float64, out: wp.array3d(dtype=Any)):
    y, x = wp.tid()
    c = frame[row0 + y, x]
    for k in range(3):
        level = wp.min(wp.max(wp.rint(wp.float64(c[k]) * top), wp.float64(0.0)), top)
        out[y, x, k] = out.dtype(wp.int32(level))


# Both overloads are declared here, at import, so the module is whole before any launch: an overload made at
# a first launch is registered into the module then, and when two host threads make it at once (the bands of a
# large render, ``_launch_banded``) Warp's module hash raced, a KeyError in about one fresh process in four.
for _depth in (wp.uint8, wp.uint16):
    wp.overload(_to_uint, {"frame": wp.array2d(dtype=wp.vec3f), "row0": int, "top": wp.float64,
                           "out": wp.array3d(dtype=_depth)})
del _depth


def to_uint(frame: wp.array, depth: int, threads: int | None = None) -> wp.array:
    """``frame`` (``(H, W)`` of ``vec3f``, sRGB in ``[0, 1]``) as ``(H, W, 3)`` uint8 (``depth`` 8)
    or uint16 (16) on the same device.

    Parameters
    ----------
    frame : wp.array2d(vec3f)
    depth : int
        8 or 16.
    threads : int, optional
        Host threads on the CPU device.

    Returns
    -------
    wp.array3d(uint8 or uint16)
    """
    dtype, top = {8: (wp.uint8, 255.0), 16: (wp.uint16, 65535.0)}[int(depth)]
    H, W = int(frame.shape[0]), int(frame.shape[1])
    out = wp.empty((H, W, 3), dtype=dtype, device=frame.device)

    def launch(r0, r1):
        wp.launch(_to_uint, dim=(r1 - r0, W), inputs=[frame, r0, wp.float64(top), out[r0:r1]], device=frame.device)

    _launch_banded(_to_uint, H, H * W, str(frame.device), threads, launch)
    return out


__all__ = ["to_uint"]
