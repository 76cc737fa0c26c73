"""Outline pieces and their search grid, built on a Warp device: the preparation of render step 5.

:class:`tpsv.gpu.coverage.DeviceBorders` measures pixels to the outlines cut
into short pieces (:func:`tpsv.rendering.borders.outline_pieces`), one copy
of each piece two regions share, sorted by the grid cell of their midpoint.
Here that is built with one code path for the ``cpu`` and ``cuda`` devices:
only the outline vertices are uploaded, and a new output size costs kernel
launches and one read-back of three numbers (the piece count, the edges
left to the host, the longest piece).

1. :class:`DevicePieces`: one thread per outline edge (:func:`_edge_counts`)
   drops the edges along the image's frame and counts the edge's pieces at
   the output scale; a prefix sum places them; one thread per edge
   (:func:`_cut`) writes its pieces, by the host's expressions in its order
   (FMA contraction is off: CUDA rounds as numpy does), so the pieces are
   the host's to the bit and in its order;
2. :meth:`DevicePieces.grid`: the second copy of a shared piece (the same
   endpoints, rounded to 1e-7 px, run backwards) found by sorting the pieces
   by a hash of those endpoints (:func:`_shared`: the earlier piece of equal
   endpoints stays, as :func:`one_of_each` keeps it), then all of them
   sorted by cell, the dropped ones after the last cell; the sorts are
   stable, so the pieces of a cell keep the host's order and the result is
   the same on every device; cell starts from a count per cell and a prefix sum;
3. :func:`apart`: for blurred borders, a lower bound of every pixel's
   distance to the pieces per cell of ``acell`` pixels: the exact Euclidean
   distance transform of the cells holding a midpoint (as :func:`apart_host`
   has it from OpenCV) as far as the bound can matter (the reach), in
   Meijster's two passes: one thread per midpoint writes the distances
   along its column, one thread per row takes the lower envelope of the
   columns' parabolas (reading only the runs of cells near a midpoint).

The host decides an edge's piece count itself where the device's length
(``sqrt``) could round to the other side of an integer than numpy's
``hypot`` (a length within 1e-12 of a whole number of pixels that is not
exact, or one that overflows), and where the outlines would need more than
:data:`~tpsv.rendering.borders.MAX_PIECES` pieces (longer pieces, the step
from numpy's sum): then it counts every edge's pieces with numpy and
uploads the counts (rare: of the bundled samples' default files at scales
1, 3.7 and 8 and at 1920x1080 and 3840x2160, only rocket at scale 1, for 2
of its 3356 edges).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..rendering.borders import MAX_PIECES, piece_counts
from .transfer import upload

# fuse_fp off: the pieces must round as numpy's (no FMA), or a piece could move by an ulp on CUDA
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

#: A length within this (relative) of a whole number of pixels is counted by the host (see the module doc).
NEAR_WHOLE = 1e-12
_NEAR_WHOLE = wp.constant(wp.float64(NEAR_WHOLE))
_SPLIT = wp.constant(wp.float64(134217729.0))  # 2^27 + 1: Dekker's split of a float64
_ROUND = wp.constant(wp.float64(1e7))
_BIG = wp.constant(wp.float64(9.0e18))  # within int64
_MULT = wp.constant(wp.uint64(0x9E3779B97F4A7C15))
#: Cells of a row flagged together as holding a column nearer than the bound needs (:func:`apart`).
RUN = wp.constant(32)
#: Cells along its column every midpoint's distance reaches at least (:func:`apart`: more where the outlines are sparse).
FAR = 32
#: Largest ``far`` (cells) of :func:`apart` found on a GPU by a window a thread a cell (:func:`_window`) rather
#: than Meijster's pass a thread a row: at most ``2 * WINDOW - 1`` reads a cell.
WINDOW = 32


# --------------------------------------------------------------------------- pieces


@wp.func
def _square_error(a: wp.float64):
    """``a * a - fl(a * a)``, exactly (Dekker: no FMA here)."""
    c = _SPLIT * a
    hi = c - (c - a)
    lo = a - hi
    p = a * a
    return ((hi * hi - p) + wp.float64(2.0) * hi * lo) + lo * lo


@wp.func
def _exact_length(dx: wp.float64, dy: wp.float64, s: wp.float64):
    """Whether ``s * s == dx * dx + dy * dy`` exactly (then every correct ``hypot`` gives ``s``)."""
    if _square_error(dx) != wp.float64(0.0) or _square_error(dy) != wp.float64(0.0):
        return False
    if _square_error(s) != wp.float64(0.0):
        return False
    xx = dx * dx
    yy = dy * dy
    t = xx + yy
    # t exact: Knuth's two-sum error is zero
    bv = t - xx
    err = (xx - (t - bv)) + (yy - bv)
    return err == wp.float64(0.0) and t == s * s


@wp.kernel
def _edge_counts(points: wp.array(dtype=wp.vec2d), nxt: wp.array(dtype=wp.int32), mw: wp.float64, mh: wp.float64,
                 kx: wp.float64, ky: wp.float64, counts: wp.array(dtype=wp.int64), info: wp.array(dtype=wp.float64)):
    """Pieces of edge ``i`` (0: along the frame, or of no finite length); ``info[1]`` += edges left to the host,
    ``info[2]``: longest piece."""
    i = wp.tid()
    p = points[i]
    q = points[nxt[i]]
    counts[i] = wp.int64(0)
    # a run along the frame (the host's test: both ends on the same frame line)
    if p[0] == q[0] and (p[0] == wp.float64(0.0) or p[0] == mw):
        return
    if p[1] == q[1] and (p[1] == wp.float64(0.0) or p[1] == mh):
        return
    dx = q[0] * kx - p[0] * kx
    dy = q[1] * ky - p[1] * ky
    s = wp.sqrt(dx * dx + dy * dy)
    if not wp.isfinite(s):
        if wp.isfinite(dx) and wp.isfinite(dy):
            wp.atomic_add(info, 1, wp.float64(1.0))  # dx^2 overflowed where hypot would not
        return
    whole = wp.rint(s)
    if dx != wp.float64(0.0) and dy != wp.float64(0.0) and whole >= wp.float64(1.0):
        if wp.abs(s - whole) <= _NEAR_WHOLE * s and not _exact_length(dx, dy, s):
            wp.atomic_add(info, 1, wp.float64(1.0))
    # (step PIECE_PX = 1; more than MAX_PIECES in all goes to the host, so the cap changes nothing)
    n = wp.max(wp.float64(1.0), wp.ceil(wp.min(s, wp.float64(4.0e9))))
    counts[i] = wp.int64(n)
    ex = dx / n
    ey = dy / n
    wp.atomic_max(info, 2, wp.sqrt(ex * ex + ey * ey))


@wp.kernel
def _total(offs: wp.array(dtype=wp.int64), info: wp.array(dtype=wp.float64)):
    info[0] = wp.float64(offs[offs.shape[0] - 1])


@wp.kernel
def _cut(points: wp.array(dtype=wp.vec2d), nxt: wp.array(dtype=wp.int32), kx: wp.float64, ky: wp.float64,
         counts: wp.array(dtype=wp.int64), offs: wp.array(dtype=wp.int64), a: wp.array(dtype=wp.vec2d),
         d: wp.array(dtype=wp.vec2d)):
    """The pieces of edge ``i`` at their place in the prefix sum, by ``outline_pieces``'s expressions."""
    i = wp.tid()
    n = counts[i]
    if n > wp.int64(0):
        first = offs[i] - n
        p = points[i]
        q = points[nxt[i]]
        ax = p[0] * kx
        ay = p[1] * ky
        dx = q[0] * kx - ax
        dy = q[1] * ky - ay
        fn = wp.float64(n)
        v = wp.vec2d(dx / fn, dy / fn)
        for k in range(int(n)):
            t0 = wp.float64(k) / fn
            a[int(first) + k] = wp.vec2d(ax + t0 * dx, ay + t0 * dy)
            d[int(first) + k] = v


