"""Anti-aliased border coverage on a Warp device: the twin of :class:`tpsv.rendering.borders.Borders`.

Render step 5 (:mod:`tpsv.rendering.borders` says what is computed) with one
code path for the ``cpu`` and ``cuda`` devices. :class:`DeviceBorders` is
prepared once per model and output size, on the device from the outline
vertices (:mod:`tpsv.gpu.pieces`: a few launches and one read-back of three
numbers): the outline pieces, cut as ``Borders`` cuts them, sorted into a
uniform grid of square cells, with (for blurred borders) a lower bound of
every pixel's distance to them, and each region's distance beyond which
none of its pixels mixes. :meth:`DeviceBorders.mix_device` then takes a
region map already on the device, in a few small launches and two prefix sums:

1. one thread per :data:`GROUP` pixels of a row: which may mix? (sharp
   borders: the pixels with an 8-neighbour of another region; blurred
   ones: the pixels a piece may lie within their region's limit of);
2. their flat indices, compacted by a prefix sum of the groups' counts;
3. (blurred borders) the regions near each search cell, as 64-bit masks
   (:func:`_row_regions`, :func:`_cell_regions`), and the same gathered
   over the cells a second border's search may read (:func:`_gather_row`,
   :func:`_gather_masks`);
4. one thread per candidate pixel: the nearest border piece (an exact
   search of the grid, row of cells by row of cells;
   ``Borders._nearest_border``), the region across (``Borders._across``),
   the pair's edge width (``Borders._sigma``), the coverage
   (``Borders._coverage``, Phi from ``wp.erf``, float64); then a second
   border (``Borders._second``: the nearest piece with a third region
   beyond, passing over the cells whose masks hold none) and the shares
   (``borders.shares``);
5. the pixels that mix (``alpha < 1 - 1e-4``), compacted by a second prefix sum.

Prefix sums keep the pixels in increasing flat index: the result is the
same on every device and for every split of the CPU launches. The two
counts are read back to size the outputs (on CUDA, two synchronisations).

Where it differs from the host, on purpose:

* the host measures a pixel to the nearest border of the few pieces
  nearest by midpoint (:data:`~tpsv.rendering.borders.NEAREST`;
  :data:`~tpsv.rendering.borders.FAR_NEAREST` for pixels beyond the
  8-neighbours of a blurred border, where that is often not the nearest:
  the distance comes out a little long); here the nearest border piece is
  found exactly. Coverages of such pixels differ by up to a few hundredths
  (mostly under 1e-4), rarely the region across or whether the pixel mixes;
* for blurred borders the host looks at the pixels within ``reach + 1``
  (chamfer distance) of an 8-neighbour pixel; here at every pixel that a
  piece may lie within its region's limit of. A pixel mixes in both only
  when a piece lies that near and the point beyond it is another region,
  so the sets differ only where an outline runs over a pixel away from
  where the region map changes;
* a border that two regions share is in both outlines: the search keeps
  one copy of each piece (the same points, to rounding).

Geometry is float64 (pixel coordinates of large outputs need it for
``1e-4`` px); alpha is float32, as on the host.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..geometry import curves
from ..rendering.borders import (MAX_REJECTED, MAX_VISIT, SECOND_LEAST, BorderMix, Borders, blur_map, edge_widths,
                                 nest_scale, region_limits, widest_sigma)
from . import resolve_device
from . import warp as _warp
from .pieces import DevicePieces, apart
from .rasterise import _launch_banded
from .transfer import upload

wp.set_module_options({"enable_backward": False})

#: Pixels per thread of the first pass (bits of a mask).
GROUP = wp.constant(8)
#: Cell side (pixels) of the bound on the pixels' distance to the pieces (blurred borders).
APART_CELL = 3
#: Most grid cells of one output (bounds the cell table: 4 bytes each).
MAX_CELLS = 1 << 22
#: Search cells per reach, for blurred borders (smaller cells: fewer pieces measured, more rows visited).
CELLS_PER_REACH = 4.0
#: Smallest search cell (pixels) by default.
MIN_CELL = 3

_INV_SQRT_2PI = wp.constant(wp.float64(1.0 / np.sqrt(2.0 * np.pi)))
_INV_SQRT_2 = wp.constant(wp.float64(1.0 / np.sqrt(2.0)))
# (a constant: an expression in a kernel would be float32)
#: Outline pieces per output pixel beyond which the host reference's k-d tree finds the nearest ones
#: faster than the device's exact search (real models: well under 1; a hostile file folding a long
#: outline into a small canvas: thousands).
DENSE_PIECES = 16
_MIXED = wp.constant(wp.float64(1.0 - 1e-4))
# most pieces one search measures, and most near ones it finds no border (borders.MAX_VISIT, MAX_REJECTED)
_MAX_VISIT = wp.constant(MAX_VISIT)
_MAX_REJECTED = wp.constant(MAX_REJECTED)
_SECOND = wp.constant(wp.float64(1.0 - SECOND_LEAST))


@dataclass
class PieceGrid:
    """Outline pieces on the device, sorted by the grid cell of their midpoint, and what the kernels need besides.

    Attributes
    ----------
    a, d : wp.array (n,) vec2d
        Piece starts and vectors, output pixels (the first ``start[-1]``;
        the second copies of shared pieces after them, never read).
    start : wp.array (gw * gh + 1,) int32
        First piece of each cell (row-major cells of ``cell x cell`` pixels).
    apart : wp.array (ah * aw,) float32
        No piece is nearer than this to a pixel centre of the cell (a grid
        of its own: ``acell x acell`` pixels, ``aw`` a row; zeros for sharp borders).
    limit : wp.array (R,) float64
        A pixel of region ``r`` mixes only nearer than ``limit[r]`` to a piece.
    limit2 : wp.array (R,) float64
        The same for a second border (``Borders.limit2``).
    gw, gh, cell : int
        Grid size in cells, cell side in pixels.
    aw, acell : int
        The same for ``apart`` (width in cells, cell side).
    slack : float
        Half the longest piece (of all, second copies too): no point of a piece is nearer than its
        midpoint less this.
    rows : int
        Most rows of cells one search visits each side of the pixel's.
    blurred : int
        1 where ``reach > 1`` (pixels beyond the 8-neighbours mix).
    keys : wp.array (m,) int64
        Blurred region pairs ``a * n_regions + b`` (``a < b``), sorted.
    sigma : wp.array (m,) float64
        Their edge widths, output pixels.
    n_regions : int
    bmap : wp.array2d float64
        The blur map's widths, output px (a 1 x 1 placeholder without one).
    bcw, bch : float
        Its cell width and height, output px.
    has_map : int
        1 where the blur map, not the pairs, gives the widths.
    """

    a: object
    d: object
    start: object
    apart: object
    limit: object
    limit2: object
    gw: int
    gh: int
    cell: int
    aw: int
    acell: int
    slack: float
    rows: int
    blurred: int
    keys: object
    sigma: object
    n_regions: int
    bmap: object = None
    bcw: float = 1.0
    bch: float = 1.0
    has_map: int = 0

    def search(self) -> list:
        """The arguments of :func:`_nearest`, in its order."""
        return [self.a, self.d, self.start, self.gw, self.gh, self.cell, wp.float64(self.slack), self.rows]


# --------------------------------------------------------------------------- per-pixel body


@wp.func
def _gap(v: wp.float64, i: int, cell: int):
    """Distance from ``v`` to the band ``[i cell, (i + 1) cell)`` along one axis."""
    lo = wp.float64(i * cell)
    return wp.max(wp.max(lo - v, v - lo - wp.float64(cell)), wp.float64(0.0))


@wp.func
def _region(index: wp.array2d(dtype=wp.int32), r: int, x: int):
    """Region at local row ``r``, column ``x``; rows and columns beyond the map repeat its edge."""
    return index[wp.clamp(r, 0, index.shape[0] - 1), wp.clamp(x, 0, index.shape[1] - 1)]


@wp.func
def _beyond_point(px: wp.float64, py: wp.float64, fx: wp.float64, fy: wp.float64, dist: wp.float64):
    """A little beyond the foot ``f`` of the perpendicular from ``p`` (the mirror image of ``p`` within 0.75 px)."""
    qx = wp.float64(2.0) * fx - px
    qy = wp.float64(2.0) * fy - py
    if dist > wp.float64(0.75):
        m = wp.max(dist, wp.float64(1e-9))
        qx = fx + wp.float64(0.75) * ((fx - px) / m)
        qy = fy + wp.float64(0.75) * ((fy - py) / m)
    return qx, qy


@wp.func
def _beyond(index: wp.array2d(dtype=wp.int32), iy0: int, px: wp.float64, py: wp.float64, fx: wp.float64,
            fy: wp.float64, dist: wp.float64):
    """Region a little beyond the foot ``f`` (``Borders._beyond``)."""
    qx, qy = _beyond_point(px, py, fx, fy, dist)
    return _region(index, int(wp.floor(qy)) - iy0, int(wp.floor(qx)))


@wp.func
def _piece(p0: wp.vec2d, dv: wp.vec2d, px: wp.float64, py: wp.float64, best2: wp.float64, bmid2: wp.float64,
           fx: wp.float64, fy: wp.float64, vx: wp.float64, vy: wp.float64, index: wp.array2d(dtype=wp.int32),
           iy0: int, mine: int, excl: int, free2: wp.float64):
    """One piece of :func:`_nearest`'s search: the best so far ``(best2, bmid2, fx, fy, vx, vy)``, updated, and
    1 if it was (-1: the piece was nearer but not a border)."""
    wx = px - p0[0]
    wy = py - p0[1]
    # the host's expression (Borders._nearest), in its order
    u = (wx * dv[0] + wy * dv[1]) / wp.max(dv[0] * dv[0] + dv[1] * dv[1], wp.float64(1e-300))
    u = wp.clamp(u, wp.float64(0.0), wp.float64(1.0))
    qx = p0[0] + u * dv[0]
    qy = p0[1] + u * dv[1]
    ox = px - qx
    oy = py - qy
    d2 = ox * ox + oy * oy
    took = int(0)
    if d2 <= best2:
        # on a tie (a pixel centre as near two pieces) the piece whose middle is nearer
        mx = wx - wp.float64(0.5) * dv[0]
        my = wy - wp.float64(0.5) * dv[1]
        m2 = mx * mx + my * my
        take = d2 < best2 or m2 < bmid2
        if take and d2 > free2:
            o = _beyond(index, iy0, px, py, qx, qy, wp.sqrt(d2))
            take = o != mine and o != excl and o >= 0
            if not take:
                took = -1
        if take:
            return d2, m2, qx, qy, dv[0], dv[1], 1
    return best2, bmid2, fx, fy, vx, vy, took


@wp.func
def _run(a: wp.array(dtype=wp.vec2d), d: wp.array(dtype=wp.vec2d), lo: int, end: int, px: wp.float64,
         py: wp.float64, best2: wp.float64, bmid2: wp.float64, fx: wp.float64, fy: wp.float64, vx: wp.float64,
         vy: wp.float64, found: int, visited: int, rejected: int, index: wp.array2d(dtype=wp.int32), iy0: int,
         mine: int, excl: int, free2: wp.float64):
    """The pieces ``lo .. end`` (one run of cells) through :func:`_piece`, within the search's caps: the best
    so far, whether it changed, and the pieces visited and rejected, updated."""
    hi = wp.max(lo, wp.min(end, lo + _MAX_VISIT - visited))
    for n in range(lo, hi):
        if rejected < _MAX_REJECTED:
            best2, bmid2, fx, fy, vx, vy, took = _piece(a[n], d[n], px, py, best2, bmid2, fx, fy, vx, vy, index,
                                                        iy0, mine, excl, free2)
            if took > 0:
                found = 1
            elif took < 0:
                rejected = rejected + 1
    return best2, bmid2, fx, fy, vx, vy, found, visited + hi - lo, rejected


@wp.func
def _nearest(a: wp.array(dtype=wp.vec2d), d: wp.array(dtype=wp.vec2d), start: wp.array(dtype=wp.int32), gw: int,
             gh: int, cell: int, slack: wp.float64, rows: int, x: int, y: int, limit: wp.float64,
             index: wp.array2d(dtype=wp.int32), iy0: int, mine: int, excl: int, free2: wp.float64,
             masks: wp.array2d(dtype=wp.uint64), mrow0: int, two: wp.uint64, use_mask: int):
    """Distance, foot and vector of the piece nearest pixel ``(x, y)``'s centre, if nearer than ``limit`` (else
    ``limit``), and 1 when the search read every piece within ``limit`` and none was (else 0).

    A piece farther than ``sqrt(free2)`` counts only with another region
    than ``mine`` and ``excl`` just beyond it (:func:`_beyond`;
    ``Borders._nearest_border``). With ``use_mask``, cells whose ``masks``
    (row ``row - mrow0``; :func:`_cell_regions`) hold no region but those of
    ``two`` are passed over: no piece in them has a third region beyond.

    Rows of cells outwards from the pixel's, alternately above and below; a
    piece nearer than the best so far has its midpoint within ``best +
    slack`` of the pixel, so each row is read only over the cells in that
    circle (one run of pieces: cells are row-major and pieces sorted by
    cell), and the search stops at the first rows wholly outside it, or
    after ``borders.MAX_VISIT`` pieces or ``MAX_REJECTED`` near ones that
    are no border (outlines folded over a few pixels: a hostile file gets
    an answer, not a hang).
    """
    cy = wp.min(y / cell, gh - 1)
    px = wp.float64(x) + wp.float64(0.5)
    py = wp.float64(y) + wp.float64(0.5)
    best = limit
    best2 = limit * limit  # compared squared: no root per piece
    bmid2 = wp.float64(1e300)
    fx = px
    fy = py
    vx = wp.float64(0.0)
    vy = wp.float64(0.0)
    visited = int(0)
    rejected = int(0)
    seen = int(0)
    for j in range(rows):
        if (wp.min(_gap(py, cy - j, cell), _gap(py, cy + j, cell)) - slack >= best or visited >= _MAX_VISIT
                or rejected >= _MAX_REJECTED):
            break
        for side in range(2):
            row = cy - j
            if side == 1:
                row = cy + j
            gy = _gap(py, row, cell)
            if row >= 0 and row < gh and (side == 0 or j > 0) and gy - slack < best:
                r = best + slack
                half = wp.sqrt(wp.max(r * r - gy * gy, wp.float64(0.0)))
                x0 = wp.clamp(int(wp.floor((px - half) / wp.float64(cell))), 0, gw - 1)
                x1 = wp.clamp(int(wp.floor((px + half) / wp.float64(cell))), 0, gw - 1)
                found = int(0)
                if use_mask == 0:
                    best2, bmid2, fx, fy, vx, vy, found, visited, rejected = _run(
                        a, d, start[row * gw + x0], start[row * gw + x1 + 1], px, py, best2, bmid2, fx, fy, vx, vy,
                        found, visited, rejected, index, iy0, mine, excl, free2)
                else:
                    for cx in range(x0, x1 + 1):
                        m = wp.uint64(0)
                        mr = row - mrow0
                        if mr >= 0 and mr < masks.shape[0]:
                            m = masks[mr, cx]
                        else:
                            m = ~two  # (beyond the masks' rows: every cell is looked at)
                        # no region but mine and excl near the cell: no piece of it counts
                        if (m & two) != m:
                            best2, bmid2, fx, fy, vx, vy, found, visited, rejected = _run(
                                a, d, start[row * gw + cx], start[row * gw + cx + 1], px, py, best2, bmid2, fx, fy,
                                vx, vy, found, visited, rejected, index, iy0, mine, excl, free2)
                if found != 0:
                    best = wp.sqrt(best2)
                    seen = 1
    # (a piece within the limit is either taken or rejected; none was, and no cap cut the search short)
    clear = int(0)
    if seen == 0 and rejected == 0 and visited < _MAX_VISIT:
        clear = 1
    return best, fx, fy, vx, vy, clear


@wp.func
def _across(index: wp.array2d(dtype=wp.int32), iy0: int, x: int, y: int, mine: int, px: wp.float64,
            py: wp.float64, fx: wp.float64, fy: wp.float64, dist: wp.float64, vx: wp.float64, vy: wp.float64):
    """Region just beyond the pixel's nearest outline (piece vector ``(vx, vy)``), else its nearest 8-neighbour
    of another region (-1: none), and a point across (``Borders._across``)."""
    qx, qy = _beyond_point(px, py, fx, fy, dist)
    other = _region(index, int(wp.floor(qy)) - iy0, int(wp.floor(qx)))
    if other != mine and other >= 0:
        return other, qx, qy
    # the point beyond fell in the pixel's own region (an outline corner): the 8-neighbour
    # of another region whose centre is nearest that point, in the host's order on ties
    best = wp.float64(1e300)
    pick = int(-1)
    cx = qx
    cy = qy
    for n in range(8):
        dy = 0
        dx = 0
        if n == 0:
            dy = -1
        elif n == 1:
            dy = 1
        elif n == 2:
            dx = -1
        elif n == 3:
            dx = 1
        elif n == 4:
            dy = -1
            dx = -1
        elif n == 5:
            dy = -1
            dx = 1
        elif n == 6:
            dy = 1
            dx = -1
        else:
            dy = 1
            dx = 1
        r = _region(index, y + dy - iy0, x + dx)
        ex = wp.float64(x + dx) + wp.float64(0.5) - qx
        ey = wp.float64(y + dy) + wp.float64(0.5) - qy
        dd = wp.sqrt(ex * ex + ey * ey)
        if r != mine and r >= 0 and dd < best - wp.float64(1e-9):
            best = dd
            pick = r
            cx = wp.float64(x + dx) + wp.float64(0.5)
            cy = wp.float64(y + dy) + wp.float64(0.5)
    tx = cx
    ty = cy
    if dist <= wp.float64(1e-9):
        # on the outline the neighbour lies along a pixel axis, the border may not: the piece's normal,
        # to the neighbour's side
        m = wp.max(wp.sqrt(vx * vx + vy * vy), wp.float64(1e-300))
        nx = -vy / m
        ny = vx / m
        if (cx - px) * nx + (cy - py) * ny < wp.float64(0.0):
            nx = -nx
            ny = -ny
        tx = px + nx
        ty = py + ny
    return pick, tx, ty


@wp.func
def _sigma(keys: wp.array(dtype=wp.int64), sigma: wp.array(dtype=wp.float64), n_regions: int, a: int, b: int):
    """Edge width (output px) of the border between regions ``a`` and ``b`` (0: sharp)."""
    m = keys.shape[0]
    key = wp.int64(wp.min(a, b)) * wp.int64(n_regions) + wp.int64(wp.max(a, b))
    lo = int(0)
    hi = m
    while lo < hi:
        mid = (lo + hi) / 2
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo < m:
        if keys[lo] == key:
            return sigma[lo]
    return wp.float64(0.0)


@wp.func
def _blur_at(bmap: wp.array2d(dtype=wp.float64), cw: wp.float64, ch: wp.float64, x: wp.float64, y: wp.float64):
    """Bilinear sample of the blur map at output point ``(x, y)`` (``borders.blur_at``)."""
    gh = bmap.shape[0]
    gw = bmap.shape[1]
    u = wp.clamp(x / cw - wp.float64(0.5), wp.float64(0.0), wp.float64(gw - 1))
    v = wp.clamp(y / ch - wp.float64(0.5), wp.float64(0.0), wp.float64(gh - 1))
    i0 = wp.min(int(wp.floor(v)), wp.max(gh - 2, 0))
    j0 = wp.min(int(wp.floor(u)), wp.max(gw - 2, 0))
    i1 = wp.min(i0 + 1, gh - 1)
    j1 = wp.min(j0 + 1, gw - 1)
    fv = v - wp.float64(i0)
    fu = u - wp.float64(j0)
    one = wp.float64(1.0)
    top = bmap[i0, j0] * (one - fu) + bmap[i0, j1] * fu
    bottom = bmap[i1, j0] * (one - fu) + bmap[i1, j1] * fu
    return top * (one - fv) + bottom * fv


@wp.func
def _F(x: wp.float64, s: wp.float64):
    """``x Phi(x / s) + s phi(x / s)``: the integral of the Gaussian-blurred unit step."""
    z = x / s
    phi = wp.exp(wp.float64(-0.5) * z * z) * _INV_SQRT_2PI
    Phi = wp.float64(0.5) * (wp.float64(1.0) + wp.erf(z * _INV_SQRT_2))
    return x * Phi + s * phi


@wp.func
def _coverage(d: wp.float64, sigma: wp.float64):
    """Share of the pixel its own region covers (``Borders._coverage``)."""
    if sigma > wp.float64(1e-3):
        return _F(d + wp.float64(0.5), sigma) - _F(d - wp.float64(0.5), sigma)
    return wp.min(wp.float64(1.0), wp.float64(0.5) + d)


# --------------------------------------------------------------------------- kernels


@wp.func
def _next_to_other(index: wp.array2d(dtype=wp.int32), r: int, x: int, mine: int):
    """Whether pixel ``(x, r)`` has an 8-neighbour of another region (not -1); beyond the map its edge repeats."""
    c = int(0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            nb = _region(index, r + dy, x + dx)
            if nb != mine and nb >= 0:
                c = 1
    return c


@wp.func
def _column(index: wp.array2d(dtype=wp.int32), ra: int, r: int, rb: int, x: int):
    """Least and greatest region of rows ``ra, r, rb`` at column ``x``."""
    u = index[ra, x]
    v = index[r, x]
    w = index[rb, x]
    return wp.min(wp.min(u, v), w), wp.max(wp.max(u, v), w)


@wp.kernel
def _row_regions(index: wp.array2d(dtype=wp.int32), cell: int, edge: int, rows: wp.array2d(dtype=wp.uint64)):
    """Which regions (bit ``r % 64``) each row of the map holds within ``edge`` px of each column of cells."""
    r, j = wp.tid()
    w = index.shape[1] - 1
    m = wp.uint64(0)
    for xx in range(wp.clamp(j * cell - edge, 0, w), wp.clamp((j + 1) * cell + edge - 1, 0, w) + 1):
        v = index[r, xx]
        if v >= 0:
            m = m | (wp.uint64(1) << wp.uint64(v % 64))
    rows[r, j] = m


@wp.kernel
def _cell_regions(rows: wp.array2d(dtype=wp.uint64), iy0: int, cell: int, row0: int, edge: int,
                  masks: wp.array2d(dtype=wp.uint64)):
    """Which regions (bit ``r % 64``) lie within ``edge`` px of each search cell of rows ``row0 ..``.

    The region a little beyond any piece whose midpoint is in the cell is
    one of them (``edge`` covers half the longest piece and 0.75 px); rows
    and columns beyond the map repeat its edge, as :func:`_region` reads it.
    """
    i, j = wp.tid()
    y0 = (row0 + i) * cell - edge
    h = rows.shape[0] - 1
    m = wp.uint64(0)
    for yy in range(wp.clamp(y0 - iy0, 0, h), wp.clamp(y0 + cell + 2 * edge - 1 - iy0, 0, h) + 1):
        m = m | rows[yy, j]
    masks[i, j] = m


@wp.kernel
def _gather_row(masks: wp.array2d(dtype=wp.uint64), k: int, out: wp.array2d(dtype=wp.uint64)):
    """Each cell's union of the masks within ``k`` cells along its row (the first pass of :func:`_gather_masks`)."""
    i, j = wp.tid()
    m = wp.uint64(0)
    for b in range(wp.max(j - k, 0), wp.min(j + k, masks.shape[1] - 1) + 1):
        m = m | masks[i, b]
    out[i, j] = m


