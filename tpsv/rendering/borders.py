"""Anti-aliased region borders (render step 5): how much of a pixel the border leaves to the region across.

This module is the rule and its host reference implementation; the renderer
runs the same rule as a Warp kernel (:mod:`tpsv.gpu.coverage`, on the CPU and
CUDA devices alike), and the tests hold the two to each other.

The region map gives every output pixel one region, sampled at its centre
(:mod:`tpsv.rendering.pixelmap`), which alone draws a border as a staircase of
whole pixels. Here every pixel near a border gets its coverage instead: with
``d`` the distance (in output pixels) from the pixel centre to the nearest
outline, the pixel's own region covers ``alpha = min(1, 0.5 + d)`` of it and
the region across the border the rest. That is the exact area coverage of a
pixel by a straight border parallel to a pixel side (a box filter), so the
coverages of two pixels facing each other across a border add up to 1; the
colour across is that region's own TPS, evaluated a little beyond its outline
(``(S, T)`` of the pixel in its patch). Borders with the image frame are not
outlines anybody crosses: they stay sharp.

A border with an edge width (``Model.blur``: the Gaussian ``sigma`` of a
defocused edge, source pixels) is a blurred step: ``alpha`` is the box
filter of the step convolved with that Gaussian (``sigma`` times the scale,
in output pixels), and pixels up to ``0.5 + 3 sigma`` output pixels from the
border mix. A soft edge stays as soft, relative to the picture, at any scale;
a sharp one stays one output pixel wide. A model with a blur map
(``Model.blur_map``) has a width per point of its borders instead: the map's
bilinear sample at the border point nearest the pixel (:func:`blur_at`).

Outlines are cut into pieces of at most :data:`PIECE_PX` output pixels
(longer when an output would need more than :data:`MAX_PIECES`), whose
midpoints go into a k-d tree; each border pixel measures its exact distance
to the :data:`NEAREST` nearest pieces. The region across is the one found
just beyond the nearest outline (else the pixel's nearest 8-neighbour of
another region), so junctions of three regions mix the right pair. A piece
with the pixel's own region beyond it is no border for that pixel (unless
within 0.75 px of a pixel next to another region): an outline may hold a
spike or sliver thinner than an output pixel, which no pixel centre
samples, and measuring to it would leave a wedge of unmixed pixels in a
blurred border.

A pixel also mixes the region across a second border, the nearest piece
with a third region beyond (:func:`shares`): a sliver region narrower than
its edges are wide then mixes both neighbours alike on both sides of its
middle, and a pixel beside it sees the region beyond it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from ..geometry import curves
from ..geometry.edgewidth import map_at

#: Longest outline piece, output pixels.
PIECE_PX = 1.0
#: Most outline pieces held for one output (bounds memory: about 100 bytes each while built).
MAX_PIECES = 1 << 21
#: Pieces measured per border pixel.
NEAREST = 8
#: Least share of a pixel a second border's region takes (less is left out: the search for a second
#: border covers every piece within its reach, so its reach is kept short).
SECOND_LEAST = 1.0 / 512.0
#: Cell side (output px) of the region masks that tell which pixels may have a second border (:func:`third_near`).
MASK_CELL = 8
#: Most pieces one search for a border measures, and most near pieces it may find no border (their
#: own region beyond) before it gives up: outlines folded over a few pixels, as a hostile file may
#: have them, get an answer rather than a hang; real outlines stay far below.
MAX_VISIT = 4096
MAX_REJECTED = 512
#: Pieces measured per pixel off the 8-neighbours of a blurred border (the far tail varies slowly).
FAR_NEAREST = 4


@dataclass
class BorderMix:
    """The border pixels of a frame or band and what mixes into them.

    Attributes
    ----------
    pixels : ndarray (n,) int32
        Flat indices ``y * W + x`` into the band.
    other : ndarray (n,) int32
        Region across the border.
    alpha : ndarray (n,) float32
        Share of the pixel its own region keeps against the region across
        (its coverage, in ``[0.5, 1)``, where ``other2`` is -1).
    xy : ndarray (n, 2) float64
        Pixel centres in the model's pixel space.
    other2 : ndarray (n,) int32
        Region across a second border (a sliver's other side, the region
        beyond a sliver), or -1.
    alpha2 : ndarray (n,) float32
        Share the pixel keeps against ``other2`` (1 without one): the
        colour is ``alpha2 * (alpha * own + (1 - alpha) * across) + (1 -
        alpha2) * across2`` (:func:`shares`).
    """

    pixels: np.ndarray
    other: np.ndarray
    alpha: np.ndarray
    xy: np.ndarray
    other2: np.ndarray | None = None
    alpha2: np.ndarray | None = None

    def __post_init__(self):
        if self.other2 is None:
            self.other2 = np.full(len(self.pixels), -1, np.int32)
        if self.alpha2 is None:
            self.alpha2 = np.ones(len(self.pixels), np.float32)

    @property
    def own(self) -> np.ndarray:
        """Share of each pixel its own region covers."""
        return self.alpha * self.alpha2

    @classmethod
    def none(cls) -> "BorderMix":
        return cls(np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros((0, 2)))


def shares(c1: np.ndarray, c2: np.ndarray, dot: np.ndarray, nested=None) -> tuple[np.ndarray, np.ndarray]:
    """How a pixel mixes the regions across its two nearest borders: ``(alpha, alpha2)`` of :class:`BorderMix`.

    ``c1`` and ``c2`` are the coverages each border alone leaves the pixel
    (:meth:`Borders._coverage`; border 1 the nearer), ``dot`` the cosine of
    the angle between the directions from the pixel to the two borders,
    ``nested`` from 0 to 1 how far border 2 is the far side of the region
    across border 1 (:func:`depth`; default 1).

    Where border 2 is beyond the region across border 1 (a sliver), the
    region across border 2 takes ``1 - c2`` of the pixel; the one across
    border 1 takes ``1 - c1`` where the borders face each other (``dot =
    -1``: the pixel's region is a strip between them, exact for a blurred
    strip), ``c2 - c1`` where border 2 is the far side of the region across
    border 1 (``dot = 1``), linearly between; the pixel's own region the
    rest. So a sliver region narrower than its edges are wide mixes both
    neighbours, the same on both sides of its middle, and a pixel beside it
    sees the region beyond it too.

    Where the two borders meet (``nested`` 0: a junction of three regions,
    the second border running through the first's line), the two regions
    across are treated alike: each takes its own ``1 - c`` less half the
    part where the two half-planes overlap (``(1 + dot) / 2`` of the
    smaller); between the two cases, linearly in ``nested``. Which border
    is "first" flips along the line where they are equally near; with the
    sliver's rule everywhere the two regions' shares swapped there from one
    pixel to the next (a hard seam below a junction).

    Returns
    -------
    alpha, alpha2 : ndarray
        Composited in two steps: ``alpha2 * (alpha * own + (1 - alpha) * across)
        + (1 - alpha2) * across2``.
    """
    w = 0.5 * (1.0 + dot)
    nu = 1.0 if nested is None else nested
    b1, b2 = 1.0 - c1, 1.0 - c2
    half = 0.5 * np.minimum(b1, b2)
    s2 = b2 - (1.0 - nu) * w * half
    s1 = np.maximum(0.0, b1 - w * (nu * b2 + (1.0 - nu) * half))
    a2 = 1.0 - s2
    return 1.0 - s1 / np.maximum(a2, 1e-12), a2


def nest_scale(kx: float, ky: float) -> float:
    """The ``scale`` of :func:`depth` at output scales ``kx``, ``ky``: one model pixel (outlines are traced
    at the model's pixels, and the corners where they meet are good to about that)."""
    return 0.5 * (kx + ky)


def depth(f1: np.ndarray, f2: np.ndarray, n1: np.ndarray, scale: float) -> np.ndarray:
    """``nested`` of :func:`shares`: how far the second border's foot ``f2`` lies beyond the line of the
    first border (its foot ``f1``, the unit direction across ``n1``), in units of ``scale`` (about a
    model pixel in output pixels), clipped to ``[0, 1]``.

    A sliver's far side lies a band's width beyond its near side: 1. The borders
    meeting at a junction run through the same point: 0 there, whichever
    border is the nearer (the feet do not depend on which of two pieces
    meeting at a vertex a search takes, so neither does this).
    """
    return np.clip(((f2 - f1) * n1).sum(-1) / scale, 0.0, 1.0)


def near_cells(reach: float) -> tuple[int, int]:
    """``(cell, k)`` of :func:`third_near` for a search ``reach`` (output px): cells of :data:`MASK_CELL`
    pixels, ``k`` cells each side covering the reach and the pixel a point beyond it falls in."""
    return MASK_CELL, int(np.ceil((reach + 1.0) / MASK_CELL))


def third_near(index: np.ndarray, cell: int, k: int, rows: np.ndarray, cols: np.ndarray, mine: np.ndarray,
               other: np.ndarray) -> np.ndarray:
    """Whether a region other than ``mine`` and ``other`` may have a pixel within ``k`` cells of each pixel.

    Each cell of ``cell x cell`` pixels of the region map ``index`` gets a
    64-bit mask of its regions (bit ``r % 64``: two regions may share a
    bit, so the answer errs only towards yes); a pixel reads the union of
    the masks of the cells within ``k`` of its own. The device keeps such
    masks per search cell (``tpsv.gpu.coverage._cell_regions``, ``_gather_masks``).

    Parameters
    ----------
    index : ndarray (h, W) int32
        Regions (-1: none).
    cell, k : int
        From :func:`near_cells`.
    rows, cols : ndarray (n,) int
        Pixels, rows of ``index``.
    mine, other : ndarray (n,) int
        Their regions and the regions across.

    Returns
    -------
    ndarray (n,) bool
    """
    h, W = index.shape
    gh, gw = -(-h // cell), -(-W // cell)
    pad = np.full((gh * cell, gw * cell), -1, np.int64)
    pad[:h, :W] = index
    bits = np.where(pad >= 0, np.left_shift(np.uint64(1), (pad % 64).astype(np.uint64)), np.uint64(0))
    masks = np.bitwise_or.reduce(bits.reshape(gh, cell, gw, cell), axis=(1, 3))
    wide = np.zeros((gh + 2 * k, gw + 2 * k), np.uint64)
    for a in range(2 * k + 1):
        for b in range(2 * k + 1):
            wide[a:a + gh, b:b + gw] |= masks
    near = wide[k:k + gh, k:k + gw][rows // cell, cols // cell]
    two = np.left_shift(np.uint64(1), (mine % 64).astype(np.uint64)) | np.left_shift(np.uint64(1),
                                                                                     (other % 64).astype(np.uint64))
    return (near & ~two) != 0


def edge_widths(model, kx: float, ky: float) -> tuple[np.ndarray, np.ndarray]:
    """The soft borders of ``model`` as sorted pair keys ``a * R + b`` (``a < b``) and their width in output px.

    Parameters
    ----------
    model : Model
    kx, ky : float
        Output pixels per model pixel.

    Returns
    -------
    keys : ndarray (n,) int64
    sigma : ndarray (n,) float64
    """
    blur = np.asarray(getattr(model, "blur", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    blur = blur[blur[:, 2] > 0]
    n = max(len(model.regions), 1)
    order = np.argsort(blur[:, 0] * n + blur[:, 1], kind="stable")
    return (blur[order, 0] * n + blur[order, 1]).astype(np.int64), blur[order, 2] * float(np.sqrt(kx * ky))


def blur_map(model, kx: float, ky: float):
    """The model's :class:`~tpsv.model.BlurMap` as ``(sigma in output px, cell width, cell height in
    output px)``, or None."""
    bm = getattr(model, "blur_map", None)
    if bm is None:
        return None
    return (np.asarray(bm.sigma, np.float64) * float(np.sqrt(kx * ky)), bm.cell * kx, bm.cell * ky)


def widest_sigma(sigma: np.ndarray, bmap) -> float:
    """The widest edge width (output px) of the pairs' ``sigma`` and a :func:`blur_map` (any border may be
    as wide as the map's widest point): how far mixed pixels reach."""
    wide = float(np.max(sigma, initial=0.0))
    return wide if bmap is None else max(wide, float(bmap[0].max(initial=0.0)))


def region_limits(n_regions: int, keys: np.ndarray, sigma: np.ndarray, bmap, reach: float,
                  least=(1e-4, SECOND_LEAST)) -> np.ndarray:
    """Per region, the distance (output px) from its border beyond which none of its pixels mixes.

    Coverage grows with the distance and shrinks with the edge width, so a
    pixel of region ``r`` mixes (coverage ``< 1 - least``) only nearer than
    where the widest of ``r``'s borders reaches ``1 - least``: a bound of
    that, at most a pixel beyond it (exact for sharp borders; plus 1e-6
    px), and never beyond ``reach``.

    Parameters
    ----------
    n_regions : int
    keys, sigma : ndarray
        The blurred pairs and their widths (:func:`edge_widths`).
    bmap : tuple or None
        The :func:`blur_map` (every region as wide as its widest point).
    reach : float
    least : sequence of float
        The least shares of a pixel that count: the first border's and a
        second border's (:attr:`Borders.limit`, :attr:`Borders.limit2`).

    Returns
    -------
    ndarray (len(least), n_regions) float64
    """
    widest = np.zeros(n_regions)
    if bmap is not None:
        widest[:] = widest_sigma(sigma, bmap)
    elif keys.size:
        np.maximum.at(widest, keys // n_regions, sigma)
        np.maximum.at(widest, keys % n_regions, sigma)
    level = 1.0 - np.asarray(least, np.float64)[:, None]
    # the box filter of the blurred step lies between Phi((d - 1/2) / s) and Phi((d + 1/2) / s): it has
    # reached the level by s z + 1/2, at most a pixel past where it does (the pixels between are
    # measured, and found not to mix)
    d = np.where(widest[None, :] > 1e-3, widest[None, :] * ndtri(level) + 0.5, 0.5 - (1.0 - level))
    return np.minimum(d + 1e-6, reach)


def blur_at(bmap, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear sample of a :func:`blur_map` at output points ``(x, y)`` (cell centres at half cells, edges
    clamped): the edge width there, output px."""
    return map_at(*bmap, x, y)


def outline_pieces(model, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Every outline of ``model`` cut into pieces of at most :data:`PIECE_PX` output pixels.

    Runs along the image's frame are no border: a pixel near the frame
    measures to the real one. An output that would need more than
    :data:`MAX_PIECES` pieces gets longer ones.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.

    Returns
    -------
    a, d : ndarray (n, 2) float64
        Piece starts and vectors, output pixels (``n`` may be 0).
    """
    model = curves.as_drawn(model, width, height)
    k = np.array([width / float(model.width), height / float(model.height)])
    ends = [np.asarray(p, np.float64) for reg in model.regions for p in reg.outline if len(p) >= 2]
    none = np.zeros((0, 2)), np.zeros((0, 2))
    if not ends:
        return none
    a = np.concatenate(ends)
    b = np.concatenate([np.roll(p, -1, axis=0) for p in ends])
    n = piece_counts(a, b, model.width, model.height, k)
    keep = n > 0
    if not keep.any():
        return none
    a, b, n = a[keep] * k, b[keep] * k, n[keep]
    i = np.repeat(np.arange(len(a)), n)
    first = np.cumsum(n) - n
    t0 = (np.arange(int(n.sum())) - first[i]) / n[i]
    d = (b - a)[i]
    return a[i] + t0[:, None] * d, d / n[i][:, None]


def piece_counts(a: np.ndarray, b: np.ndarray, model_width: float, model_height: float, k: np.ndarray) -> np.ndarray:
    """Pieces of every outline edge ``a -> b`` (model pixels) at output scale ``k``, as :func:`outline_pieces` cuts them.

    0 for a run along the image's frame or an edge of no finite length; at
    most :data:`PIECE_PX` output pixels a piece, longer where all the edges
    would need more than :data:`MAX_PIECES` pieces.

    Returns
    -------
    ndarray (len(a),) int64
    """
    frame = np.zeros(len(a), bool)
    for axis, size in ((0, model_width), (1, model_height)):
        for edge in (0.0, float(size)):
            frame |= (a[:, axis] == edge) & (b[:, axis] == edge)
    seg = np.hypot(*(b * k - a * k).T)
    keep = ~frame & np.isfinite(seg)
    counts = np.zeros(len(a), np.int64)
    if keep.any():
        step = max(PIECE_PX, float(seg[keep].sum()) / MAX_PIECES)
        counts[keep] = np.maximum(1, np.ceil(seg[keep] / step)).astype(np.int64)
    return counts


class Borders:
    """Every outline of a model as short pieces in output pixels, prepared once per output size.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.
    second : bool
        Mix the region across a second border too (off: one region across,
        for outlines too dense for the device, where that search is long).
    """

    #: Measure every point to its truly nearest border piece (tests), not the nearest of a few.
    exact = False

    def __init__(self, model, width: int, height: int, second: bool = True):
        from scipy.spatial import cKDTree

        self.width, self.height = int(width), int(height)
        #: whether pixels mix a second border's region too (:meth:`_second`)
        self.second = bool(second)
        self.kx = self.width / float(model.width)
        self.ky = self.height / float(model.height)
        #: a model pixel in output pixels: the depth at which a second border counts as a sliver's (:func:`depth`)
        self.nest = nest_scale(self.kx, self.ky)
        self.n_regions = max(len(model.regions), 1)
        self.blur_keys, self.blur_sigma = edge_widths(model, self.kx, self.ky)
        self.blur_map = blur_map(model, self.kx, self.ky)
        #: farthest a mixed pixel lies from its border, output pixels; rows of halo a band needs
        self.reach_px = 0.5 + 3.0 * widest_sigma(self.blur_sigma, self.blur_map)
        self.halo = int(np.ceil(self.reach_px)) + 1
        #: per region, how far from its border a pixel mixes; ``limit2``: the same for a second border
        #: (:meth:`_second`), whose share counts from :data:`SECOND_LEAST`
        self.limit, self.limit2 = region_limits(self.n_regions, self.blur_keys, self.blur_sigma, self.blur_map,
                                                self.reach_px)
        self.a, self.d = outline_pieces(model, self.width, self.height)
        self.tree = cKDTree(self.a + 0.5 * self.d) if len(self.a) else None
        #: half the longest piece: no point of a piece is nearer than its midpoint less this
        self.slack = 0.5 * float(np.hypot(*self.d.T).max(initial=0.0))

    def mix(self, index: np.ndarray, y0: int = 0, halo: tuple[np.ndarray | None, np.ndarray | None] = (None, None)) -> BorderMix:
        """The border pixels of rows ``y0 .. y0 + len(index)`` and their coverage.

        Parameters
        ----------
        index : ndarray (h, W) int32
            Region of every pixel of the band (``region_index`` rows).
        y0 : int
            Output row of ``index``'s first row.
        halo : (rows above, rows below)
            Region rows just outside the band, ``(k, W)`` arrays of up to
            :attr:`halo` rows (None at the frame's edge), so that a band's
            border pixels are the whole frame's.

        Returns
        -------
        BorderMix
        """
        if self.tree is None or index.size == 0:
            return BorderMix.none()
        h, W = index.shape
        up, down = halo
        up = index[:1] if up is None else np.asarray(up).reshape(-1, W)
        down = index[-1:] if down is None else np.asarray(down).reshape(-1, W)
        top = up.shape[0]
        # the band and its halo, the first and last rows and columns repeated once: one array
        # (``ext`` is its rows of the band and halo, a view)
        pad = np.pad(np.vstack([up, index, down]), 1, mode="edge")
        ext = pad[1:-1]
        inner = ext[:, 1:-1]
        # pixels with an 8-neighbour of another region, over the band and its halo
        # (beyond the first and last rows the rows repeat: no neighbour differs there)
        n = inner.shape[0]
        differs = np.zeros(inner.shape, bool)
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            nb = pad[1 + dy:1 + dy + n, 1 + dx:1 + dx + W]
            differs |= (nb != inner) & (nb >= 0)
        differs &= inner >= 0
        near = differs[top:top + h]
        ys, xs = np.nonzero(near)
        if self.reach_px > 1.0:
            import cv2

            # a blurred border reaches further: every pixel within reach of a border pixel
            # (measured to fewer pieces: the far tail of a blurred step varies slowly)
            dist = cv2.distanceTransform((~differs).astype(np.uint8), cv2.DIST_L2, 5)
            far = (dist[top:top + h] <= self.reach_px + 1.0) & ~near & (index >= 0)
            fy, fx = np.nonzero(far)
        else:
            fy = fx = np.zeros(0, np.int64)
        if ys.size + fy.size == 0:
            return BorderMix.none()
        ys, xs = np.concatenate([ys, fy]), np.concatenate([xs, fx])
        p = np.column_stack([xs + 0.5, ys + y0 + 0.5])
        mine = index[ys, xs]
        k = np.r_[np.full(len(ys) - len(fy), NEAREST), np.full(len(fy), FAR_NEAREST)]
        beside = np.arange(len(ys)) < len(ys) - len(fy)
        f, dmin, vec = self._nearest_border(ext, top, mine, p, k, beside, y0)
        keep = dmin < self.limit[mine]
        if not keep.any():
            return BorderMix.none()
        p, f, dmin, ys, xs, mine, vec = p[keep], f[keep], dmin[keep], ys[keep], xs[keep], mine[keep], vec[keep]
        other, toward = self._across(ext, top, mine, p, f, dmin, vec, ys, xs, y0)
        ok = other >= 0
        p, f, dmin, ys, xs, other, mine, toward = (p[ok], f[ok], dmin[ok], ys[ok], xs[ok], other[ok], mine[ok],
                                                   toward[ok])
        alpha = self._coverage(dmin, self._sigma(mine, other, f))
        mixed = alpha < 1.0 - 1e-4
        p, f, alpha, ys, xs, other, mine, toward = (p[mixed], f[mixed], alpha[mixed], ys[mixed], xs[mixed],
                                                    other[mixed], mine[mixed], toward[mixed])
        other2, alpha, alpha2 = self._second(ext, top, mine, other, p, f, toward, alpha, ys, xs, y0)
        xy = np.column_stack([p[:, 0] / self.kx, p[:, 1] / self.ky])
        return BorderMix(pixels=(ys * W + xs).astype(np.int32), other=other.astype(np.int32),
                         alpha=alpha.astype(np.float32), xy=xy, other2=other2.astype(np.int32),
                         alpha2=alpha2.astype(np.float32))

    def _second(self, ext, top, mine, other, p, f, toward, c1, ys, xs, y0):
        """The region across a second border of each mixed pixel: ``(other2, alpha, alpha2)``.

        See :func:`shares`; ``other2`` -1 (and ``alpha`` the coverage ``c1``,
        ``alpha2`` 1) where no second border is near enough to matter. Only
        pixels with a third region's pixel near (:func:`third_near`), whose
        first border leaves them at least :data:`SECOND_LEAST`, are searched.
        The directions across are to the points where the regions across were
        read (``toward`` for the first border, from :meth:`_across`); ``f``
        are the feet on the first border.
        """
        n = len(p)
        other2 = np.full(n, -1, np.int64)
        alpha, alpha2 = c1.copy(), np.ones(n)
        if not n or not self.second:
            return other2, alpha, alpha2
        cell, k = near_cells(float(self.limit2.max()))
        # (a second border is no nearer than the first: it counts only where the first does)
        look = np.flatnonzero(third_near(ext[:, 1:-1], cell, k, ys + top, xs, mine, other)
                              & (c1 < 1.0 - SECOND_LEAST))
        j, f2, d2, r2 = self._second_border(ext, top, mine[look], other[look], p[look], y0)
        i = look[j]
        v1 = toward[i] - p[i]
        v2 = self._beyond_point(p[i], f2, d2) - p[i]
        n1 = np.hypot(*v1.T)
        nested = depth(f[i], f2, v1 / np.maximum(n1, 1e-300)[:, None], self.nest)
        dot = (v1 * v2).sum(1) / np.maximum(n1 * np.hypot(*v2.T), 1e-300)
        # the second border is the far side of the region across or one of the pixel's own: the wider
        # of the two pairs (no choice by the sign of dot, which rounding decides for a pixel on a border)
        c2 = self._coverage(d2, np.maximum(self._sigma(mine[i], r2, f2), self._sigma(other[i], r2, f2)))
        a, a2 = shares(c1[i], c2, dot, nested)
        two = c2 < 1.0 - SECOND_LEAST
        i = i[two]
        other2[i], alpha[i], alpha2[i] = r2[two], a[two], a2[two]
        return other2, alpha, alpha2

    def _nearest(self, p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(p, foot, distance, vector)``: each point's foot on the nearest of its ``k`` nearest pieces (by
        midpoint), and that piece's vector."""
        if not len(p):
            return p, p.copy(), np.zeros(0), p.copy()
        foot, dist, _, vec = self._feet(p, k)
        best = np.argmin(dist, axis=1)
        rows = np.arange(len(p))
        return p, foot[rows, best], dist[rows, best], vec[rows, best]

    def _nearest_border(self, ext, top, mine, p, k, beside, y0):
        """``(foot, distance, vector)`` of each point on its nearest border piece (the piece's vector).

        A piece is a border for the point only with another region just
        beyond it (:meth:`_beyond`), or within 0.75 px of a point ``beside``
        a pixel of another region (an 8-neighbour): a sliver of an outline
        thinner than a pixel, which no pixel centre samples, is none (its
        far side is the point's own region). Nor is a piece beyond the
        region's :attr:`limit`. Each point is measured to the ``k[i]`` pieces
        nearest it by midpoint; where none of those is a border, to 64, then 4
        times as many (up to :data:`MAX_REJECTED`), until one is or the
        pieces left lie beyond the limit (with :attr:`exact`, also until
        the pieces left lie beyond the best); where none is, the nearest piece.
        """
        n = len(p)
        foot = np.zeros((n, 2))
        vec = np.zeros((n, 2))
        dist = np.full(n, np.inf)
        lim = self.limit[mine]
        rows, kk = np.arange(n), k
        while rows.size:
            nxt = []
            for kn in np.unique(kk):
                r_ = rows[kk == kn]
                f, d, far, v = self._feet(p[r_], int(kn))
                m = mine[r_][:, None]
                r = self._beyond(ext, top, p[r_][:, None, :], f, d, y0)
                ok = (((d <= 0.75) & beside[r_][:, None]) | ((r != m) & (r >= 0))) & (d < lim[r_][:, None])
                best = np.argmin(np.where(ok, d, np.inf), axis=1)
                i = np.arange(len(r_))
                found = ok[i, best]
                foot[r_[found]] = f[i, best][found]
                dist[r_[found]] = d[i, best][found]
                vec[r_[found]] = v[i, best][found]
                # a piece nearer than the best so far (or the limit) has its midpoint within that + slack
                bound = np.where(found, dist[r_], lim[r_]) if self.exact else np.where(found, -np.inf, lim[r_])
                more = (far <= bound + self.slack) & (kn < min(self.tree.n, MAX_REJECTED))
                nxt.append((r_[more], np.full(int(more.sum()), min(max(64, 4 * int(kn)), MAX_REJECTED))))
            rows = np.concatenate([r for r, _ in nxt]) if nxt else np.zeros(0, np.int64)
            kk = np.concatenate([v for _, v in nxt]) if nxt else np.zeros(0, np.int64)
        todo = np.flatnonzero(~np.isfinite(dist))
        if todo.size:
            _, foot[todo], dist[todo], vec[todo] = self._nearest(p[todo], NEAREST)
        return foot, dist, vec

    def _second_border(self, ext, top, mine, other, p, y0):
        """The nearest piece of each point with neither ``mine`` nor ``other`` just beyond it, within
        :attr:`limit2`: ``(points that have one, their feet, distances, regions beyond)``.

        Exact (every piece whose midpoint lies within the limit and half the
        longest piece, up to the :data:`MAX_REJECTED` nearest), as the
        device's search: a second border chosen among a few pieces would as
        often be a far one.
        """
        lim = self.limit2[mine]
        rows, pieces = [], []
        for bound in np.unique(lim):
            at = np.flatnonzero(lim == bound)
            k = min(int(self.tree.query_ball_point(p[at], bound + self.slack, workers=-1, return_length=True).max()),
                    MAX_REJECTED)
            if k == 0:
                continue
            step = max(1, (1 << 22) // k)  # (memory: a few million pairs at a time)
            for c in range(0, len(at), step):
                rc = at[c:c + step]
                _, near = self.tree.query(p[rc], k=k, distance_upper_bound=bound + self.slack, workers=-1)
                near = np.asarray(near).reshape(len(rc), k)
                hit = near < self.tree.n
                rows.append(np.broadcast_to(rc[:, None], near.shape)[hit])
                pieces.append(near[hit])
        row = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        piece = np.concatenate(pieces) if pieces else np.zeros(0, np.int64)
        a, d, q = self.a[piece], self.d[piece], p[row]
        w = q - a
        t = np.clip((w * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
        foot = a + t[:, None] * d
        off = q - foot
        dist = np.sqrt(off[:, 0] ** 2 + off[:, 1] ** 2)
        r = self._beyond(ext, top, q, foot, dist, y0)
        ok = (r != mine[row]) & (r != other[row]) & (r >= 0) & (dist < lim[row])
        row, foot, dist, r, w, d = row[ok], foot[ok], dist[ok], r[ok], w[ok], d[ok]
        # the nearest per point; on a tie the piece whose middle is nearer (as the device)
        mid = (w[:, 0] - 0.5 * d[:, 0]) ** 2 + (w[:, 1] - 0.5 * d[:, 1]) ** 2
        o = np.lexsort((mid, dist, row))
        first = o[np.r_[True, row[o][1:] != row[o][:-1]]] if len(o) else o
        return row[first], foot[first], dist[first], r[first]

    @staticmethod
    def _beyond_point(p, f, dist):
        """A little beyond feet ``f`` seen from ``p``: 0.75 px on, or the mirror image of ``p`` within 0.75 px."""
        away = (f - p) / np.maximum(dist, 1e-9)[..., None]
        return np.where((dist > 0.75)[..., None], f + 0.75 * away, 2.0 * f - p)

    @staticmethod
    def _region_at(ext, top, q, y0):
        """Region of the pixels holding points ``q`` (rows and columns beyond the map repeat its edge)."""
        H, W = ext.shape[0], ext.shape[1] - 2
        qx = np.clip(np.floor(q[..., 0]).astype(np.int64), -1, W)
        qy = np.clip(np.floor(q[..., 1]).astype(np.int64) - y0 + top, 0, H - 1)
        return ext[qy, qx + 1]

    @staticmethod
    def _beyond(ext, top, p, f, dist, y0):
        """Region at :meth:`_beyond_point`."""
        return Borders._region_at(ext, top, Borders._beyond_point(p, f, dist), y0)

    def _feet(self, p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Feet ``(n, k, 2)`` and distances ``(n, k)`` of each point on its ``k`` pieces nearest by
        midpoint, the distance to the farthest of those midpoints ``(n,)``, and the pieces' vectors
        ``(n, k, 2)``."""
        k = min(k, self.tree.n)
        mid, near = self.tree.query(p, k=k, workers=-1)
        near = near.reshape(len(p), k)
        a = self.a[near]
        d = self.d[near]
        w = p[:, None, :] - a
        t = np.clip((w * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
        foot = a + t[..., None] * d
        off = p[:, None, :] - foot
        return foot, np.sqrt(off[..., 0] ** 2 + off[..., 1] ** 2), np.asarray(mid).reshape(len(p), k)[:, -1], d

    def _sigma(self, a: np.ndarray, b: np.ndarray, foot: np.ndarray) -> np.ndarray:
        """Edge width (output px) of the border between regions ``a`` and ``b`` at its points ``foot``
        (n, 2) (0: sharp): the blur map's there, else the pair's."""
        if self.blur_map is not None:
            return blur_at(self.blur_map, foot[:, 0], foot[:, 1])
        if self.blur_keys.size == 0:
            return np.zeros(a.shape)
        key = np.minimum(a, b).astype(np.int64) * self.n_regions + np.maximum(a, b)
        i = np.clip(np.searchsorted(self.blur_keys, key), 0, self.blur_keys.size - 1)
        return np.where(self.blur_keys[i] == key, self.blur_sigma[i], 0.0)

    @staticmethod
    def _coverage(d: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """Share of a pixel (centre ``d`` output px inside its region) that a step blurred by ``sigma`` leaves it.

        The box filter of the blurred step: ``F(d + 1/2) - F(d - 1/2)`` with
        ``F(x) = x Phi(x / sigma) + sigma phi(x / sigma)``; ``min(1, 0.5 + d)``
        for a sharp step.
        """
        sharp = np.minimum(1.0, 0.5 + d)
        s = np.maximum(sigma, 1e-6)

        def F(x):
            z = x / s
            return x * ndtr(z) + s * np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)

        return np.where(sigma > 1e-3, F(d + 0.5) - F(d - 0.5), sharp)

    def _across(self, ext, top, mine, p, f, dist, vec, ys, xs, y0):
        """Region just beyond each pixel's nearest outline (piece vector ``vec``), else its nearest
        8-neighbour of another region; and a point across: where the region was read (a little beyond
        the foot, or that neighbour's centre), or for a pixel centre on the outline one step along the
        piece's normal, on the neighbour's side."""
        H = ext.shape[0]
        q = self._beyond_point(p, f, dist)
        other = self._region_at(ext, top, q, y0)
        toward = q.copy()
        bad = (other == mine) | (other < 0)
        if bad.any():
            # the point beyond fell in the pixel's own region (an outline corner): the
            # 8-neighbour of another region whose centre is nearest that point
            ib = np.flatnonzero(bad)
            best = np.full(len(ib), np.inf)
            pick = np.full(len(ib), -1, np.int64)
            centre = q[ib].copy()
            for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
                r = ext[np.clip(top + ys[ib] + dy, 0, H - 1), 1 + xs[ib] + dx]
                c = np.column_stack([xs[ib] + dx + 0.5, ys[ib] + y0 + dy + 0.5])
                e = c - q[ib]
                dd = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1])  # (the device's expression: ties break alike)
                take = (r != mine[ib]) & (r >= 0) & (dd < best - 1e-9)  # (near ties: the first, on any rounding)
                best[take] = dd[take]
                pick[take] = r[take]
                centre[take] = c[take]
            other = other.copy()
            other[ib] = pick
            toward[ib] = centre
            on = dist[ib] <= 1e-9
            if on.any():
                # on the outline the neighbour lies along a pixel axis, the border may not: the piece's
                # normal, to the neighbour's side
                i, v = ib[on], vec[ib[on]]
                n = np.column_stack([-v[:, 1], v[:, 0]]) / np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-300)[:, None]
                side = np.where(((centre[on] - p[i]) * n).sum(1) < 0.0, -1.0, 1.0)
                toward[i] = p[i] + side[:, None] * n
        return other, toward


__all__ = ["BorderMix", "Borders", "FAR_NEAREST", "MASK_CELL", "MAX_PIECES", "MAX_REJECTED", "MAX_VISIT", "NEAREST",
           "PIECE_PX", "SECOND_LEAST", "edge_widths", "near_cells", "outline_pieces", "piece_counts", "region_limits",
           "shares", "third_near"]
