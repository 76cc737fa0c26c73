"""Region borders at sub-pixel precision, fitted to the image's own edges.

A label map puts every border on pixel edges: traced as is, outlines are
staircases (:func:`tpsv.geometry.outline.trace_outline`) that magnification
shows. Here each region gets a soft membership field ``m`` sampled at pixel
centres, whose level 0.5 (marching squares, linear between centres) is the
outline:

* Inside a region, ``m`` is 1; far outside, 0.
* On a border pixel between regions A and B (its own region A, B the most
  frequent other region among its 8 neighbours), the pixel's colour ``c`` is
  read as a mix of the two sides: ``alpha = (c - mu_B) . (mu_A - mu_B) / |mu_A
  - mu_B|^2`` (clipped to [0, 1]), ``mu`` each side's colour at the pixel: the
  plane through that region's interior pixels in a :data:`WINDOW` x
  :data:`WINDOW` window around it. ``alpha`` is that side's coverage of the
  pixel; ``m = 0.5 + d``, ``d`` the distance from the pixel centre to a
  straight border at the label map's angle that covers ``alpha`` of it, so
  that the level 0.5 is exactly on a straight border (on the coverage itself it
  was off by up to 0.05 px with the angle). A pixel wholly on one side takes
  the distance its partly covered neighbours on the same border imply. A
  pixel wholly of its own colour with a second region among its neighbours (a
  line one pixel wide between two regions) is read against that one too.
* Where the two sides' colours are too close to tell (``|mu_A - mu_B|`` below
  :data:`CONTRAST`), ``m`` leans, in proportion, on the region's mask smoothed
  by a Gaussian of :data:`SMOOTH_SIGMA` px, whose level 0.5 follows pixel
  edges on straight runs and cuts staircases into smooth diagonals.

Between two regions ``m_A + m_B = 1`` on every border pixel (both readings
and both smoothed masks add up to 1), so their contours pass through the same
points. All regions are outlined together (:func:`fitted_outlines`): each
border between two regions is simplified once and both sides keep the same
vertices, so the outlines are one curve (stored once in the file,
``tpsv.codec.chains``). Where three or more regions meet, the short runs
where their contours part are closed into one junction point that all of
them share, and where contours part around a sliver (a cycle of stretches of
their own), one region takes it. Gaps and overlaps between regions are then
rare (a few output pixels at 4x on the samples), except where a region falls
back to its traced outline (below).

Corners, which no straight border describes, are put back where the straight
runs either side cross. The outlines are drawn as curves through their
vertices (:mod:`tpsv.geometry.curves`), so each run between junctions is
smoothed (a local cubic fit over :data:`SMOOTH_WINDOW` contour points, fewer
where a border between flat colours turns fast, its corners kept) and
simplified for its curve: it keeps the points whose curve
stays within :data:`TOLERANCE` px of the smoothed run where the colours are
trusted (up to :data:`TEXTURED_TOLERANCE` where its sides hold texture),
easing to :data:`LOOSE_TOLERANCE` px where only the smoothed mask
speaks (it is no more precise than the label map); the vertices are then put
on the file's grid. A
region whose fitted outline would lose it (a one-pixel line of a colour
close to a neighbour's, say) keeps its traced outline.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..threads import map_ordered
from . import curves, outline

#: Side of the window (px) whose interior pixels give each side's colour.
WINDOW = 5
#: Ridge (px^2) on the slope of each side's colour plane: a side seen over less spread than this leans on its mean.
SLOPE_RIDGE = 1.0
#: Border pixels whose sides one thread reads at once (bounds the memory of the reading: about 0.6 KB a
#: pixel, :data:`SIDE_THREADS` chunks at a time).
SIDE_CHUNK = 1 << 14
#: Most host threads reading border pixels at once.
SIDE_THREADS = 8
#: Gaussian (px) weighting the window's pixels for a border pixel's normal.
NORMAL_SIGMA = 1.2
#: Coverage this close to 0 or 1 reads as a pixel wholly on one side.
SATURATED = 0.03
#: Colour difference (sRGB, 0-1, Euclidean) above which a border is read from the image alone.
CONTRAST = 0.08
#: Gaussian (px) that smooths a region's mask where the colours cannot tell.
SMOOTH_SIGMA = 0.7
#: Tolerance of fitted outlines where the colours tell where the border is, px: how far their
#: curve may pass from the (smoothed) contour. Polygons at 0.06 px left facets half an output
#: pixel deep at 8x; curves at 0.03 px keep 15-23 % fewer vertices on the samples than polygons
#: at 0.04 and took the synthetic shapes at 8x from 43.71 (polygons at 0.06) to 45.2 dB.
TOLERANCE = 0.03
#: The most a border's texture raises its tolerance (px). A reading's position is no surer than the
#: spread of its sides' colours relative to the contrast between them (alpha, and the distance it
#: implies, are off by about that much), so a point's tolerance is at least that ratio
#: (:attr:`BorderReading.near_grain`: 0.004-0.03 along the edge table's shapes, 0.06-0.14 at the
#: median on the samples), up to this: a curve held within :data:`TOLERANCE` of a photo's smoothed
#: contour followed the texture's noise with vertices that bought nothing. Quality 75, before -> after:
#: the samples' files 0.3-2.1 % smaller, BD-PSNR over qualities 20-95 +0.06..+0.14 dB with their label
#: maps or without, coins and cat (never seen) +0.25 and +0.27; area-downscaled 2x and 4x, vectorised
#: and rendered back, -0.05..+0.04 dB for -6..+2 % bytes; the edge table the same (docs/DESIGN.md,
#: "Automatic regions"). A flat 0.1 px on every border not between flat colours lost 0.8-1.9 dB there.
TEXTURED_TOLERANCE = 0.1
#: Outline vertices are rounded to 1/GRID px, the ``.tpsv`` file's outline quantum
#: (``tpsv.codec.quant.OUTLINE_SCALE``; a test keeps them equal).
GRID = 16
#: A contour turning by more than this (degrees) between straight runs has a corner.
CORNER_TURN = 35.0
#: Arc (px) over which a contour's turning is measured.
CORNER_ARM = 2.0
#: The straight runs either side of a corner: (from, to) px along the contour, tried in turn.
CORNER_RUNS = ((2.0, 6.0), (0.7, 3.5))
#: Largest distance (px) of a run's point from its line for the run to be straight.
CORNER_STRAIGHT = 0.08
#: A point this close (px) to a corner's line is on it, not on the rounding.
CORNER_ON_LINE = 0.04
#: Farthest (px) a corner's sides may cross from the contour's sharpest point for a corner to be put
#: back there; where the sides cross at 70-110 degrees, :data:`CORNER_DEPTH_RIGHT`. The reading rounds
#: a sharp right angle by at most 0.92 px on the bench's shapes; a rounded rectangle's corner of radius
#: 3 px lies 1.26-1.33 px inside, and was squared (its texture drew a light blob there at 8x).
CORNER_DEPTH, CORNER_DEPTH_RIGHT = 1.5, 1.1
#: Outline vertices turning less than this (degrees) slide along the border onto the grid point nearest to it.
SNAP_TURN = 30.0
#: Cost of sliding a vertex along its border, relative to moving it across.
SNAP_SLIDE = 0.25
#: Grid steps (of 1/GRID px) between the vertices of loose stretches (1/4 px: they are known to half a pixel).
LOOSE_STEP = 4
#: Tolerance where they cannot (low contrast, texture): the label map's own precision.
LOOSE_TOLERANCE = 0.5
#: Runs of a contour of their own shorter than this (px) are junctions of three or more regions.
JUNCTION = 2.0
#: Pixels a part of a region pinched off by its field must hold to become a region of its own.
#: A smaller part is left to the rest, whose fitted outline drops it (its pixels go to the
#: neighbours and the gap fill): a region of its own costs 100-200 B in a quality-75 file,
#: more than such a part's pixels are worth (40 px on astronaut cost 195 B for 0.00 dB).
PINCHED_MIN = 64

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def _coverage_distance(a: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Signed distance (px) from a pixel's centre to a straight border that covers ``a`` of
    the pixel, its normal along ``normal`` (positive: the centre is on the covered side).

    A unit square seen along a normal at angle ``t`` spreads over a trapezoid
    (the sum of two uniforms of widths ``|cos t|`` and ``|sin t|``); the coverage
    is its distribution function, inverted here. A pixel wholly covered or wholly
    uncovered gets the half width of the trapezoid (the least distance it implies).
    Without a normal (a pixel its neighbours surround evenly) the border is read
    as parallel to a pixel side: ``d = a - 0.5``.
    """
    c = np.abs(normal[:, 0])
    s = np.abs(normal[:, 1])
    L = np.hypot(c, s)
    known = L > 1e-12
    L = np.where(known, L, 1.0)
    w1 = np.where(known, np.maximum(c, s) / L, 1.0)
    w2 = np.where(known, np.minimum(c, s) / L, 0.0)
    mid = 0.5 * (w1 - w2) / w1  # coverage where the linear part ends
    lo = a < 0.5 - mid
    hi = a > 0.5 + mid
    d = w1 * (a - 0.5)
    tail = np.sqrt(2.0 * w1 * w2 * np.where(lo, a, 1.0 - a))
    d = np.where(lo, -0.5 * (w1 + w2) + tail, d)
    return np.where(hi, 0.5 * (w1 + w2) - tail, d)


class PlaneFit:
    """Per border pixel, a least-squares plane ``c(d) = c0 + G d`` through colours at offsets ``d`` (px).

    The slope is shrunk towards 0 (ridge :data:`SLOPE_RIDGE`), so a side seen
    at a few pixels in a line falls back to their mean.
    """

    def __init__(self, n: int):
        self.count = np.zeros(n)
        self.pos = np.zeros((n, 2))
        self.second = np.zeros((n, 2, 2))
        self.col = np.zeros((n, 3))
        self.cross = np.zeros((n, 2, 3))
        self.square = np.zeros(n)

    def add(self, dx: int, dy: int, col: np.ndarray, sel: np.ndarray) -> None:
        w = sel.astype(np.float64)
        d = np.array([dx, dy], np.float64)
        self.count += w
        self.pos += w[:, None] * d
        self.second += w[:, None, None] * np.outer(d, d)
        wc = col * w[:, None]
        self.col += wc
        self.cross += d[None, :, None] * wc[:, None, :]
        self.square += (col * col).sum(axis=1) * w

    def solve(self) -> tuple[np.ndarray, np.ndarray]:
        """The plane's colour at offset 0, and the spread (rms) of the colours about the plane."""
        k = np.maximum(self.count, 1.0)
        m = self.pos / k[:, None]
        mc = self.col / k[:, None]
        cov = self.second / k[:, None, None] - m[:, :, None] * m[:, None, :]
        vc = self.cross / k[:, None, None] - m[:, :, None] * mc[:, None, :]
        slope = np.linalg.solve(cov + SLOPE_RIDGE * np.eye(2), vc)  # (n, 2, 3)
        at0 = mc - np.einsum("ni,nic->nc", m, slope)
        var = self.square / k - (mc * mc).sum(axis=1) - np.einsum("nic,nic->n", slope, vc)
        return at0, np.sqrt(np.maximum(var, 0.0))