@wp.func
def _cell_of(v: wp.float64, cell: wp.float64, n: int):
    """``clip(floor(v / cell), 0, n - 1)``, as the host bins (clipped before the cast: no overflow).

    A midpoint off the grid goes to the nearest cell: no nearer to any pixel than it really is.
    """
    return int(wp.clamp(wp.floor(v / cell), wp.float64(0.0), wp.float64(n - 1)))


@wp.kernel
def _keys(a: wp.array(dtype=wp.vec2d), d: wp.array(dtype=wp.vec2d), cell: wp.float64, gw: int, gh: int, bits: int,
          cellkey: wp.array(dtype=wp.int32), hashkey: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)):
    """Each piece's cell (of its midpoint) and a hash of its endpoints in a fixed order (``bits`` bits)."""
    j = wp.tid()
    p = a[j]
    v = d[j]
    mx = p[0] + wp.float64(0.5) * v[0]
    my = p[1] + wp.float64(0.5) * v[1]
    cellkey[j] = _cell_of(my, cell, gh) * gw + _cell_of(mx, cell, gw)
    k0, k1, k2, k3 = _ends(p, v)
    h = wp.uint64(0x2545F4914F6CDD1D)
    h = (h ^ wp.uint64(k0)) * _MULT
    h = (h ^ (h >> wp.uint64(29)) ^ wp.uint64(k1)) * _MULT
    h = (h ^ (h >> wp.uint64(29)) ^ wp.uint64(k2)) * _MULT
    h = (h ^ (h >> wp.uint64(29)) ^ wp.uint64(k3)) * _MULT
    hashkey[j] = wp.int32(h >> wp.uint64(64 - bits))
    order[j] = j


