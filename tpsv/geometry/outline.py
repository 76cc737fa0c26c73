"""Region outlines as polygons, and region membership at any output size.

Tracing
-------
``trace_outline`` runs marching squares (``skimage.measure.find_contours`` at
level 0.5) on the region's mask padded by one pixel. In the pixel space of
``tpsv.model`` (pixel ``(r, c)`` covers ``[c, c+1] x [r, r+1]``) the contour
passes through the midpoints between the centre of each region pixel and the
centre of each 4-neighbour outside the region, i.e. along pixel edges, with a
45-degree cut across every corner. Every vertex therefore lies on the
half-integer lattice (coordinates are multiples of 0.5), which codecs can
exploit. The contour is then simplified by Ramer-Douglas-Peucker
(``cv2.approxPolyDP``, tolerance :data:`RDP_TOLERANCE` px); the result is
checked by rasterising it back at scale 1, and retried with a smaller
tolerance (down to none) when it loses pixels (thin parts) or degenerates.

Connectivity: a region is a 4-connected set of pixels (``segment`` produces
those); the background, and therefore holes, are 8-connected. Two region
pixels that touch only diagonally are not joined by the outline (the contour
cuts between them).

Orientation: with ``x`` to the right and ``y`` down, the outer polygon has a
positive shoelace area ``sum(x_i y_{i+1} - x_{i+1} y_i) / 2 > 0`` (it appears
clockwise on screen; it is counter-clockwise in the mathematical sense of the
(x, y) coordinates taken as is); holes have a negative area.

A single-pixel region becomes the diamond through the midpoints of its four
edges; a one-pixel-wide line becomes a thin hexagon of width 1. Both contain
their pixel centres.

Rasterising
-----------
``rasterize_regions`` fills every region's polygons (outer minus holes) at the
output size by an exact scanline fill: an output pixel belongs to a polygon
when its sample point lies inside (even-odd rule, half-open edges), with
vertices in full floating-point precision (``cv2.fillPoly`` rounds vertices to
whole pixels and fills boundaries inclusively, which loses half a pixel at
scale 1). Regions are filled first to last; a pixel already claimed keeps its
region. Pixels
that no polygon covers (thin gaps where independently simplified outlines of
neighbours do not meet, the cut corners at junctions of three or more regions
and at image corners) take the region of the nearest covered pixel (Euclidean
distance transform). So every output pixel gets exactly one region.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from ..errors import TpsvError

#: RDP tolerance in pixels.
RDP_TOLERANCE = 0.5



def signed_area(poly: np.ndarray) -> float:
    """Shoelace area of a closed polygon (k, 2) with x right and y down."""
    x = poly[:, 0]
    y = poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _fill_polys(shape: tuple[int, int], polys: Sequence[np.ndarray], offset=(0.0, 0.0), scale=(1.0, 1.0)) -> np.ndarray:
    """uint8 mask of ``shape`` (h, w): pixels whose sample point lies inside.

    Output pixel (X, Y) samples source point ``((X + 0.5) / kx + ox,
    (Y + 0.5) / ky + oy)`` where ``(ox, oy) = offset`` and ``(kx, ky) = scale``.
    Exact scanline fill with the even-odd rule over all polygons together
    (so holes are cut), half-open on both axes (a point on an edge shared by
    two polygons belongs to exactly one of them).
    """
    h, w = shape
    if not polys or h == 0 or w == 0:
        return np.zeros((h, w), np.uint8)
    kx, ky = float(scale[0]), float(scale[1])
    ox, oy = float(offset[0]), float(offset[1])
    xa_l, ya_l, xb_l, yb_l = [], [], [], []
    for p in polys:
        p = np.asarray(p, np.float64)
        x = (p[:, 0] - ox) * kx - 0.5
        y = (p[:, 1] - oy) * ky - 0.5
        xa_l.append(x)
        ya_l.append(y)
        xb_l.append(np.roll(x, -1))
        yb_l.append(np.roll(y, -1))
    xa = np.concatenate(xa_l)
    ya = np.concatenate(ya_l)
    xb = np.concatenate(xb_l)
    yb = np.concatenate(yb_l)
    keep = ya != yb
    xa, ya, xb, yb = xa[keep], ya[keep], xb[keep], yb[keep]
    lo = np.minimum(ya, yb)
    hi = np.maximum(ya, yb)
    r0 = np.clip(np.ceil(lo), 0, h).astype(np.int64)
    r1 = np.clip(np.ceil(hi), 0, h).astype(np.int64)
    cnt = r1 - r0
    tot = int(cnt.sum())
    if tot == 0:
        return np.zeros((h, w), np.uint8)
    e = np.repeat(np.arange(cnt.size), cnt)
    start = np.cumsum(cnt) - cnt
    rows = r0[e] + (np.arange(tot) - start[e])
    xs = xa[e] + (rows - ya[e]) * (xb[e] - xa[e]) / (yb[e] - ya[e])
    order = np.lexsort((xs, rows))
    rows = rows[order]
    xs = xs[order]
    # consecutive crossings of a row pair up (even-odd); rows always hold an even count
    rl, xl, xr = rows[0::2], xs[0::2], xs[1::2]
    cl = np.clip(np.ceil(xl), 0, w).astype(np.int64)
    cr = np.clip(np.ceil(xr), 0, w).astype(np.int64)
    ok = cr > cl
    rl, cl, cr = rl[ok], cl[ok], cr[ok]
    diff = np.zeros((h, w + 1), np.int32)
    np.add.at(diff, (rl, cl), 1)
    np.add.at(diff, (rl, cr), -1)
    cov = np.cumsum(diff, axis=1, dtype=np.int32)[:, :w]
    out = (cov > 0).view(np.uint8)
    return out


def _raw_contours(mask: np.ndarray):
    """Marching-squares contours of a bool mask (pixel coordinates, unclosed)."""
    from skimage.measure import find_contours

    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    sub = np.pad(mask[r0:r1, c0:c1], 1).astype(np.float64)
    out = []
    for con in find_contours(sub, 0.5, fully_connected="low"):
        if np.allclose(con[0], con[-1]):
            con = con[:-1]
        if len(con) < 3:
            continue
        # padded index (i, j) is pixel (r0 + i - 1, c0 + j - 1), centre +0.5
        xy = np.stack([con[:, 1] + (c0 - 0.5), con[:, 0] + (r0 - 0.5)], axis=1)
        xy = np.round(xy * 2.0) / 2.0  # exact half-integer lattice
        out.append(xy)
    return out, (r0, r1, c0, c1)


def _simplify(poly: np.ndarray, eps: float) -> np.ndarray:
    if eps <= 0:
        return poly
    s = cv2.approxPolyDP(poly.astype(np.float32).reshape(-1, 1, 2), eps, True).reshape(-1, 2)
    return s.astype(np.float64)


def trace_outline(mask: np.ndarray, tolerance: float = RDP_TOLERANCE) -> list[np.ndarray]:
    """Vector outline of one connected region.

    Parameters
    ----------
    mask : ndarray, shape (H, W), bool
        The region's pixels (one 4-connected component; if there are several,
        only the largest outline and the holes inside it are kept).
    tolerance : float
        RDP tolerance in pixels (reduced automatically where it would lose
        pixels).

    Returns
    -------
    list of ndarray, each (k, 2) float64
        Closed polygons (last vertex not repeated), vertices on the
        half-integer lattice. The first is the outer boundary (positive
        shoelace area, x right, y down), the others holes (negative area).

    Raises
    ------
    TpsvError
        Empty mask.
    """
    mask = np.asarray(mask, bool)
    if mask.ndim != 2 or not mask.any():
        raise TpsvError("cannot trace the outline of an empty region")
    raw, (r0, r1, c0, c1) = _raw_contours(mask)
    areas = [signed_area(p) for p in raw]
    io = int(np.argmax(np.abs(areas)))
    outer_sign = np.sign(areas[io])
    outer = raw[io]
    holes = []
    ocv = outer.astype(np.float32).reshape(-1, 1, 2)
    for p, a in zip(raw, areas):
        if p is outer or np.sign(a) == outer_sign:
            continue
        if cv2.pointPolygonTest(ocv, (float(p[0, 0]), float(p[0, 1])), False) >= 0:
            holes.append(p)
    if outer_sign < 0:
        outer = outer[::-1]
    holes = [h if signed_area(h) < 0 else h[::-1] for h in holes]

    sub = mask[r0:r1, c0:c1]
    n = int(sub.sum())
    best = None
    for eps in (tolerance, tolerance * 0.5, 0.0):
        polys = []
        ok = True
        for i, p in enumerate([outer] + holes):
            s = _simplify(p, eps)
            a = signed_area(s)
            if len(s) < 3 or (a <= 0 if i == 0 else a >= 0) or abs(a) < 0.25 * abs(signed_area(p)):
                ok = False
                break
            polys.append(s)
        if not ok:
            continue
        got = _fill_polys(sub.shape, polys, offset=(c0, r0)).astype(bool)
        lost = int(np.count_nonzero(sub & ~got))
        extra = int(np.count_nonzero(got & ~sub))
        if eps == 0.0 or (lost <= 0.01 * n and extra <= 0.03 * n + 2 and (lost == 0 or n > 50)):
            best = polys
            break
    if best is None:  # eps == 0 always succeeds for a valid contour; keep raw as a last resort
        best = [outer] + holes
    return [np.ascontiguousarray(p, np.float64) for p in best]


def rasterize_regions(regions, width: int, height: int, src_size: tuple[int, int]) -> np.ndarray:
    """Region index of every output pixel, from the vector outlines.

    Parameters
    ----------
    regions : list of Region (or of outlines: lists of polygons)
    width, height : int
        Output size.
    src_size : (W, H)
        Size of the pixel space the outlines live in. Output pixel ``(X, Y)``
        samples source point ``((X + 0.5) * W / width, (Y + 0.5) * H / height)``.

    Returns
    -------
    index : ndarray, shape (height, width), int32
        Index into ``regions`` for every pixel (all >= 0 when ``regions`` is
        not empty).
    """
    W, H = src_size
    width = int(width)
    height = int(height)
    if width <= 0 or height <= 0:
        raise TpsvError(f"output size {width}x{height} is empty")
    kx = width / float(W)
    ky = height / float(H)
    out = np.full((height, width), -1, np.int32)
    for idx, reg in enumerate(regions):
        polys = reg.outline if hasattr(reg, "outline") else reg
        if not len(polys):
            continue
        outer = polys[0]
        x0 = max(int(np.floor(outer[:, 0].min() * kx - 0.5)) - 1, 0)
        x1 = min(int(np.ceil(outer[:, 0].max() * kx - 0.5)) + 2, width)
        y0 = max(int(np.floor(outer[:, 1].min() * ky - 0.5)) - 1, 0)
        y1 = min(int(np.ceil(outer[:, 1].max() * ky - 0.5)) + 2, height)
        if x1 <= x0 or y1 <= y0:
            continue
        sub = _fill_polys((y1 - y0, x1 - x0), list(polys), offset=(x0 / kx, y0 / ky), scale=(kx, ky))
        view = out[y0:y1, x0:x1]
        sel = (sub != 0) & (view < 0)
        view[sel] = idx
    missing = out < 0
    if missing.any() and not missing.all():
        _, lab = cv2.distanceTransformWithLabels(
            missing.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE, labelType=cv2.DIST_LABEL_PIXEL
        )
        # labels number the zero (covered) pixels 1.. in raster order
        covered = out[~missing]
        out[missing] = covered[lab[missing] - 1]
    elif missing.all():
        out[:] = 0 if len(regions) else -1
    return out
