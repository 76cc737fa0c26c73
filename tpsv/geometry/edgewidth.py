"""Edge width of region borders: how much the photo blurs the step between two regions.

A defocused or soft edge is a step blurred by a Gaussian of some ``sigma``;
rendered as a sharp border at 8x it looks cut out. For a step of colour
contrast ``C`` blurred by ``sigma`` (and box-sampled by the pixels), the
largest colour gradient across it is ``C / (sqrt(2 pi) sigma_eff)``, with
``sigma_eff^2 = sigma^2 + S0^2`` where ``S0`` is what the pixels and the
gradient operator add to a sharp step (:data:`S0`, measured on synthetic
edges). Along every border that two regions share, at points every pixel,
``C`` is read from the image :data:`PROBE` px on either side (in the right
regions only) and the gradient at the border; each pair of regions gets the
median reading.

A border long enough to read but mostly without contrast is one the photo
hardly shows, and one whose outline lies, in RMS, more than
:data:`MISPLACED` from the photo's strongest gradient across it is one the
outline does not follow; the label map alone places both, to about half a
pixel. Rendered sharp, magnification would show a cut-out edge where the
photo has none (a label map drawn a pixel off a soft nose, at 4x), so both
get at least :data:`UNSURE_SIGMA`. On a border of at most
:data:`SHORT_BORDER` points most points lie near a junction, whose other
borders reach the gradient read (a grid of sharp squares read as misplaced):
there only the points whose border runs on :data:`JUNCTION_REACH` px both
ways, with its two regions either side, are read.

One width per pair cannot suit a border that follows an edge in one stretch
and cuts across a flat area in the next; magnified, the flat stretch shows a
seam. :func:`edge_width_map` also gives each border point a width of its
own, gathered in a coarse map (``Model.blur_map``) that the renderer samples
where each border pixel's border is.
"""

from __future__ import annotations

import numpy as np

from ..model import BlurMap

#: Distance (px) from the border at which each side's colour is read.
PROBE = 4.0
#: Blur of a sharp, box-sampled step as this reading sees it (px; synthetic edges at 0, 0.3 and 0.79 rad:
#: sharp steps then read 0-0.28 px, steps blurred by 0.5, 1, 1.5, 2, 3 px read 0.44-0.5, 0.94-1.0, 1.44, 1.88, 2.38).
S0 = 0.85
#: Points (one a pixel) of a border short enough for its junctions to matter, and how far along it
#: (px) another region makes a point of it unreadable.
SHORT_BORDER = 16
JUNCTION_REACH = 1.5
#: Least colour step (sRGB, Euclidean) a point needs to be read.
MIN_CONTRAST = 0.16
#: Least points a border needs to get a width.
MIN_POINTS = 8
#: Widths below this are sharp; above :data:`MAX_SIGMA`, capped (px).
MIN_SIGMA = 0.3
MAX_SIGMA = 4.0
#: Least edge width of a border the photo does not show or the outline does not follow (px): the label
#: map's precision. Measured on the samples area-downscaled 4x, vectorized at quality 75 and rendered back
#: at 4x, PSNR within 4 output px of a border, every border sharp or soft: sharp 26.3/22.2/22.6/21.3 dB
#: (chelsea, rocket, coffee, astronaut), 0.5 px 27.8/23.1/23.1/21.7, 0.75 px 27.5/23.1/22.8/21.5.
UNSURE_SIGMA = 0.5
#: RMS distance (px) between the outline and the photo's strongest gradient across it above which the
#: outline is taken not to follow the photo's edge. The synthetic shapes' fitted outlines read 0.18-0.35
#: (the reading's 1/4 px steps); photo borders that the label map alone places 0.9-1.8. With these two
#: rules, the same 4x figures went from 26.3/22.2/22.6/21.3 dB to 27.4/22.2/22.6/21.8 (2x downscale and
#: back: 29.8/24.7/26.1/25.9 -> 30.9/25.0/26.4/25.9).
MISPLACED = 0.7
#: Least edge width (px) where a border crosses a flat stretch of the photo (both sides read, no step): a
#: label map cut there, and a sharp step, magnified, shows a seam where the two regions' colours meet (the
#: detail layer evens them out pixel by pixel at scale 1, not between the pixels). Measured on the samples
#: area-downscaled 4x, vectorised at quality 75 and rendered at 4x, PSNR within 4 px of the borders
#: (astronaut, chelsea, coffee, rocket): widths per pair 22.39/27.70/22.80/22.20 dB; this rule with 1.5 px
#: 22.57/28.11/23.18/22.31 (with 1 px about the same; with 2 px and 4 px cells 22.57/27.82/23.03/22.51).
FLAT_SIGMA = 1.5
#: Least vector step (sRGB, Euclidean) across a border, and the most of it the photo's step may have, for a
#: point to get :data:`FLAT_SIGMA` (:func:`false_steps`).
FALSE_STEP = 0.08
FALSE_SHARE = 0.5
#: Distance (px) from the border at which :func:`false_steps` compares the two.
FALSE_PROBE = 1.5
#: Least share of the points of a cell's 3 x 3 block that must be false steps for :func:`soften_map` to
#: raise the cell (as the block's median would). At 0.25 a split coin's last finger went too, but the
#: samples area-downscaled 4x lost 0.12-0.19 dB within 4 px of the borders at 4x.
FALSE_BLOCK = 0.5
#: Cell side (px) of the blur map (:func:`edge_width_map`). 4 px cells cost about twice the bytes (70-200 B a
#: sample, 8 px cells 60-130) and were no better on the whole: 22.62/27.73/22.99/22.50 dB (with 1 px).
MAP_CELL = 8
#: Steps per px of the blur map's widths (coarser than the format's 1/16 px: fewer symbols, about 30 % fewer
#: bytes).
MAP_STEPS = 4