@wp.func
def _fixed(v: wp.float64):
    """``round(v * 1e7)`` as int64 (half to even, as numpy)."""
    return wp.int64(wp.clamp(wp.rint(v * _ROUND), -_BIG, _BIG))


@wp.func
def _ends(p: wp.vec2d, v: wp.vec2d):
    """The piece's endpoints, the lesser (x, then y) first, in units of 1e-7 px (:func:`one_of_each`'s key)."""
    bx = p[0] + v[0]
    by = p[1] + v[1]
    if p[0] < bx or (p[0] == bx and p[1] <= by):
        return _fixed(p[0]), _fixed(p[1]), _fixed(bx), _fixed(by)
    return _fixed(bx), _fixed(by), _fixed(p[0]), _fixed(p[1])


@wp.kernel
def _shared(hashkey: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32), a: wp.array(dtype=wp.vec2d),
            d: wp.array(dtype=wp.vec2d), dropped: int, cellkey: wp.array(dtype=wp.int32),
            order2: wp.array(dtype=wp.int32)):
    """Sorted by hash (stably): a piece with the endpoints of one before it in its run of equal hashes goes."""
    i = wp.tid()
    order2[i] = i
    j = order[i]
    h = hashkey[i]
    k0, k1, k2, k3 = _ends(a[j], d[j])
    m = i - 1
    while m >= 0:
        if hashkey[m] != h:
            break
        o = order[m]
        l0, l1, l2, l3 = _ends(a[o], d[o])
        if l0 == k0 and l1 == k1 and l2 == k2 and l3 == k3:
            cellkey[j] = dropped
            break
        m = m - 1


@wp.kernel
def _place(cellkey: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32), a: wp.array(dtype=wp.vec2d),
           d: wp.array(dtype=wp.vec2d), dropped: int, a_out: wp.array(dtype=wp.vec2d),
           d_out: wp.array(dtype=wp.vec2d), count: wp.array(dtype=wp.int32)):
    """Pieces in cell order; the pieces of each cell counted."""
    i = wp.tid()
    j = order[i]
    a_out[i] = a[j]
    d_out[i] = d[j]
    c = cellkey[i]
    if c < dropped:
        wp.atomic_add(count, c, 1)