@wp.kernel
def _gather_masks(rows: wp.array2d(dtype=wp.uint64), k: int, more_above: int, more_below: int,
                  near: wp.array2d(dtype=wp.uint64)):
    """Each cell's union of the masks of the cells within ``k`` of it (``borders.third_near`` on cells),
    from :func:`_gather_row`'s; every region where those cells reach rows of cells the masks do not cover
    (``more_above``/``below``)."""
    i, j = wp.tid()
    m = wp.uint64(0)
    if (i - k < 0 and more_above != 0) or (i + k > rows.shape[0] - 1 and more_below != 0):
        m = ~m
    else:
        for a in range(wp.max(i - k, 0), wp.min(i + k, rows.shape[0] - 1) + 1):
            m = m | rows[a, j]
    near[i, j] = m


@wp.kernel
def _candidates(apart: wp.array(dtype=wp.float32), limit: wp.array(dtype=wp.float64), aw: int, acell: int,
                blurred: int, index: wp.array2d(dtype=wp.int32), iy0: int, y0: int, mask: wp.array(dtype=wp.int32),
                count: wp.array(dtype=wp.int32)):
    """Which of a group of :data:`GROUP` pixels of row ``y0 + i`` may mix (bit mask) and how many.

    A pixel of a blurred border may mix when a piece may lie within its
    region's limit; one of a sharp border when an 8-neighbour belongs to
    another region: read from the least and greatest region of its 3 x 3
    block (sliding column extremes), the full test only next to pixels of
    no region.
    """
    yy, gi = wp.tid()
    y = y0 + yy
    r = y - iy0
    h = index.shape[0]
    W = index.shape[1]
    x0 = gi * GROUP
    x1 = wp.min(x0 + GROUP, W)
    m = int(0)
    n = int(0)
    if blurred != 0:
        row = (y / acell) * aw
        for x in range(x0, x1):
            mine = index[r, x]
            if mine >= 0:
                if apart[row + x / acell] < wp.float32(limit[mine]):
                    m = m | (1 << (x - x0))
                    n = n + 1
    else:
        ra = wp.max(r - 1, 0)
        rb = wp.min(r + 1, h - 1)
        lo0, hi0 = _column(index, ra, r, rb, wp.max(x0 - 1, 0))
        lo1, hi1 = _column(index, ra, r, rb, x0)
        for x in range(x0, x1):
            lo2, hi2 = _column(index, ra, r, rb, wp.min(x + 1, W - 1))
            mine = index[r, x]
            if mine >= 0:
                lo = wp.min(wp.min(lo0, lo1), lo2)
                hi = wp.max(wp.max(hi0, hi1), hi2)
                c = int(0)
                if hi > mine:
                    c = 1
                elif lo >= 0:
                    if lo < mine:
                        c = 1
                else:
                    c = _next_to_other(index, r, x, mine)
                if c != 0:
                    m = m | (1 << (x - x0))
                    n = n + 1
            lo0 = lo1
            hi0 = hi1
            lo1 = lo2
            hi1 = hi2
    mask[yy * ((W + GROUP - 1) / GROUP) + gi] = m
    count[yy * ((W + GROUP - 1) / GROUP) + gi] = n