def _bilinear(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``img`` (H, W[, C]) at points ``xy`` (pixel centres at +0.5), edges clamped."""
    x = np.clip(xy[:, 0] - 0.5, 0, img.shape[1] - 1)
    y = np.clip(xy[:, 1] - 0.5, 0, img.shape[0] - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), img.shape[1] - 2).clip(0)
    y0 = np.minimum(np.floor(y).astype(np.int64), img.shape[0] - 2).clip(0)
    fx, fy = x - x0, y - y0
    if img.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    x1 = np.minimum(x0 + 1, img.shape[1] - 1)
    y1 = np.minimum(y0 + 1, img.shape[0] - 1)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _shared_edges(regions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every outline edge regions ``a < b`` share (exact vertices): ``a``, ``b`` (k,) and the edge's
    start and end (k, 2), in the order of the regions' polygons and their edges."""
    from ..codec import chains
    from ..codec.quant import OUTLINE_SCALE

    polys, owner = [], []
    for r, reg in enumerate(regions):
        for p in reg.outline:
            polys.append(np.rint(np.asarray(p, np.float64) * OUTLINE_SCALE).astype(np.int64).reshape(-1, 2))
            owner.append(r)
    if not polys or not sum(len(p) for p in polys):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
    part = np.concatenate(chains.partners(polys))
    start = np.concatenate(polys)
    end = np.concatenate([np.roll(p, -1, axis=0) for p in polys])
    owner = np.asarray(owner, np.int64)
    a = np.repeat(owner, [len(p) for p in polys])
    b = np.where(part[:, 0] >= 0, owner[np.maximum(part[:, 0], 0)], -1)
    keep = (part[:, 0] >= 0) & (a < b)
    return a[keep], b[keep], start[keep] / OUTLINE_SCALE, end[keep] / OUTLINE_SCALE


def edge_widths(rgb: np.ndarray, regions, index: np.ndarray) -> np.ndarray:
    """The edge width of every border two regions share.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float
        The image, sRGB in [0, 1].
    regions : list of Region
        With their (fitted) outlines; borders are the edges two regions share.
    index : ndarray (H, W) int
        Region of every pixel.

    Returns
    -------
    ndarray (n, 3) float64
        Rows ``(a, b, sigma)``, ``a < b`` sorted, ``sigma`` in px on the
        1/16 px grid; only borders with ``sigma > 0``.
    """
    r = _readings(rgb, regions, index)
    if r is None:
        return np.zeros((0, 3))
    return _pair_widths(r, len(regions))


def gradient_magnitude(rgb: np.ndarray) -> np.ndarray:
    """The colour gradient's magnitude at every pixel: ``sqrt(sum over channels of sobel_y^2 + sobel_x^2) / 8``.

    SciPy's ``ndimage.sobel`` (mode ``reflect``) as OpenCV's ``Sobel`` computes it
    (``BORDER_REFLECT``), over bands of rows on a few host threads, each band
    read with the row either side: the same values as the whole image at once
    (exactly for pictures of 8- or 16-bit samples, whose sums of a few integer
    multiples are exact in float64; within 1e-15 for any floats).

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float

    Returns
    -------
    ndarray (H, W) float64
    """
    # (imported here: reading a file's blur map, `tpsv info`, needs no image filters)
    import cv2

    from .bands import for_bands

    H = rgb.shape[0]
    grad = np.empty(rgb.shape[:2])

    def band(rows: tuple[int, int]) -> None:
        a, b = rows
        lo, hi = max(a - 1, 0), min(b + 1, H)
        acc = np.zeros((hi - lo, rgb.shape[1]))
        for k in range(3):
            channel = np.ascontiguousarray(rgb[lo:hi, :, k], np.float64)
            term = cv2.Sobel(channel, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT) ** 2
            term += cv2.Sobel(channel, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT) ** 2
            acc += term
        part = acc[a - lo:a - lo + (b - a)]
        grad[a:b] = np.sqrt(part) / 8.0

    for_bands(band, H, rgb.shape[1])
    return grad


def _points(regions, index: np.ndarray):
    """Points every pixel along the shared borders, or None without borders: ``(f, a, b, normal,
    region_at)``, ``normal`` a unit vector into region ``a`` and ``region_at(xy)`` the region of the
    pixel under each point of ``xy``."""
    a, b, p0, p1 = _shared_edges(regions)
    if not len(a):
        return None
    seg = p1 - p0
    length = np.hypot(*seg.T)
    n_pts = np.maximum(1, np.floor(length)).astype(np.int64)
    which = np.repeat(np.arange(len(a)), n_pts)
    t = (np.arange(int(n_pts.sum())) - np.repeat(np.cumsum(n_pts) - n_pts, n_pts) + 0.5) / n_pts[which]
    f = p0[which] + t[:, None] * seg[which]
    normal = np.stack([-seg[which, 1], seg[which, 0]], 1) / np.maximum(length[which], 1e-12)[:, None]
    a, b = a[which], b[which]
    H, W = index.shape

    def region_at(xy):
        x = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, W - 1)
        y = np.clip(np.floor(xy[:, 1]).astype(np.int64), 0, H - 1)
        return index[y, x]

    # the normal points into region a
    flip = region_at(f + normal) != a
    normal[flip] *= -1
    return f, a, b, normal, region_at