class DevicePieces:
    """Every outline of a model cut into pieces of at most ``PIECE_PX`` output pixels, on a Warp device.

    The device twin of :func:`~tpsv.rendering.borders.outline_pieces`: the
    same pieces, to the bit, in the same order.

    Parameters
    ----------
    model : Model
        As drawn at this size (:func:`tpsv.geometry.curves.as_drawn`).
    width, height : int
        Output size.
    device : str
        Warp device.

    Attributes
    ----------
    n : int
        Pieces (0: nothing to cut).
    a, d : wp.array (n,) vec2d or None
        Piece starts and vectors, output pixels.
    longest : float
        Length of the longest piece, output pixels.
    host_counted : bool
        Whether the host counted the pieces of each edge (module doc).
    """

    def __init__(self, model, width: int, height: int, device: str):
        self.device = device
        self.n, self.a, self.d, self.longest, self.host_counted = 0, None, None, 0.0, False
        polys = [np.asarray(p, np.float64).reshape(-1, 2) for reg in model.regions for p in reg.outline if len(p) >= 2]
        if not polys:
            return
        points = np.concatenate(polys)
        E = len(points)
        # each vertex's successor along its polygon (the last one's: the polygon's first)
        sizes = np.array([len(p) for p in polys])
        nxt = np.arange(1, E + 1, dtype=np.int32)
        ends = np.cumsum(sizes)
        nxt[ends - 1] = (ends - sizes).astype(np.int32)
        kx, ky = width / float(model.width), height / float(model.height)
        dev = device
        points_d, nxt_d = upload(dev, (points, wp.vec2d), (nxt, wp.int32))
        counts = wp.empty(E, dtype=wp.int64, device=dev)
        info = wp.zeros(3, dtype=wp.float64, device=dev)
        wp.launch(_edge_counts, dim=E, inputs=[points_d, nxt_d, wp.float64(model.width), wp.float64(model.height),
                                              wp.float64(kx), wp.float64(ky), counts, info], device=dev)
        offs = wp.empty(E, dtype=wp.int64, device=dev)
        wp.utils.array_scan(counts, offs, inclusive=True)
        wp.launch(_total, dim=1, inputs=[offs, info], device=dev)
        total, doubtful, longest = info.numpy()  # the one read-back
        if doubtful > 0 or total > MAX_PIECES:
            self.host_counted = True
            c, longest = _host_counts(points, nxt, model.width, model.height, kx, ky)
            counts = wp.array(c, dtype=wp.int64, device=dev)
            offs = wp.array(np.cumsum(c), dtype=wp.int64, device=dev)
            total = int(c.sum())
        self.n, self.longest = int(total), float(longest)
        if self.n == 0:
            return
        self.a = wp.empty(self.n, dtype=wp.vec2d, device=dev)
        self.d = wp.empty(self.n, dtype=wp.vec2d, device=dev)
        wp.launch(_cut, dim=E, inputs=[points_d, nxt_d, wp.float64(kx), wp.float64(ky), counts, offs, self.a,
                                            self.d], device=dev)

    def grid(self, cell: int, gw: int, gh: int):
        """The pieces less the second copy of each shared one, sorted by the cell of their midpoint.

        Parameters
        ----------
        cell : int
            Cell side, output pixels.
        gw, gh : int
            Grid size in cells.

        Returns
        -------
        a, d : wp.array (n,) vec2d
            Pieces, sorted by cell and, within a cell, in the host's order;
            the ``n - start[-1]`` dropped copies come after the last cell.
        start : wp.array (gw * gh + 1,) int32
            First piece of each cell; ``start[-1]``: pieces kept.
        """
        dev, n, cells = self.device, self.n, gw * gh
        cellkey = wp.empty(2 * n, dtype=wp.int32, device=dev)
        hashkey = wp.empty(2 * n, dtype=wp.int32, device=dev)
        order = wp.empty(2 * n, dtype=wp.int32, device=dev)
        order2 = wp.empty(2 * n, dtype=wp.int32, device=dev)
        # a few times more hash values than pieces: short runs of equal hashes, few bits to sort
        bits = min(31, max(8, n.bit_length() + 2))
        wp.launch(_keys, dim=n, inputs=[self.a, self.d, wp.float64(cell), gw, gh, bits, cellkey, hashkey, order],
                  device=dev)
        wp.utils.radix_sort_pairs(hashkey, order, n, end_bit=bits)
        wp.launch(_shared, dim=n, inputs=[hashkey, order, self.a, self.d, cells, cellkey, order2], device=dev)
        del hashkey, order
        wp.utils.radix_sort_pairs(cellkey, order2, n, end_bit=max(1, int(cells).bit_length()))
        a = wp.empty(n, dtype=wp.vec2d, device=dev)
        d = wp.empty(n, dtype=wp.vec2d, device=dev)
        count = wp.zeros(cells + 1, dtype=wp.int32, device=dev)
        wp.launch(_place, dim=n, inputs=[cellkey, order2, self.a, self.d, cells, a, d, count], device=dev)
        start = wp.empty(cells + 1, dtype=wp.int32, device=dev)
        wp.utils.array_scan(count, start, inclusive=False)
        return a, d, start