@wp.kernel
def _gather(mask: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32), offs: wp.array(dtype=wp.int32),
            g0: int, W: int, out: wp.array(dtype=wp.int32)):
    """Flat index of each pixel a group's mask names, at its place in the prefix sum of the counts."""
    i = wp.tid()
    m = mask[i]
    if m != 0:
        groups = (W + GROUP - 1) / GROUP
        g = g0 + i
        yy = g / groups
        x0 = (g - yy * groups) * GROUP
        k = offs[i] - count[i]
        for b in range(GROUP):
            if (m & (1 << b)) != 0:
                out[k] = yy * W + x0 + b
                k = k + 1


@wp.func
def _shares(c1: wp.float64, c2: wp.float64, dot: wp.float64, nu: wp.float64):
    """``borders.shares``: ``(alpha, alpha2)`` of two borders' coverages, the cosine between them, and how far
    the second is the far side of the region across the first (``nested``)."""
    w = wp.float64(0.5) * (wp.float64(1.0) + dot)
    b1 = wp.float64(1.0) - c1
    b2 = wp.float64(1.0) - c2
    half = wp.float64(0.5) * wp.min(b1, b2)
    s2 = b2 - (wp.float64(1.0) - nu) * w * half
    s1 = wp.max(wp.float64(0.0), b1 - w * (nu * b2 + (wp.float64(1.0) - nu) * half))
    a2 = wp.float64(1.0) - s2
    return wp.float64(1.0) - s1 / wp.max(a2, wp.float64(1e-12)), a2