def _readings(rgb: np.ndarray, regions, index: np.ndarray):
    """The readings at points every pixel along the shared borders (module doc), or None without borders:
    ``(f, a, b, ok, placed, sigma_eff, offset)``."""
    rgb = np.asarray(rgb)[..., :3]  # float32 is read in float64 where sampled (no float64 copy of the photo)
    points = _points(regions, index)
    if points is None:
        return None
    f, a, b, normal, region_at = points
    H, W = index.shape
    grad = gradient_magnitude(rgb)
    side_a, side_b = f + PROBE * normal, f - PROBE * normal
    ok = (region_at(side_a) == a) & (region_at(side_b) == b) & (region_at(f + normal) == a) & \
        (region_at(f - normal) == b)
    ok &= (side_a.min(1) >= 0) & (side_b.min(1) >= 0) & (side_a[:, 0] <= W) & (side_b[:, 0] <= W) & \
        (side_a[:, 1] <= H) & (side_b[:, 1] <= H)
    # on a short border most points lie near its ends, where the junction's other borders reach the
    # gradient read: there only points whose border runs on both ways are read
    key = a.astype(np.int64) * (int(b.max(initial=0)) + 1) + b
    _, pair, count = np.unique(key, return_inverse=True, return_counts=True)
    short = count[pair] <= SHORT_BORDER
    if short.any():
        tangent = np.stack([normal[:, 1], -normal[:, 0]], 1)
        runs_on = np.ones(len(a), bool)
        for along in (-JUNCTION_REACH, JUNCTION_REACH):
            for side, want in ((0.5, a), (-0.5, b)):
                runs_on &= region_at(f + along * tangent + side * normal) == want
        ok &= runs_on | ~short
    contrast = np.hypot.reduce(_bilinear(rgb, side_a) - _bilinear(rgb, side_b), axis=1)
    # the gradient across the border, within 2 px of it
    steps = np.arange(-2.0, 2.01, 0.25)
    across = np.array([_bilinear(grad, f + s * normal) for s in steps])
    g = across[np.isin(steps, (-1.0, -0.5, 0.0, 0.5, 1.0))].max(axis=0)  # the steepest at the border
    # where the photo's edge is: its strongest gradient (the middle of a plateau, as a step on a pixel edge gives)
    top = across >= 0.99 * across.max(axis=0)
    offset = (steps @ top) / top.sum(axis=0)
    placed = ok.copy()  # both sides readable where they should be
    ok &= (contrast >= MIN_CONTRAST) & (g > 1e-6)
    sigma_eff = contrast / (np.sqrt(2.0 * np.pi) * np.maximum(g, 1e-6))
    return f, a, b, ok, placed, sigma_eff, offset


