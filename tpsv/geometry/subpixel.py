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
  - mu_B|^2`` (clipped to [0, 1]), ``mu`` the mean colours of the two regions'
  interior pixels in a :data:`WINDOW` x :data:`WINDOW` window around it. An
  anti-aliased or slightly blurred edge then puts the 0.5 level where the
  colour is half way, not on the pixel edge.
* Where the two sides' colours are too close to tell (``|mu_A - mu_B|`` below
  :data:`CONTRAST`), ``m`` leans, in proportion, on the region's mask smoothed
  by a Gaussian of :data:`SMOOTH_SIGMA` px, whose level 0.5 follows pixel
  edges on straight runs and cuts staircases into smooth diagonals.

Between two regions ``m_A + m_B = 1`` on every border pixel (both readings
and both smoothed masks add up to 1), so their outlines are the same curve
and neither a gap nor an overlap opens between them; at junctions of three
regions small gaps remain, which the renderer fills as it always has.

The curve is simplified by Ramer-Douglas-Peucker at :data:`TOLERANCE` px
where the colours are trusted, easing to :data:`LOOSE_TOLERANCE` px where
only the smoothed mask speaks (it is no more precise than the label map). A
region whose fitted outline would lose it (a one-pixel line of a colour
close to a neighbour's, say) keeps its traced outline.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from . import outline

#: Side of the window (px) whose interior pixels give each side's colour.
WINDOW = 5
#: Colour difference (sRGB, 0-1, Euclidean) above which a border is read from the image alone.
CONTRAST = 0.08
#: Gaussian (px) that smooths a region's mask where the colours cannot tell.
SMOOTH_SIGMA = 0.7
#: RDP tolerance of fitted outlines where the colours tell where the border is, px.
TOLERANCE = 0.06
#: Outline vertices are rounded to 1/GRID px, the ``.tpsv`` file's outline quantum
#: (``tpsv.codec.quant.OUTLINE_SCALE``; a test keeps them equal).
GRID = 8
#: RDP tolerance where they cannot (low contrast, texture): the label map's own precision.
LOOSE_TOLERANCE = 0.5

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


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
    trust : ndarray (H, W) float64
        How far ``alpha`` is to be believed, in [0, 1] (0 off the border).
    near_trust : ndarray (H, W) float64
        The largest ``trust`` in each pixel's 3 x 3 neighbourhood (what an
        outline point between pixels goes by).
    """

    def __init__(self, comp: np.ndarray, rgb: np.ndarray):
        comp = np.asarray(comp, np.int64)
        rgb = np.asarray(rgb, np.float64)[..., :3]
        H, W = comp.shape
        pad = np.pad(comp, 1, mode="edge")
        votes = []
        for dy, dx in _NEIGHBOURS:
            nb = pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
            votes.append(np.where(nb != comp, nb, -1))
        votes = np.stack(votes, axis=-1)  # (H, W, 8)
        border = (votes >= 0).any(axis=-1)
        self.across = np.full((H, W), -1, np.int32)
        self.alpha = np.ones((H, W))
        self.trust = np.zeros((H, W))
        self.near_trust = self.trust
        ys, xs = np.nonzero(border)
        if ys.size == 0:
            return
        v = votes[ys, xs]
        # the most frequent other region among the neighbours (ties: the smaller index)
        best = np.full(len(ys), -1, np.int64)
        count = np.zeros(len(ys), np.int64)
        for k in range(8):
            c = (v == v[:, k:k + 1]).sum(axis=1)
            take = (v[:, k] >= 0) & ((c > count) | ((c == count) & (v[:, k] < best)))
            best[take] = v[take, k]
            count[take] = c[take]
        own = comp[ys, xs]
        self.across[ys, xs] = best
        # side colours: interior (non-border) pixels of each side in the window
        h = WINDOW // 2
        cpad = np.pad(comp, h, mode="constant", constant_values=-1)
        bpad = np.pad(border, h, mode="constant", constant_values=True)
        rpad = np.pad(rgb, ((h, h), (h, h), (0, 0)), mode="edge")
        offs = [(dy, dx) for dy in range(-h, h + 1) for dx in range(-h, h + 1)]
        n = len(ys)
        sums = {key: np.zeros((n, 3)) for key in ("a", "b", "fa", "fb")}
        squares = {key: np.zeros(n) for key in ("a", "b", "fa", "fb")}
        counts = {key: np.zeros(n) for key in ("a", "b", "fa", "fb")}
        for dy, dx in offs:
            cc = cpad[ys + h + dy, xs + h + dx]
            bb = bpad[ys + h + dy, xs + h + dx]
            col = rpad[ys + h + dy, xs + h + dx]
            sq = (col * col).sum(axis=1)
            for key, sel in (("a", (cc == own) & ~bb), ("b", (cc == best) & ~bb), ("fa", cc == own), ("fb", cc == best)):
                sums[key] += col * sel[:, None]
                squares[key] += sq * sel
                counts[key] += sel

        def side(inner, whole):
            # no interior pixel of a side in the window (thin parts): all its pixels there
            use = (counts[inner] > 0)[:, None]
            k = np.where(use[:, 0], counts[inner], np.maximum(counts[whole], 1))
            mu = np.where(use, sums[inner], sums[whole]) / np.maximum(k, 1)[:, None]
            var = np.where(use[:, 0], squares[inner], squares[whole]) / np.maximum(k, 1) - (mu * mu).sum(axis=1)
            return mu, np.sqrt(np.maximum(var, 0.0))

        mu_a, sd_a = side("a", "fa")
        mu_b, sd_b = side("b", "fb")
        d = mu_a - mu_b
        dd = (d * d).sum(axis=1)
        a = ((rgb[ys, xs] - mu_b) * d).sum(axis=1) / np.maximum(dd, 1e-12)
        self.alpha[ys, xs] = np.clip(a, 0.0, 1.0)
        # a side whose colour varies (texture) is a poor reference: trust fades out as its
        # spread goes from a quarter to a half of the contrast
        contrast = np.sqrt(dd)
        texture = np.clip(2.0 - 4.0 * (sd_a + sd_b) / np.maximum(contrast, 1e-12), 0.0, 1.0)
        self.trust[ys, xs] = np.clip(contrast / CONTRAST - 1.0, 0.0, 1.0) * texture
        self.near_trust = ndimage.maximum_filter(self.trust, size=3)

    def field(self, comp: np.ndarray, region: int, window: tuple[slice, slice]) -> np.ndarray:
        """The membership field ``m`` of ``region`` in ``window`` (rows, cols) of the image."""
        sub = comp[window] == region
        smooth = ndimage.gaussian_filter(sub.astype(np.float64), SMOOTH_SIGMA, mode="nearest")
        across = self.across[window]
        alpha = self.alpha[window]
        trust = self.trust[window]
        # read from the colour: own border pixels facing one region, and that region's facing back
        read = np.where(sub, alpha, 1.0 - alpha)
        facing = np.where(sub, across >= 0, across == region)
        w = np.where(facing, trust, 0.0)
        m = w * read + (1.0 - w) * smooth
        # away from the border the mask itself (the smoothing reaches 2 px into flat parts)
        border_near = ndimage.binary_dilation(across >= 0, iterations=1)
        return np.where(border_near, m, sub.astype(np.float64))


def fitted_outline(reading: BorderReading, comp: np.ndarray, region: int, mask: np.ndarray,
                   tolerance: float = TOLERANCE) -> list[np.ndarray] | None:
    """Sub-pixel outline of ``region`` (outer polygon first, then holes), or None when it would lose the region.

    Parameters
    ----------
    reading : BorderReading
    comp : ndarray (H, W) int
        Region of every pixel.
    region : int
    mask : ndarray (H, W) bool
        ``comp == region``.
    tolerance : float
        RDP tolerance, px.

    Returns
    -------
    list of ndarray (k, 2) float64, or None
    """
    import cv2
    from skimage.measure import find_contours

    H, W = comp.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(int(rows[0]) - 2, 0), min(int(rows[-1]) + 3, H)
    c0, c1 = max(int(cols[0]) - 2, 0), min(int(cols[-1]) + 3, W)
    m = reading.field(comp, region, (slice(r0, r1), slice(c0, c1)))
    # beyond the image's frame the field carries on as it is at the frame (the
    # frame is no border: contours cross it straight and are cut there), and
    # everything is closed by a ring of zeros
    P = 3
    m = np.pad(m, P, mode="edge")
    if r0 > 0:
        m[:P] = 0.0
    if r1 < H:
        m[-P:] = 0.0
    if c0 > 0:
        m[:, :P] = 0.0
    if c1 < W:
        m[:, -P:] = 0.0
    m = np.pad(m, 1, constant_values=0.0)
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
    # where the colours tell where the border is, keep it to ``tolerance``; where
    # only the smoothed mask does, the label map's own precision (half a pixel) is all there is
    near_trust = reading.near_trust
    out = []
    for i, p in enumerate([outer] + holes):
        cx = np.clip(np.floor(p[:, 0]).astype(np.int64), 0, W - 1)
        cy = np.clip(np.floor(p[:, 1]).astype(np.int64), 0, H - 1)
        tol = tolerance + (LOOSE_TOLERANCE - tolerance) * (1.0 - near_trust[cy, cx])
        # where a border meets the image's frame, and the frame's corners, stay where they are
        fx = (p[:, 0] == 0.0) | (p[:, 0] == W)
        fy = (p[:, 1] == 0.0) | (p[:, 1] == H)
        frame = fx | fy
        tol = np.where((fx & fy) | (frame & ~(np.roll(frame, 1) & np.roll(frame, -1))), 0.0, tol)
        # on the file's grid already: the encoder's scale-1 maps are then the decoded file's
        s = np.round(simplify_closed(p, tol) * GRID) / GRID
        s = s[np.any(s != np.roll(s, 1, axis=0), axis=1)]
        a = outline.signed_area(s)
        if len(s) < 3 or (a <= 0 if i == 0 else a >= 0):
            if i == 0:
                return None
            continue
        out.append(s)
    # the fitted outline must still hold the region (pixel centres, as the renderer samples them)
    sub = mask[r0:r1, c0:c1]
    got = outline._fill_polys(sub.shape, out, offset=(c0, r0)).astype(bool)
    n = int(sub.sum())
    lost = int(np.count_nonzero(sub & ~got))
    if not got[sub].any() or lost > 0.25 * n + 1:
        return None
    return [np.ascontiguousarray(p, np.float64) for p in out]


def _rdp_open(p: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """Indices kept by Ramer-Douglas-Peucker on an open chain, each point with its own tolerance."""
    keep = np.zeros(len(p), bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(p) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        seg = p[b] - p[a]
        q = p[a + 1:b] - p[a]
        L = float(np.hypot(*seg))
        if L > 1e-12:
            d = np.abs(q[:, 0] * seg[1] - q[:, 1] * seg[0]) / L
        else:
            d = np.hypot(q[:, 0], q[:, 1])
        excess = d - tol[a + 1:b]
        k = int(np.argmax(excess))
        if excess[k] > 0:
            m = a + 1 + k
            keep[m] = True
            stack.append((a, m))
            stack.append((m, b))
    return np.flatnonzero(keep)


def simplify_closed(poly: np.ndarray, tol) -> np.ndarray:
    """Ramer-Douglas-Peucker of a closed polygon with a tolerance per point (px).

    The polygon is cut at its first point and the point farthest from it, and
    each half simplified; every dropped point lies within its own tolerance of
    the kept chord (of its line, as ``cv2.approxPolyDP`` measures).
    """
    p = np.asarray(poly, np.float64)
    tol = np.broadcast_to(np.asarray(tol, np.float64), (len(p),))
    if len(p) < 4:
        return p.copy()
    far = int(np.argmax(np.hypot(*(p - p[0]).T)))
    if far == 0:
        return p[:1].copy()
    first = _rdp_open(p[:far + 1], tol[:far + 1])
    ring = np.concatenate([p[far:], p[:1]])
    second = _rdp_open(ring, np.concatenate([tol[far:], tol[:1]]))[1:-1] + far
    return p[np.concatenate([first, second])]


__all__ = ["BorderReading", "CONTRAST", "LOOSE_TOLERANCE", "SMOOTH_SIGMA", "TOLERANCE", "WINDOW", "fitted_outline",
           "simplify_closed"]
