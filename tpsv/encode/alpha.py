"""Transparency of an RGBA input: its transparent part becomes regions marked transparent.

A pixel whose alpha is below one half belongs to the transparent part; the
label map gets one more label there (overriding a given map's labels), and
the regions of that label are marked ``Region.transparent``. Partial alpha
along the border of the transparent part is its anti-aliasing. The encoder
works from two pictures:

- the geometry (label map, outlines, edge widths) from the picture flattened
  onto a backdrop that contrasts with the opaque pixels along that border
  (:func:`flatten`), so the outline fit puts the border where alpha crosses
  one half and a soft alpha ramp reads as a blurred border;
- the colours (features, fit, detail) from the straight colours, the fully
  transparent pixels filled with the mean colour along the border
  (:func:`straight`), so no backdrop darkens or lightens the edge's colour.

The renderer turns the border's coverage back into alpha
(``tpsv.rendering.raster.opacity``), so a logo anti-aliased on a transparent
background comes back anti-aliased at any scale.
"""

from __future__ import annotations

import numpy as np

from ..errors import TpsvError

#: Alpha below this is the transparent part.
CUT = 0.5
#: Partial alpha is an edge's anti-aliasing only within this many pixels of the cut.
EDGE_PX = 2


def transparent_mask(alpha: np.ndarray | None) -> np.ndarray | None:
    """Pixels of the transparent part, or None when there is none.

    Parameters
    ----------
    alpha : ndarray (H, W) float in [0, 1], optional

    Returns
    -------
    ndarray (H, W) bool or None

    Raises
    ------
    TpsvError
        Every pixel is transparent (there is no picture to vectorise), or
        some are partly transparent away from the edge of the transparent
        part (translucency, which the model does not hold).
    """
    import cv2

    if alpha is None:
        return None
    alpha = np.asarray(alpha)
    mask = alpha < CUT
    kernel = np.ones((2 * EDGE_PX + 1, 2 * EDGE_PX + 1), np.uint8)
    m8 = mask.astype(np.uint8)
    edge = cv2.dilate(m8, kernel).astype(bool) & cv2.dilate(1 - m8, kernel).astype(bool)
    loose = int(((alpha > 0) & (alpha < 1) & ~edge).sum())
    if mask.all() and not loose:
        raise TpsvError("the image is fully transparent: nothing to vectorize")
    if loose:  # (an image translucent all over is this, not fully transparent)
        raise TpsvError(f"the image is partly transparent in {loose} px away from the edges of its transparent "
                        "part; tpsv keeps transparent areas and their anti-aliased edges, not translucency: "
                        "flatten it onto a background first")
    return mask if mask.any() else None


def flatten(rgb: np.ndarray, alpha: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``rgb`` composited over a backdrop that contrasts with the opaque pixels along the transparent part.

    The backdrop is black when those pixels are light on average, else white,
    so the border between the two parts is a strong edge wherever alpha
    crosses :data:`CUT`.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float in [0, 1]
    alpha : ndarray (H, W) float in [0, 1]
    mask : ndarray (H, W) bool
        :func:`transparent_mask`.

    Returns
    -------
    ndarray (H, W, 3) float32
    """
    luma = rgb[_along(mask)] @ np.array([0.299, 0.587, 0.114])
    backdrop = 0.0 if luma.size and luma.mean() > 0.5 else 1.0
    a = np.asarray(alpha, np.float32)[..., None]
    return (a * rgb + (1.0 - a) * backdrop).astype(np.float32)


def straight(rgb: np.ndarray, alpha: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The colours to encode: ``rgb`` where alpha > 0, the mean colour along the transparent part elsewhere.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float in [0, 1]
        Straight (not premultiplied) colours, as PNG and WebP store them.
    alpha : ndarray (H, W) float in [0, 1]
    mask : ndarray (H, W) bool
        :func:`transparent_mask`.

    Returns
    -------
    ndarray (H, W, 3) float32
    """
    out = np.array(rgb, np.float32, copy=True)
    empty = np.asarray(alpha) <= 0
    edge = _along(mask)
    fill = out[edge].mean(axis=0) if edge.any() else np.full(3, 0.5, np.float32)
    out[empty] = fill
    return out


def _along(mask: np.ndarray) -> np.ndarray:
    """Opaque pixels next to the transparent part."""
    import cv2

    return cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask


def with_transparent_label(labels: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, int]:
    """``labels`` with the transparent part given a label of its own; returns ``(labels, that label)``."""
    labels = np.array(labels, np.int64, copy=True)
    keep = labels[~mask]
    label = int(keep.max()) + 1 if keep.size else 0
    labels[mask] = label
    return labels, label


def has_transparency(model) -> bool:
    """Whether any region of ``model`` is transparent."""
    return any(getattr(r, "transparent", False) for r in model.regions)


__all__ = ["CUT", "flatten", "has_transparency", "straight", "transparent_mask", "with_transparent_label"]
