"""Flat-colour drawings of the bench's graphics table: what a logo, a diagram or pixel art is made of.

Four pictures, each with its exact magnified picture:

* ``frames``: nested square frames of flat colours crossed by a bar 2 px
  wide, on pixel edges (48 x 48);
* ``grid``: squares of 5 px between gutters 1 px wide, on pixel edges
  (50 x 50);
* ``logo``: a ring, a rectangle and a line 2 px wide at 36 degrees over them,
  anti-aliased (64 x 48);
* ``dots``: discs of radii 2.5, 4 and 6 px and an elliptic ring, anti-aliased
  (64 x 48): small round shapes, which a curve through a few vertices must
  keep round.

The first two have no anti-aliasing: their exact picture at scale ``k`` is the
nearest-neighbour upscale. An anti-aliased one (:data:`ANTI_ALIASED`) is the
area average (box filter) of its scene over each pixel, sampled on :data:`DENSITY` x :data:`DENSITY` points per
scale-1 pixel, and its scale-``k`` picture the average of the same samples
over each output pixel (``k`` divides :data:`DENSITY`), so that the
scale-``k`` picture area-downscaled by ``k`` is the scale-1 picture.
"""

from __future__ import annotations

import numpy as np

#: Samples per scale-1 pixel and axis of the anti-aliased drawing.
DENSITY = 32
#: The drawings, in the table's order.
NAMES = ("frames", "grid", "logo", "dots")


def _frames() -> tuple[np.ndarray, np.ndarray]:
    labels = np.zeros((48, 48), np.int32)
    labels[6:42, 6:42] = 1
    labels[12:36, 12:36] = 2
    labels[18:30, 18:30] = 3
    labels[2:46, 23:25] = 4
    colours = np.array([[240, 240, 230], [40, 90, 200], [230, 180, 40], [250, 250, 250], [200, 30, 40]])
    return labels, colours


def grid_labels(n: int) -> np.ndarray:
    """The label map of ``n x n`` squares of 5 px between gutters 1 px wide (``2 + 6 n`` px square:
    a margin of 2 px before the first squares, 1 px after the last): 0 the gutters, the squares
    ``1 .. n^2`` row by row."""
    labels = np.zeros((2 + 6 * n, 2 + 6 * n), np.int32)
    for i in range(n):
        for j in range(n):
            labels[2 + 6 * i:7 + 6 * i, 2 + 6 * j:7 + 6 * j] = 1 + n * i + j
    return labels


def _grid() -> tuple[np.ndarray, np.ndarray]:
    return grid_labels(8), np.random.default_rng(3).integers(0, 256, (65, 3))


def _logo_scene(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """sRGB (0-255) of the logo's scene at points ``(x, y)`` (scale-1 pixels)."""
    out = np.empty(x.shape + (3,))
    out[:] = (245, 240, 235)
    r = np.hypot(x - 14.0, y - 24.0)
    out[(r < 11.0) & (r >= 5.5)] = (200, 90, 40)
    out[(np.abs(x - 42.0) < 14.0) & (np.abs(y - 16.0) < 8.0)] = (40, 60, 200)
    # a segment from (24, 4) to (60, 30), 2 px wide
    ux, uy = 36.0, 26.0
    n = np.hypot(ux, uy)
    t = ((x - 24.0) * ux + (y - 4.0) * uy) / n
    d = np.abs((x - 24.0) * uy - (y - 4.0) * ux) / n
    out[(d < 1.0) & (t > 0.0) & (t < n)] = (25, 25, 30)
    return out


def _dots_scene(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """sRGB (0-255) of the dots' scene at points ``(x, y)`` (scale-1 pixels)."""
    out = np.empty(x.shape + (3,))
    out[:] = (250, 248, 240)
    for cx, cy, r, colour in ((9.3, 9.6, 2.5, (30, 40, 160)), (23.7, 11.2, 4.0, (210, 40, 60)),
                              (45.4, 12.8, 6.0, (20, 150, 90))):
        out[np.hypot(x - cx, y - cy) < r] = colour
    # an elliptic ring, turned by 0.3 rad: semi-axes 13 x 8 outside, 8 x 4 inside
    c, s = np.cos(0.3), np.sin(0.3)
    u, v = (x - 32.2) * c + (y - 33.1) * s, -(x - 32.2) * s + (y - 33.1) * c
    out[((u / 13.0) ** 2 + (v / 8.0) ** 2 < 1) & ((u / 8.0) ** 2 + (v / 4.0) ** 2 >= 1)] = (240, 170, 30)
    return out


#: The drawings drawn anti-aliased from a scene (the others on pixel edges), and their scenes.
SCENES = {"logo": _logo_scene, "dots": _dots_scene}
ANTI_ALIASED = tuple(SCENES)


def _anti_aliased(scene, scale: int, w: int = 64, h: int = 48) -> np.ndarray:
    """A scene at ``scale`` (float in [0, 1]), each pixel the average of its samples."""
    per = DENSITY // scale
    ys = (np.arange(h * DENSITY) + 0.5) / DENSITY
    xs = (np.arange(w * DENSITY) + 0.5) / DENSITY
    samples = scene(*np.meshgrid(xs, ys))
    return samples.reshape(h * scale, per, w * scale, per, 3).mean(axis=(1, 3)) / 255.0


def drawing(name: str, scale: int = 1) -> np.ndarray:
    """The drawing ``name`` (one of :data:`NAMES`) at ``scale`` (a divisor of :data:`DENSITY`),
    (H, W, 3) float32 in [0, 1]; at scale 1 quantised to 8 bits, as a PNG holds it."""
    if DENSITY % int(scale):
        raise ValueError(f"scale {scale} does not divide {DENSITY}")
    if name in ANTI_ALIASED:
        img = _anti_aliased(SCENES[name], int(scale))
    else:
        labels, colours = _frames() if name == "frames" else _grid()
        big = np.repeat(np.repeat(labels, scale, 0), scale, 1)
        img = colours[big] / 255.0
    if scale == 1:
        img = np.round(img * 255.0) / 255.0
    return img.astype(np.float32)


__all__ = ["DENSITY", "NAMES", "drawing", "grid_labels"]
