"""The texture detail layer: what the vector image misses, coded in patch space.

The residual ``photo - render(vector model)`` at scale 1 is stored as one
10-bit texture laid out like the photo, and every region reads it through its
rest frame (``tpsv.model.Detail``): the affine map of its patch when it was
vectorised. At rest a pixel's ``(S, T)`` leads back to its own texel, so
nothing is resampled and the scale-1 picture gets the whole residual; after
``deform`` the texels follow ``(S, T)``. The texture is coded with AVIF
(docs/DESIGN.md, "Detail layer", for the codec comparison behind the choice).
"""

from __future__ import annotations

import numpy as np

from ..codec import detail as detail_codec
from ..geometry.bands import for_bands
from ..geometry.patch import affine_frame
from ..model import DETAIL_FULL, DETAIL_GAIN, DETAIL_OFF, DETAIL_YCC, DETAIL_ZERO, Detail, Model


def rest_frames(model: Model) -> np.ndarray:
    """Each region's rest frame ``(origin, d/dS, d/dT)`` (R, 3, 2): its patch, which is affine when fresh.

    A patch that is not affine (a model deformed before its detail layer was
    made) gets the affine map through three of its corners.
    """
    out = np.zeros((len(model.regions), 3, 2), np.float64)
    for r, region in enumerate(model.regions):
        M, N = region.patch.shape
        ctrl = np.asarray(region.patch.ctrl, np.float64)
        fa = affine_frame(region.patch)
        if fa is not None:
            O, A = fa
            out[r] = (O, A[:, 0] * (M - 1), A[:, 1] * (N - 1))
        else:
            O = ctrl[0, 0, 0]
            out[r] = (O, ctrl[-1, 0, 0] - O, ctrl[0, -1, 0] - O)
    return out


def residual_texels(rgb: np.ndarray, rendered: np.ndarray) -> np.ndarray:
    """The residual ``rgb - rendered`` (sRGB, both (H, W, 3) in [0, 1]) as 10-bit (Y, Cb, Cr) texels (uint16).

    Computed band by band of rows (float64 temporaries of a band only).
    """
    h, w = rgb.shape[:2]
    out = np.empty((h, w, 3), np.uint16)

    def band(rows):
        a, b = rows
        res = (np.asarray(rgb[a:b], np.float64) - np.asarray(rendered[a:b], np.float64)) @ DETAIL_YCC.T
        out[a:b] = np.clip(np.rint(DETAIL_ZERO + DETAIL_GAIN * res), 0, 1023)

    for_bands(band, h, w)
    return out


#: (Y, Cb, Cr) -> sRGB, for rows of texels (``residual @ _TO_RGB``).
_TO_RGB = np.linalg.inv(DETAIL_YCC).T


def _residual_rgb(texels: np.ndarray) -> np.ndarray:
    """The sRGB residual (float64) of some (Y, Cb, Cr) texels."""
    return ((texels.astype(np.float64) - DETAIL_ZERO) / DETAIL_GAIN) @ _TO_RGB


def texel_rgb(texels: np.ndarray) -> np.ndarray:
    """The sRGB residual (h, w, 3) float32 of (Y, Cb, Cr) texels (band by band of rows)."""
    h, w = texels.shape[:2]
    out = np.empty((h, w, 3), np.float32)

    def band(rows):
        a, b = rows
        out[a:b] = _residual_rgb(texels[a:b])

    for_bands(band, h, w)
    return out


def code_texels(texels: np.ndarray, quality: int) -> tuple[tuple, np.ndarray]:
    """``(payload, decoded texels)`` of ``texels`` coded at ``quality`` (1-100): the AVIF files
    (``Detail.payload``) and what they decode to."""
    payload = detail_codec.encode_texels(texels, quality)
    h, w = texels.shape[:2]
    return payload, detail_codec.decode_texels(payload, w, h)


def make_detail(model: Model, texels: np.ndarray, quality: int, coded: tuple | None = None) -> Detail:
    """The detail layer of ``model`` with residual ``texels`` at ``quality`` (every region in full mode,
    transparent regions off).

    ``coded``: ``code_texels(texels, quality)`` when already computed.
    """
    payload, decoded = coded if coded is not None else code_texels(texels, quality)
    R = len(model.regions)
    return Detail(payload=payload, texels=decoded, frame=rest_frames(model),
                  mode=np.array([DETAIL_OFF if r.transparent else DETAIL_FULL for r in model.regions], np.uint8).reshape(R),
                  quality=int(quality))


def with_texels(rendered: np.ndarray, texels: np.ndarray) -> np.ndarray:
    """What the renderer shows at scale 1 for a model at rest: ``rendered`` plus the texels' residual."""
    h, w = rendered.shape[:2]
    out = np.empty(np.broadcast_shapes(rendered.shape, texels.shape), np.result_type(rendered, np.float32))

    def band(rows):  # (not texel_rgb: a band must not wait on the pool it runs on)
        a, b = rows
        np.clip(rendered[a:b] + _residual_rgb(texels[a:b]).astype(np.float32), 0.0, 1.0, out=out[a:b])

    for_bands(band, h, w)
    return out
