"""The detail layer on a Warp device: texture residual added to rendered pixels.

One thread per output pixel: its region's rest frame maps the pixel's
``(S, T)`` to a texture position, the texture is sampled there with the
weights of the Keys cubic, ``a = -0.75`` (interpolating: at scale 1 a pixel
centre lands on its texel and gets it exactly; magnified, the texture is
smooth, C1, and a little sharper than with Catmull-Rom's ``a = -0.5``), and the
residual (stored as Y, Cb, Cr) is added to the sRGB colour, clamped to
``[0, 1]``. A region in luma mode adds only the residual's Y, the same to
all three channels.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..model import DETAIL_GAIN, DETAIL_YCC, DETAIL_ZERO
from .rasterise import _as_region_map, _as_st_map, _launch_banded
from .cubic import sample as _sample
from .transfer import upload

wp.set_module_options({"enable_backward": False, "fast_math": True})

#: (Y, Cb, Cr) residual -> sRGB residual.
_FROM_YCC = wp.constant(wp.mat33f(*np.linalg.inv(DETAIL_YCC).astype(np.float32).ravel()))


@wp.func
def _detail(region: int, st: wp.vec2f, frame: wp.array(dtype=wp.vec2f), mode: wp.array(dtype=wp.int32),
            tex: wp.array2d(dtype=wp.vec3f)):
    m = mode[region]
    if m == 0:
        return wp.vec3f(0.0, 0.0, 0.0)
    p = frame[3 * region] + st[0] * frame[3 * region + 1] + st[1] * frame[3 * region + 2]
    d = _sample(tex, p[0], p[1])
    if m == 2:
        return wp.vec3f(d[0], d[0], d[0])
    return _FROM_YCC * d


@wp.func
def _saturate(c: wp.vec3f):
    return wp.vec3f(wp.clamp(c[0], 0.0, 1.0), wp.clamp(c[1], 0.0, 1.0), wp.clamp(c[2], 0.0, 1.0))


@wp.kernel
def _add_detail(
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    frame: wp.array(dtype=wp.vec2f),
    mode: wp.array(dtype=wp.int32),
    tex: wp.array2d(dtype=wp.vec3f),
    y0: int,
    out: wp.array2d(dtype=wp.vec3f),
):
    yy, x = wp.tid()
    y = yy + y0
    r = region[y, x]
    if r >= 0:
        out[y, x] = _saturate(out[y, x] + _detail(r, stmap[y, x], frame, mode, tex))


@wp.kernel
def _add_detail_list(
    region: wp.array2d(dtype=wp.int32),
    stmap: wp.array2d(dtype=wp.vec2f),
    pixels: wp.array(dtype=wp.int32),
    width: int,
    frame: wp.array(dtype=wp.vec2f),
    mode: wp.array(dtype=wp.int32),
    tex: wp.array2d(dtype=wp.vec3f),
    out: wp.array2d(dtype=wp.vec3f),
):
    p = pixels[wp.tid()]
    y = p / width
    x = p - y * width
    r = region[y, x]
    if r >= 0:
        out[y, x] = _saturate(out[y, x] + _detail(r, stmap[y, x], frame, mode, tex))


_ZERO = wp.constant(wp.float32(DETAIL_ZERO))
_GAIN = wp.constant(wp.float32(DETAIL_GAIN))


@wp.kernel
def _residual(texels: wp.array3d(dtype=wp.uint16), tex: wp.array2d(dtype=wp.vec3f)):
    """10-bit texels to the residual (Y, Cb, Cr) they stand for."""
    y, x = wp.tid()
    tex[y, x] = wp.vec3f((wp.float32(texels[y, x, 0]) - _ZERO) / _GAIN, (wp.float32(texels[y, x, 1]) - _ZERO) / _GAIN,
                         (wp.float32(texels[y, x, 2]) - _ZERO) / _GAIN)


class DeviceDetail:
    """A model's detail layer uploaded to a device (once per model).

    The texels go up as they are stored (16-bit words, half the bytes of the
    float residual) and become the residual on the device.

    Parameters
    ----------
    detail : tpsv.model.Detail
    device : str
    """

    def __init__(self, detail, device: str):
        self.device = device
        raw, self.frame, self.mode = upload(device, (detail.texels, wp.uint16),
                                            (np.asarray(detail.frame).reshape(-1, 2), wp.vec2f),
                                            (detail.mode, wp.int32))
        h, w = raw.shape[:2]
        self.tex = wp.empty((h, w), dtype=wp.vec3f, device=device)
        wp.launch(_residual, dim=(h, w), inputs=[raw, self.tex], device=device)


def add_detail(dd: DeviceDetail, out: wp.array, region, st, pixels=None, threads: int | None = None) -> None:
    """Add the detail layer to ``out`` (sRGB, device frame) in place.

    Parameters
    ----------
    dd : DeviceDetail
    out : wp.array2d(vec3f) (H, W)
    region, st : region and ``(S, T)`` maps (ndarray or device arrays, as :func:`rasterise` takes)
    pixels : ndarray of int, optional
        Only these flat pixel indices (default: every pixel).
    threads : int, optional
        Host threads on the CPU device.
    """
    dev = dd.device
    reg = _as_region_map(region, dev)
    stm = _as_st_map(st, dev)
    H, W = reg.shape
    if pixels is None:
        def launch(r0, r1):
            wp.launch(_add_detail, dim=(r1 - r0, W), inputs=[reg, stm, dd.frame, dd.mode, dd.tex, r0, out], device=dev)

        _launch_banded(_add_detail, H, H * W, dev, threads, launch)
        return
    pix = np.ascontiguousarray(pixels, np.int32)
    if pix.size == 0:
        return
    pix_d = wp.array(pix, dtype=wp.int32, device=dev)

    def launch_list(a, b):
        wp.launch(_add_detail_list, dim=b - a, inputs=[reg, stm, pix_d[a:b], int(W), dd.frame, dd.mode, dd.tex, out],
                  device=dev)

    _launch_banded(_add_detail_list, pix.size, pix.size, dev, threads, launch_list)
