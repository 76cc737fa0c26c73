"""The region of every output pixel on a Warp device: render step 1, the twin of ``pixelmap.region_index``.

:class:`DeviceOutlines` is prepared once per model and output size: every
edge of every outline, in its region's own frame exactly as
:class:`tpsv.geometry.outline.Coverage` prepares it (that object does the
arithmetic, so the edges are the same float64 values), binned by the bands
of :data:`BAND` output rows it crosses, and uploaded once.
:meth:`DeviceOutlines.index_device` then gives any band of rows in four
launches:

1. :func:`_fill_rows` (a thread a row), then :func:`_fill_pixels` (a thread
   a pixel, its span found by bisection): the crossings of the row with the edges of its bin
   (``xa + (y - ya) (xb - xa) / (yb - ya)``, the host's expression in its
   order; FMA contraction is off so that CUDA rounds as numpy does); the
   crossings of each region sorted and paired (even-odd), each span
   ``[ceil(xl), ceil(xr))`` clipped to the region's box; spans sorted by
   start and written left to right, ``-1`` between them. Where spans
   overlap (an edit moved a region over others) the region drawn first
   keeps the pixel. These are exactly the pixels of ``Coverage.rows``.
2. :func:`_find_gaps` (a thread a pixel): a pixel no polygon covers takes the region of the
   covered pixel nearest in the metric of the 5x5 chamfer distance transform
   that ``rasterize_regions`` runs (OpenCV's, integer weights), searched ring
   by ring out to :data:`SEARCH` pixels. Equally near pixels are chosen as
   OpenCV's two passes choose: one the forward pass reaches at that
   distance (above, at most two columns right per row up, or left in the
   same row) first, the earliest in raster order; otherwise the latest.
   The distances are always OpenCV's; the choice among equals is a rule
   derived from its scan order, not its scan, and differs in rare corners
   (3 of 158 245 uncovered pixels over 160 random outputs, all on the
   image's top rows in wide gaps at scale 11; 0 on the tests' models and
   the sample models at 1920x1080 and 3840x2160).
3. :func:`_put_gaps`: those regions written into the map (after every
   search has read it).

A pixel with no covered pixel within :data:`SEARCH` (large areas outside
every outline) is filled on the host by ``outline.GapFill``, exactly as the
host fills it; a flag read back (one int) says whether any is left. Steps 2
and 3 run only where step 1 left a pixel of the band uncovered (its rows'
counts are read back).

The result is the same on every device and for every split of the CPU
launches, and a band of rows equals those rows of the whole frame (the band
is covered :data:`SEARCH` rows beyond it for the search).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import TpsvError
from ..geometry import curves, outline
from ..rendering.pixelmap import draw_order
from . import resolve_device
from . import warp as _warp
from .rasterise import _launch_banded
from .transfer import upload

# fuse_fp off: the crossing x must round as numpy's (no FMA), or edge pixels could flip on CUDA
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

#: Output rows per bin of edges.
BAND = 8
#: Farthest (Chebyshev, output pixels) the device looks for a covered pixel from an uncovered one.
SEARCH = 32

_HV = wp.constant(wp.int64(outline._HV))
_DIAG = wp.constant(wp.int64(outline._DIAG))
_LONG = wp.constant(wp.int64(outline._LONG))
_FAR = wp.constant(wp.int64(1 << 62))
_AFTER = wp.constant(wp.int64(1 << 50))
#: Written by the gap kernel where no covered pixel lies within SEARCH.
UNRESOLVED = wp.constant(-2)


@wp.kernel
def _fill_rows(
    xa: wp.array(dtype=wp.float64),
    ya: wp.array(dtype=wp.float64),
    xb: wp.array(dtype=wp.float64),
    yb: wp.array(dtype=wp.float64),
    ereg: wp.array(dtype=wp.int32),
    g0: wp.array(dtype=wp.int32),
    g1: wp.array(dtype=wp.int32),
    bstart: wp.array(dtype=wp.int32),
    bedge: wp.array(dtype=wp.int32),
    rx0: wp.array(dtype=wp.int32),
    ry0: wp.array(dtype=wp.int32),
    rw: wp.array(dtype=wp.int32),
    lut: wp.array(dtype=wp.int32),
    rowstart: wp.array(dtype=wp.int64),
    base: wp.int64,
    xs: wp.array(dtype=wp.float64),
    rs: wp.array(dtype=wp.int32),
    band: int,
    row0: int,
    out_row0: int,
    out: wp.array2d(dtype=wp.int32),
    n_gap: wp.array(dtype=wp.int32),
    spans: wp.array(dtype=wp.int32),
):
    """The spans of row ``row0 + tid`` of the coverage, its uncovered pixels counted.

    The spans are left sorted by start in ``xs``/``rs`` and their count in
    ``spans[row]`` (negated where two overlap), for :func:`_fill_pixels` to
    write a thread a pixel.
    """
    y = row0 + wp.tid()
    orow = y - out_row0
    width = out.shape[1]
    o0 = rowstart[y] - base
    n = int(0)
    b = y / band
    # bins hold edges in drawing order of their region: the row's crossings come out grouped by region
    for k in range(bstart[b], bstart[b + 1]):
        e = bedge[k]
        if g0[e] <= y and y < g1[e]:
            r = ereg[e]
            local = wp.float64(y - ry0[r])
            xs[o0 + wp.int64(n)] = xa[e] + (local - ya[e]) * (xb[e] - xa[e]) / (yb[e] - ya[e])
            rs[o0 + wp.int64(n)] = r
            n += 1
    # spans: consecutive crossings of one region pair up (even-odd), each span [ceil(xl), ceil(xr)) clipped
    # to its region's box; span s is kept in place of the crossings already read (xs[2s], xs[2s + 1], rs[s])
    ns = int(0)
    i = int(0)
    while i < n:
        r = rs[o0 + wp.int64(i)]
        j = i + 1
        while j < n and rs[o0 + wp.int64(j)] == r:
            j += 1
        # insertion sort of the region's crossings (a few per row)
        for p in range(i + 1, j):
            v = xs[o0 + wp.int64(p)]
            q = p - 1
            while q >= i and xs[o0 + wp.int64(q)] > v:
                xs[o0 + wp.int64(q + 1)] = xs[o0 + wp.int64(q)]
                q -= 1
            xs[o0 + wp.int64(q + 1)] = v
        wr = wp.float64(rw[r])
        x0 = wp.float64(rx0[r])
        p = i
        while p + 1 < j:
            fl = wp.clamp(wp.ceil(xs[o0 + wp.int64(p)]), wp.float64(0.0), wr) + x0
            fr = wp.clamp(wp.ceil(xs[o0 + wp.int64(p + 1)]), wp.float64(0.0), wr) + x0
            if fr > fl:
                xs[o0 + wp.int64(2 * ns)] = fl
                xs[o0 + wp.int64(2 * ns + 1)] = fr
                rs[o0 + wp.int64(ns)] = r
                ns += 1
            p += 2
        i = j
    # spans by start (stable: drawing order among equal starts)
    for p in range(1, ns):
        vl = xs[o0 + wp.int64(2 * p)]
        vr = xs[o0 + wp.int64(2 * p + 1)]
        vg = rs[o0 + wp.int64(p)]
        q = p - 1
        while q >= 0 and xs[o0 + wp.int64(2 * q)] > vl:
            xs[o0 + wp.int64(2 * q + 2)] = xs[o0 + wp.int64(2 * q)]
            xs[o0 + wp.int64(2 * q + 3)] = xs[o0 + wp.int64(2 * q + 1)]
            rs[o0 + wp.int64(q + 1)] = rs[o0 + wp.int64(q)]
            q -= 1
        xs[o0 + wp.int64(2 * q + 2)] = vl
        xs[o0 + wp.int64(2 * q + 3)] = vr
        rs[o0 + wp.int64(q + 1)] = vg
    # the pixels the spans cover, each once (sorted by start: a sweep); and whether two spans overlap
    overlap = int(0)
    claimed = int(0)
    c = int(0)
    for p in range(ns):
        cl = int(xs[o0 + wp.int64(2 * p)])
        cr = int(xs[o0 + wp.int64(2 * p + 1)])
        if cl < c:
            overlap = 1
        lo = wp.max(cl, c)
        if cr > lo:
            claimed += cr - lo
        c = wp.max(c, cr)
    # overlapping outlines (after an edit moved a region): -ns, and each pixel of the row takes the region
    # drawn first among its spans (_fill_pixels: a thread a pixel, not this row's thread)
    spans[orow] = ns
    if overlap != 0:
        spans[orow] = -ns
    n_gap[orow] = width - claimed


@wp.kernel
def _fill_pixels(rowstart: wp.array(dtype=wp.int64), base: wp.int64, xs: wp.array(dtype=wp.float64),
                 rs: wp.array(dtype=wp.int32), lut: wp.array(dtype=wp.int32), spans: wp.array(dtype=wp.int32), row0: int,
                 out_row0: int, out: wp.array2d(dtype=wp.int32)):
    """Pixel ``(row0 + i, x)``: the region of its span, else -1; where spans overlap (``spans`` negative),
    the region drawn first among those covering it (the row's few spans, each looked at)."""
    i, x = wp.tid()
    y = row0 + i
    orow = y - out_row0
    ns = spans[orow]
    o0 = rowstart[y] - base
    lab = int(-1)
    if ns < 0:
        first = int(-1)
        for p in range(-ns):
            g = rs[o0 + wp.int64(p)]
            if int(xs[o0 + wp.int64(2 * p)]) <= x and x < int(xs[o0 + wp.int64(2 * p + 1)]):
                if first < 0 or g < first:
                    first = g
        if first >= 0:
            lab = lut[first]
        out[orow, x] = lab
        return
    # the last span starting at or before x (spans sorted by start, disjoint)
    lo = int(0)
    hi = ns
    while lo < hi:
        mid = (lo + hi) / 2
        if int(xs[o0 + wp.int64(2 * mid)]) <= x:
            lo = mid + 1
        else:
            hi = mid
    if lo > 0 and x < int(xs[o0 + wp.int64(2 * lo - 1)]):
        lab = lut[rs[o0 + wp.int64(lo - 1)]]
    out[orow, x] = lab


@wp.func
def _chamfer(dx: int, dy: int):
    """OpenCV's 5x5 chamfer distance over ``(dx, dy)`` (1/65536 px)."""
    m = wp.max(wp.abs(dx), wp.abs(dy))
    n = wp.min(wp.abs(dx), wp.abs(dy))
    if 2 * n <= m:
        return wp.int64(n) * _LONG + wp.int64(m - 2 * n) * _HV
    return wp.int64(m - n) * _LONG + wp.int64(2 * n - m) * _DIAG


@wp.func
def _nearest(cov: wp.array2d(dtype=wp.int32), cov_row0: int, height: int, y: int, x: int, search: int):
    """Region of the covered pixel nearest ``(x, y)`` in the chamfer metric (:data:`UNRESOLVED`: none within ``search``)."""
    width = cov.shape[1]
    best = _FAR
    bkey = _FAR
    lab = int(UNRESOLVED)
    for rad in range(1, search + 1):
        # a pixel ``rad`` rings out is at least rad * HV away
        if wp.int64(rad) * _HV > best:
            break
        for dy in range(-rad, rad + 1):
            qy = y + dy
            if qy >= 0 and qy < height:
                step = 1
                if dy != -rad and dy != rad:
                    step = 2 * rad
                dx = -rad
                while dx <= rad:
                    qx = x + dx
                    if qx >= 0 and qx < width:
                        w = cov[qy - cov_row0, qx]
                        if w >= 0:
                            d = _chamfer(dx, dy)
                            # ties as OpenCV's two passes break them (see the module docstring)
                            key = wp.int64(dy) * wp.int64(width) + wp.int64(dx)
                            if not ((dy < 0 and dx <= -2 * dy) or (dy == 0 and dx < 0)):
                                key = _AFTER - key
                            if d < best or (d == best and key < bkey):
                                best = d
                                bkey = key
                                lab = w
                    dx += step
    return lab


@wp.kernel
def _find_gaps(cov: wp.array2d(dtype=wp.int32), cov_row0: int, n_gap: wp.array(dtype=wp.int32), height: int,
               row0: int, search: int, found: wp.array2d(dtype=wp.int32), found_row0: int,
               unresolved: wp.array(dtype=wp.int32)):
    """The region of uncovered pixel ``(row0 + i, x)`` (thread ``(i, x)``) into ``found`` (whose first row
    is output row ``found_row0``; a thread a pixel: a wide gap's searches run side by side, not one row's
    after another)."""
    i, x = wp.tid()
    y = row0 + i
    r = y - cov_row0
    if n_gap[r] == 0:
        return
    if cov[r, x] < 0:
        lab = _nearest(cov, cov_row0, height, y, x, search)
        found[y - found_row0, x] = lab
        if lab == UNRESOLVED:
            unresolved[0] = 1


@wp.kernel
def _put_gaps(cov: wp.array2d(dtype=wp.int32), cov_row0: int, n_gap: wp.array(dtype=wp.int32), row0: int,
              found: wp.array2d(dtype=wp.int32), found_row0: int):
    """Write ``found`` into uncovered pixel ``(row0 + i, x)`` (after every search has read the map)."""
    i, x = wp.tid()
    r = row0 + i - cov_row0
    if n_gap[r] == 0:
        return
    if cov[r, x] < 0:
        cov[r, x] = found[r + cov_row0 - found_row0, x]


class DeviceOutlines:
    """A model's outlines on a Warp device, for the region map at one output size.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.
    device : str
        Warp device (``cpu``, ``cuda``, ``cuda:N``).
    threads : int, optional
        Host threads for the CPU device (None: every core).
    max_gap_bytes : int, optional
        Host memory the fill of pixels far from every outline may take
        (``outline.GapFill``; beyond it: :class:`TpsvError`).

    Raises
    ------
    TpsvError
        Empty output, an invalid draw order or outline (as ``region_index``).

    Notes
    -----
    Device memory: the edges (44 bytes each, plus 4 per bin they cross);
    for the rows of a call (and :data:`SEARCH` rows each side), 12 bytes per
    edge crossing (scratch, kept for the next call) and one int32 a pixel
    for the map, and one more where gaps are filled. A band of rows thus
    costs memory in proportion to the band, not to the output. Calls may
    not run at once (they share the scratch).
    """

    def __init__(self, model, width: int, height: int, device: str = "cpu", threads: int | None = None,
                 max_gap_bytes: int | None = None):
        _warp()
        self.device = resolve_device(device)
        self.threads = threads
        self.width, self.height = int(width), int(height)
        model = curves.as_drawn(model, self.width, self.height)
        order = draw_order(model)
        regions = [model.regions[r] for r in order]
        # the host's own preparation: the same edges, boxes and float64 values
        self.coverage = cov = outline.Coverage(regions, self.width, self.height, (model.width, model.height))
        self._lut_host = np.asarray(order + [-1], np.int32)
        self._gaps = None
        self._max_gap_bytes = max_gap_bytes
        self._found = None
        self.n_regions = len(order)
        if cov.empty:
            return
        H = self.height
        g0 = cov._g0.astype(np.int64)
        g1 = cov._g1.astype(np.int64)
        ne = g0.size
        if ne >= 2**31:
            raise TpsvError(f"outline too complex: {ne} edges")
        # crossings per row -> offsets of each row's scratch
        per_row = np.cumsum(np.bincount(g0, minlength=H + 1)[:H + 1] - np.bincount(g1, minlength=H + 1)[:H + 1])[:H]
        rowstart = np.zeros(H + 1, np.int64)
        np.cumsum(per_row, out=rowstart[1:])
        # bins of BAND rows: edge e lies in bins g0 // BAND .. (g1 - 1) // BAND, in edge (drawing) order
        b0 = g0 // BAND
        nbin = (g1 - 1) // BAND - b0 + 1
        tot = int(nbin.sum())
        e = np.repeat(np.arange(ne, dtype=np.int64), nbin)
        bins = np.repeat(b0 - (np.cumsum(nbin) - nbin), nbin) + np.arange(tot)
        order_e = np.argsort(bins, kind="stable")
        nb = (H + BAND - 1) // BAND
        bstart = np.zeros(nb + 1, np.int64)
        np.cumsum(np.bincount(bins, minlength=nb)[:nb], out=bstart[1:])
        if tot >= 2**31:
            raise TpsvError(f"outline too complex: {tot} edge bins")
        dev = self.device
        f64, i32 = wp.float64, wp.int32
        self._arrays = upload(
            dev, (cov._xa, f64), (cov._ya, f64), (cov._xb, f64), (cov._yb, f64), (cov._reg, i32), (g0, i32),
            (g1, i32), (bstart, i32), (e[order_e], i32), (cov._x0, i32), (cov._y0, i32), (cov._w, i32),
            (self._lut_host, i32), (rowstart, wp.int64))
        self._lut, self._rowstart = self._arrays[12], self._arrays[13]
        self._rowstart_host = rowstart
        self._xs = self._rs = None  # the crossings' scratch, made for the first call's rows

    def _scratch(self, y0: int, y1: int) -> int:
        """Scratch for the crossings of rows ``y0 .. y1`` (grown when too small); returns their first slot."""
        base, need = int(self._rowstart_host[y0]), int(self._rowstart_host[y1] - self._rowstart_host[y0])
        if self._xs is None or self._xs.shape[0] < need:
            self._xs = wp.empty(max(need, 1), dtype=wp.float64, device=self.device)
            self._rs = wp.empty(max(need, 1), dtype=wp.int32, device=self.device)
        return base

    def coverage_device(self, y0: int = 0, y1: int | None = None) -> wp.array:
        """Rows ``y0 <= y < y1`` of the coverage: region index, ``-1`` where no polygon covers the pixel.

        Returns
        -------
        wp.array2d(int32) (y1 - y0, width)
        """
        y0, y1 = self._rows(y0, y1)
        return self._coverage(y0, y1)[0]

    def _coverage(self, y0, y1):
        dev, W = self.device, self.width
        out = wp.empty((y1 - y0, W), dtype=wp.int32, device=dev)
        n_gap = wp.empty(y1 - y0, dtype=wp.int32, device=dev)
        if self.coverage.empty:
            out.fill_(-1)
            n_gap.fill_(W)
            return out, n_gap

        spans = wp.empty(y1 - y0, dtype=wp.int32, device=dev)
        base = wp.int64(self._scratch(y0, y1))

        def launch(a, b):
            wp.launch(_fill_rows, dim=b - a,
                      inputs=self._arrays + [base, self._xs, self._rs, BAND, y0 + a, y0, out, n_gap, spans], device=dev)

        def fill(a, b):
            wp.launch(_fill_pixels, dim=(b - a, W), inputs=[self._rowstart, base, self._xs, self._rs, self._lut,
                                                            spans, y0 + a, y0, out], device=dev)

        _launch_banded(_fill_rows, y1 - y0, (y1 - y0) * W, dev, self.threads, launch)
        _launch_banded(_fill_pixels, y1 - y0, (y1 - y0) * W, dev, self.threads, fill)
        return out, n_gap

    def index_device(self, y0: int = 0, y1: int | None = None) -> wp.array:
        """Rows ``y0 <= y < y1`` of ``pixelmap.region_index`` on the device.

        Parameters
        ----------
        y0, y1 : int
            Band of output rows (default: the whole frame).

        Returns
        -------
        wp.array2d(int32) (y1 - y0, width)
            Region index of every pixel (``-1`` only when the model has no region).
        """
        y0, y1 = self._rows(y0, y1)
        dev, W, H = self.device, self.width, self.height
        if self.coverage.empty:
            out = wp.empty((y1 - y0, W), dtype=wp.int32, device=dev)
            out.fill_(int(self._lut_host[0]) if self.n_regions else -1)
            return out
        # the gaps of the band read covered pixels up to SEARCH rows beyond it
        c0, c1 = max(y0 - SEARCH, 0), min(y1 + SEARCH, H)
        cov, n_gap = self._coverage(c0, c1)
        out = cov[y0 - c0:y1 - c0]
        # the rows' counts read back: a band no pixel of which is uncovered (the usual case) needs no gap pass
        # (on the CPU the two launches cost 12 ns a pixel for nothing, 3 ms of a 512 x 512 render)
        if not n_gap.numpy()[y0 - c0:y1 - c0].any():
            return out
        if self._found is None or tuple(self._found.shape) != (y1 - y0, W):
            # the call's rows (only uncovered pixels are written and read), kept for the next frame
            self._found = wp.empty((y1 - y0, W), dtype=wp.int32, device=dev)
        found = self._found
        unresolved = wp.zeros(1, dtype=wp.int32, device=dev)

        def find(a, b):
            wp.launch(_find_gaps, dim=(b - a, W), inputs=[cov, c0, n_gap, H, y0 + a, SEARCH, found, y0, unresolved],
                      device=dev)

        def put(a, b):
            wp.launch(_put_gaps, dim=(b - a, W), inputs=[cov, c0, n_gap, y0 + a, found, y0], device=dev)

        _launch_banded(_find_gaps, y1 - y0, (y1 - y0) * W, dev, self.threads, find)
        _launch_banded(_put_gaps, y1 - y0, (y1 - y0) * W, dev, self.threads, put)
        # one int read back: whether any pixel needs the host (none within SEARCH px of a covered one)
        if int(unresolved.numpy()[0]):
            out = self._resolve(out, y0)
        return out

    def index(self, y0: int = 0, y1: int | None = None) -> np.ndarray:
        """:meth:`index_device` copied to the host: ndarray (y1 - y0, width) int32."""
        return self.index_device(y0, y1).numpy()

    def _rows(self, y0, y1):
        y0 = int(y0)
        y1 = self.height if y1 is None else int(y1)
        if not 0 <= y0 < y1 <= self.height:
            raise TpsvError(f"rows {y0}..{y1} are not a band of the {self.height}-row output")
        return y0, y1

    def _resolve(self, out, y0):
        """Fill the pixels the device left unresolved exactly as the host does (``outline.GapFill``)."""
        if self._gaps is None:
            self._gaps = outline.GapFill(self.coverage, band_rows=256, max_bytes=self._max_gap_bytes)
        idx = out.numpy()
        miss = idx == UNRESOLVED
        host = np.full(idx.shape, -1, np.int32)
        self._gaps.apply(host, y0)
        idx[miss] = self._lut_host[host[miss]]
        return wp.array(idx, dtype=wp.int32, device=self.device)


__all__ = ["BAND", "DeviceOutlines", "SEARCH"]
