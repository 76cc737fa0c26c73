"""Lab -> sRGB as a Warp function: the float32 twin of :func:`tpsv.color.lab_to_srgb` (``clip=True``).

The matrix and the white point are :data:`tpsv.color.XYZ2RGB` and
:data:`tpsv.color.WHITE`; ``tests/test_gpu_pinning.py`` pins the two
conversions together.
"""

from __future__ import annotations

import warp as wp

from ..color import WHITE, XYZ2RGB

_XYZ2RGB_W = wp.constant(wp.mat33(*[float(v) for v in XYZ2RGB.ravel()]))
_WHITE_W = wp.constant(wp.vec3(*[float(v) for v in WHITE]))


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