def _window(ys: np.ndarray, xs: np.ndarray, shape: tuple[int, int], half: int):
    """Every offset ``(dx, dy)`` of a ``2 half + 1`` square window around pixels ``(ys, xs)``, with the
    neighbours' coordinates clipped to the image and whether each lies in it."""
    H, W = shape
    for dy in range(-half, half + 1):
        for dx in range(-half, half + 1):
            qy, qx = ys + dy, xs + dx
            inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
            yield dx, dy, np.clip(qy, 0, H - 1), np.clip(qx, 0, W - 1), inside


def own_side_colours(rgb: np.ndarray, index: np.ndarray, pixels: np.ndarray, near=None,
                     window: int = WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """The colour each of ``pixels`` would have wholly inside its own region.

    A pixel a border crosses mixes two regions' colours. Its own region's
    colour there is the plane through that region's unmixed pixels (neither in
    ``pixels`` nor in ``near``, the pixels a border touches at all) in the
    ``window`` x ``window`` square around it, read at its centre.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float
    index : ndarray (H, W) int
        Region of every pixel.
    pixels : ndarray (n,) int
        Flat indices ``y * W + x`` of the mixed pixels.

    Returns
    -------
    colours : ndarray (n, 3) float64
    ok : ndarray (n,) bool
        False where no unmixed pixel of the region is in the window.
    """
    H, W = index.shape
    pixels = np.asarray(pixels, np.int64)
    ys, xs = pixels // W, pixels % W
    mixed = np.zeros(H * W, bool)
    mixed[pixels] = True
    if near is not None:
        mixed[np.asarray(near, np.int64)] = True
    mixed = mixed.reshape(H, W)
    own = index[ys, xs]
    fit = PlaneFit(len(pixels))
    for dx, dy, qy, qx, inside in _window(ys, xs, (H, W), window // 2):
        sel = inside & (index[qy, qx] == own) & ~mixed[qy, qx]
        fit.add(dx, dy, np.asarray(rgb[qy, qx, :3], np.float64), sel)
    colours, _ = fit.solve()
    return np.clip(colours, 0.0, 1.0), fit.count > 0


def _sides(comp, border, rgb, ys, xs, own, across):
    """Both sides' colours at border pixels ``(ys, xs)`` (own region, region across), their spread,
    the border's normal (towards the own side: Gaussian-weighted offsets of own minus across pixels)
    and whether both sides have interior pixels in the window.

    Each side's colour is a plane fitted to its interior (non-border) pixels in the
    window and read at the border pixel: a mean alone would be off by the gradient
    times the window's offset from the pixel. A side with no interior pixel there
    (thin parts) takes its pixel farthest from the other side's colour (its spread:
    all its pixels').
    """
    n = len(ys)
    fits = {key: PlaneFit(n) for key in ("a", "b", "fa", "fb")}
    normal = np.zeros((n, 2))
    for dx, dy, qy, qx, inside in _window(ys, xs, comp.shape, WINDOW // 2):
        cc = np.where(inside, comp[qy, qx], -1)
        bb = ~inside | border[qy, qx]
        g = np.exp(-(dx * dx + dy * dy) / (2.0 * NORMAL_SIGMA**2))
        normal += (g * ((cc == own).astype(np.float64) - (cc == across)))[:, None] * np.array([dx, dy], np.float64)
        col = rgb[qy, qx].astype(np.float64)
        for key, sel in (("a", (cc == own) & ~bb), ("b", (cc == across) & ~bb), ("fa", cc == own),
                         ("fb", cc == across)):
            fits[key].add(dx, dy, col, sel)
    out = []
    for inner, whole in (("a", "fa"), ("b", "fb")):
        use = fits[inner].count > 0
        mu_i, sd_i = fits[inner].solve()
        mu_w, sd_w = fits[whole].solve()
        out += [np.where(use[:, None], mu_i, mu_w), np.where(use, sd_i, sd_w)]
    # a side with no unmixed pixel (a line one or two pixels wide) has no pixel of its own colour: the
    # mean of its mixed pixels lies towards the other side, and read against it the line's pixels came
    # out wider than it (a dark line 2 px wide ended in a blob at 8x). Its pixel farthest from the other
    # side's colour is nearer its own.
    for k, (key, other, region) in enumerate((("a", 2, own), ("b", 0, across))):
        thin = (fits[key].count == 0) & (fits["b" if key == "a" else "a"].count > 0)
        if not thin.any():
            continue
        ref = out[other]
        best = np.full(n, -1.0)
        pick = out[2 * k].copy()
        for _, _, qy, qx, inside in _window(ys, xs, comp.shape, WINDOW // 2):
            col = rgb[qy, qx].astype(np.float64)
            d = ((col - ref) ** 2).sum(axis=1)
            take = thin & inside & (comp[qy, qx] == region) & (d > best)
            best[take] = d[take]
            pick[take] = col[take]
        out[2 * k] = pick
    return (*out, normal, (fits["a"].count > 0) & (fits["b"].count > 0))


def _most_frequent(v: np.ndarray) -> np.ndarray:
    """Per row of ``v`` (n, 8) (-1: none), its most frequent value (ties: the smaller), -1 where none."""
    best = np.full(len(v), -1, np.int64)
    count = np.zeros(len(v), np.int64)
    for k in range(v.shape[1]):
        c = (v == v[:, k:k + 1]).sum(axis=1)
        take = (v[:, k] >= 0) & ((c > count) | ((c == count) & (v[:, k] < best)))
        best[take] = v[take, k]
        count[take] = c[take]
    return best


def _read(comp, border, rgb, ys, xs, own, across):
    """Border pixels ``(ys, xs)`` read against region ``across``: the share ``alpha`` of their own
    region in their colour, the border's normal, the reading's trust, both sides' spread together
    and that spread relative to the contrast across (the grain)."""
    # the sides' colours, a bounded number of border pixels at a time (each holds ~0.6 KB meanwhile), the
    # chunks on the host's threads (each pixel's reading is its own: the same values on any core count)
    n = len(ys)
    mu_a, mu_b, normal = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2))
    sd_a, sd_b = np.empty(n), np.empty(n)
    inner = np.empty(n, bool)
    chunks = [slice(a0, a0 + SIDE_CHUNK) for a0 in range(0, n, SIDE_CHUNK)]

    def read(k):
        mu_a[k], sd_a[k], mu_b[k], sd_b[k], normal[k], inner[k] = _sides(comp, border, rgb, ys[k], xs[k], own[k],
                                                                        across[k])

    map_ordered("sides", read, chunks, SIDE_THREADS)
    d = mu_a - mu_b
    dd = (d * d).sum(axis=1)
    a = np.clip(((rgb[ys, xs].astype(np.float64) - mu_b) * d).sum(axis=1) / np.maximum(dd, 1e-12), 0.0, 1.0)
    # a side whose colour varies (texture) is a poor reference: trust fades out as its
    # spread goes from a quarter to a half of the contrast
    contrast = np.sqrt(dd)
    spread = sd_a + sd_b
    ratio = spread / np.maximum(contrast, 1e-12)
    texture = np.clip(2.0 - 4.0 * ratio, 0.0, 1.0)
    # a side seen only at its mixed pixels (a line one or two pixels wide) spreads by the mix, not by texture
    grain = np.where(inner, ratio, 0.0)
    return a, normal, np.clip(contrast / CONTRAST - 1.0, 0.0, 1.0) * texture, spread, grain


class BorderReading:
    """Every border pixel of a component map: the region across and the colour reading.

    Parameters
    ----------
    comp : ndarray (H, W) int
        Region of every pixel (connected components, ``0 .. n-1``).
    rgb : ndarray (H, W, 3) float
        The image, sRGB in [0, 1].

    Attributes
    ----------
    across : ndarray (H, W) int32
        Region across the border (``-1`` off the border).
    alpha : ndarray (H, W) float64
        Share of the pixel's own region, read from its colour (1 off the border).
    level : ndarray (H, W) float64
        ``0.5 +`` the distance (px) from the pixel centre to the border, towards
        its own side, that ``alpha`` implies (1 off the border).
    trust : ndarray (H, W) float64
        How far ``alpha`` is to be believed, in [0, 1] (0 off the border).
    near_trust : ndarray (H, W) float64
        The largest ``trust`` in each pixel's 3 x 3 neighbourhood (what an
        outline point between pixels goes by).
    near_clean : ndarray (H, W) bool
        Whether every border pixel in the 3 x 3 neighbourhood (one at
        least) reads a border between two flat colours: trusted, both sides'
        spread at most :data:`CLEAN_SPREAD` (a drawing's border, whose
        contour needs little smoothing, :func:`_smooth_run`).
    near_grain : ndarray (H, W) float32
        The least ratio, among the border pixels in each pixel's 3 x 3
        neighbourhood, of the spread of their sides' colours to the contrast
        across (about how far off, px, the texture may put the reading;
        1e9 where there is none).
    """

    def __init__(self, comp: np.ndarray, rgb: np.ndarray):
        comp = np.asarray(comp)
        rgb = np.asarray(rgb)[..., :3]  # read at the pixels it needs, in float64 there
        H, W = comp.shape
        pad = np.pad(comp, 1, mode="edge")
        neighbours = [pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] for dy, dx in _NEIGHBOURS]
        border = np.zeros((H, W), bool)
        for nb in neighbours:
            border |= (nb != comp) & (nb >= 0)
        self.across = np.full((H, W), -1, np.int32)
        self.alpha = np.ones((H, W))
        self.level = np.ones((H, W))
        self.trust = np.zeros((H, W))
        self.near_trust = self.trust
        self.near_clean = np.zeros((H, W), bool)
        self.near_grain = np.full((H, W), np.float32(1e9))
        self._second = None
        ys, xs = np.nonzero(border)
        if ys.size == 0:
            return
        # the other regions among the 8 neighbours, of the border pixels only (-1: the pixel's own)
        v = np.stack([nb[ys, xs] for nb in neighbours], axis=1).astype(np.int64)
        v = np.where(v != comp[ys, xs][:, None], v, -1)
        del neighbours, pad
        # the most frequent other region among the neighbours (ties: the smaller index)
        best = _most_frequent(v)
        own = comp[ys, xs]
        self.across[ys, xs] = best
        # a pixel with another region on two sides (a line one pixel wide, a junction) is read against
        # the second most frequent one too, so that its field does not leave that border to the
        # smoothed mask (which put the borders of a one-pixel line 0.2 px into it)
        second = _most_frequent(np.where(v != best[:, None], v, -1))
        a, normal, trust, spread, grain = _read(comp, border, rgb, ys, xs, own, best)
        self.alpha[ys, xs] = a
        self.level[ys, xs] = 0.5 + _coverage_distance(a, normal)
        self._extrapolate(ys, xs, a, normal, own, best)
        self.trust[ys, xs] = trust
        self.near_trust = _max3(self.trust)
        # a border between two flat colours (a drawing's, not a photo's): every border pixel around
        # trusted and both sides without spread
        clean = np.zeros((H, W), bool)
        clean[ys, xs] = (trust >= 1.0) & (spread <= CLEAN_SPREAD)
        self.near_clean = _min3(clean | ~border) & _max3(clean)
        self.near_grain[ys, xs] = grain
        self.near_grain = _min3(self.near_grain)
        two = np.flatnonzero((second >= 0) & (a >= 1.0 - SATURATED))
        if two.size:
            self._read_second(comp, border, rgb, ys[two], xs[two], own[two], second[two])

    def _read_second(self, comp, border, rgb, ys, xs, own, across) -> None:
        """The reading of border pixels ``(ys, xs)`` against a second region ``across``, kept sparse
        (sorted flat indices, region across, level, trust): few pixels have one."""
        W = comp.shape[1]
        a, normal, trust, _, _ = _read(comp, border, rgb, ys, xs, own, across)
        whole = a >= 1.0 - SATURATED
        ys, xs, across, a, normal, trust = (v[whole] for v in (ys, xs, across, a, normal, trust))
        flat = ys.astype(np.int64) * W + xs
        order = np.argsort(flat, kind="stable")
        self._second = (flat[order], across[order].astype(np.int32), (0.5 + _coverage_distance(a, normal))[order],
                        trust[order])

    def _second_in(self, window: tuple[slice, slice], region: int):
        """The second readings against ``region`` in ``window``: ``((rows, cols) in the window, level,
        trust)``, or None."""
        if self._second is None:
            return None
        flat, across, level, trust = self._second
        H, W = self.level.shape
        r0, r1, _ = window[0].indices(H)
        c0, c1, _ = window[1].indices(W)
        lo, hi = np.searchsorted(flat, [r0 * W, r1 * W])
        y, x = np.divmod(flat[lo:hi], W)
        sel = np.flatnonzero((across[lo:hi] == region) & (x >= c0) & (x < c1))
        if sel.size == 0:
            return None
        return (y[sel] - r0, x[sel] - c0), level[lo:hi][sel], trust[lo:hi][sel]

    def _extrapolate(self, ys, xs, a, normal, own, across) -> None:
        """A pixel wholly on one side (alpha 0 or 1) only says its centre is at least the
        pixel's half width from the border; where a neighbour on the same border is
        partly covered, its distance carried along the normal says how far."""
        H, W = self.level.shape
        u = normal / np.maximum(np.hypot(normal[:, 0], normal[:, 1]), 1e-12)[:, None]
        partial = (a > SATURATED) & (a < 1.0 - SATURATED)
        full = ~partial
        if not full.any() or not partial.any():
            return
        index = np.full((H, W), -1, np.int64)
        index[ys, xs] = np.arange(len(ys))
        total = np.zeros(len(ys))
        weight = np.zeros(len(ys))
        fi = np.flatnonzero(full)
        fy, fx = ys[fi], xs[fi]
        for dy, dx in _NEIGHBOURS:
            qy, qx = fy + dy, fx + dx
            ok = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
            k = np.full(len(fy), -1, np.int64)
            k[ok] = index[qy[ok], qx[ok]]
            ok = k >= 0
            ok[ok] = partial[k[ok]]
            kk = k[ok]
            i = fi[ok]
            same = (own[kk] == own[i]) & (across[kk] == across[i])
            flip = (own[kk] == across[i]) & (across[kk] == own[i])
            use = same | flip
            kk, i = kk[use], i[use]
            sign = np.where(same[use], 1.0, -1.0)
            # the neighbour's distance from the border, towards its own side, carried to this pixel (offset -d)
            dist = self.level[ys[kk], xs[kk]] - 0.5 - (u[kk, 0] * dx + u[kk, 1] * dy)
            np.add.at(total, i, sign * dist)
            np.add.at(weight, i, 1.0)
        got = weight > 0
        est = total[got] / weight[got]
        cur = self.level[ys[got], xs[got]] - 0.5
        # keep the side the colour says, and at least the half width it implies
        est = np.where(np.sign(est) == np.sign(cur), np.where(np.abs(est) > np.abs(cur), est, cur), cur)
        self.level[ys[got], xs[got]] = 0.5 + est

    def field(self, comp: np.ndarray, region: int, window: tuple[slice, slice]) -> np.ndarray:
        """The membership field ``m`` of ``region`` in ``window`` (rows, cols) of the image."""
        # m = w read + (1 - w) smooth, worked out in place (a window may be the whole image)
        sub = comp[window] == region
        smooth = _gaussian(sub.astype(np.float64), SMOOTH_SIGMA)
        across = self.across[window]
        level = self.level[window]
        trust = self.trust[window]
        # read from the colour: own border pixels facing one region, and that region's facing back
        m = 1.0 - level
        np.copyto(m, level, where=sub)
        facing = np.where(sub, across >= 0, across == region)
        w = np.where(facing, trust, 0.0)
        del facing
        # a line one pixel wide between this region and another: its pixels, read against this region
        # too, say where this border is when their colour is wholly their own (then the two sides'
        # fields add up to 1 there, as where a pixel faces this region)
        second = self._second_in(window, region)
        if second is not None:
            (ry, rx), lv, tr = second
            m[ry, rx] = 1.0 - lv
            w[ry, rx] = tr
        m *= w
        np.subtract(1.0, w, out=w)
        w *= smooth
        m += w
        del w, smooth
        # away from the border the mask itself (the smoothing reaches 2 px into flat parts)
        out = sub.astype(np.float64)
        np.copyto(out, m, where=_grow(across >= 0))
        return out


def _max3(a: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.maximum_filter(a, size=3)`` (float64 or bool) by OpenCV's dilation: the same
    values (a 3 x 3 window's reflected pixels are its own), several times faster on a photo."""
    import cv2

    if a.dtype == bool:
        return cv2.dilate(np.ascontiguousarray(a).view(np.uint8), _SQUARE).view(bool)
    return cv2.dilate(a, _SQUARE)


def _min3(a: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.minimum_filter(a, size=3)`` (float or bool) by OpenCV's erosion (as :func:`_max3`)."""
    import cv2

    if a.dtype == bool:
        return cv2.erode(np.ascontiguousarray(a).view(np.uint8), _SQUARE).view(bool)
    return cv2.erode(a, _SQUARE)


def _grow(mask: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.binary_dilation(mask)`` (one step of the 4-neighbour cross) by OpenCV."""
    import cv2

    return cv2.dilate(np.ascontiguousarray(mask).view(np.uint8), _CROSS).view(bool)


_SQUARE = np.ones((3, 3), np.uint8)
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


def _gaussian(img: np.ndarray, sigma: float) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter(img, sigma, mode="nearest")`` (its kernel: radius ``4 sigma``,
    normalised) by OpenCV's separable filter, several times faster on a large window; the same
    values to rounding."""
    import cv2

    radius = int(4.0 * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 / float(sigma) ** 2 * x * x)
    k /= k.sum()
    return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REPLICATE)


def split_pinched(reading: BorderReading, comp: np.ndarray, regions: list[int],
                  boxes: list[tuple[slice, slice]]) -> np.ndarray | None:
    """Split the regions whose field falls apart into several parts.

    A region joined by a neck the colours say is thinner than half a pixel has
    a level-0.5 contour in two or more pieces, and an outline is one outer
    polygon: all but the largest piece would be lost (and with more than a
    quarter of its pixels, the region fell back to its staircase outline).
    Here each part of at least :data:`PINCHED_MIN` pixels becomes a region of
    its own; the region's pixels in no such part go to the nearest one.

    Parameters
    ----------
    reading : BorderReading
        Of ``comp``.
    comp : ndarray (H, W) int
        Region of every pixel, ``0 .. n-1``.
    regions, boxes : list
        Regions to look at and their bounding boxes (rows, columns).

    Returns
    -------
    ndarray (H, W) int32 or None
        ``comp`` with the new regions numbered from ``comp.max() + 1``, in the
        order of ``regions``; None when no region falls apart.
    """
    H, W = comp.shape
    out = None
    nxt = int(comp.max()) + 1
    for region, box in zip(regions, boxes):
        # the box and a pixel around it: a neck's parts are cut by the region's own field
        window = (slice(max(box[0].start - 1, 0), min(box[0].stop + 1, H)),
                  slice(max(box[1].start - 1, 0), min(box[1].stop + 1, W)))
        m = reading.field(comp, region, window)
        own = comp[window] == region
        parts, count = ndimage.label(m > 0.5)
        if count < 2:
            continue
        size = np.bincount(parts[own], minlength=count + 1)
        size[0] = 0
        kept = np.flatnonzero(size >= PINCHED_MIN)
        if kept.size < 2:
            continue
        # every pixel of the region to its nearest kept part
        seed = np.isin(parts, kept) & own
        _, (iy, ix) = ndimage.distance_transform_edt(~seed, return_indices=True)
        nearest = parts[iy, ix]
        if out is None:
            out = np.array(comp, np.int32)
        sub = out[window]
        order = kept[np.argsort(-size[kept], kind="stable")]
        for part in order[1:]:
            sub[own & (nearest == part)] = nxt
            nxt += 1
    return out


def _contours(reading: BorderReading, comp: np.ndarray, region: int,
              box: tuple[slice, slice]) -> list[np.ndarray] | None:
    """The level-0.5 contours of ``region``'s field, unsimplified: outer polygon (CCW) first, then holes (CW)."""
    import cv2
    from skimage.measure import find_contours

    H, W = comp.shape
    r0, r1 = max(box[0].start - 2, 0), min(box[0].stop + 2, H)
    c0, c1 = max(box[1].start - 2, 0), min(box[1].stop + 2, W)
    # beyond the image's frame the field carries on as it is at the frame (the
    # frame is no border: contours cross it straight and are cut there), and
    # everything is closed by a ring of zeros (one padded copy: P rows of the edge, then the ring)
    P = 3
    m = np.pad(reading.field(comp, region, (slice(r0, r1), slice(c0, c1))), P + 1, mode="edge")
    m[0] = m[-1] = 0.0
    m[:, 0] = m[:, -1] = 0.0
    if r0 > 0:
        m[1:P + 1] = 0.0
    if r1 < H:
        m[-P - 1:-1] = 0.0
    if c0 > 0:
        m[:, 1:P + 1] = 0.0
    if c1 < W:
        m[:, -P - 1:-1] = 0.0
    polys = []
    for con in find_contours(m, 0.5):
        if np.allclose(con[0], con[-1]):
            con = con[:-1]
        # field index (i, j) is pixel (r0 + i - P - 1, c0 + j - P - 1), whose centre is +0.5
        xy = np.stack([con[:, 1] + (c0 - P - 0.5), con[:, 0] + (r0 - P - 0.5)], axis=1)
        xy[:, 0] = np.clip(xy[:, 0], 0.0, float(W))
        xy[:, 1] = np.clip(xy[:, 1], 0.0, float(H))
        # points cut onto the frame repeat: keep one of each run
        step = np.any(xy != np.roll(xy, 1, axis=0), axis=1)
        xy = xy[step] if step.any() else xy[:1]
        if len(xy) < 3:
            continue
        polys.append(xy)
    if not polys:
        return None
    areas = [outline.signed_area(p) for p in polys]
    io = int(np.argmax(np.abs(areas)))
    outer = polys[io] if areas[io] > 0 else polys[io][::-1]
    ocv = outer.astype(np.float32).reshape(-1, 1, 2)
    holes = []
    for k, (p, a) in enumerate(zip(polys, areas)):
        if k == io or np.sign(a) == np.sign(areas[io]):
            continue
        if cv2.pointPolygonTest(ocv, (float(p[0, 0]), float(p[0, 1])), False) > 0:
            holes.append(p if outline.signed_area(p) < 0 else p[::-1])
    return [outer] + holes


def _tolerances(reading: BorderReading, p: np.ndarray, tolerance: float, W: int, H: int) -> np.ndarray:
    """RDP tolerance of every contour point: ``tolerance`` where the colours tell, the label map's half pixel where not."""
    cy, cx = _pixels_of(p, W, H)
    tol = tolerance + (LOOSE_TOLERANCE - tolerance) * (1.0 - reading.near_trust[cy, cx])
    # where a border meets the image's frame, and the frame's corners, stay where they are
    fx = (p[:, 0] == 0.0) | (p[:, 0] == W)
    fy = (p[:, 1] == 0.0) | (p[:, 1] == H)
    frame = fx | fy
    return np.where((fx & fy) | (frame & ~(np.roll(frame, 1) & np.roll(frame, -1))), 0.0, tol)


def _clean_points(reading: BorderReading, p: np.ndarray, W: int, H: int) -> np.ndarray:
    """Which contour points lie on a border between flat colours (:attr:`BorderReading.near_clean`)."""
    return reading.near_clean[_pixels_of(p, W, H)]


def _grain_floors(reading: BorderReading, p: np.ndarray, W: int, H: int) -> np.ndarray:
    """The least tolerance (px) of each contour point: the texture of the border's sides relative to
    its contrast (:attr:`BorderReading.near_grain`), at most :data:`TEXTURED_TOLERANCE`."""
    return np.minimum(reading.near_grain[_pixels_of(p, W, H)].astype(np.float64), TEXTURED_TOLERANCE)


def _pixels_of(p: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)`` of the pixel each contour point ``p`` (n, 2) lies in, clipped to the image."""
    return (np.clip(np.floor(p[:, 1]).astype(np.int64), 0, H - 1),
            np.clip(np.floor(p[:, 0]).astype(np.int64), 0, W - 1))


def _point_keys(polys: list[np.ndarray]) -> list[np.ndarray]:
    """Integer keys of contour points: the same point on both sides of a border, up to the
    last bits of the contour interpolation, gets the same key."""
    return [np.rint(p * 2**20).astype(np.int64) for p in polys]


def _free_runs(polys: list[np.ndarray], W: int, H: int):
    """Keys of every point, and every run of a contour that no other contour shares, off the frame.

    Returns ``(keys, [(polygon, run indices), ...])``.
    """
    from ..codec import chains

    keys = _point_keys(polys)
    part = chains.partners(keys)
    sizes = [len(p) for p in polys]
    cuts = chains.cuts(part, sizes)
    runs = []
    for i, p in enumerate(polys):
        n = sizes[i]
        c = cuts[i].tolist()
        if len(c) < 2:
            continue
        for a, b in zip(c, c[1:] + [n]):
            run = np.arange(a, b + 1) % n
            pts = p[run]
            if part[i][a, 0] >= 0 or (pts == 0.0).any() or (pts[:, 0] == W).any() or (pts[:, 1] == H).any():
                continue
            runs.append((i, run))
    return keys, runs


def _close_cycles(polys: list[np.ndarray], tols: list[np.ndarray], W: int,
                  H: int) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Where the contours around a spot part company, one region takes the spot.

    Near a junction, or where border pixels read their colour against
    another neighbour, contours leave their common curves for stretches of
    their own that close into a cycle around a sliver or a small triangle
    (uncovered, or covered twice): region A's stretch runs P1 -> P2, B's P2
    -> P3, ..., and the last one back to P1. The first region's stretch is
    replaced by the others' reversed, so that it takes the spot and every
    stretch is shared. Cycles around more than a thin spot (mean width over
    2 px) are left alone. Returns the contours, their tolerances and how many
    were changed.
    """
    keys, runs = _free_runs(polys, W, H)
    starting: dict = {}
    for k, (i, run) in enumerate(runs):
        starting.setdefault(tuple(keys[i][run[0]]), []).append(k)
    polys, tols = list(polys), list(tols)
    changed = set()
    for k0, (i0, run0) in enumerate(runs):
        first = tuple(keys[i0][run0[0]])
        cycle, cur = [k0], tuple(keys[i0][run0[-1]])
        while cur != first and len(cycle) <= 8:
            nxt = starting.get(cur, [])
            if len(nxt) != 1 or nxt[0] in cycle:
                break
            cycle.append(nxt[0])
            i, run = runs[nxt[0]]
            cur = tuple(keys[i][run[-1]])
        members = {runs[k][0] for k in cycle}
        if cur != first or len(cycle) < 2 or len(members) != len(cycle) or members & changed or \
                i0 != min(members):
            continue
        ring = np.concatenate([polys[runs[k][0]][runs[k][1][:-1]] for k in cycle])
        perimeter = float(np.hypot(*np.diff(np.vstack([ring, ring[:1]]), axis=0).T).sum())
        if abs(outline.signed_area(ring)) > perimeter + 2.0:
            continue
        # P1 -> P2 becomes P1 -> Pk -> ... -> P2: the other stretches, reversed, last first
        path = [polys[runs[k][0]][runs[k][1][::-1]] for k in cycle[:0:-1]]
        tpath = [tols[runs[k][0]][runs[k][1][::-1]] for k in cycle[:0:-1]]
        new = np.concatenate([path[0]] + [q[1:] for q in path[1:]])
        t_new = np.concatenate([tpath[0]] + [t[1:] for t in tpath[1:]])
        a, b = int(run0[0]), int(run0[-1])
        if b > a:
            polys[i0] = np.concatenate([polys[i0][:a], new, polys[i0][b + 1:]])
            tols[i0] = np.concatenate([tols[i0][:a], t_new, tols[i0][b + 1:]])
        else:
            # the stretch wraps past vertex 0: it becomes the polygon's start
            polys[i0] = np.concatenate([new, polys[i0][b + 1:a]])
            tols[i0] = np.concatenate([t_new, tols[i0][b + 1:a]])
        # the changed contours' other stretches were indexed before: one change per contour and pass
        changed |= members
    return polys, tols, len(changed)


def _close_junctions(polys: list[np.ndarray], tols: list[np.ndarray], W: int,
                     H: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Where three or more regions meet, all their contours through one point.

    Between two regions the contours coincide; where a third one is near,
    each region's contour leaves the shared curves for a short run of its own
    (the fields no longer add up to 1), and the runs of the regions around a
    junction leave a sliver uncovered or covered twice. Every such run,
    shorter than :data:`JUNCTION` px and off the image's frame, is replaced by
    one point that all the regions there share: where the lines of the curves
    coming into the junction cross (the mean of the runs' ends when they are
    near parallel).
    """
    keys, free = _free_runs(polys, W, H)
    sizes = [len(p) for p in polys]
    parent: dict = {}

    def find(k):
        while parent.setdefault(k, k) != k:
            k = parent[k]
        return k

    runs = []
    for i, run in free:
        if np.hypot(*np.diff(polys[i][run], axis=0).T).sum() > JUNCTION:
            continue
        ka, kb = tuple(keys[i][run[0]]), tuple(keys[i][run[-1]])
        parent[find(ka)] = find(kb)
        runs.append((i, run))
    if not runs:
        return polys, tols
    where: dict = {}
    for i, p in enumerate(polys):
        for j, k in enumerate(map(tuple, keys[i])):
            if k in parent:
                where.setdefault(find(k), []).append(p[j])
    # the curves coming into a junction, as lines: the last 2 JUNCTION px of contour before each run, the first
    # after; each with the tolerance of its points (a border the colours place, or one the label map places)
    lines: dict = {}
    for i, run in runs:
        p, n = polys[i], sizes[i]
        for end, step in ((run[0], -1), (run[-1], 1)):
            idx = (end + step * np.arange(min(n, 24))) % n
            k = _incoming(p[idx], bool(tols[i][idx[:3]].mean() <= 2 * TOLERANCE))
            if k >= 3:
                lines.setdefault(find(tuple(keys[i][end])), []).append((p[idx[:k]], float(tols[i][idx[:k]].mean())))
    # a cluster spread wider than a junction is several junctions chained by short runs: left alone
    centre = {root: _on_lattice(_meeting_point(lines.get(root, []), np.mean(pts, axis=0)), lines.get(root, []))
              for root, pts in where.items()
              if np.hypot(*(np.asarray(pts) - np.mean(pts, axis=0)).T).max() <= JUNCTION}
    drop = [np.zeros(n, bool) for n in sizes]
    for i, run in runs:
        if find(tuple(keys[i][run[0]])) in centre:
            drop[i][run[1:-1]] = True
    out_p, out_t = [], []
    for i, p in enumerate(polys):
        q = p.copy()
        at: dict = {}
        for j, k in enumerate(map(tuple, keys[i])):
            if k in parent and find(k) in centre:
                q[j] = centre[find(k)]
                at.setdefault(find(k), []).append(j)
        n = sizes[i]
        for js in at.values():
            # the contour passes the junction twice: what lies between, if short, is a loop
            a, b = js[0], js[-1]
            arc = np.arange(a, b + 1) if b - a <= n // 2 else np.arange(b, a + n + 1) % n
            if len(arc) > 2 and np.hypot(*np.diff(p[arc], axis=0).T).sum() <= 2 * JUNCTION:
                drop[i][arc[1:-1]] = True
        keep = ~drop[i]
        q, t = _drop_repeats(q[keep], tols[i][keep])  # a run's two ends became one point
        out_p.append(q)
        out_t.append(t)
    return out_p, out_t


def _on_lattice(x: np.ndarray, segments: list) -> np.ndarray:
    """A junction ``x`` whose incoming curves all run along pixel edges (each placed by the colours,
    every point within :data:`CAP_SLACK` of a pixel edge line it shares with the others: a label map's
    flat-colour drawing) put on the pixel corner those lines meet at, when it is that near it.

    The lines' least-squares crossing reads the colours around a corner of three regions, which pulls
    it by up to 0.06 px: a step of 1/16 px in a bar's side at each of its junctions.
    """
    if len(segments) < 2:
        return x
    corner = np.round(x)
    if np.abs(x - corner).max() > CAP_SLACK:
        return x
    for seg, tol in segments:
        # (the first point may lie in the junction's rounding)
        on_x = np.abs(seg[1:, 0] - corner[0]) <= CAP_SLACK
        on_y = np.abs(seg[1:, 1] - corner[1]) <= CAP_SLACK
        if tol > 2 * TOLERANCE or not (on_x.all() or on_y.all()):
            return x
    return corner


def _incoming(seg: np.ndarray, precise: bool) -> int:
    """How many leading points of ``seg`` (a contour leaving a junction) make the straight curve coming
    into it: at most 2 :data:`JUNCTION` px along the contour and, where the colours place it
    (``precise``), up to where it turns by more than :data:`CORNER_TURN` from its first stretch.

    Around a thin part (a bar 2 px wide) the contour turns back within that reach: its points there
    are near the junction but on another curve, and a line through them all crossed the others
    0.6 px inside the bar. A curve the label map places wavers by more than that turn on its own
    (a disc cut in two where the photo shows no edge): it keeps its points.
    """
    if len(seg) < 2:
        return len(seg)
    step = np.diff(seg, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*step.T))])
    k = int(np.searchsorted(arc, 2 * JUNCTION, side="right"))
    if not precise:
        return k
    # the first stretch: the chord to the second point on (the first point may lie in the junction's rounding)
    u = seg[min(2, k - 1)] - seg[0]
    nu = float(np.hypot(*u))
    if nu == 0.0:
        return k
    ns = np.hypot(*step[:k - 1].T)
    turned = step[:k - 1] @ u < np.cos(np.radians(CORNER_TURN)) * nu * np.maximum(ns, 1e-12)
    bad = np.flatnonzero(turned & (ns > 0))
    return k if bad.size == 0 else int(bad[0]) + 1


def _drop_repeats(p: np.ndarray, tol: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed contour and its points' tolerances without points equal to the one before (all of them
    kept when every point is the same)."""
    step = np.any(p != np.roll(p, 1, axis=0), axis=1)
    return (p[step], tol[step]) if step.any() else (p, tol)


def _meeting_point(segments: list, fallback: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to the lines through ``segments``; ``fallback`` when they are near parallel.

    The curves meeting at a junction are straight at this scale, and their
    lines cross where the regions' corner is; the junction zone's own points
    are pulled off it by the third region's colour. ``segments`` holds
    ``(points, tolerance)`` per curve. Where a precise curve runs on through
    the junction and every other border there is placed at least partly by
    the label map (:func:`_through_curve`), the junction is put on that curve.
    """
    x = _through_curve(segments, fallback)
    if x is None:
        A = np.zeros((2, 2))
        b = np.zeros(2)
        for seg, _ in segments:
            c = seg.mean(axis=0)
            _, _, vt = np.linalg.svd(seg - c)
            P = np.eye(2) - np.outer(vt[0], vt[0])
            A += P
            b += P @ c
        if len(segments) < 2 or np.linalg.cond(A) > 50.0:
            return fallback
        x = np.linalg.solve(A, b)
    # the lines are only a local reading: a point found far away is a misreading
    return x if np.hypot(*(x - fallback)) <= JUNCTION else fallback


def _through_curve(segments: list, near: np.ndarray) -> np.ndarray | None:
    """At a junction where a precise curve runs on (two of its curves leave in nearly opposite
    directions, turning by less than :data:`CORNER_TURN`, both placed by the colours) and every
    other curve there is placed at least partly by the label map, the point of the precise curve
    beside ``near`` (across it); None otherwise.

    There the lines of the two arcs cross outside the curve (by 0.14-0.21 px on
    a disc of radius 11) and the loose border's line is no help: a background
    cut in two where the photo shows no edge put the crossing 1.7 px from the
    junction, a notch 0.39 px deep in the disc's outline at 8x. The point is put
    on the parabola through both arcs' points.
    """
    # (two regions' contours bring the same curve: one line)
    distinct = {np.round(seg, 6).tobytes(): (seg, tol) for seg, tol in segments}.values()
    precise = [seg for seg, tol in distinct if tol <= 2 * TOLERANCE]
    if len(precise) != 2:
        return None  # no single precise curve through the junction: the lines decide
    a, b = precise
    da, db = a[-1] - a[0], b[-1] - b[0]
    if float(da @ db) > -np.cos(np.radians(CORNER_TURN)) * np.hypot(*da) * np.hypot(*db):
        return None  # the two precise curves make a corner
    pts = np.concatenate(precise)
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c)
    u, v = vt[0], vt[1]
    x, y = (pts - c) @ u, (pts - c) @ v
    coef = np.polyfit(x, y, 2) if np.ptp(x) > 0 else np.zeros(3)  # (each curve brings 3 points or more)
    xn = float((near - c) @ u)
    return c + xn * u + float(np.polyval(coef, xn)) * v


def _simplify_together(polys: list[np.ndarray], tols: list[np.ndarray],
                       cleans: list[np.ndarray] | None = None, floors: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """All contours simplified at once for drawing as curves, a border between two regions once for both.

    Two regions' contours along their common border pass through the same
    points (their fields add up to 1 there), in opposite directions. Each
    such run is simplified once and both sides keep the same points, so the
    outlines stay one curve (and the file stores it once, ``tpsv.codec.chains``).
    Each run is first smoothed (:func:`_smooth_run`; both sides take the
    smoothed points), then keeps the points whose curve
    (``tpsv.geometry.curves``: its ends and corners breaks) stays within each
    point's tolerance of all of them, added where the curve is farthest off
    (``curves.simplify_open``, from the run's ends), each point's tolerance at
    least its ``floors`` (:func:`_grain_floors`).
    """
    from ..codec import chains

    part = chains.partners(_point_keys(polys))
    sizes = [len(p) for p in polys]
    cuts = chains.cuts(part, sizes)
    keep = [np.zeros(n, bool) for n in sizes]
    done = [np.zeros(n, bool) for n in sizes]
    out = [p.copy() for p in polys]
    for i, p in enumerate(polys):
        # a loop between two regions lying on an ellipse: points on it, vertices spread evenly
        n = sizes[i]
        if not n or done[i].any() or _loop_partner(part[i]) < 0:
            continue
        found = _on_ellipse(p)
        if found is None:
            continue
        on, fit = found
        kept, at = _ellipse_vertices(on, fit)
        on[kept] = at
        q, j = (int(v) for v in part[i][-1])
        twin = (j + n - np.arange(n + 1)) % sizes[q]  # our vertex v (v = n is vertex 0) is q's vertex twin[v]
        out[i], keep[i][kept] = on, True
        out[q][twin] = on[np.arange(n + 1) % n]
        keep[q][twin[kept]] = True
        done[i][:] = done[q][:] = True
    for i, (p, tol) in enumerate(zip(polys, tols)):
        n = sizes[i]
        c = cuts[i].tolist()
        for a, b in zip(c, c[1:] + [n]):
            if done[i][a]:
                continue
            run = np.arange(a, b + 1)
            pts, t = _smooth_run(p[run % n], None if cleans is None else cleans[i][run % n]), tol[run % n]
            if floors is not None:
                t = np.maximum(t, floors[i][run % n])
            kept = run[curves.simplify_open(pts, t, np.array([0, len(pts) - 1]))]
            keep[i][kept % n] = True
            out[i][run % n] = pts
            q, j = (int(v) for v in part[i][b - 1])
            if q >= 0:
                # the twin run, in contour q, goes from our vertex b (its vertex j) back to our vertex a
                keep[q][(j + b - kept) % sizes[q]] = True
                out[q][(j + b - run) % sizes[q]] = pts
                done[q][j] = True
    return [p[k] for p, k in zip(out, keep)]


#: A border that closes on itself between two regions and no other (a disc, a ring's hole) whose
#: contour points lie this near one ellipse (px: root mean square, and every point) is drawn through
#: their projections onto it, when it has this many points and axes of at least a pixel.
CONIC_RMS, CONIC_MAX, CONIC_POINTS = 0.04, 0.1, 12


def _ellipse(p: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The ellipse ``(x - c)^T M (x - c) = 1`` through points ``p`` (n, 2) by algebraic least squares
    (Fitzgibbon's direct fit in Halir and Flusser's form, on the points centred and scaled), as
    ``(c, M)``; None when the best conic is no ellipse."""
    m = p.mean(axis=0)
    s = float(np.sqrt(((p - m) ** 2).sum(axis=1).mean()))
    if not s > 0:
        return None
    x, y = ((p - m) / s).T
    d1 = np.stack([x * x, x * y, y * y], axis=1)
    d2 = np.stack([x, y, np.ones_like(x)], axis=1)
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return None
    r = s1 + s2 @ t
    r = np.stack([r[2] / 2, -r[1], r[0] / 2])  # the constraint 4ac - b^2 = 1 folded in
    _, vecs = np.linalg.eig(r)
    vecs = np.real(vecs)
    ok = 4 * vecs[0] * vecs[2] - vecs[1] ** 2 > 0
    if not ok.any():
        return None
    a, b, c = vecs[:, np.flatnonzero(ok)[0]]
    d, e, f = t @ np.array([a, b, c])
    q = np.array([[a, b / 2], [b / 2, c]])
    try:
        centre = np.linalg.solve(2 * q, [-d, -e])
    except np.linalg.LinAlgError:
        return None
    level = -(centre @ q @ centre + d * centre[0] + e * centre[1] + f)
    if level == 0:
        return None
    shape = q / level
    if not (np.linalg.eigvalsh(shape) > 0).all():
        return None
    return m + s * centre, shape / (s * s)


def _on_ellipse(p: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None:
    """A closed contour's points moved onto the ellipse they lie near (:data:`CONIC_RMS`,
    :data:`CONIC_MAX`), each along the ray from its centre, and the ellipse (:func:`_ellipse`);
    None when they do not.

    Smoothing a run's points by a local cubic and keeping the points a curve needs drew small
    circles up to 0.13 px inside their contour points (a disc of radius 4 px, its points within
    0.02 px of the circle, rms): magnified 8x, faint flats along the rim.
    """
    if len(p) < CONIC_POINTS:
        return None
    fit = _ellipse(p)
    if fit is None:
        return None
    centre, shape = fit
    if np.linalg.eigvalsh(shape).max() > 1.0:  # an axis under a pixel
        return None
    d = p - centre
    k = np.sqrt(np.einsum("ni,ij,nj->n", d, shape, d))
    off = np.hypot(d[:, 0], d[:, 1]) * (1 - 1 / k)  # along the ray from the centre
    if np.sqrt((off ** 2).mean()) > CONIC_RMS or np.abs(off).max() > CONIC_MAX:
        return None
    return centre + d / k[:, None], fit


def _ellipse_loops(polys: list[np.ndarray]) -> set:
    """Indices of the contours that close on themselves between two regions and no other and lie on
    an ellipse (:func:`_on_ellipse`), both sides of each."""
    from ..codec import chains

    part = chains.partners(_point_keys(polys))
    out: set = set()
    for i, p in enumerate(polys):
        q = _loop_partner(part[i])
        if i not in out and q >= 0 and _on_ellipse(p) is not None:
            out |= {i, q}
    return out


def _loop_partner(edges: np.ndarray) -> int:
    """The one contour a contour shares all its edges with (``chains.partners`` of it), or -1."""
    if not len(edges) or edges[0, 0] < 0 or (edges[:, 0] != edges[0, 0]).any():
        return -1
    return int(edges[0, 0])


#: How far (px) the curve through a loop's vertices on an ellipse may pass from the ellipse.
CONIC_DRAWN = 0.01


def _ellipse_vertices(on: np.ndarray, fit: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices for a closed contour on the ellipse ``fit`` (:func:`_on_ellipse`): ``(indices, points)``, as few
    points on the ellipse, evenly spread in its eccentric angle (closer where it turns faster), as
    keep the closed curve through them (no breaks; :func:`tpsv.geometry.curves.densify`) within
    :data:`CONIC_DRAWN` of it; each takes the place of the contour point nearest it.

    The runs' simplification from their ends cannot know that the closed curve has no break there:
    through the 17 vertices it kept on the bench logo's ring (radius 11 px) the curve passed 0.08 px
    inside the circle next to the run's end.
    """
    n = len(on)
    centre, shape = fit
    inv, axes = np.linalg.eigh(shape)
    to_circle = (axes / np.sqrt(inv)).T  # the ellipse onto the unit circle
    from_circle = axes * np.sqrt(1 / inv)
    w = (on - centre) @ to_circle.T
    phase = np.unwrap(np.arctan2(w[:, 1], w[:, 0]))  # monotonic along a convex loop
    turn = 1.0 if phase[-1] > phase[0] else -1.0
    count = 12
    while 2 * count <= n:
        target = phase[0] + turn * 2 * np.pi * np.arange(count) / count
        v = centre + np.stack([np.cos(target), np.sin(target)], axis=1) @ from_circle.T
        d = curves.densify(v, np.zeros(count, bool), CONIC_DRAWN / 10) - centre
        off = np.hypot(d[:, 0], d[:, 1]) * (1 - 1 / np.sqrt(np.einsum("ni,ij,nj->n", d, shape, d)))
        if np.abs(off).max() <= CONIC_DRAWN:
            near = np.argmin(np.abs(turn * (phase[None, :] - target[:, None])), axis=1)
            if len(np.unique(near)) == count and (np.diff(near) > 0).all():
                return near, v
        count = int(np.ceil(count * 1.25))
    return np.arange(n), on


#: Savitzky-Golay window (contour points) and degree smoothing a run's reading noise before it is
#: simplified for a curve (a local cubic fit: a circle is not shrunk, as a Gaussian would).
SMOOTH_WINDOW, SMOOTH_DEGREE = 9, 3
#: Where a clean border (:attr:`BorderReading.near_clean`) turns by more than this (degrees) over the
#: window, it is smoothed over 5 points, by more than half of it over 7: a cubic over 9 points of a
#: small circle is not exact (the bench logo's ring hole, radius 5.5 px, read 0.08 px small where it
#: runs along the pixel axes, square at 8x), and a flat-colour border has little noise to smooth.
#: (Shortened on photos' borders too, their noise made them look curved: their borders lost 0.02-0.29
#: dB magnified; docs/DESIGN.md.)
SHORT_SMOOTH_TURN = 30.0
#: Largest spread (sRGB) of both sides' colours together for a border to be clean: flat colours.
CLEAN_SPREAD = 0.004


def _savgol_weights(window: int, degree: int) -> np.ndarray:
    """Savitzky-Golay smoothing weights: the value at the window's centre of the least-squares
    polynomial of ``degree`` through ``window`` points (``scipy.signal.savgol_coeffs(window, degree)``
    to the bit; that import alone, scipy.signal and scipy.stats with it, took 1-2 s of every
    command's start)."""
    half = window // 2
    x = np.arange(-half, window - half, dtype=float)[::-1]
    rhs = np.zeros(degree + 1)
    rhs[0] = 1.0
    return np.linalg.lstsq(x ** np.arange(degree + 1).reshape(-1, 1), rhs, rcond=None)[0]


_SMOOTH_WEIGHTS = _savgol_weights(SMOOTH_WINDOW, SMOOTH_DEGREE)
_SHORT_WEIGHTS = {k: _savgol_weights(k, SMOOTH_DEGREE) for k in (5, 7)}


def _smooth_run(p: np.ndarray, clean: np.ndarray | None = None) -> np.ndarray:
    """An open run of contour points smoothed along itself, its ends and corners kept where they are;
    points where ``clean`` (a border between flat colours) and the run turns fast are smoothed over
    fewer points (:data:`SHORT_SMOOTH_TURN`)."""
    n = len(p)
    if n < 5:
        return p
    pins = np.flatnonzero(curves.open_breaks(p))  # its ends and corners
    out = p.copy()
    r = SMOOTH_WINDOW // 2
    w = _SMOOTH_WEIGHTS
    for a, b in zip(pins[:-1], pins[1:]):
        seg = p[a:b + 1]
        if len(seg) <= r + 1:
            continue  # too short to smooth
        # reflected about the fixed ends (odd extension): the ends stay where they are
        ext = np.vstack([2 * seg[0] - seg[r:0:-1], seg, 2 * seg[-1] - seg[-2:-r - 2:-1]])
        sm = np.stack([np.convolve(ext[:, k], w, mode="valid") for k in range(2)], axis=1)
        if clean is not None and clean[a + 1:b].any():
            sm = _shorter(ext, sm, clean[a:b + 1], r)
        out[a + 1:b] = sm[1:-1]
    return out


def _shorter(ext: np.ndarray, sm: np.ndarray, clean: np.ndarray, r: int) -> np.ndarray:
    """``sm`` (a run's points smoothed over 9 points, ``ext`` the run extended by ``r`` a side) with its
    clean points where the smoothed run turns fast smoothed over 5 or 7 points instead."""
    s9 = np.vstack([ext[:r], sm, ext[-r:]])
    u, v = s9[2 * r:] - s9[r:-r], s9[r:-r] - s9[:-2 * r]
    cos = (u * v).sum(axis=1) / np.maximum(np.hypot(u[:, 0], u[:, 1]) * np.hypot(v[:, 0], v[:, 1]), 1e-12)
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    out = sm.copy()
    for k, limit in ((7, SHORT_SMOOTH_TURN / 2), (5, SHORT_SMOOTH_TURN)):
        h = k // 2
        e = ext[r - h:len(ext) - (r - h)]
        short = np.stack([np.convolve(e[:, c], _SHORT_WEIGHTS[k], mode="valid") for c in range(2)], axis=1)
        use = clean & (turn > limit)
        out[use] = short[use]
    return out


def _finish(polys: list[np.ndarray], comp: np.ndarray, region: int, box: tuple[slice, slice]) -> list[np.ndarray] | None:
    """Simplified contours on the file grid, or None when they would lose the region."""
    out = []
    for i, p in enumerate(polys):
        # on the file's grid already (_snap_to_grid): the encoder's scale-1 maps are then the
        # decoded file's; points that snapped onto each other are one
        s = p[np.any(p != np.roll(p, 1, axis=0), axis=1)]
        a = outline.signed_area(s)
        if len(s) < 3 or (a <= 0 if i == 0 else a >= 0):
            if i == 0:
                return None
            continue
        out.append(np.ascontiguousarray(s, np.float64))
    # the fitted outline must still hold the region (pixel centres, as the renderer samples them)
    sub = comp[box] == region
    got = outline._fill_polys(sub.shape, out, offset=(box[1].start, box[0].start)).astype(bool)
    n = int(sub.sum())
    lost = int(np.count_nonzero(sub & ~got))
    if not got[sub].any() or lost > 0.25 * n + 1:
        return None
    return out


def fitted_outlines(reading: BorderReading, comp: np.ndarray, regions: list[int],
                    boxes: list[tuple[slice, slice]], tolerance: float = TOLERANCE) -> list[list[np.ndarray] | None]:
    """Sub-pixel outlines of ``regions`` (outer polygon first, then holes; None where it would lose the region).

    Parameters
    ----------
    reading : BorderReading
    comp : ndarray (H, W) int
        Region of every pixel.
    regions : list of int
        Regions to outline (values of ``comp``).
    boxes : list of (slice, slice)
        Bounding box of each region's pixels (rows, columns).
    tolerance : float
        RDP tolerance where the colours tell where the border is, px.

    Returns
    -------
    list (one per region) of list of ndarray (k, 2) float64, or None
    """
    H, W = comp.shape
    raw = [_contours(reading, comp, r, box) for r, box in zip(regions, boxes)]
    flat = [p for polys in raw if polys for p in polys]
    tols = [_tolerances(reading, p, tolerance, W, H) for p in flat]
    # short stretches at junctions first (one point where the curves cross), then what is longer
    flat, tols = _close_junctions(flat, tols, W, H)
    for _ in range(8):
        flat, tols, changed = _close_cycles(flat, tols, W, H)
        if not changed:
            break
    flat, tols = _pin_crossings(flat, tols, comp)
    # a loop on an ellipse has no corner: a small or thin one turns fast enough for the corner test
    flat, tols = _sharpen_corners(flat, tols, W, H, tolerance, skip=_ellipse_loops(flat))
    simple = _simplify_together(flat, tols, [_clean_points(reading, p, W, H) for p in flat],
                                [_grain_floors(reading, p, W, H) for p in flat])
    # where only the smoothed mask speaks, the border is known to half a pixel: a coarser grid there
    steps = [np.where(_tolerances(reading, q, tolerance, W, H) > 2 * tolerance, LOOSE_STEP, 1) for q in simple]
    simple = iter(_snap_to_grid(simple, W, H, steps))
    done = [None if polys is None else _finish([next(simple) for _ in polys], comp, r, box)
            for polys, r, box in zip(raw, regions, boxes)]
    return _drop_orphan_holes(done, boxes)


#: How near (px, each axis) a contour point must be to a crossing of four regions to be put on it: the
#: crossing is then the pixel corner nearest the point.
CROSSING = 0.5


def crossings(comp: np.ndarray) -> np.ndarray:
    """Pixel corners ``(x, y)`` (k, 2) where four regions meet crosswise: every side of the corner a border.

    Parameters
    ----------
    comp : ndarray (H, W) int
        Region of every pixel.
    """
    a, b, c, d = comp[:-1, :-1], comp[:-1, 1:], comp[1:, :-1], comp[1:, 1:]
    ys, xs = np.nonzero((a != b) & (a != c) & (d != b) & (d != c))
    return np.stack([xs + 1.0, ys + 1.0], axis=1)


def _pin_crossings(polys: list[np.ndarray], tols: list[np.ndarray], comp: np.ndarray):
    """Every contour point within :data:`CROSSING` px (each axis) of a crossing of four regions put on it.

    Where four regions meet crosswise (a grid, a checkerboard) the two
    diagonal regions touch at a point only: the membership fields form a
    saddle there, and the contours of the diagonal pair cut across it each
    their own way, a loop no junction rule closes (a notch and a slanted
    border when magnified). The crossing is the pixel corner, as the label
    map has it; consecutive points that land on it become one.
    """
    pts = crossings(comp)
    if not len(pts):
        return polys, tols
    row = comp.shape[1] + 1
    known = pts[:, 1].astype(np.int64) * row + pts[:, 0].astype(np.int64)
    out_p, out_t = [], []
    for p, t in zip(polys, tols):
        corner = np.rint(p)  # each point's nearest pixel corner (contour points lie within the frame)
        hit = np.isin(corner[:, 1].astype(np.int64) * row + corner[:, 0].astype(np.int64), known)
        if hit.any():
            p = p.copy()
            p[hit] = corner[hit]
            p, t = _drop_repeats(p, t)
        out_p.append(p)
        out_t.append(t)
    return out_p, out_t


#: How far (px) a region filling a hole may reach beyond the hole's bounding box (its fitted outline, or its
#: pixels where it has none).
HOLE_SLACK = 1.5


def _drop_orphan_holes(outlines: list, boxes: list[tuple[slice, slice]]) -> list:
    """Each region's holes that no other region fills, left out (the region covers them).

    A hole of a region's field is another region's outline only where that
    region lies wholly inside it; a thin spur of a neighbour that its own field
    pinches off (noise along a border) leaves a hole in this region that nobody
    fills: a gap in the picture, and a file the decoder refuses when such holes
    outnumber the regions. A hole is kept when some other region lies
    within its bounding box, give or take :data:`HOLE_SLACK`: its fitted outer
    polygon, or its pixels where it has no fitted outline (``boxes``).
    """
    lo = np.array([[b[1].start, b[0].start] if p is None else p[0].min(0) for p, b in zip(outlines, boxes)], np.float64)
    hi = np.array([[b[1].stop, b[0].stop] if p is None else p[0].max(0) for p, b in zip(outlines, boxes)], np.float64)
    out = []
    for r, polys in enumerate(outlines):
        if polys is None or len(polys) == 1:
            out.append(polys)
            continue
        keep = [polys[0]]
        for hole in polys[1:]:
            inside = np.all(lo >= hole.min(0) - HOLE_SLACK, axis=1) & np.all(hi <= hole.max(0) + HOLE_SLACK, axis=1)
            inside[r] = False
            if inside.any():
                keep.append(hole)
        out.append(keep)
    return out


#: Farthest (px along the contour) :func:`_sharpen_corners` looks from a corner: its longest run.
_CORNER_REACH = max(max(far for _, far in CORNER_RUNS), 2 * CORNER_ARM)


def _within_arc(ext: np.ndarray, n: int, at: float, total: float) -> np.ndarray:
    """Indices (ascending) of the vertices of a closed contour of ``n`` vertices and perimeter ``total``
    that lie within a little more than :data:`_CORNER_REACH` of arc position ``at`` (either way
    round); ``ext`` is the arc of the vertices three times over, shifted by ``-total``, 0 and ``total``."""
    reach = _CORNER_REACH + 1.0
    if 2 * reach >= total:
        return np.arange(n)
    lo, hi = np.searchsorted(ext, [at - reach, at + reach])
    return np.unique(np.arange(lo, hi) % n)


def _arc(p: np.ndarray) -> np.ndarray:
    """Arc length at each vertex of a closed polygon, then the perimeter."""
    seg = np.diff(np.vstack([p, p[:1]]), axis=0)
    return np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])


def _line(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares line through points: a point on it, its unit direction, and the largest distance from it."""
    q = q[np.lexsort((q[:, 1], q[:, 0]))]  # either direction of a shared border gives the same line
    c = q.mean(axis=0)
    _, _, vt = np.linalg.svd(q - c, full_matrices=False)
    u = vt[0]
    off = q - c
    return c, u, float(np.abs(off[:, 0] * u[1] - off[:, 1] * u[0]).max())


def _sharpen_corners(polys: list[np.ndarray], tols: list[np.ndarray], W: int, H: int,
                     tolerance: float, skip: set | frozenset = frozenset()) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Corners the contours rounded off, put back where the straight borders meet.

    The field is a distance to one straight border, which a pixel at a corner
    is not: the contour cuts the corner by up to a pixel. Where a contour turns
    by more than :data:`CORNER_TURN` degrees (over :data:`CORNER_ARM` px) between
    two runs that are straight (within :data:`CORNER_STRAIGHT` px, over one of
    the stretches of :data:`CORNER_RUNS`), shared with
    one other region and read from the colours, the points in between are
    replaced by the crossing of the two runs' lines, in both regions' contours. Contours in
    ``skip`` are left as they are.
    """
    from ..codec import chains

    keys = _point_keys(polys)
    part = chains.partners(keys)
    # points on three contours or more (junctions, which the junction closing placed): a corner there
    # would move them in two of the regions only
    allk = np.concatenate(keys) if keys else np.zeros((0, 2), np.int64)
    uk, nk = np.unique(allk, axis=0, return_counts=True)
    junctions = {tuple(k) for k in uk[nk >= 3]}
    edits: dict[int, list[tuple[set, np.ndarray]]] = {}
    claimed: set = set()

    def claim(i: int, zone: np.ndarray, twin: int, corner: np.ndarray) -> None:
        # the zone's points go to the corner in both regions' contours, unless another edit or a
        # junction has them
        zkeys = {tuple(k) for k in keys[i][zone]}
        if zkeys & claimed or zkeys & junctions:
            return
        claimed.update(zkeys)
        for j in (i, twin):
            edits.setdefault(j, []).append((zkeys, corner))

    for i, p in enumerate(polys):
        n = len(p)
        if n < 12 or i in skip:
            continue
        s = _arc(p)
        total = s[-1]
        ext = np.concatenate([s[:-1] - total, s[:-1], s[:-1] + total])
        px, py = np.tile(p[:, 0], 3), np.tile(p[:, 1], 3)

        def at(arc):
            return np.stack([np.interp(arc, ext, px), np.interp(arc, ext, py)], axis=1)

        b = p - at(s[:-1] - CORNER_ARM)
        a = at(s[:-1] + CORNER_ARM) - p
        cos = (a * b).sum(axis=1) / np.maximum(np.hypot(*a.T) * np.hypot(*b.T), 1e-12)
        turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        # points within 2 CORNER_ARM (along the contour) of a corner taken: no second corner there
        blocked = np.zeros(n, bool)
        for c in np.argsort(-turn):
            if turn[c] < CORNER_TURN:
                break
            if blocked[c]:
                continue
            # everything below looks at most _CORNER_REACH px along the contour from the corner: the
            # points there, in index order (a long contour has thousands of candidates)
            win = _within_arc(ext, n, s[c], total)
            rel = (s[win] - s[c] + total / 2) % total - total / 2  # signed arc from the corner
            blocked[win[np.abs(rel) < 2 * CORNER_ARM]] = True
            # the runs either side: long ones first (the rounding can reach 2-3 px along
            # the sides of a sharp corner), short ones for small shapes
            for near, far in CORNER_RUNS:
                side_b = win[(rel > -far) & (rel < -near)]
                side_a = win[(rel > near) & (rel < far)]
                if len(side_b) < 3 or len(side_a) < 3 or total < 4 * far:
                    continue
                cb, ub, eb = _line(p[side_b])
                ca, ua, ea = _line(p[side_a])
                if max(eb, ea) <= CORNER_STRAIGHT:
                    break
            else:
                continue
            if abs(ub[0] * ua[1] - ub[1] * ua[0]) < np.sin(np.radians(CORNER_TURN)):
                continue
            # the crossing: cb + ub x = ca + ua y
            x = np.linalg.solve(np.array([ub, -ua]).T, ca - cb)[0]
            corner = _on_lattice(cb + ub * x, [(p[side_b], 0.0), (p[side_a], 0.0)])
            # a rounded corner (a button's, radius 2.5 px and up) lies farther inside than the reading
            # rounds a sharp one (at most 0.92 px at right angles on the bench's shapes)
            depth = CORNER_DEPTH_RIGHT if abs(float(ub @ ua)) < np.cos(np.radians(70.0)) else CORNER_DEPTH
            if np.hypot(*(corner - p[c])) > depth or not (0 < corner[0] < W and 0 < corner[1] < H):
                continue
            # the points the rounding moved off the two lines
            q = p[win]
            db = np.abs((q - cb)[:, 0] * ub[1] - (q - cb)[:, 1] * ub[0])
            da = np.abs((q - ca)[:, 0] * ua[1] - (q - ca)[:, 1] * ua[0])
            # from the farthest point before the corner that is off its line to the farthest after
            off_b = win[(rel > -far) & (rel <= 0) & (db > CORNER_ON_LINE)]
            off_a = win[(rel < far) & (rel >= 0) & (da > CORNER_ON_LINE)]
            lo = c - int(((c - off_b) % n).max(initial=0))
            hi = c + int(((off_a - c) % n).max(initial=0))
            zone = np.arange(lo, hi + 1) % n
            around = np.arange(lo - len(side_b), hi + len(side_a) + 1) % n
            twin = part[i][around[:-1], 0]
            if (twin < 0).any() or (twin != twin[0]).any() or (tols[i][around] > 1.5 * tolerance).any():
                continue
            claim(i, zone, int(twin[0]), corner)
    # the ends of bars one to four pixels wide: their corners have no straight run on the short side
    for i, p in enumerate(polys):
        if i in skip:
            continue
        for zone, corners in _caps(p, tols[i], tolerance):
            twin = part[i][zone, 0]  # the edges from the zone's points on: the cap and the runs' last steps
            if (twin < 0).any() or (twin != twin[0]).any():
                continue
            claim(i, zone, int(twin[0]), corners)
    polys, tols = list(polys), list(tols)
    for j, todo in edits.items():
        kj = [tuple(k) for k in keys[j]]
        p, t = polys[j], tols[j]
        drop = np.zeros(len(p), bool)
        first: dict[int, np.ndarray] = {}
        for zkeys, corner in todo:
            idx = np.array([k in zkeys for k in kj])
            if not idx.any():
                continue
            # where the run starts, going round (the zone may wrap past vertex 0)
            start = int(np.flatnonzero(idx & ~np.roll(idx, 1))[0])
            drop |= idx
            corner = np.asarray(corner, np.float64).reshape(-1, 2)
            # several corners go in the contour's own direction: the nearest to the point before first
            first[start] = corner[np.argsort(np.hypot(*(corner - p[start - 1]).T), kind="stable")]
        new_p, new_t = [], []
        for k in range(len(p)):
            if k in first:
                new_p.extend(first[k])
                new_t.extend([0.0] * len(first[k]))
            if not drop[k]:
                new_p.append(p[k])
                new_t.append(t[k])
        polys[j], tols[j] = np.array(new_p), np.array(new_t)
    return polys, tols


#: Longest cap (unit steps between its two cuts) :func:`_caps` squares: the end of a bar up to 4 px wide.
CAP_STEPS = 3
#: How far (px) a contour step may be from a unit step or a 45-degree cut of the pixel lattice and count as
#: one (the reading bends the last pixel of a bar 1 px wide by 0.08 px).
CAP_SLACK = 0.1


def _edge_line(v: np.ndarray) -> float:
    """The coordinate of the straight run through values ``v``: the pixel edge (an integer) their mean is
    within :data:`CAP_SLACK` of, else the mean."""
    m = float(np.mean(v))
    return float(round(m)) if abs(m - round(m)) <= CAP_SLACK else m


def _caps(p: np.ndarray, tol: np.ndarray, tolerance: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The square ends of bars in a contour: ``(zone, corners)``, the contour points to replace and
    the cap's two corners.

    A label map's bar 1-4 px wide ends in a cap: a straight run along one axis,
    a cut of 45 degrees, 0-3 unit steps along the other axis, a cut, and a run
    back the opposite way (the runs at least 2 unit steps, every point placed
    by the colours). Marching squares cut both corners, and the short cap gives
    the corner test of :func:`_sharpen_corners` no straight run on its side,
    so the bar ended in a round blob at 8x. Each corner is put where the side's
    line meets the cap's, in place of the cap and the sides' last two points
    (the reading bends a bar's sides by up to 0.08 px next to its end). A
    staircase (runs the same way) is no cap.
    """
    n = len(p)
    if n < 8:
        return []
    step = np.roll(p, -1, axis=0) - p  # step k: point k -> k + 1
    a = np.abs(step)

    def near(v, x):
        return np.abs(v - x) <= CAP_SLACK

    unit = (near(a[:, 0], 1.0) & near(a[:, 1], 0.0), near(a[:, 1], 1.0) & near(a[:, 0], 0.0))  # along x, along y
    cut = near(a[:, 0], 0.5) & near(a[:, 1], 0.5)
    precise = tol <= 1.5 * tolerance
    out = []
    for k in np.flatnonzero(cut):
        for m in range(CAP_STEPS + 1):
            k2 = (k + m + 1) % n
            if not cut[k2]:
                continue
            before = np.array([k - 2, k - 1]) % n
            after = np.array([k2 + 1, k2 + 2]) % n
            cap = (k + 1 + np.arange(m)) % n
            span = (k - 2 + np.arange(m + 7)) % n  # every point from the run before to the run after
            for side in (0, 1):  # the runs along x (0) or y (1), the cap along the other
                if not (unit[side][before].all() and unit[side][after].all() and unit[1 - side][cap].all()):
                    continue
                sb, sa = np.sign(step[before, side]), np.sign(step[after, side])
                if (sb != sb[0]).any() or (sa != sa[0]).any() or sb[0] == sa[0]:
                    continue
                if m and (np.sign(step[cap, 1 - side]) != np.sign(step[cap[0], 1 - side])).any():
                    continue
                if not precise[span].all():
                    continue
                # the sides' lines (constant coordinate 1 - side) and the cap's (constant coordinate side),
                # on the pixel edge they run along (the reading bends the last pixel of a thin bar inwards)
                line_b = _edge_line(p[np.array([k - 2, k - 1, k]) % n, 1 - side])
                line_a = _edge_line(p[np.array([k2 + 1, k2 + 2, k2 + 3]) % n, 1 - side])
                cap_line = _edge_line(p[(k + 1 + np.arange(m + 1)) % n, side])
                c1, c2 = np.empty(2), np.empty(2)
                c1[1 - side], c1[side] = line_b, cap_line
                c2[1 - side], c2[side] = line_a, cap_line
                # the runs' last two points go too: the reading bends a bar's sides next to its end
                out.append((span, np.array([c1, c2])))
            break
    return out


def _snap_to_grid(polys: list[np.ndarray], W: int, H: int, steps: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Vertices on the file's 1/GRID px grid (every ``steps``-th point of it), each moved to where its border is.

    Plain rounding shifts a vertex across its border by up to half a grid step
    (0.036 px rms at 1/8), which is most of the error left on a clean edge. Along
    the border a vertex may slide freely, so each vertex where the outline runs
    on smoothly takes, of the 3 x 3 grid points around it, the one nearest to
    the line through it along the outline (sliding is charged a little, so a
    vertex stays put when nothing is to gain). Corners, junctions and the
    frame's points are rounded. Both sides of a shared border see the same line
    and choose alike; a vertex that would still come out differently in two
    outlines is rounded in all of them.
    """
    offsets = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], np.float64)
    if steps is None:
        steps = [np.ones(len(p)) for p in polys]
    chosen, rounded = [], []
    for p, step in zip(polys, steps):
        step = np.asarray(step, np.float64)[:, None]
        base = np.round(p * GRID / step) * step
        rounded.append(base)
        before, after = p - np.roll(p, 1, axis=0), np.roll(p, -1, axis=0) - p
        lb = np.hypot(before[:, 0], before[:, 1])
        la = np.hypot(after[:, 0], after[:, 1])
        smooth = (before * after).sum(axis=1) > np.cos(np.radians(SNAP_TURN)) * lb * la
        smooth &= (p[:, 0] > 0) & (p[:, 0] < W) & (p[:, 1] > 0) & (p[:, 1] < H)
        # the line's direction, the same either way round up to its sign
        t = before / np.maximum(lb, 1e-12)[:, None] + after / np.maximum(la, 1e-12)[:, None]
        t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
        cand = base[:, None, :] + offsets[None] * step[:, None]
        off = cand / GRID - p[:, None, :]
        across = np.abs(off[..., 0] * t[:, None, 1] - off[..., 1] * t[:, None, 0])
        along = np.abs(off[..., 0] * t[:, None, 0] + off[..., 1] * t[:, None, 1])
        best = np.argmin(across + SNAP_SLIDE * along, axis=1)
        q = np.where(smooth[:, None], cand[np.arange(len(p)), best], base)
        chosen.append(q)
    # a vertex shared by outlines that disagree is rounded in all of them
    picks: dict = {}
    keys = _point_keys(polys)
    for k, q in zip(keys, chosen):
        for key, v in zip(map(tuple, k), map(tuple, q)):
            picks.setdefault(key, set()).add(v)
    out = []
    for k, q, base in zip(keys, chosen, rounded):
        torn = np.array([len(picks[key]) > 1 for key in map(tuple, k)], bool)
        q = np.where(torn[:, None], base, q)
        out.append(q / GRID)
    return out


__all__ = ["BorderReading", "CONTRAST", "LOOSE_TOLERANCE", "PlaneFit", "SMOOTH_SIGMA", "TOLERANCE", "WINDOW", "fitted_outlines",
           "own_side_colours"]