def _host_counts(points: np.ndarray, nxt: np.ndarray, mw: float, mh: float, kx: float, ky: float):
    """Pieces of every edge and the longest piece, by ``outline_pieces``'s numpy (its step, its ``hypot``)."""
    a, b, k = points, points[nxt], np.array([kx, ky])
    counts = piece_counts(a, b, mw, mh, k)
    keep = counts > 0
    if not keep.any():
        return counts, 0.0
    d = (b * k - a * k)[keep] / counts[keep][:, None]
    return counts, float(np.hypot(*d.T).max())


# --------------------------------------------------------------------------- distance bound (blurred borders)


@wp.kernel
def _columns(a: wp.array(dtype=wp.vec2d), d: wp.array(dtype=wp.vec2d), start: wp.array(dtype=wp.int32),
             acell: wp.float64, aw: int, ah: int, far: int, g: wp.array(dtype=wp.int32),
             near: wp.array(dtype=wp.int32)):
    """Meijster's first pass, from the cells that hold a midpoint: each cell's distance to the nearest of its column.

    Only the ``far - 1`` cells each side (``g`` starts at ``far``): the
    midpoints are few beside the cells. ``near`` flags the runs of
    :data:`RUN` cells of a row that have any. (The grids are flat arrays,
    rows of ``aw`` cells: the CPU indexes them faster.)
    """
    i = wp.tid()
    if i < start[start.shape[0] - 1]:
        p = a[i]
        v = d[i]
        x = _cell_of(p[0] + wp.float64(0.5) * v[0], acell, aw)
        y = _cell_of(p[1] + wp.float64(0.5) * v[1], acell, ah)
        runs = (aw + RUN - 1) / RUN
        for k in range(wp.max(0, y - far + 1), wp.min(ah, y + far)):
            wp.atomic_min(g, k * aw + x, wp.abs(k - y))
            near[k * runs + x / RUN] = 1


@wp.func
def _parabola(x: int, i: int, gi: int):
    return wp.int64(x - i) * wp.int64(x - i) + wp.int64(gi) * wp.int64(gi)


@wp.func
def _push(g: wp.array(dtype=wp.int32), s: wp.array(dtype=wp.int32), t: wp.array(dtype=wp.int32), r: int, y: int,
          ah: int, aw: int, q: int, u: int, gu: int):
    """Column ``u``'s parabola onto row ``y``'s lower envelope (``s``: columns, ``t``: where each begins); the new top."""
    while q >= 0:
        tq = t[q * ah + y]
        sq = s[q * ah + y]
        if _parabola(tq, sq, g[r + sq]) <= _parabola(tq, u, gu):
            break
        q = q - 1
    if q < 0:
        s[y] = u
        t[y] = 0
        return 0
    # the first column where u's parabola is below the top one's (floor division)
    i = s[q * ah + y]
    gi = g[r + i]
    num = wp.int64(u) * wp.int64(u) - wp.int64(i) * wp.int64(i) + wp.int64(gu) * wp.int64(gu) \
        - wp.int64(gi) * wp.int64(gi)
    den = wp.int64(2 * (u - i))
    sep = num / den
    if sep * den > num:
        sep = sep - wp.int64(1)
    if sep + wp.int64(1) < wp.int64(aw):
        s[(q + 1) * ah + y] = u
        t[(q + 1) * ah + y] = int(sep) + 1
        return q + 1
    return q