@wp.kernel
def _measure(a: wp.array(dtype=wp.vec2d), d: wp.array(dtype=wp.vec2d), start: wp.array(dtype=wp.int32), gw: int,
             gh: int, cell: int, slack: wp.float64, rows: int, limit: wp.array(dtype=wp.float64),
             limit2: wp.array(dtype=wp.float64), keys: wp.array(dtype=wp.int64), sigma: wp.array(dtype=wp.float64),
             n_regions: int, bmap: wp.array2d(dtype=wp.float64), bcw: wp.float64, bch: wp.float64, has_map: int,
             index: wp.array2d(dtype=wp.int32), iy0: int, y0: int, cand: wp.array(dtype=wp.int32),
             keep: wp.array(dtype=wp.int32), other: wp.array(dtype=wp.int32), alpha: wp.array(dtype=wp.float32),
             other2: wp.array(dtype=wp.int32), alpha2: wp.array(dtype=wp.float32),
             masks: wp.array2d(dtype=wp.uint64), near: wp.array2d(dtype=wp.uint64), mrow0: int, nest: wp.float64):
    """Each candidate: nearest border piece, region across, coverage, a second border; ``keep`` 1 where it mixes.

    ``masks``: the regions near each search cell (:func:`_cell_regions`), ``near`` the same gathered over
    the cells a second border's search from the cell may read (:func:`_gather_masks`).
    """
    i = wp.tid()
    W = index.shape[1]
    p = cand[i]
    yy = p / W
    x = p - yy * W
    y = y0 + yy
    keep[i] = 0
    mine = index[y - iy0, x]
    lim = limit[mine]
    px = wp.float64(x) + wp.float64(0.5)
    py = wp.float64(y) + wp.float64(0.5)
    # pieces within 0.75 px are borders of a pixel next to another region whatever lies beyond
    free2 = wp.float64(-1.0)
    if _next_to_other(index, y - iy0, x, mine) != 0:
        free2 = wp.float64(0.5625)
    dist, fx, fy, vx, vy, clear = _nearest(a, d, start, gw, gh, cell, slack, rows, x, y, lim, index, iy0, mine, -1,
                                           free2, masks, mrow0, wp.uint64(0), 0)
    if dist >= lim and clear == 0:
        # no border piece: the nearest piece (none when no piece at all lay within the limit: most candidates)
        dist, fx, fy, vx, vy, clear = _nearest(a, d, start, gw, gh, cell, slack, rows, x, y, lim, index, iy0, mine,
                                               -1, wp.float64(1e300), masks, mrow0, wp.uint64(0), 0)
    if dist < lim:
        o, tx, ty = _across(index, iy0, x, y, mine, px, py, fx, fy, dist, vx, vy)
        if o >= 0:
            w = wp.float64(0.0)
            if has_map != 0:
                w = _blur_at(bmap, bcw, bch, fx, fy)
            else:
                w = _sigma(keys, sigma, n_regions, mine, o)
            s = _coverage(dist, w)
            if s < _MIXED:
                keep[i] = 1
                other[i] = o
                # a second border (Borders._second)
                o2 = int(-1)
                a1 = s
                a2 = wp.float64(1.0)
                # (a second border is no nearer than the first: it counts only where the first does)
                lim2 = limit2[mine]
                if s >= _SECOND:
                    lim2 = wp.float64(0.0)
                two = (wp.uint64(1) << wp.uint64(mine % 64)) | (wp.uint64(1) << wp.uint64(o % 64))
                mr = y / cell - mrow0
                if mr >= 0 and mr < near.shape[0]:
                    m = near[mr, x / cell]
                    if (m & two) == m:
                        lim2 = wp.float64(0.0)  # no third region within the reach of any cell's pieces
                dist2, gx, gy, ux, uy, clear = _nearest(a, d, start, gw, gh, cell, slack, rows, x, y, lim2, index, iy0,
                                                        mine, o, wp.float64(-1.0), masks, mrow0, two, 1)
                if dist2 < lim2:
                    r2 = _beyond(index, iy0, px, py, gx, gy, dist2)
                    hx, hy = _beyond_point(px, py, gx, gy, dist2)
                    v1x = tx - px
                    v1y = ty - py
                    v2x = hx - px
                    v2y = hy - py
                    dot = (v1x * v2x + v1y * v2y) / wp.max(wp.sqrt(v1x * v1x + v1y * v1y)
                                                          * wp.sqrt(v2x * v2x + v2y * v2y), wp.float64(1e-300))
                    w2 = wp.float64(0.0)
                    if has_map != 0:
                        w2 = _blur_at(bmap, bcw, bch, gx, gy)
                    else:
                        w2 = wp.max(_sigma(keys, sigma, n_regions, mine, r2), _sigma(keys, sigma, n_regions, o, r2))
                    c2 = _coverage(dist2, w2)
                    if c2 < _SECOND:
                        o2 = r2
                        # (borders.depth)
                        n1 = wp.max(wp.sqrt(v1x * v1x + v1y * v1y), wp.float64(1e-300))
                        nu = wp.clamp(((gx - fx) * v1x + (gy - fy) * v1y) / (n1 * nest), wp.float64(0.0),
                                      wp.float64(1.0))
                        a1, a2 = _shares(s, c2, dot, nu)
                alpha[i] = wp.float32(a1)
                other2[i] = o2
                alpha2[i] = wp.float32(a2)


