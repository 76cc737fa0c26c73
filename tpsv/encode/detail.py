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
from ..geometry.bands import for_bands, map_bands
from ..geometry.patch import affine_frame
from ..model import DETAIL_FULL, DETAIL_GAIN, DETAIL_LUMA, DETAIL_OFF, DETAIL_YCC, DETAIL_ZERO, Detail, Model

#: A region whose residual's chroma stays within these (texel units, 1/510 of sRGB: half an 8-bit
#: level) reads its texture's luma alone (``DETAIL_LUMA``): its root mean square over the region
#: (Cb and Cr) and no texel further off than the peak (4 levels). The codec's own chroma error is
#: larger than that at every quality (about 1 texel at quality 95, 2 at 75), and small textures
#: are coded as one image of the three planes stacked (``codec.detail``), where AV1's blocks and
#: loop filters reach across the seams: scikit-image's grey coins (384 x 303) came back with R, G
#: and B up to 22 8-bit levels apart at quality 75 (55 at quality 20), worst in its top rows; now
#: none, for the same bytes. A region's border pixels count: beside a coloured region the mix
#: drawn along the border leaves chroma in the residual, and the region keeps full mode.
GREY_RMS, GREY_PEAK = 1.0, 8


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


def make_detail(model: Model, texels: np.ndarray, quality: int, coded: tuple | None = None,
                grey: np.ndarray | None = None) -> Detail:
    """The detail layer of ``model`` with residual ``texels`` at ``quality``: every region in full mode,
    luma mode where ``grey`` (:func:`grey_regions`), transparent regions off.

    ``coded``: ``code_texels(texels, quality)`` when already computed.
    """
    payload, decoded = coded if coded is not None else code_texels(texels, quality)
    R = len(model.regions)
    grey = np.zeros(R, bool) if grey is None else np.asarray(grey, bool)
    mode = [DETAIL_OFF if r.transparent else DETAIL_LUMA if g else DETAIL_FULL for r, g in zip(model.regions, grey)]
    return Detail(payload=payload, texels=decoded, frame=rest_frames(model), mode=np.array(mode, np.uint8).reshape(R),
                  quality=int(quality))


def grey_regions(texels: np.ndarray, index: np.ndarray, n_regions: int) -> np.ndarray:
    """Which regions' residual has no chroma worth coding (:data:`GREY_RMS`, :data:`GREY_PEAK`).

    Parameters
    ----------
    texels : ndarray (H, W, 3) uint16
        The residual texels (:func:`residual_texels`).
    index : ndarray (H, W) int
        Region of every pixel at scale 1, -1 for none.
    n_regions : int

    Returns
    -------
    ndarray (n_regions,) bool
        True for a region with pixels whose chroma is within the bounds.
    """
    h, w = index.shape
    slots = n_regions + 1  # the last for pixels of no region
    lo, hi = DETAIL_ZERO - GREY_PEAK, DETAIL_ZERO + GREY_PEAK

    def peaks(rows):
        a, b = rows
        c = texels[a:b, :, 1:]
        at = index[a:b][((c < lo) | (c > hi)).any(axis=2)]
        return np.bincount(np.where(at >= 0, at, n_regions), minlength=slots)

    # a colour photo's regions fail on their peaks (a few comparisons a texel); only the others are summed
    grey = sum(map_bands(peaks, h, w))[:n_regions] == 0
    if not grey.any():
        return grey
    keep = np.append(grey, False)

    def squares(rows):
        a, b = rows
        inside = keep[index[a:b]]
        at = index[a:b][inside]
        c = texels[a:b][inside][:, 1:].astype(np.int32) - DETAIL_ZERO
        return np.bincount(at, minlength=slots), np.bincount(at, (c * c).sum(axis=1), minlength=slots)

    parts = map_bands(squares, h, w)
    count, square = (sum(part[k] for part in parts)[:n_regions] for k in range(2))
    return grey & (count > 0) & (square <= 2 * GREY_RMS**2 * count)


def with_texels(rendered: np.ndarray, texels: np.ndarray, luma: np.ndarray | None = None) -> np.ndarray:
    """What the renderer shows at scale 1 for a model at rest: ``rendered`` plus the texels' residual,
    its luma alone where the (H, W) mask ``luma`` is set (a region in ``DETAIL_LUMA`` mode)."""
    h, w = rendered.shape[:2]
    out = np.empty(np.broadcast_shapes(rendered.shape, texels.shape), np.result_type(rendered, np.float32))

    def band(rows):  # (not texel_rgb: a band must not wait on the pool it runs on)
        a, b = rows
        t = texels[a:b]
        if luma is not None:
            t = t.copy()
            t[luma[a:b], 1:] = DETAIL_ZERO  # Y alone is the same value on every channel
        np.clip(rendered[a:b] + _residual_rgb(t).astype(np.float32), 0.0, 1.0, out=out[a:b])

    for_bands(band, h, w)
    return out
