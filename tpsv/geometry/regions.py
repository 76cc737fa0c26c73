"""Regions of a label map, and points between pixel space and patch space.

A label map becomes connected regions, each with its outline (vector
polygons) and its Hermite patch; the region index every pixel gets at scale 1
comes from the outlines, as the renderer draws them. Points move between pixel
space ``(x, y)`` and a region's normalised patch parameters ``(S, T)`` with
:func:`to_patch_space` (the patch inverse) and :func:`to_pixel_space` (the
patch map ``M``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..errors import TpsvError
from ..model import Patch, Region
from . import curves, outline, patch, segment, subpixel


def build_regions(labels: np.ndarray, rgb: np.ndarray | None = None,
                  max_regions: int | None = None) -> tuple[list[Region], np.ndarray]:
    """Regions with outlines and patches from a label map.

    With ``rgb`` the outlines are to be drawn as curves (``Model.curves``,
    :mod:`tpsv.geometry.curves`): they are simplified for that, and the
    index comes from the curves.

    Disconnected labels become several regions (each keeps its label value);
    nothing is merged away, so a single-pixel region stays a region.

    Parameters
    ----------
    labels : ndarray (H, W) int
        Label map.
    rgb : ndarray (H, W, 3) float, optional
        The image: outlines are then fitted to its edges at sub-pixel
        precision (:mod:`tpsv.geometry.subpixel`); without it they follow
        the label map's pixel edges (:func:`tpsv.geometry.outline.trace_outline`).
    max_regions : int, optional
        Refuse a label map of more connected parts than this before any
        outline is made (a file holds at most ``tpsv.codec.MAX_REGIONS``).

    Returns
    -------
    regions : list of Region
    index : ndarray (H, W) int32
        Region index of every pixel as the renderer sees it at scale 1 (from
        the outlines).

    Raises
    ------
    TpsvError
        The label map has no region, or more than ``max_regions``.
    """
    h, w = labels.shape
    comp, slices, present = _components(labels)
    if max_regions is not None and len(present) > max_regions:
        # (a file's limit, found before the minutes the outlines of that many regions take)
        raise TpsvError(f"{len(present)} regions (the label map's connected parts) exceed the {max_regions} "
                        f"a .tpsv holds")
    regions: list[Region] = []
    fitted = [None] * len(present)
    if rgb is not None:
        reading = subpixel.BorderReading(comp, rgb)
        split = subpixel.split_pinched(reading, comp, present, [slices[i] for i in present])
        if split is not None:
            comp, slices, present = _components(split)
            reading = subpixel.BorderReading(comp, rgb)
        # all at once: a border between two regions is simplified once, for both
        fitted = subpixel.fitted_outlines(reading, comp, present, [slices[i] for i in present])
    for i, polys in zip(present, fitted):
        sl = slices[i]
        mask = comp == i
        label = int(np.bincount(labels[sl][mask[sl]].ravel()).argmax())
        if polys is None:
            polys = outline.trace_outline(mask)
        regions.append(Region(label=label, outline=polys, patch=patch.build_patch(mask, polys)))
    if not regions:
        raise TpsvError("label map has no regions")
    drawn = regions if rgb is None else curves.drawn_regions(regions, w, h, curves.DRAWN_TOL)
    index = outline.rasterize_regions(drawn, w, h, src_size=(w, h))
    return regions, index


def _components(labels: np.ndarray):
    """Connected components of a label map (``comp``, ``0 .. n-1``), the bounding box of each
    (``find_objects`` slices, None for an absent value), and the values present."""
    comp = segment.split_connected(labels, min_size=1)
    n = int(comp.max()) + 1
    slices = ndimage.find_objects(comp + 1, max_label=n)
    return comp, slices, [i for i in range(n) if slices[i] is not None]


def _by_region(region: np.ndarray, n: int):
    """``(r, indices)`` of the points of each region ``0..n-1`` that has any."""
    order = np.argsort(region, kind="stable")
    bounds = np.searchsorted(region[order], np.arange(n + 1))
    for r in range(n):
        idx = order[bounds[r] : bounds[r + 1]]
        if idx.size:
            yield r, idx


def to_patch_space(patches: list[Patch], xy: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Normalised ``(S, T)`` of pixel-space points, each in the patch of its region.

    Parameters
    ----------
    patches : list of Patch
        One per region.
    xy : ndarray (n, 2) float
        Pixel-space points.
    region : ndarray (n,) int
        Region index of each point.

    Returns
    -------
    ndarray (n, 2) float64
        ``(S, T)`` clamped to ``[0, 1]``.
    """
    st = np.zeros((xy.shape[0], 2), np.float64)
    for r, idx in _by_region(np.asarray(region), len(patches)):
        raw = patch.inverse(patches[r], xy[idx])
        st[idx] = np.clip(patch.normalize(patches[r], raw), 0.0, 1.0)
    return st


def to_pixel_space(patches: list[Patch], region: np.ndarray, st: np.ndarray) -> np.ndarray:
    """Pixel-space positions ``M(S (M-1), T (N-1))`` of patch points, each in its region's patch.

    Parameters
    ----------
    patches : list of Patch
        One per region.
    region : ndarray (n,) int
        Region index of each point.
    st : ndarray (n, 2) float
        Normalised patch parameters ``(S, T)``.

    Returns
    -------
    ndarray (n, 2) float64
    """
    region = np.asarray(region, np.int64)
    st = np.asarray(st, np.float64).reshape(-1, 2)
    xy = np.zeros((region.size, 2), np.float64)
    for r, idx in _by_region(region, len(patches)):
        s, t = patch.denormalize(patches[r], st[idx]).T
        xy[idx] = patch.forward(patches[r], s, t)
    return xy


def region_borders(index: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour in another region: both sides of every region border.

    Parameters
    ----------
    index : ndarray (H, W) int
        Region index of every pixel.

    Returns
    -------
    ndarray (H, W) bool
    """
    border = np.zeros(index.shape, bool)
    d = index[:, :-1] != index[:, 1:]
    border[:, :-1] |= d
    border[:, 1:] |= d
    d = index[:-1, :] != index[1:, :]
    border[:-1, :] |= d
    border[1:, :] |= d
    return border