@wp.kernel
def _rows(g: wp.array(dtype=wp.int32), near: wp.array(dtype=wp.int32), aw: int, far: int, s: wp.array(dtype=wp.int32),
          t: wp.array(dtype=wp.int32), acell: wp.float64, less: wp.float64, apart: wp.array(dtype=wp.float32)):
    """Meijster's second pass over a row: the lower envelope of the parabolas of the columns nearer than ``far``.

    The columns as far as ``far`` are left out (and the runs of cells with
    none read no further): a cell's distance comes out exact below ``far``
    cells and ``far`` where it is more (still a lower bound). The envelopes
    are stored column-major (entry ``q`` of row ``y`` at ``q * ah + y``): the
    short envelopes of most rows share a few pages, and the threads of a
    warp read adjacent words.
    """
    y = wp.tid()
    ah = apart.shape[0] / aw
    r = y * aw
    runs = (aw + RUN - 1) / RUN
    q = int(-1)
    for c in range(runs):
        if near[y * runs + c] != 0:
            for u in range(c * RUN, wp.min(c * RUN + RUN, aw)):
                gu = g[r + u]
                if gu < far:
                    q = _push(g, s, t, r, y, ah, aw, q, u, gu)
    # cells of no parabola nearer than ``far`` keep the value ``apart`` starts with
    far2 = wp.int64(far) * wp.int64(far)
    u = aw - 1
    while q >= 0:
        i = s[q * ah + y]
        gi = g[r + i]
        # the cells of this parabola, from t[q] to u: those nearer than ``far``
        tq = t[q * ah + y]
        for x in range(wp.max(tq, i - far + 1), wp.min(u, i + far - 1) + 1):
            p = _parabola(x, i, gi)
            if p < far2:
                apart[r + x] = wp.float32(wp.max(wp.sqrt(wp.float64(p)) * acell - less, wp.float64(0.0)))
        u = tq - 1
        q = q - 1


@wp.kernel
def _window(g: wp.array(dtype=wp.int32), aw: int, far: int, acell: wp.float64, less: wp.float64,
            apart: wp.array(dtype=wp.float32)):
    """What :func:`_rows` finds, a thread a cell: the nearest of the columns fewer than ``far`` cells away.

    The parabolas of farther columns reach no cell below ``far``, so the
    minimum over the window is the envelope's wherever that is below
    ``far``, the same integer and the same value written. For a short
    ``far`` (:data:`WINDOW`): ``_rows`` runs a thread a row along it, a
    few hundred threads that each wait on every read.
    """
    y, x = wp.tid()
    r = y * aw
    far2 = wp.int64(far) * wp.int64(far)
    best = far2
    for u in range(wp.max(0, x - far + 1), wp.min(aw, x + far)):
        gu = g[r + u]
        if gu < far:
            best = wp.min(best, _parabola(x, u, gu))
    if best < far2:
        apart[r + x] = wp.float32(wp.max(wp.sqrt(wp.float64(best)) * acell - less, wp.float64(0.0)))


