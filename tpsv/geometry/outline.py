"""Region outlines as polygons, and region membership at any output size.

Tracing
-------
``trace_outline`` runs marching squares (``skimage.measure.find_contours`` at
level 0.5) on the region's mask padded by one pixel. In the pixel space of
``tpsv.model`` (pixel ``(r, c)`` covers ``[c, c+1] x [r, r+1]``) the contour
passes through the midpoints between the centre of each region pixel and the
centre of each 4-neighbour outside the region, i.e. along pixel edges, with a
45-degree cut across every corner. A cut between two straight runs of at
least :data:`SQUARE_RUN` pixel edges is replaced by the pixel corner it cuts
(:func:`_square_corners`: a rectangle of pixels is traced as that
rectangle); the cuts of staircases stay. Every vertex therefore lies on the
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

The fill runs for all regions at once (:class:`Coverage`: every edge is
prepared once, in its region's own frame, so the arithmetic is the
region-by-region fill's), for any band of rows, in memory bounded by the
band and :data:`FILL_CROSSINGS_PER_BAND`. The distance transform needs the
whole image; :class:`GapFill` computes the same labels (the same chamfer
transform, tie for tie) from a sparse record of the uncovered pixels, in
memory that grows with them, not with the image: the device's region map
(``tpsv.gpu.regions``, a whole frame or a band of a large render) hands it
the pixels farther than its search from every outline.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from ..errors import TpsvError

#: RDP tolerance in pixels.
RDP_TOLERANCE = 0.5
#: Pixel edges a straight run needs on both sides of a corner for the corner to be traced square.
SQUARE_RUN = 2



def signed_area(poly: np.ndarray) -> float:
    """Shoelace area of a closed polygon (k, 2) with x right and y down."""
    x = poly[:, 0]
    y = poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


#: Most edge/row crossings held in memory at once by the scanline fill; a band of
#: rows is filled at a time so memory does not scale with vertices x rows.
FILL_CROSSINGS_PER_BAND = 1 << 20


def _fill_polys(shape: tuple[int, int], polys: Sequence[np.ndarray], offset=(0.0, 0.0), scale=(1.0, 1.0)) -> np.ndarray:
    """uint8 mask of ``shape`` (h, w): pixels whose sample point lies inside.

    Output pixel (X, Y) samples source point ``((X + 0.5) / kx + ox,
    (Y + 0.5) / ky + oy)`` where ``(ox, oy) = offset`` and ``(kx, ky) = scale``.
    Exact scanline fill with the even-odd rule over all polygons together
    (so holes are cut), half-open on both axes (a point on an edge shared by
    two polygons belongs to exactly one of them). Rows are filled in bands of
    at most ``FILL_CROSSINGS_PER_BAND`` edge crossings (a band is one row at
    least), so a hostile outline costs time in proportion to its crossings but
    memory only in proportion to its vertices and the mask.
    """
    h, w = shape
    out = np.zeros((h, w), np.uint8)
    if not polys or h == 0 or w == 0:
        return out
    kx, ky = float(scale[0]), float(scale[1])
    ox, oy = float(offset[0]), float(offset[1])
    pts = [(np.asarray(p, np.float64) - (ox, oy)) * (kx, ky) - 0.5 for p in polys]
    xa, ya = np.concatenate(pts).T
    xb, yb = np.concatenate([np.roll(p, -1, axis=0) for p in pts]).T
    keep = ya != yb
    xa, ya, xb, yb = xa[keep], ya[keep], xb[keep], yb[keep]
    r0 = np.clip(np.ceil(np.minimum(ya, yb)), 0, h).astype(np.int64)
    r1 = np.clip(np.ceil(np.maximum(ya, yb)), 0, h).astype(np.int64)
    # crossings per row (difference array), to cut the rows into bounded bands
    per_row = np.bincount(r0, minlength=h + 1)[:h + 1] - np.bincount(r1, minlength=h + 1)[:h + 1]
    per_row = np.cumsum(per_row)[:h]
    cum = np.concatenate([[0], np.cumsum(per_row)])
    if cum[-1] > 4 * h * w + 4 * len(xa) + 4096:
        # more than 4 edges through every pixel on average (beyond a few crossings per
        # edge, which a detailed outline drawn small has): no traced outline looks like
        # this, and filling it would cost far more than rendering the pixels
        raise TpsvError(f"outline too complex: {int(cum[-1])} edge crossings for {w}x{h} pixels")
    b0 = 0
    while b0 < h:
        b1 = int(np.searchsorted(cum, cum[b0] + FILL_CROSSINGS_PER_BAND, side="right")) - 1
        b1 = min(max(b1, b0 + 1), h)
        sel = (r0 < b1) & (r1 > b0)
        if sel.any():
            _fill_band(out, b0, b1, xa[sel], ya[sel], xb[sel], yb[sel], r0[sel], r1[sel])
        b0 = b1
    return out


def _fill_band(out, b0, b1, xa, ya, xb, yb, r0, r1) -> None:
    """Even-odd fill of rows ``b0 <= row < b1`` of ``out`` from the edges crossing them."""
    w = out.shape[1]
    r0 = np.maximum(r0, b0)
    r1 = np.minimum(r1, b1)
    cnt = r1 - r0
    tot = int(cnt.sum())
    if tot == 0:
        return
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
    rl, cl, cr = rl[ok] - b0, cl[ok], cr[ok]
    diff = np.zeros((b1 - b0, w + 1), np.int32)
    np.add.at(diff, (rl, cl), 1)
    np.add.at(diff, (rl, cr), -1)
    out[b0:b1] = (np.cumsum(diff, axis=1, dtype=np.int32)[:, :w] > 0).view(np.uint8)


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
        out.append(_square_corners(xy))
    return out, (r0, r1, c0, c1)


def _square_corners(xy: np.ndarray) -> np.ndarray:
    """A marching-squares contour with each 45-degree cut between two straight runs of at least
    :data:`SQUARE_RUN` pixel edges replaced by the pixel corner it cuts.

    Left cut, such a corner lets the simplification join two cuts by a
    slanted side (a rectangle of pixels became a square turned by half a
    pixel: slanted borders when magnified). Every pixel centre stays on the
    same side (the corner is 0.71 px from the nearest centres, the cut 0.35).
    Cuts of a staircase, between runs of one edge, are kept.
    """
    n = len(xy)
    if n < 4:
        return xy
    step = np.roll(xy, -1, axis=0) - xy  # step i: vertex i -> i + 1
    unit_x = (np.abs(step[:, 0]) == 1.0) & (step[:, 1] == 0.0)
    unit_y = (step[:, 0] == 0.0) & (np.abs(step[:, 1]) == 1.0)
    cut = (np.abs(step[:, 0]) == 0.5) & (np.abs(step[:, 1]) == 0.5)

    def run(axis_steps, first):
        """Steps ``first .. first + SQUARE_RUN - 1`` (cyclic) all the same unit step along one axis."""
        idx = (first[:, None] + np.arange(SQUARE_RUN)) % n
        same = (step[idx] == step[idx[:, :1]]).all(axis=(1, 2))
        return axis_steps[idx].all(axis=1) & same

    i = np.flatnonzero(cut)
    before = i - SQUARE_RUN
    after = i + 1
    into_y, into_x = run(unit_y, before), run(unit_x, before)
    from_x, from_y = run(unit_x, after), run(unit_y, after)
    square = (into_y & from_x) | (into_x & from_y)
    if not square.any():
        return xy
    i = i[square]
    corner = np.where((into_y[square])[:, None],
                      np.stack([xy[i, 0], xy[(i + 1) % n, 1]], axis=1),   # vertical run in, horizontal out
                      np.stack([xy[(i + 1) % n, 0], xy[i, 1]], axis=1))   # horizontal run in, vertical out
    out = xy.copy()
    out[i] = corner
    keep = np.ones(n, bool)
    keep[(i + 1) % n] = False
    return out[keep]


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


# --------------------------------------------------------------------------- coverage, band by band


#: Most expanded pixels of overlapping spans resolved at once by :class:`Coverage`.
_OVERLAP_PIXELS = 1 << 22


class Coverage:
    """The first region whose polygons cover each output pixel, for any band of rows.

    The same fill as :func:`_fill_polys` applied region by region (each region
    in its own sub-rectangle, with its own offset, so that the arithmetic and
    therefore every pixel is the same), but for all regions at once: every
    edge of every region is prepared once, then :meth:`rows` fills any band
    of output rows from the edges crossing it. Cost grows with edge crossings
    and pixels, not with a Python loop per region; memory with the vertices
    and the band.

    Parameters
    ----------
    regions : list of Region (or of outlines: lists of polygons)
        In drawing order: where polygons of several regions cover a pixel, the
        first one keeps it.
    width, height : int
        Output size.
    src_size : (W, H)
        Size of the pixel space the outlines live in (see :func:`rasterize_regions`).

    Raises
    ------
    TpsvError
        Empty output, non-finite vertices, or an outline with more than 4 edge
        crossings per pixel of its box on average.
    """

    def __init__(self, regions, width: int, height: int, src_size: tuple[int, int]):
        W, H = src_size
        width = int(width)
        height = int(height)
        if width <= 0 or height <= 0:
            raise TpsvError(f"output size {width}x{height} is empty")
        self.width, self.height = width, height
        self.n_regions = len(regions)
        kx = width / float(W)
        ky = height / float(H)
        polys, preg, first = [], [], []
        for r, reg in enumerate(regions):
            outl = reg.outline if hasattr(reg, "outline") else reg
            for i, p in enumerate(outl):
                polys.append(np.asarray(p, np.float64).reshape(-1, 2))
                preg.append(r)
                first.append(i == 0)
        self._empty = True
        if not polys:
            return
        lens = np.array([p.shape[0] for p in polys], np.int64)
        preg = np.asarray(preg, np.int64)
        first = np.asarray(first, bool) & (lens > 0)
        V = np.concatenate(polys)
        if not np.isfinite(V).all():
            raise TpsvError("an outline has a vertex that is not a finite number")
        ends = np.cumsum(lens)
        starts = ends - lens
        # each region's box, from its outer polygon, exactly as the per-region fill computes it
        R = self.n_regions
        has = np.zeros(R, bool)
        has[preg[first]] = True
        x0 = np.zeros(R, np.int64)
        x1 = np.zeros(R, np.int64)
        y0 = np.zeros(R, np.int64)
        y1 = np.zeros(R, np.int64)
        if has.any():
            # per-polygon extremes (reduceat over the starts of the non-empty polygons), kept for outer ones
            ne = np.flatnonzero(lens > 0)
            fo = np.flatnonzero(first)
            pick = np.searchsorted(ne, fo)
            mnx = np.minimum.reduceat(V[:, 0], starts[ne])[pick]
            mxx = np.maximum.reduceat(V[:, 0], starts[ne])[pick]
            mny = np.minimum.reduceat(V[:, 1], starts[ne])[pick]
            mxy = np.maximum.reduceat(V[:, 1], starts[ne])[pick]
            ro = preg[fo]

            def whole(v, n):  # whole pixels, clipped first so that no finite value overflows int64
                return np.clip(v, -4.0, n + 4.0).astype(np.int64)

            x0[ro] = np.maximum(whole(np.floor(mnx * kx - 0.5), width) - 1, 0)
            x1[ro] = np.minimum(whole(np.ceil(mxx * kx - 0.5), width) + 2, width)
            y0[ro] = np.maximum(whole(np.floor(mny * ky - 0.5), height) - 1, 0)
            y1[ro] = np.minimum(whole(np.ceil(mxy * ky - 0.5), height) + 2, height)
        ok = has & (x1 > x0) & (y1 > y0)
        # every edge of every polygon of a drawn region, in its region's local frame
        vreg = np.repeat(preg, lens)
        nxt = np.arange(V.shape[0]) + 1
        nxt[ends[lens > 0] - 1] = starts[lens > 0]
        keepv = ok[vreg]
        ox = x0.astype(np.float64) / kx
        oy = y0.astype(np.float64) / ky
        lx = (V[:, 0] - ox[vreg]) * kx - 0.5
        ly = (V[:, 1] - oy[vreg]) * ky - 0.5
        xa, ya = lx[keepv], ly[keepv]
        xb, yb = lx[nxt][keepv], ly[nxt][keepv]
        er = vreg[keepv]
        keep = ya != yb
        xa, ya, xb, yb, er = xa[keep], ya[keep], xb[keep], yb[keep], er[keep]
        h = (y1 - y0)[er]
        r0 = np.clip(np.ceil(np.minimum(ya, yb)), 0, h).astype(np.int64)
        r1 = np.clip(np.ceil(np.maximum(ya, yb)), 0, h).astype(np.int64)
        cross = np.bincount(er, weights=(r1 - r0).astype(np.float64), minlength=R)
        area = (y1 - y0) * (x1 - x0)
        bad = np.flatnonzero(ok & (cross > 4 * area + 4096))
        if bad.size:
            r = int(bad[0])
            # more than 4 edges through every pixel on average: no traced outline looks
            # like this, and filling it would cost far more than rendering the pixels
            raise TpsvError(f"outline too complex: {int(cross[r])} edge crossings for {int(x1[r] - x0[r])}x{int(y1[r] - y0[r])} pixels")
        live = r1 > r0
        self._xa, self._ya, self._xb, self._yb = xa[live], ya[live], xb[live], yb[live]
        self._reg = er[live]
        self._g0 = (r0 + y0[er])[live]  # first and one past the last output row each edge crosses
        self._g1 = (r1 + y0[er])[live]
        self._x0, self._y0, self._w = x0, y0, x1 - x0
        self._empty = self._reg.size == 0

    @property
    def empty(self) -> bool:
        """No polygon covers any output pixel."""
        return self._empty

    def rows(self, a: int, b: int) -> np.ndarray:
        """Rows ``a <= y < b`` of the region index, ``-1`` where no polygon covers the pixel.

        Returns
        -------
        ndarray (b - a, width) int32
            Index into ``regions`` (drawing order).
        """
        a, b = int(a), int(b)
        out = np.full((b - a, self.width), -1, np.int32)
        if self._empty or b <= a:
            return out
        sel = np.flatnonzero((self._g0 < b) & (self._g1 > a))
        if not sel.size:
            return out
        n = b - a
        c0 = np.maximum(self._g0[sel], a) - a
        c1 = np.minimum(self._g1[sel], b) - a
        per_row = np.cumsum(np.bincount(c0, minlength=n + 1)[: n + 1] - np.bincount(c1, minlength=n + 1)[: n + 1])[:n]
        cum = np.concatenate([[0], np.cumsum(per_row)])
        q0 = 0
        while q0 < n:
            q1 = int(np.searchsorted(cum, cum[q0] + FILL_CROSSINGS_PER_BAND, side="right")) - 1
            q1 = min(max(q1, q0 + 1), n)
            part = sel[(c0 < q1) & (c1 > q0)]
            if part.size:
                self._paint(out[q0:q1], a + q0, a + q1, part)
            q0 = q1
        return out

    def _paint(self, out: np.ndarray, a: int, b: int, e: np.ndarray) -> None:
        """Fill rows ``a..b`` (``out``) from the edges ``e`` crossing them."""
        w = self.width
        g0 = np.maximum(self._g0[e], a)
        cnt = np.minimum(self._g1[e], b) - g0
        tot = int(cnt.sum())
        ee = np.repeat(e, cnt)
        start = np.cumsum(cnt) - cnt
        rows = np.repeat(g0 - start, cnt) + np.arange(tot)  # output row of each crossing
        reg = self._reg[ee]
        local = rows - self._y0[reg]
        xa, ya = self._xa[ee], self._ya[ee]
        xs = xa + (local - ya) * (self._xb[ee] - xa) / (self._yb[ee] - ya)
        del ee, local, xa, ya
        order = np.lexsort((xs, rows, reg))
        rows, xs, reg = rows[order], xs[order], reg[order]
        del order
        # consecutive crossings of one region's row pair up (even-odd); such a row holds an even count
        rl, xl, xr, rg = rows[0::2] - a, xs[0::2], xs[1::2], reg[0::2]
        del rows, xs, reg
        wr = self._w[rg]
        cl = np.clip(np.ceil(xl), 0, wr).astype(np.int64)
        cr = np.clip(np.ceil(xr), 0, wr).astype(np.int64)
        ok = cr > cl
        x0 = self._x0[rg[ok]]
        rl, cl, cr, rg = rl[ok], cl[ok] + x0, cr[ok] + x0, rg[ok].astype(np.int32)
        if not rl.size:
            return
        # spans in raster order; chains of overlapping spans in a row are resolved pixel by pixel
        order = np.lexsort((cl, rl))
        rl, cl, cr, rg = rl[order], cl[order], cr[order], rg[order]
        kl = rl * (w + 2) + cl
        kr = rl * (w + 2) + cr
        reach = np.maximum.accumulate(kr)
        new = np.ones(kl.size, bool)
        new[1:] = kl[1:] >= reach[:-1]
        gid = np.cumsum(new) - 1
        single = np.bincount(gid)[gid] == 1
        starts = np.flatnonzero(new)
        # the union of each chain is one interval: paint chains as runs, -1 between them
        gl = kl[starts] - rl[starts] * 2
        gr = np.maximum.reduceat(kr, starts) - rl[starts] * 2
        val = np.where(single[starts], rg[starts], np.int32(-2))
        edges = np.empty(2 * gl.size + 1, np.int64)
        edges[0] = 0
        edges[1::2] = gl
        edges[2::2] = gr
        lengths = np.diff(np.append(edges, out.size))
        vals = np.empty(2 * gl.size + 1, np.int32)
        vals[0::2] = -1
        vals[1::2] = val
        flat = out.reshape(-1)
        flat[:] = np.repeat(vals, lengths)
        multi = np.flatnonzero(~single)
        if multi.size:
            flat[flat == -2] = np.iinfo(np.int32).max
            lens = (cr - cl)[multi]
            cum = np.cumsum(lens)
            i = 0
            while i < multi.size:
                j = int(np.searchsorted(cum, (cum[i] - lens[i]) + _OVERLAP_PIXELS, side="right"))
                j = min(max(j, i + 1), multi.size)
                m = multi[i:j]
                ln = lens[i:j]
                pix = np.repeat(rl[m] * w + cl[m] - (np.cumsum(ln) - ln), ln) + np.arange(int(ln.sum()))
                np.minimum.at(flat, pix, np.repeat(rg[m], ln))
                i = j


# --------------------------------------------------------------------------- uncovered pixels


# The 5x5 chamfer distance transform (Borgefors) that OpenCV's
# ``distanceTransformWithLabels(DIST_L2, DIST_MASK_PRECISE)`` runs when labels
# are asked for: integer weights in 1/65536 px, a forward pass in raster order
# and a backward pass in reverse raster order, each taking the first strictly
# smaller candidate in this order (row offset, column offset, weight).
_HV, _DIAG, _LONG = 65536, 91750, 143976
_FORWARD = ((-2, -1, _LONG), (-2, 1, _LONG), (-1, -2, _LONG), (-1, -1, _DIAG), (-1, 0, _HV), (-1, 1, _DIAG), (-1, 2, _LONG))
_BACKWARD = ((2, 1, _LONG), (2, -1, _LONG), (1, 2, _LONG), (1, 1, _DIAG), (1, 0, _HV), (1, -1, _DIAG), (1, -2, _LONG))
_FAR = 2**31 - 1
#: Bytes :class:`GapFill` keeps per uncovered pixel and per covered pixel beside one
#: (while preparing it also holds about 16 bytes per pixel of one band of rows).
GAP_BYTES, RING_BYTES = 28, 8


class GapFill:
    """The region of every uncovered pixel, as :func:`rasterize_regions` fills it, for any band of rows.

    :func:`rasterize_regions` gives each pixel that no polygon covers the
    region of its nearest covered pixel by OpenCV's labelled distance
    transform, which needs the whole image. This computes the same
    transform (same integer weights, same scan order, same tie-breaking:
    the labels are identical) from a sparse record: the uncovered pixels,
    and the covered pixels within two pixels of one, found in one pass over
    the coverage in bands. Memory grows with the number of uncovered pixels
    (a thin fraction of the output: the gaps between neighbouring outlines),
    not with the output size.

    Parameters
    ----------
    coverage : Coverage
        (or any object with ``width``, ``height``, ``n_regions`` and ``rows(a, b)``).
    band_rows : int
        Rows read from ``coverage`` at a time.
    max_bytes : int, optional
        Refuse (:class:`TpsvError`) when the record would exceed this.
    """

    def __init__(self, coverage, band_rows: int, max_bytes: int | None = None):
        H, W = int(coverage.height), int(coverage.width)
        self.width, self.height = W, H
        self._n_regions = int(coverage.n_regions)
        band_rows = max(int(band_rows), 1)
        self._cols: list = [None] * H  # per row: uncovered columns (int32), forward distance, forward label
        self._t: list = [None] * H
        self._lab: list = [None] * H
        self._ring: list = [None] * H  # per row: (columns, labels) of covered pixels right of / below a gap
        n_gap = n_ring = 0
        if getattr(coverage, "empty", False):  # nothing covered: no record needed
            self.n_gap, self._all = W * H, True
            return
        # padded rows (2 border columns each side): forward distance and label (int32: a distance
        # never exceeds _FAR); the two rows above the band come from the previous band (above the image: far)
        tprev = np.full((2, W + 4), _FAR, np.int32)
        lprev = np.full((2, W + 4), -1, np.int32)
        gaps_prev = [False, False]
        for a in range(0, H, band_rows):
            b = min(a + band_rows, H)
            block = coverage.rows(a, b)
            n = b - a
            tb = np.zeros((n + 2, W + 4), np.int32)
            tb[:2] = tprev
            tb[2:, :2] = tb[2:, -2:] = _FAR
            lb = np.full((n + 2, W + 4), -1, np.int32)
            lb[:2] = lprev
            lb[2:, 2:-2] = block
            gap = np.zeros(n + 2, bool)
            gap[:2] = gaps_prev
            gap[2:] = (block < 0).any(axis=1)
            busy = gap.copy()
            busy[1:] |= gap[:-1]
            busy[2:] |= gap[:-2]
            for i in np.flatnonzero(busy[2:]) + 2:
                y = a + i - 2
                row = block[i - 2]
                js = np.flatnonzero(row < 0) if gap[i] else np.zeros(0, np.int64)
                if js.size:
                    t, lab = self._forward(js, row, tb[i - 2:i], lb[i - 2:i])
                    tb[i, js + 2] = t
                    lb[i, js + 2] = lab
                    self._cols[y], self._t[y], self._lab[y] = js.astype(np.int32), t, lab
                    n_gap += js.size
                # covered pixels of this row that a backward step from a gap pixel reads
                need = np.zeros(W + 4, bool)
                for dy, offs in ((2, (-1, 1)), (1, (-2, -1, 0, 1, 2)), (0, (1,))):
                    m = self._cols[y - dy] if y - dy >= 0 else None
                    if m is not None:
                        for o in offs:
                            need[m + (2 + o)] = True
                need = need[2:-2] & (row >= 0)
                rc = np.flatnonzero(need)
                if rc.size:
                    self._ring[y] = (rc.astype(np.int32), row[rc].astype(np.int32))
                    n_ring += rc.size
                if max_bytes is not None and n_gap * GAP_BYTES + n_ring * RING_BYTES > max_bytes:
                    raise TpsvError(
                        f"at {W}x{H} px the model leaves more pixels outside every region than tpsv can fill "
                        f"in bounded memory ({n_gap:,} px by row {y}); render it at a smaller size")
            tprev, lprev, gaps_prev = tb[-2:].copy(), lb[-2:].copy(), list(gap[-2:])
            del tb, lb, block
        self.n_gap = n_gap
        self._all = n_gap == W * H
        self._pos = np.zeros(0, np.int64)
        self._fin = np.zeros(0, np.int32)
        if n_gap and not self._all:
            self._backward()

    @staticmethod
    def _chain(js: np.ndarray, a: np.ndarray, la: np.ndarray, run_start: np.ndarray):
        """``t[i] = min(a[i], t[i-1] + HV)`` along runs of consecutive columns, ``a`` winning ties."""
        n = js.size
        run = np.cumsum(run_start) - 1
        bb = a - js.astype(np.int64) * _HV - run.astype(np.int64) * (1 << 42)
        m = np.minimum.accumulate(bb)
        win = np.maximum.accumulate(np.where(bb == m, np.arange(n), -1))
        return a[win] + (js - js[win]).astype(np.int64) * _HV, la[win]

    def _candidates(self, first_t, first_l, js, steps, rows_t, rows_l):
        """The first strictly smallest of ``first`` and the neighbours ``steps`` in two padded rows."""
        offs, wts = steps
        n = js.size
        idx = offs[:, None] + (js + 2)[None, :]
        ts = np.empty((offs.size + 1, n), np.int64)
        ts[0] = first_t
        ts[1:] = rows_t.reshape(-1)[idx] + wts[:, None]
        k = np.argmin(ts, axis=0)
        cols = np.arange(n)
        lab = np.where(k == 0, first_l, rows_l.reshape(-1)[idx[np.maximum(k - 1, 0), cols]])
        return ts[k, cols], lab.astype(np.int32)

    def _steps(self, table, row_of):
        """Flat offsets into two padded rows, and weights, of the neighbour steps ``table``."""
        offs = np.array([row_of[dr] * (self.width + 4) + dc for dr, dc, _ in table], np.int64)
        return offs, np.array([w for _, _, w in table], np.int64)

    def _forward(self, js, row, tprev, lprev):
        a, la = self._candidates(_FAR, -1, js, self._steps(_FORWARD, {-2: 0, -1: 1}), tprev, lprev)
        start = np.ones(js.size, bool)
        start[1:] = js[1:] != js[:-1] + 1
        # the pixel left of a run is covered (distance 0) or the border
        s = np.flatnonzero(start & (js > 0))
        left = np.full(js.size, _FAR, np.int64)
        left[s] = _HV
        better = left < a
        a = np.where(better, left, a)
        la = np.where(better, np.where(js > 0, row[np.maximum(js - 1, 0)], -1), la).astype(np.int32)
        return self._chain(js, a, la, start)

    def _dense(self, y):
        """Padded distance and label rows of row ``y`` after the backward pass (border rows: far)."""
        W = self.width
        t = np.full(W + 4, _FAR, np.int64)
        lab = np.full(W + 4, -1, np.int32)
        if y >= self.height:
            return t, lab
        t[2:-2] = 0
        if self._ring[y] is not None:
            rc, rl = self._ring[y]
            lab[rc + 2] = rl
        if self._cols[y] is not None:
            t[self._cols[y] + 2] = self._t[y]
            lab[self._cols[y] + 2] = self._lab[y]
        return t, lab

    def _backward(self):
        W, H = self.width, self.height
        steps = self._steps(_BACKWARD, {1: 0, 2: 1})
        dense: dict = {}  # padded rows y+1, y+2 after the backward pass
        pos, fin = [], []
        ring = np.full(W + 1, -1, np.int32)
        for y in [y for y in range(H - 1, -1, -1) if self._cols[y] is not None]:
            below = [dense[r] if r in dense else self._dense(r) for r in (y + 1, y + 2)]
            js = self._cols[y].astype(np.int64)
            a, la = self._candidates(self._t[y], self._lab[y], js, steps,
                                     np.stack([below[0][0], below[1][0]]), np.stack([below[0][1], below[1][1]]))
            # right to left: mirror the columns, then the chain runs as in the forward pass
            jr = (W - 1 - js)[::-1]
            a, la = a[::-1], la[::-1]
            start = np.ones(jr.size, bool)
            start[1:] = jr[1:] != jr[:-1] + 1
            # the pixel right of a run is covered (distance 0) or the border
            right = np.full(jr.size, _FAR, np.int64)
            right[start & (jr > 0)] = _HV
            better = right < a
            if self._ring[y] is not None:
                ring[self._ring[y][0]] = self._ring[y][1]
            a = np.where(better, right, a)
            la = np.where(better, ring[np.minimum(W - jr, W)], la).astype(np.int32)
            if self._ring[y] is not None:
                ring[self._ring[y][0]] = -1
            t, lab = self._chain(jr, a, la, start)
            self._t[y], self._lab[y] = t[::-1].copy(), lab[::-1].copy()
            pos.append(y * W + js)
            fin.append(self._lab[y])
            dense = {y: self._dense(y), y + 1: below[0]}
            for r in (y + 2, y + 3):  # no longer read
                if r < H:
                    self._cols[r] = self._t[r] = self._lab[r] = self._ring[r] = None
        self._pos = np.concatenate(pos[::-1]) if pos else np.zeros(0, np.int64)
        self._fin = np.concatenate(fin[::-1]) if fin else np.zeros(0, np.int32)
        self._cols = self._t = self._lab = self._ring = None

    def apply(self, index: np.ndarray, a: int) -> np.ndarray:
        """Fill the uncovered pixels (``-1``) of rows ``a..`` of the region index in place.

        Parameters
        ----------
        index : ndarray (rows, width) int32
            ``Coverage.rows(a, a + rows)``.
        a : int
            Its first row.

        Returns
        -------
        ndarray
            ``index``.
        """
        if self._all:
            index[:] = 0 if self._n_regions else -1
            return index
        W = self.width
        lo = int(np.searchsorted(self._pos, a * W))
        hi = int(np.searchsorted(self._pos, (a + index.shape[0]) * W))
        index.reshape(-1)[self._pos[lo:hi] - a * W] = self._fin[lo:hi]
        return index


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
    cov = Coverage(regions, width, height, src_size)
    out = cov.rows(0, cov.height)
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