def false_steps(photo: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Border points where the vector image steps as the photo does not: ``photo`` and ``vector`` (k, 3)
    are the colour differences across the border (side a minus side b, :data:`FALSE_PROBE` px out).

    A point is marked where the vector step is at least :data:`FALSE_STEP` and the photo's step along it
    is less than :data:`FALSE_SHARE` of it (a flat or textured stretch the label map cut, an object the
    automatic regions split). There the detail layer holds the difference, at scale 1 pixel by pixel;
    magnified, its smooth interpolation cannot follow a sharp vector step, and the two make a seam.
    """
    dv = np.asarray(vector, np.float64)
    norm2 = (dv * dv).sum(axis=1)
    along = (np.asarray(photo, np.float64) * dv).sum(axis=1)
    return (norm2 >= FALSE_STEP ** 2) & (along < FALSE_SHARE * norm2)


def _pair_widths(readings, n_regions: int) -> np.ndarray:
    """:func:`edge_widths` from the :func:`_readings`: one width per pair of regions."""
    f, a, b, ok, placed, sigma_eff, offset = readings
    out = []
    key = a * (n_regions + 1) + b
    for k in np.unique(key):
        mine = key == k
        s = sigma_eff[ok & mine]
        if s.size >= MIN_POINTS:
            sigma = float(np.sqrt(max(np.median(s) ** 2 - S0 ** 2, 0.0)))
            if np.sqrt(np.mean(offset[ok & mine] ** 2)) > MISPLACED:
                sigma = max(sigma, UNSURE_SIGMA)
        elif np.count_nonzero(placed & mine) >= max(MIN_POINTS, 2 * s.size):
            sigma = UNSURE_SIGMA  # long enough to read, but mostly without a step in the photo
        else:
            continue  # too short to tell: sharp
        if sigma < MIN_SIGMA:
            continue
        ra, rb = divmod(int(k), n_regions + 1)
        out.append((ra, rb, np.round(min(sigma, MAX_SIGMA) * 16) / 16))
    return np.array(out, np.float64).reshape(-1, 3)


#: Most points :func:`border_cells` samples (a hostile file's borders could be far longer than any picture's:
#: 12 megapixels with fine automatic regions make about a million).
MAX_MAP_POINTS = 1 << 24


def border_cells(regions, width: int, height: int, cell: int = MAP_CELL) -> np.ndarray:
    """Flat indices (sorted) of the blur map's cells that a shared border passes through.

    From the outlines as stored (vertices on the format's grid, so a decoder
    finds the same cells): each shared edge clipped to the picture, points
    every half pixel along it (docs/FORMAT.md, "Blur map").

    Returns
    -------
    ndarray (k,) int64
        ``row * gw + column`` in a ``ceil(height / cell) x ceil(width / cell)`` grid.

    Raises
    ------
    ValueError
        The borders would need more than :data:`MAX_MAP_POINTS` points.
    """
    gh, gw = -(-int(height) // cell), -(-int(width) // cell)
    _, _, p0, p1 = _shared_edges(regions)
    if not len(p0):
        return np.zeros(0, np.int64)
    d = p1 - p0
    # the part of each edge inside [0, width] x [0, height] (Liang-Barsky)
    t0, t1 = np.zeros(len(d)), np.ones(len(d))
    for k, size in ((0, float(width)), (1, float(height))):
        for q, r in ((-d[:, k], p0[:, k]), (d[:, k], size - p0[:, k])):
            flat = q == 0
            t = np.divide(r, q, out=np.zeros_like(r), where=~flat)
            t1 = np.where(~flat & (q > 0), np.minimum(t1, t), t1)
            t0 = np.where(~flat & (q < 0), np.maximum(t0, t), t0)
            t1 = np.where(flat & (r < 0), -1.0, t1)  # parallel and outside
    keep = t0 <= t1
    p0, d, t0, t1 = p0[keep], d[keep], t0[keep], t1[keep]
    n = np.maximum(1, np.ceil(2.0 * (t1 - t0) * np.hypot(d[:, 0], d[:, 1]))).astype(np.int64)
    total = int((n + 1).sum())
    if total > MAX_MAP_POINTS:
        raise ValueError(f"the borders need {total} points to map, more than {MAX_MAP_POINTS}")
    out = []
    for lo in range(0, len(n), 4096):
        nn = n[lo:lo + 4096]
        which = np.repeat(np.arange(len(nn)), nn + 1)
        k = np.arange(int((nn + 1).sum())) - np.repeat(np.cumsum(nn + 1) - (nn + 1), nn + 1)
        t = t0[lo:lo + 4096][which] + k * ((t1 - t0)[lo:lo + 4096] / nn)[which]
        pts = p0[lo:lo + 4096][which] + t[:, None] * d[lo:lo + 4096][which]
        i = np.clip(np.floor(pts[:, 1] / cell).astype(np.int64), 0, gh - 1)
        j = np.clip(np.floor(pts[:, 0] / cell).astype(np.int64), 0, gw - 1)
        out.append(np.unique(i * gw + j))
    return np.unique(np.concatenate(out))


def map_at(sigma: np.ndarray, cw: float, ch: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear sample of a grid of widths ``sigma`` (cells ``cw x ch``, centres at half cells, the grid's
    edges clamped) at points ``(x, y)`` in the grid's units: a border point's width (``Model.blur_map``)."""
    gh, gw = sigma.shape
    u = np.clip(np.asarray(x, np.float64) / cw - 0.5, 0.0, gw - 1)
    v = np.clip(np.asarray(y, np.float64) / ch - 0.5, 0.0, gh - 1)
    i0 = np.minimum(np.floor(v).astype(np.int64), max(gh - 2, 0))
    j0 = np.minimum(np.floor(u).astype(np.int64), max(gw - 2, 0))
    i1, j1 = np.minimum(i0 + 1, gh - 1), np.minimum(j0 + 1, gw - 1)
    fv, fu = v - i0, u - j0
    top = sigma[i0, j0] * (1 - fu) + sigma[i0, j1] * fu
    bottom = sigma[i1, j0] * (1 - fu) + sigma[i1, j1] * fu
    return top * (1 - fv) + bottom * fv


#: Rings of cells around the stored ones that :func:`fill_map` fills: a border pixel's width is sampled
#: bilinearly at its border point, within a pixel of the stored outline, so it reads cells at most two
#: cells from a stored one.
FILL_RINGS = 2


def fill_map(width: int, height: int, cell: int, cells: np.ndarray, values: np.ndarray) -> BlurMap:
    """The :class:`~tpsv.model.BlurMap` whose ``cells`` hold ``values`` (px).

    The other cells within :data:`FILL_RINGS` cells of them get, ring by
    ring, the mean (float64, then float32) of their 8-neighbours filled
    before; the rest 0 (never read).
    """
    gh, gw = -(-int(height) // cell), -(-int(width) // cell)
    grid = np.zeros((gh + 2, gw + 2), np.float64)  # a frame of unfilled cells: no wrap-around
    have = np.zeros((gh + 2, gw + 2), bool)
    i, j = np.divmod(np.asarray(cells, np.int64), gw)
    grid[i + 1, j + 1] = np.asarray(values, np.float32)
    have[i + 1, j + 1] = True
    for _ in range(FILL_RINGS):
        total = np.zeros((gh, gw))
        count = np.zeros((gh, gw))
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di or dj:
                    total += np.where(have, grid, 0.0)[1 + di:gh + 1 + di, 1 + dj:gw + 1 + dj]
                    count += have[1 + di:gh + 1 + di, 1 + dj:gw + 1 + dj]
        new = ~have[1:-1, 1:-1] & (count > 0)
        inner = grid[1:-1, 1:-1]
        inner[new] = (total[new] / count[new]).astype(np.float32)
        have[1:-1, 1:-1] |= new
    return BlurMap(cell=int(cell), sigma=grid[1:-1, 1:-1].astype(np.float32))


def edge_width_map(rgb: np.ndarray, regions, index: np.ndarray, drawn=None, cell: int = MAP_CELL):
    """The edge widths of the shared borders, per pair and point by point.

    Each reading point gets a width of its own, never below its pair's
    (:func:`edge_widths`): a step it reads, that step's width (at least
    :data:`UNSURE_SIGMA` where the photo's strongest gradient lies more than
    :data:`MISPLACED` from the outline); both sides readable but no step,
    :data:`FLAT_SIGMA` (the border crosses a flat area: a label map cut
    there); neither, its pair's width. A cell of the map gets the median of
    the points in it and its 8 neighbours, in steps of 1 / :data:`MAP_STEPS` px.

    Parameters
    ----------
    rgb, index : as :func:`edge_widths`
    regions : list of Region
        As stored: the map's cells are where their shared borders pass (:func:`border_cells`).
    drawn : list of Region, optional
        The same regions with their outlines as drawn (the readings are taken
        along them); default ``regions``.
    cell : int
        Cell side of the map, px.

    Returns
    -------
    blur : ndarray (n, 3)
        :func:`edge_widths`.
    blur_map : BlurMap or None
        None without shared borders.
    """
    h, w = index.shape
    r = _readings(rgb, regions if drawn is None else drawn, index)
    if r is None:
        return np.zeros((0, 3)), None
    pair = _pair_widths(r, len(regions))
    f, a, b, ok, placed, sigma_eff, offset = r
    n_reg = len(regions) + 1
    # each point's width; unreadable points take their pair's
    pair_keys = (pair[:, 0] * n_reg + pair[:, 1]).astype(np.int64)  # sorted, as edge_widths lists them
    key = (a * n_reg + b).astype(np.int64)
    pair_sigma = np.zeros(len(key))
    if len(pair_keys):
        at = np.clip(np.searchsorted(pair_keys, key), 0, len(pair_keys) - 1)
        pair_sigma = np.where(pair_keys[at] == key, pair[at, 2], 0.0)
    sp = pair_sigma.copy()
    sp[placed & ~ok] = FLAT_SIGMA
    step = np.sqrt(np.maximum(sigma_eff[ok] ** 2 - S0 ** 2, 0.0))
    step = np.where(np.abs(offset[ok]) > MISPLACED, np.maximum(step, UNSURE_SIGMA), step)
    sp[ok] = step
    # never narrower than the pair's: one point's reading is noisy, and where a stretch reads sharp the
    # pair's rules (an outline off the photo's edge somewhere along it) still hold
    sp = np.maximum(sp, pair_sigma)
    try:
        cells = border_cells(regions, w, h, cell)
    except ValueError:
        return pair, None  # borders too long to map (far beyond any photo): one width per pair
    keys, vals = _blocks(f, sp, w, h, cell)
    if vals.size == 0:
        return pair, fill_map(w, h, cell, cells, np.zeros(len(cells), np.float32))
    order = np.lexsort((vals, keys))
    keys, vals = keys[order], vals[order]
    lo = np.searchsorted(keys, cells, side="left")
    count = np.searchsorted(keys, cells, side="right") - lo
    has = count > 0
    mid = np.where(has, 0.5 * (vals[np.minimum(lo + (count - 1) // 2, len(vals) - 1)]
                               + vals[np.minimum(lo + count // 2, len(vals) - 1)]), 0.0)
    values = np.where(mid < MIN_SIGMA, 0.0, np.round(np.minimum(mid, MAX_SIGMA) * MAP_STEPS) / MAP_STEPS)
    values = values.astype(np.float32)
    return pair, fill_map(w, h, cell, cells, values)


def _blocks(f: np.ndarray, values: np.ndarray, width: int, height: int, cell: int):
    """Every point's ``values`` entry counted in its cell's 3 x 3 block: ``(cell keys, values)``, a point
    once for each cell of the map its block reaches."""
    gh, gw = -(-int(height) // cell), -(-int(width) // cell)
    ci = np.clip(np.floor(f[:, 1] / cell).astype(np.int64), 0, gh - 1)
    cj = np.clip(np.floor(f[:, 0] / cell).astype(np.int64), 0, gw - 1)
    near = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)]
    inside = [(ci + di >= 0) & (ci + di < gh) & (cj + dj >= 0) & (cj + dj < gw) for di, dj in near]
    keys = np.concatenate([((ci + di) * gw + cj + dj)[m] for (di, dj), m in zip(near, inside)])
    return keys, np.concatenate([values[m] for m in inside])


def soften_map(blur_map: BlurMap, rgb: np.ndarray, vector: np.ndarray, regions, index: np.ndarray,
               drawn=None) -> BlurMap | None:
    """``blur_map`` with the cells where the vector image steps as the photo does not raised to
    :data:`FLAT_SIGMA`, or None when none is.

    Magnified, a sharp vector step the photo does not share fights the detail
    layer, which holds the difference at scale 1 pixel by pixel and is
    interpolated smoothly between: a seam. A stored cell is raised where at
    least :data:`FALSE_BLOCK` of the points of its 3 x 3 block are false steps
    (:func:`false_steps`, read :data:`FALSE_PROBE` px either side); borders of
    transparent regions are left alone (their colours are no picture's, their
    edge is the alpha's).

    Parameters
    ----------
    blur_map : BlurMap
        The map read from the photo (:func:`edge_width_map`), of ``regions``.
    rgb : ndarray (H, W, 3)
        The colours the vector image and its texture are fitted to.
    vector : ndarray (H, W, 3)
        The vector image rendered at scale 1, before its detail layer.
    regions, index, drawn : as :func:`edge_width_map`
    """
    h, w = index.shape
    points = _points(regions if drawn is None else drawn, index)
    if points is None:
        return None
    f, a, b, normal, region_at = points
    # read close to the border: a thin piece of a region (a finger of an object split in two) is where
    # the step shows most
    near_a, near_b = f + FALSE_PROBE * normal, f - FALSE_PROBE * normal
    rgb = np.asarray(rgb)[..., :3]
    false = (region_at(near_a) == a) & (region_at(near_b) == b) & false_steps(
        _bilinear(rgb, near_a) - _bilinear(rgb, near_b), _bilinear(vector, near_a) - _bilinear(vector, near_b))
    clear = np.array([bool(getattr(reg, "transparent", False)) for reg in regions] + [False])
    false &= ~clear[a] & ~clear[b]
    if not false.any():
        return None
    cell = blur_map.cell
    try:
        cells = border_cells(regions, w, h, cell)
    except ValueError:
        return None
    keys, vals = _blocks(f, false.astype(np.int64), w, h, cell)
    total = np.bincount(keys, minlength=len(blur_map.sigma.ravel()))
    flagged = np.bincount(keys, vals, minlength=total.size)
    values = blur_map.sigma.ravel()[cells].astype(np.float32)
    raise_ = (FALSE_BLOCK * total[cells] <= flagged[cells]) & (flagged[cells] > 0) & (values < FLAT_SIGMA)
    if not raise_.any():
        return None
    values[raise_] = FLAT_SIGMA
    return fill_map(w, h, cell, cells, values)


__all__ = ["FILL_RINGS", "FLAT_SIGMA", "MAP_CELL", "MAP_STEPS", "MAX_MAP_POINTS", "MAX_SIGMA", "MIN_CONTRAST",
           "MIN_POINTS", "MIN_SIGMA", "MISPLACED", "PROBE", "S0", "UNSURE_SIGMA", "border_cells", "edge_width_map",
           "edge_widths", "false_steps", "fill_map", "map_at", "soften_map"]