def apart_size(width: int, height: int, max_cells: int, cell: int) -> tuple[int, int, int]:
    """Cell side and grid size (width, height in cells) of the distance bound: ``cell`` px, more past ``max_cells``."""
    acell = max(cell, int(np.ceil(np.sqrt(width * height / max_cells))))
    return acell, -(-width // acell), -(-height // acell)


def apart(a, d, start, slack: float, reach: float, width: int, height: int, max_cells: int, cell: int, device: str,
          window: bool | None = None):
    """A lower bound of every pixel's distance to the kept pieces, per cell of about ``cell`` pixels, up to ``reach``.

    The twin of :func:`apart_host` where that is below ``reach`` (exact
    distances here, float32 in OpenCV: the bounds agree to float32
    rounding); at least ``reach`` where that is (a little less for
    outlines far denser than the grid: see the code).

    Parameters
    ----------
    a, d, start : wp.array
        :meth:`DevicePieces.grid`'s pieces and cell starts.
    slack : float
        Half the longest piece.
    reach : float
        Output pixels beyond which the bound need not be exact.
    width, height : int
        Output size.
    max_cells, cell : int
        Most cells, and the cell side where that allows.
    device : str
    window : bool, optional
        Find the bound a thread a cell (:func:`_window`) where it reaches at
        most :data:`WINDOW` cells, not by Meijster's pass a thread a row (the
        same values). Default: on a GPU, where the row pass is a few hundred
        threads that each wait on every read; the CPU runs it as well on its
        few cores.

    Returns
    -------
    acell, aw, ah : int
        Cell side, grid width and height in cells.
    apart : wp.array (ah * aw,) float32
    """
    acell, aw, ah = apart_size(width, height, max_cells, cell)
    less = acell * np.sqrt(2.0) + slack + 1e-3
    # cells beyond which every bound is at least ``reach``: distances exact up to there (nearer where
    # spreading every midpoint that far along its column would cost much more than passes over the
    # grid: a smaller bound only makes more pixels candidates, each searched exactly)
    far = min(int(np.ceil((reach + less) / acell)) + 1, aw + ah + 1, max(FAR, 4 * aw * ah // max(int(a.shape[0]), 1)))
    g = wp.full(ah * aw, far, dtype=wp.int32, device=device)
    runs = -(-aw // RUN)
    near = wp.zeros(ah * runs, dtype=wp.int32, device=device)
    # (one launch: CPU atomics are plain stores)
    wp.launch(_columns, dim=a.shape[0], inputs=[a, d, start, wp.float64(acell), aw, ah, far, g, near], device=device)
    out = wp.full(ah * aw, np.float32(max(far * acell - less, 0.0)), dtype=wp.float32, device=device)
    if window is None:
        window = not wp.get_device(device).is_cpu
    if window and far <= WINDOW:
        wp.launch(_window, dim=(ah, aw), inputs=[g, aw, far, wp.float64(acell), wp.float64(less), out], device=device)
        return acell, aw, ah, out
    s = wp.empty(ah * aw, dtype=wp.int32, device=device)
    t = wp.empty(ah * aw, dtype=wp.int32, device=device)
    wp.launch(_rows, dim=ah, inputs=[g, near, aw, far, s, t, wp.float64(acell), wp.float64(less), out], device=device)
    return acell, aw, ah, out


# --------------------------------------------------------------------------- host references


def one_of_each(a: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pieces less the second copy of each border that two regions share (the same piece, run backwards).

    The host reference of :meth:`DevicePieces.grid`'s de-duplication. Both
    copies are the same points to within rounding, so the nearest foot (and
    all that follows from it) is the same; the search reads half as many.
    """
    if not len(a):
        return a, d
    b = a + d
    # endpoints in a fixed order, rounded (1e-7 px): a pair that rounds apart just stays twice
    fwd = (a[:, 0] < b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] <= b[:, 1]))
    lo = np.where(fwd[:, None], a, b)
    hi = np.where(fwd[:, None], b, a)
    key = np.ascontiguousarray(np.round(np.hstack([lo, hi]) * 1e7).astype(np.int64))
    _, first = np.unique(key.view(np.dtype((np.void, 32))).ravel(), return_index=True)
    first.sort()
    return a[first], d[first]


def apart_host(mid: np.ndarray, slack: float, width: int, height: int, max_cells: int, cell: int):
    """The host reference of :func:`apart`, from the pieces' midpoints (OpenCV's exact distance transform).

    The exact distance between the cell's centre and the nearest centre of
    a cell holding a midpoint, less a half-diagonal each side and half a
    piece (and 1e-3 px for rounding).

    Returns
    -------
    acell, aw, ah : int
    apart : ndarray (ah, aw) float32
    """
    import cv2

    acell, aw, ah = apart_size(width, height, max_cells, cell)
    empty = np.ones((ah, aw), np.uint8)
    empty[np.clip(np.floor(mid[:, 1] / acell), 0, ah - 1).astype(np.int64),
          np.clip(np.floor(mid[:, 0] / acell), 0, aw - 1).astype(np.int64)] = 0
    dist = cv2.distanceTransform(empty, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64) * acell
    return acell, aw, ah, np.maximum(dist - acell * np.sqrt(2.0) - slack - 1e-3, 0.0).astype(np.float32)


__all__ = ["DevicePieces", "apart", "apart_host", "apart_size", "one_of_each"]