@wp.kernel
def _compact(cand: wp.array(dtype=wp.int32), keep: wp.array(dtype=wp.int32), offs: wp.array(dtype=wp.int32),
             other: wp.array(dtype=wp.int32), alpha: wp.array(dtype=wp.float32), other2: wp.array(dtype=wp.int32),
             alpha2: wp.array(dtype=wp.float32), W: int, y0: int, kx: wp.float64,
             ky: wp.float64, pixels_out: wp.array(dtype=wp.int32), other_out: wp.array(dtype=wp.int32),
             alpha_out: wp.array(dtype=wp.float32), other2_out: wp.array(dtype=wp.int32),
             alpha2_out: wp.array(dtype=wp.float32), xy_out: wp.array(dtype=wp.vec2d)):
    i = wp.tid()
    if keep[i] != 0:
        j = offs[i] - 1
        p = cand[i]
        yy = p / W
        x = p - yy * W
        pixels_out[j] = p
        other_out[j] = other[i]
        alpha_out[j] = alpha[i]
        other2_out[j] = other2[i]
        alpha2_out[j] = alpha2[i]
        xy_out[j] = wp.vec2d((wp.float64(x) + wp.float64(0.5)) / kx,
                             (wp.float64(y0 + yy) + wp.float64(0.5)) / ky)


