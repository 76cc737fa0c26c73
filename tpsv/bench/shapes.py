"""The synthetic test picture of the edge benchmark: a disc, a rotated square and a
ring with linear-gradient fills on a linear-gradient background, drawn analytically.

A pixel's value is the area average (box filter) of the scene over the pixel.
Every fill is affine in x and y and never clipped, so a pixel lying wholly inside
one shape is exact at its centre; a pixel crossed by a border is supersampled
on a grid of :data:`DENSITY` x :data:`DENSITY` samples per scale-1 pixel (``DENSITY /
scale`` per output pixel and axis). The sample grid is therefore the same at
every scale that divides :data:`DENSITY`, and the scale-k picture area-downscaled
by k equals the scale-1 picture up to float rounding.

Coordinates are scale-1 pixels: pixel (i, j) of the scale-1 picture covers
``[j, j+1] x [i, i+1]``; at scale k, output pixel (i, j) covers
``[j/k, (j+1)/k] x [i/k, (i+1)/k]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Samples per scale-1 pixel and axis on border pixels.
DENSITY = 64
#: Labels of the label map.
BACKGROUND, DISC, SQUARE, RING = 0, 1, 2, 3
#: Samples evaluated at once (bounds memory).
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Fill:
    """An affine colour ``c0 + (c1 - c0) * t``, ``t = 0.5 + dot(p - centre, dir) / (2 R)``,
    in ``[0, 1]`` wherever ``|p - centre| <= R``."""

    c0: np.ndarray
    c1: np.ndarray
    angle: float
    centre: tuple[float, float]
    reach: float

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        d = (x - self.centre[0]) * np.cos(self.angle) + (y - self.centre[1]) * np.sin(self.angle)
        t = (0.5 + d / (2.0 * self.reach))[..., None]
        return self.c0 + (self.c1 - self.c0) * t


@dataclass(frozen=True)
class Scene:
    """Shapes of one variant, in scale-1 pixels."""

    size: int
    disc: tuple[float, float, float]  # cx, cy, r
    square: tuple[float, float, float, float]  # cx, cy, half side, angle (rad)
    ring: tuple[float, float, float, float]  # cx, cy, r outer, r inner
    fills: tuple[Fill, Fill, Fill, Fill]  # background, disc, square, ring

    def boundary_distance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest shape border."""
        cx, cy, r = self.disc
        dist = np.abs(np.hypot(x - cx, y - cy) - r)
        cx, cy, ro, ri = self.ring
        rad = np.hypot(x - cx, y - cy)
        dist = np.minimum(dist, np.minimum(np.abs(rad - ro), np.abs(rad - ri)))
        return np.minimum(dist, np.abs(self._square_sdf(x, y)))

    def _square_sdf(self, x, y):
        cx, cy, h, a = self.square
        u = np.abs((x - cx) * np.cos(a) + (y - cy) * np.sin(a)) - h
        v = np.abs(-(x - cx) * np.sin(a) + (y - cy) * np.cos(a)) - h
        outside = np.hypot(np.maximum(u, 0), np.maximum(v, 0))
        return outside + np.minimum(np.maximum(u, v), 0)

    def label(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Owner of each point: :data:`BACKGROUND`, :data:`DISC`, :data:`SQUARE` or :data:`RING`."""
        out = np.full(np.shape(x), BACKGROUND, np.int32)
        cx, cy, r = self.disc
        out[np.hypot(x - cx, y - cy) < r] = DISC
        out[self._square_sdf(x, y) < 0] = SQUARE
        cx, cy, ro, ri = self.ring
        rad = np.hypot(x - cx, y - cy)
        out[(rad < ro) & (rad >= ri)] = RING
        return out

    def colour(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """RGB of the scene at each point, shape ``x.shape + (3,)``."""
        lab = self.label(x, y)
        out = np.empty(np.shape(x) + (3,), np.float64)
        for k, fill in enumerate(self.fills):
            m = lab == k
            if m.any():
                out[m] = fill(x[m], y[m])
        return out


def _colour(rng, avoid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Two endpoint colours of a gradient, its mean at least 0.25 (mean abs) from ``avoid``."""
    while True:
        c0, c1 = rng.uniform(0.05, 0.95, 3), rng.uniform(0.05, 0.95, 3)
        if avoid is None or np.abs((c0 + c1) / 2 - avoid).mean() >= 0.25:
            return c0, c1


def scene(size: int = 96, seed: int = 0) -> Scene:
    """The scene of variant ``seed``: positions, sizes, angles and colours drawn from
    ``numpy.random.default_rng(seed)``; shapes never overlap and stay inside the frame."""
    rng = np.random.default_rng(seed)
    s = float(size)
    while True:
        disc = (s * (0.28 + rng.uniform(-0.03, 0.03)), s * (0.30 + rng.uniform(-0.03, 0.03)),
                s * rng.uniform(0.145, 0.175))
        sq = (s * (0.72 + rng.uniform(-0.03, 0.03)), s * (0.32 + rng.uniform(-0.03, 0.03)),
              s * rng.uniform(0.11, 0.135), rng.uniform(0.1, np.pi / 2 - 0.1))
        ro = s * rng.uniform(0.17, 0.2)
        ring = (s * (0.5 + rng.uniform(-0.04, 0.04)), s * (0.72 + rng.uniform(-0.03, 0.03)),
                ro, ro * rng.uniform(0.45, 0.65))
        circles = [(disc[0], disc[1], disc[2]), (sq[0], sq[1], sq[2] * np.sqrt(2)), (ring[0], ring[1], ring[2])]
        ok = all(min(cx - r, cy - r, s - cx - r, s - cy - r) >= 0.04 * s for cx, cy, r in circles)
        for i in range(3):
            for j in range(i):
                a, b = circles[i], circles[j]
                ok &= np.hypot(a[0] - b[0], a[1] - b[1]) >= a[2] + b[2] + 0.03 * s
        if ok:
            break
    bg = _colour(rng)
    mean_bg = (bg[0] + bg[1]) / 2
    fills = [Fill(*bg, rng.uniform(0, 2 * np.pi), (s / 2, s / 2), s / np.sqrt(2))]
    for cx, cy, r in circles:
        fills.append(Fill(*_colour(rng, mean_bg), rng.uniform(0, 2 * np.pi), (cx, cy), r))
    return Scene(size=size, disc=disc, square=sq, ring=ring, fills=tuple(fills))


def draw(sc: Scene, scale: float = 1, density: int = DENSITY) -> tuple[np.ndarray, np.ndarray]:
    """Area-averaged picture of ``sc`` at ``scale`` and its centre-sample label map.

    Returns
    -------
    rgb : ndarray (H, W, 3) float32, H = W = round(size * scale)
    labels : ndarray (H, W) int32
        Owner of each output pixel's centre.
    """
    n = max(1, int(round(sc.size * scale)))
    px = sc.size / n  # output pixel size in scale-1 pixels
    c = (np.arange(n) + 0.5) * px
    yc, xc = np.meshgrid(c, c, indexing="ij")
    labels = sc.label(xc, yc)
    rgb = sc.colour(xc, yc)
    # a pixel whose centre is further than half its diagonal from every border lies
    # in one shape: its affine fill averages to the centre value
    border = np.flatnonzero(sc.boundary_distance(xc, yc) <= px * np.sqrt(0.5) * 1.001)
    ss = max(1, int(round(density * px)))
    off = ((np.arange(ss) + 0.5) / ss - 0.5) * px
    oy, ox = (g.ravel() for g in np.meshgrid(off, off, indexing="ij"))
    flat = rgb.reshape(-1, 3)
    step = max(1, _CHUNK // (ss * ss))
    for i in range(0, border.size, step):
        idx = border[i:i + step]
        x = xc.ravel()[idx][:, None] + ox
        y = yc.ravel()[idx][:, None] + oy
        flat[idx] = sc.colour(x, y).mean(axis=1)
    return rgb.astype(np.float32), labels


def shapes(size: int = 96, scale: float = 1, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The test picture of variant ``seed`` at ``scale`` (see the module docstring).

    Parameters
    ----------
    size : int
        Side of the scale-1 picture in pixels.
    scale : float
        Magnification; the output is ``round(size * scale)`` px square.
    seed : int
        Variant.

    Returns
    -------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int32
        :data:`BACKGROUND`, :data:`DISC`, :data:`SQUARE` or :data:`RING`: the
        owner of each pixel's centre (at scale 1: the label map for vectorize).
    """
    return draw(scene(size, seed), scale)
