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
get at least :data:`UNSURE_SIGMA`.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: Distance (px) from the border at which each side's colour is read.
PROBE = 4.0
#: Blur of a sharp, box-sampled step as this reading sees it (px; synthetic edges at 0, 0.3 and 0.79 rad:
#: sharp steps then read 0-0.28 px, steps blurred by 0.5, 1, 1.5, 2, 3 px read 0.44-0.5, 0.94-1.0, 1.44, 1.88, 2.38).
S0 = 0.85
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


def _shared_edges(regions) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """``(a, b, start, end)`` of every outline edge regions ``a < b`` share (exact vertices)."""
    from ..codec import chains
    from ..codec.quant import OUTLINE_SCALE

    polys, owner = [], []
    for r, reg in enumerate(regions):
        for p in reg.outline:
            polys.append(np.rint(np.asarray(p, np.float64) * OUTLINE_SCALE).astype(np.int64))
            owner.append(r)
    part = chains.partners(polys)
    out = []
    for i, (p, pt) in enumerate(zip(polys, part)):
        q = np.roll(p, -1, axis=0)
        for e in np.flatnonzero(pt[:, 0] >= 0):
            a, b = owner[i], owner[int(pt[e, 0])]
            if a < b:
                out.append((a, b, p[e] / OUTLINE_SCALE, q[e] / OUTLINE_SCALE))
    return out


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
    rgb = np.asarray(rgb)[..., :3]  # float32 is read in float64 where sampled (no float64 copy of the photo)
    edges = _shared_edges(regions)
    if not edges:
        return np.zeros((0, 3))
    grad = np.zeros(rgb.shape[:2])
    for k in range(3):
        channel = rgb[..., k].astype(np.float64)
        term = ndimage.sobel(channel, 0) ** 2
        term += ndimage.sobel(channel, 1) ** 2
        grad += term
    del channel, term
    grad = np.sqrt(grad, out=grad)
    grad /= 8.0
    pair = np.array([(a, b) for a, b, _, _ in edges], np.int64)
    p0 = np.array([s for _, _, s, _ in edges])
    p1 = np.array([e for _, _, _, e in edges])
    seg = p1 - p0
    length = np.hypot(*seg.T)
    n_pts = np.maximum(1, np.floor(length)).astype(np.int64)
    which = np.repeat(np.arange(len(edges)), n_pts)
    t = (np.arange(int(n_pts.sum())) - np.repeat(np.cumsum(n_pts) - n_pts, n_pts) + 0.5) / n_pts[which]
    f = p0[which] + t[:, None] * seg[which]
    normal = np.stack([-seg[which, 1], seg[which, 0]], 1) / np.maximum(length[which], 1e-12)[:, None]
    a, b = pair[which, 0], pair[which, 1]
    H, W = index.shape

    def region_at(xy):
        x = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, W - 1)
        y = np.clip(np.floor(xy[:, 1]).astype(np.int64), 0, H - 1)
        return index[y, x]

    # the normal points into region a
    flip = region_at(f + normal) != a
    normal[flip] *= -1
    side_a, side_b = f + PROBE * normal, f - PROBE * normal
    ok = (region_at(side_a) == a) & (region_at(side_b) == b) & (region_at(f + normal) == a) & \
        (region_at(f - normal) == b)
    ok &= (side_a.min(1) >= 0) & (side_b.min(1) >= 0) & (side_a[:, 0] <= W) & (side_b[:, 0] <= W) & \
        (side_a[:, 1] <= H) & (side_b[:, 1] <= H)
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
    out = []
    key = a * (len(regions) + 1) + b
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
        ra, rb = divmod(int(k), len(regions) + 1)
        out.append((ra, rb, np.round(min(sigma, MAX_SIGMA) * 16) / 16))
    return np.array(out, np.float64).reshape(-1, 3)


__all__ = ["MAX_SIGMA", "MIN_CONTRAST", "MIN_POINTS", "MIN_SIGMA", "MISPLACED", "PROBE", "S0", "UNSURE_SIGMA",
           "edge_widths"]