# --------------------------------------------------------------------------- host side


@dataclass
class DeviceBorderMix:
    """:class:`~tpsv.rendering.borders.BorderMix` on the device: the border pixels of a band, in increasing order.

    Attributes
    ----------
    pixels : wp.array (n,) int32
        Flat indices ``y * W + x`` into the band.
    other : wp.array (n,) int32
        Region across the border.
    alpha : wp.array (n,) float32
        Share the pixel's own region keeps against the region across.
    xy : wp.array (n,) vec2d
        Pixel centres in the model's pixel space.
    other2 : wp.array (n,) int32
        Region across a second border, or -1.
    alpha2 : wp.array (n,) float32
        Share the pixel keeps against ``other2``.
    """

    pixels: object
    other: object
    alpha: object
    xy: object
    other2: object
    alpha2: object

    @property
    def n(self) -> int:
        return int(self.pixels.shape[0])

    def numpy(self) -> BorderMix:
        """Download: the host :class:`BorderMix`."""
        if self.n == 0:
            return BorderMix.none()
        return BorderMix(pixels=self.pixels.numpy().copy(), other=self.other.numpy().copy(),
                         alpha=self.alpha.numpy().copy(), xy=self.xy.numpy().reshape(-1, 2).astype(np.float64),
                         other2=self.other2.numpy().copy(), alpha2=self.alpha2.numpy().copy())


