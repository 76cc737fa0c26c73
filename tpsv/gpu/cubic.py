"""The Keys cubic (``a = -0.75``, OpenCV's ``INTER_CUBIC``) sampling a ``vec3f`` picture, as Warp functions.

Interpolating: at a texel centre the weights are (0, 1, 0, 0), so a sample
there is the texel; the detail layer (:mod:`tpsv.gpu.detail`) reads its
texture with it, and the refinement (:mod:`tpsv.gpu.refine`) upsamples its
residual with it.
"""

from __future__ import annotations

import warp as wp

#: How near (texels) a sample must be to a texel centre to read that texel alone. The cubic's
#: weights there differ from (0, 1, 0, 0) by about 0.75 times the distance: 1e-4 at most here, 1e-5 of
#: a residual step of 0.1; a pixel of a model at rest at its own size lands within ~3e-5 (float32).
ON_TEXEL = wp.constant(1.0e-4)


@wp.func
def keys(t: float):
    """Keys cubic weights (``a = -0.75``) of the four texels around a position ``t`` past the second."""
    t2 = t * t
    t3 = t2 * t
    return wp.vec4f(
        -0.75 * t3 + 1.5 * t2 - 0.75 * t,
        1.25 * t3 - 2.25 * t2 + 1.0,
        -1.25 * t3 + 1.5 * t2 + 0.75 * t,
        0.75 * t3 - 0.75 * t2,
    )


@wp.func
def sample(tex: wp.array2d(dtype=wp.vec3f), x: float, y: float):
    """Cubic sample at texture position (x, y) (texel centres at half-integers), edges clamped."""
    th = tex.shape[0]
    tw = tex.shape[1]
    fx = x - 0.5
    fy = y - 0.5
    # on a texel centre (to float32 rounding: a model at rest at its own size) the cubic is that texel
    cx = wp.round(fx)
    cy = wp.round(fy)
    if wp.abs(fx - cx) < ON_TEXEL and wp.abs(fy - cy) < ON_TEXEL:
        return tex[wp.clamp(int(cy), 0, th - 1), wp.clamp(int(cx), 0, tw - 1)]
    ix = int(wp.floor(fx))
    iy = int(wp.floor(fy))
    wx = keys(fx - float(ix))
    wy = keys(fy - float(iy))
    acc = wp.vec3f(0.0, 0.0, 0.0)
    for j in range(4):
        yy = wp.clamp(iy - 1 + j, 0, th - 1)
        row = wp.vec3f(0.0, 0.0, 0.0)
        for i in range(4):
            xx = wp.clamp(ix - 1 + i, 0, tw - 1)
            row = row + wx[i] * tex[yy, xx]
        acc = acc + wy[j] * row
    return acc


__all__ = ["ON_TEXEL", "keys", "sample"]