class DeviceBorders:
    """Every outline of a model as short pieces in a grid of cells on a Warp device, for one output size.

    The device twin of :class:`tpsv.rendering.borders.Borders` (same pieces,
    same :attr:`reach_px` and :attr:`halo`).

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.
    device : str
        Warp device (``cpu``, ``cuda``, ``cuda:N``).
    cell : int, optional
        Side of the search grid's cells, output pixels (default: a quarter
        of the reach, at least :data:`MIN_CELL`; larger where the grid
        would pass :data:`MAX_CELLS`). Results do not depend on it.
    """

    def __init__(self, model, width: int, height: int, device: str = "cpu", cell: int | None = None):
        _warp()
        self.device = resolve_device(device)
        self.width, self.height = int(width), int(height)
        model = curves.as_drawn(model, self.width, self.height)
        self.kx = self.width / float(model.width)
        self.ky = self.height / float(model.height)
        self.nest = nest_scale(self.kx, self.ky)
        nr = max(len(model.regions), 1)
        keys, sigma = edge_widths(model, self.kx, self.ky)
        bmap = blur_map(model, self.kx, self.ky)
        wide = widest_sigma(sigma, bmap)
        #: farthest a mixed pixel lies from its border, output pixels; rows of halo a band needs
        self.reach_px = 0.5 + 3.0 * wide
        self.halo = int(np.ceil(self.reach_px)) + 1
        pieces = DevicePieces(model, self.width, self.height, self.device)
        self._host = None
        self._kept = None
        self.grid = None
        if pieces.n > DENSE_PIECES * self.width * self.height:
            # outlines folded over a few pixels (a hostile or degenerate file): an exact search
            # would visit thousands of pieces per pixel, the host's k-d tree a few (and no second
            # border, whose search covers every piece within its reach)
            self._host = Borders(model, self.width, self.height, second=False)
            self._kept = pieces.n
            return
        if pieces.n == 0:
            self._kept = 0
            return
        # cells of about a quarter of the reach, a few pixels at least (a small table to build), few enough to hold
        if cell is None:
            cell = max(MIN_CELL, self.reach_px / CELLS_PER_REACH)
        cell = max(1, int(round(cell)), int(np.ceil(np.sqrt(self.width * self.height / MAX_CELLS))))
        gw = -(-self.width // cell)
        gh = -(-self.height // cell)
        a, d, start = pieces.grid(cell, gw, gh)
        slack = 0.5 * pieces.longest
        # (sharp borders: only 8-neighbours of another region mix, all of them next to a piece)
        blurred = self.reach_px > 1.0
        if blurred:
            acell, aw, _, apart_d = apart(a, d, start, slack, self.reach_px, self.width, self.height, MAX_CELLS,
                                          APART_CELL, self.device)
        else:
            acell, aw, apart_d = 1, 1, wp.zeros(1, dtype=wp.float32, device=self.device)

        dev = self.device
        lim1, lim2 = region_limits(nr, keys, sigma, bmap, self.reach_px)
        self._reach2 = float(lim2.max(initial=0.0))
        keys_d, sigma_d, limit, limit2, bmap_d = upload(
            dev, (keys, wp.int64), (sigma, wp.float64), (lim1, wp.float64), (lim2, wp.float64),
            (np.zeros((1, 1)) if bmap is None else bmap[0], wp.float64))
        self.grid = PieceGrid(a=a, d=d, start=start, apart=apart_d, limit=limit, limit2=limit2, gw=gw, gh=gh, cell=cell,
                              aw=aw, acell=acell, slack=slack, rows=int(np.ceil((self.reach_px + slack) / cell)) + 2,
                              blurred=int(blurred), keys=keys_d, sigma=sigma_d, n_regions=nr,
                              bmap=bmap_d,
                              bcw=1.0 if bmap is None else float(bmap[1]), bch=1.0 if bmap is None else float(bmap[2]),
                              has_map=int(bmap is not None))
        self.cell = cell
        self.grid_shape = (gh, gw)

    @property
    def n_pieces(self) -> int:
        """Outline pieces searched (one copy of each shared one; all of them where the host searches them)."""
        if self._kept is None:
            self._kept = int(self.grid.start[-1:].numpy()[0])  # (a read-back, on demand only)
        return self._kept

    def pieces(self) -> tuple[np.ndarray, np.ndarray]:
        """The pieces searched, downloaded: starts and vectors ``(n, 2)``, sorted by cell."""
        if self.grid is None:
            return np.zeros((0, 2)), np.zeros((0, 2))
        n = self.n_pieces
        return self.grid.a.numpy()[:n].reshape(-1, 2), self.grid.d.numpy()[:n].reshape(-1, 2)

    def _empty(self) -> DeviceBorderMix:
        dev = self.device
        return DeviceBorderMix(wp.zeros(0, dtype=wp.int32, device=dev), wp.zeros(0, dtype=wp.int32, device=dev),
                               wp.zeros(0, dtype=wp.float32, device=dev), wp.zeros(0, dtype=wp.vec2d, device=dev),
                               wp.zeros(0, dtype=wp.int32, device=dev), wp.zeros(0, dtype=wp.float32, device=dev))

    def _with_halo(self, index_d, halo):
        """``index_d`` with the host rows ``halo = (above, below)`` joined on the device; rows above."""
        up, down = halo
        W = index_d.shape[1]
        parts = [np.zeros((0, W), np.int32) if h is None else np.ascontiguousarray(h, np.int32).reshape(-1, W)
                 for h in (up, down)]
        top, bottom = parts[0].shape[0], parts[1].shape[0]
        if top + bottom == 0:
            return index_d, 0
        h = index_d.shape[0]
        ext = wp.empty((top + h + bottom, W), dtype=wp.int32, device=self.device)
        if top:
            wp.copy(ext, wp.array(parts[0], dtype=wp.int32, device=self.device), 0, 0, top * W)
        wp.copy(ext, index_d, top * W, 0, h * W)
        if bottom:
            wp.copy(ext, wp.array(parts[1], dtype=wp.int32, device=self.device), (top + h) * W, 0, bottom * W)
        return ext, top

    def mix_device(self, index_d, y0: int = 0, band: tuple[int, int] | None = None,
                   halo: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
                   threads: int | None = None) -> DeviceBorderMix:
        """The border pixels of a band of output rows and their coverage, left on the device.

        Parameters
        ----------
        index_d : wp.array2d (h, W) int32
            Region of every pixel of output rows ``y0 .. y0 + h`` (``region_index``
            rows), contiguous, on this object's device: the whole frame, or a
            band with the rows around it that it reaches.
        y0 : int
            Output row of ``index_d``'s first row.
        band : (a, b), optional
            Output rows ``a <= y < b`` whose border pixels are wanted (default:
            every row of ``index_d``). The other rows of ``index_d`` are the
            halo: a band's border pixels are the whole frame's when
            :attr:`halo` rows each side are there (or the frame ends).
        halo : (rows above, rows below), optional
            Host region rows just outside ``index_d`` (``(k, W)`` arrays or
            None), as :meth:`Borders.mix <tpsv.rendering.borders.Borders.mix>`
            takes them; joined to ``index_d`` on the device.
        threads : int, optional
            Host threads on the CPU device.

        Returns
        -------
        DeviceBorderMix
            Pixels in increasing order, flat indices into the band.
        """
        h, W = int(index_d.shape[0]), int(index_d.shape[1])
        a, b = (y0, y0 + h) if band is None else (int(band[0]), int(band[1]))
        if not (y0 <= a <= b <= y0 + h):
            raise ValueError(f"band {a}..{b} is not within rows {y0}..{y0 + h} of the region map")
        if W != self.width:
            raise ValueError(f"region map is {W} px wide, the borders were prepared for {self.width}")
        if self._host is not None:
            return self._host_mix(index_d, y0, a, b, halo)
        g = self.grid
        if g is None or a == b:
            return self._empty()
        index_d, top = self._with_halo(index_d, halo)
        iy0 = y0 - top
        dev = self.device
        groups = -(-W // int(GROUP))
        n = (b - a) * groups
        mask = wp.empty(n, dtype=wp.int32, device=dev)
        count = wp.empty(n, dtype=wp.int32, device=dev)

        def launch_rows(r0, r1):
            wp.launch(_candidates, dim=(r1 - r0, groups), inputs=[g.apart, g.limit, g.aw, g.acell, g.blurred, index_d, iy0,
                                                                 a + r0, mask[r0 * groups:r1 * groups],
                                                                 count[r0 * groups:r1 * groups]], device=dev)

        _launch_banded(_candidates, b - a, (b - a) * W, dev, threads, launch_rows)
        offs = wp.empty(n, dtype=wp.int32, device=dev)
        wp.utils.array_scan(count, offs, inclusive=True)
        nc = int(offs[n - 1:].numpy()[0])
        if nc == 0:
            return self._empty()
        cand = wp.empty(nc, dtype=wp.int32, device=dev)

        def launch_gather(i0, i1):
            wp.launch(_gather, dim=i1 - i0, inputs=[mask[i0:i1], count[i0:i1], offs[i0:i1], i0, W, cand], device=dev)

        _launch_banded(_gather, n, n, dev, threads, launch_gather)
        del mask, count, offs
        # the regions near each search cell of the rows the map covers (a second border's search passes over
        # the cells of none but the pixel's two)
        # (sharp borders: a second border lies within a pixel, its search is short: no masks)
        h_ext = int(index_d.shape[0])
        mrow0 = max(0, iy0 // g.cell)
        mrow1 = min(g.gh - 1, (iy0 + h_ext - 1) // g.cell) if g.blurred else mrow0 - 1
        masks = wp.empty((max(mrow1 - mrow0 + 1, 0), g.gw), dtype=wp.uint64, device=dev)
        if masks.shape[0]:
            edge = int(np.ceil(g.slack + 0.75)) + 1
            rows_m = wp.empty((h_ext, g.gw), dtype=wp.uint64, device=dev)

            def launch_rows_m(r0, r1):
                wp.launch(_row_regions, dim=(r1 - r0, g.gw), inputs=[index_d[r0:r1], g.cell, edge, rows_m[r0:r1]],
                          device=dev)

            _launch_banded(_row_regions, h_ext, h_ext * W, dev, threads, launch_rows_m)
            wp.launch(_cell_regions, dim=masks.shape, inputs=[rows_m, iy0, g.cell, mrow0, edge, masks], device=dev)
            del rows_m
            near = wp.empty_like(masks)
            along = wp.empty_like(masks)
            k = int(np.ceil((self._reach2 + g.slack) / g.cell)) + 1
            wp.launch(_gather_row, dim=masks.shape, inputs=[masks, k, along], device=dev)
            wp.launch(_gather_masks, dim=masks.shape, inputs=[along, k, int(mrow0 > 0), int(mrow1 < g.gh - 1), near],
                      device=dev)
            del along
        else:
            near = masks
        keep = wp.empty(nc, dtype=wp.int32, device=dev)
        other = wp.empty(nc, dtype=wp.int32, device=dev)
        alpha = wp.empty(nc, dtype=wp.float32, device=dev)
        other2 = wp.empty(nc, dtype=wp.int32, device=dev)
        alpha2 = wp.empty(nc, dtype=wp.float32, device=dev)

        def launch_measure(i0, i1):
            wp.launch(_measure, dim=i1 - i0, inputs=[*g.search(), g.limit, g.limit2, g.keys, g.sigma, g.n_regions, g.bmap,
                                                     wp.float64(g.bcw), wp.float64(g.bch), g.has_map, index_d, iy0, a,
                                                     cand[i0:i1], keep[i0:i1], other[i0:i1], alpha[i0:i1],
                                                     other2[i0:i1], alpha2[i0:i1], masks, near, mrow0,
                                                     wp.float64(self.nest)], device=dev)

        _launch_banded(_measure, nc, nc, dev, threads, launch_measure)
        koffs = wp.empty(nc, dtype=wp.int32, device=dev)
        wp.utils.array_scan(keep, koffs, inclusive=True)
        nk = int(koffs[nc - 1:].numpy()[0])
        if nk == 0:
            return self._empty()
        out = DeviceBorderMix(wp.empty(nk, dtype=wp.int32, device=dev), wp.empty(nk, dtype=wp.int32, device=dev),
                              wp.empty(nk, dtype=wp.float32, device=dev), wp.empty(nk, dtype=wp.vec2d, device=dev),
                              wp.empty(nk, dtype=wp.int32, device=dev), wp.empty(nk, dtype=wp.float32, device=dev))

        def launch_compact(i0, i1):
            wp.launch(_compact, dim=i1 - i0, inputs=[cand[i0:i1], keep[i0:i1], koffs[i0:i1], other[i0:i1], alpha[i0:i1],
                                                     other2[i0:i1], alpha2[i0:i1], W, a, wp.float64(self.kx),
                                                     wp.float64(self.ky), out.pixels, out.other, out.alpha,
                                                     out.other2, out.alpha2, out.xy], device=dev)

        _launch_banded(_compact, nc, nc, dev, threads, launch_compact)
        return out

    def _host_mix(self, index_d, y0: int, a: int, b: int, halo) -> DeviceBorderMix:
        """:meth:`mix_device` by the host reference (outlines too dense for the device search)."""
        if a == b:
            return self._empty()
        rows = index_d.numpy()
        up, down = halo
        above = rows[:a - y0] if up is None else np.vstack([np.asarray(up, np.int32).reshape(-1, self.width),
                                                             rows[:a - y0]])
        below = rows[b - y0:] if down is None else np.vstack([rows[b - y0:],
                                                               np.asarray(down, np.int32).reshape(-1, self.width)])
        mix = self._host.mix(rows[a - y0:b - y0], a, (above if len(above) else None, below if len(below) else None))
        if mix.pixels.size == 0:
            return self._empty()

        def up_(v, dtype):
            return wp.array(np.ascontiguousarray(v), dtype=dtype, device=self.device)

        return DeviceBorderMix(up_(mix.pixels, wp.int32), up_(mix.other, wp.int32), up_(mix.alpha, wp.float32),
                               up_(mix.xy, wp.vec2d), up_(mix.other2, wp.int32), up_(mix.alpha2, wp.float32))

    def mix(self, index: np.ndarray, y0: int = 0, halo: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
            threads: int | None = None) -> BorderMix:
        """:meth:`Borders.mix <tpsv.rendering.borders.Borders.mix>` from host rows: upload, :meth:`mix_device`, download.

        Parameters
        ----------
        index : ndarray (h, W) int32
            Region of every pixel of the band.
        y0 : int
            Output row of ``index``'s first row.
        halo : (rows above, rows below)
            As :meth:`Borders.mix <tpsv.rendering.borders.Borders.mix>`.
        threads : int, optional
            Host threads on the CPU device.

        Returns
        -------
        BorderMix
            Pixels in increasing order.
        """
        index = np.ascontiguousarray(index, np.int32)
        if index.size == 0 or (self.grid is None and self._host is None):
            return BorderMix.none()
        index_d = wp.array(index, dtype=wp.int32, device=self.device)
        return self.mix_device(index_d, y0, None, halo, threads).numpy()


def border_mix(model, index, device: str = "cpu", threads: int | None = None) -> BorderMix:
    """The anti-aliased border pixels of a whole frame: ``Borders(model, W, H).mix(index)`` on a Warp device.

    Parameters
    ----------
    model : Model
    index : ndarray or wp.array2d (H, W) int32
        Region of every output pixel (``region_index``); a device array
        stays where it is.
    device : str
    threads : int, optional
        Host threads on the CPU device.

    Returns
    -------
    BorderMix
    """
    H, W = int(index.shape[0]), int(index.shape[1])
    db = DeviceBorders(model, W, H, device)
    if isinstance(index, wp.array):
        return db.mix_device(index, threads=threads).numpy()
    return db.mix(index, threads=threads)


__all__ = ["DeviceBorderMix", "DeviceBorders", "PieceGrid", "border_mix"]
