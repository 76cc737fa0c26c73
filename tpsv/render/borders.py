"""Anti-aliased region borders (render step 5): how much of a pixel the border leaves to the region across.

The region map gives every output pixel one region, sampled at its centre
(:mod:`tpsv.render.pixelmap`), which alone draws a border as a staircase of
whole pixels. Here every pixel that a border crosses gets its coverage
instead: with ``d`` the distance (in output pixels) from the pixel centre to
the nearest outline, the pixel's own region covers ``alpha = min(1, 0.5 + d)``
of it and the region across the border the rest. That is the exact area
coverage of a pixel by a straight border parallel to a pixel side (a box
filter), so the coverages of two pixels facing each other across a border
add up to 1; the colour across is that region's own TPS, evaluated a little
beyond its outline (``(S, T)`` of the pixel in its patch). Borders with the
image frame are not outlines anybody crosses: they stay sharp.

Outlines are cut into pieces of at most :data:`PIECE_PX` output pixels
(longer when an output would need more than :data:`MAX_PIECES`), whose
midpoints go into a k-d tree; each border pixel measures its exact distance
to the :data:`NEAREST` nearest pieces. The region across is the one found at
the pixel's mirror image in that nearest outline (else its nearest
4-neighbour of another region), so junctions of three regions mix the right
pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Longest outline piece, output pixels.
PIECE_PX = 1.0
#: Most outline pieces held for one output (bounds memory: about 100 bytes each while built).
MAX_PIECES = 1 << 21
#: Pieces measured per border pixel.
NEAREST = 8


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
        Coverage of the pixel's own region, in ``[0.5, 1)``.
    xy : ndarray (n, 2) float64
        Pixel centres in the model's pixel space.
    """

    pixels: np.ndarray
    other: np.ndarray
    alpha: np.ndarray
    xy: np.ndarray

    @classmethod
    def none(cls) -> "BorderMix":
        return cls(np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros((0, 2)))


class Borders:
    """Every outline of a model as short pieces in output pixels, prepared once per output size.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.
    """

    def __init__(self, model, width: int, height: int):
        from scipy.spatial import cKDTree

        self.width, self.height = int(width), int(height)
        self.kx = self.width / float(model.width)
        self.ky = self.height / float(model.height)
        k = np.array([self.kx, self.ky])
        ends = [(np.asarray(p, np.float64) * k) for reg in model.regions for p in reg.outline if len(p) >= 2]
        if not ends:
            self.tree = None
            return
        a = np.concatenate(ends)
        b = np.concatenate([np.roll(p, -1, axis=0) for p in ends])
        seg = np.hypot(*(b - a).T)
        ok = np.isfinite(seg)
        a, b, seg = a[ok], b[ok], seg[ok]
        total = float(seg.sum())
        step = max(PIECE_PX, total / MAX_PIECES)
        n = np.maximum(1, np.ceil(seg / step)).astype(np.int64)
        i = np.repeat(np.arange(len(a)), n)
        first = np.cumsum(n) - n
        t0 = (np.arange(int(n.sum())) - first[i]) / n[i]
        d = (b - a)[i]
        self.a = a[i] + t0[:, None] * d
        self.d = d / n[i][:, None]
        self.tree = cKDTree(self.a + 0.5 * self.d)
        self.reach = 0.5 * step

    def mix(self, index: np.ndarray, y0: int = 0, halo: tuple[np.ndarray | None, np.ndarray | None] = (None, None)) -> BorderMix:
        """The border pixels of rows ``y0 .. y0 + len(index)`` and their coverage.

        Parameters
        ----------
        index : ndarray (h, W) int32
            Region of every pixel of the band (``region_index`` rows).
        y0 : int
            Output row of ``index``'s first row.
        halo : (row above, row below)
            The region rows just outside the band (None at the frame's edge),
            so that a band's border pixels are the whole frame's.

        Returns
        -------
        BorderMix
        """
        if self.tree is None or index.size == 0:
            return BorderMix.none()
        h, W = index.shape
        up, down = halo
        ext = np.vstack([index[:1] if up is None else up[None], index, index[-1:] if down is None else down[None]])
        ext = np.hstack([ext[:, :1], ext, ext[:, -1:]])
        own = ext[1:-1, 1:-1]
        differs = np.zeros((h, W), bool)
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            nb = ext[1 + dy:1 + dy + h, 1 + dx:1 + dx + W]
            differs |= (nb != own) & (nb >= 0)
        differs &= own >= 0
        ys, xs = np.nonzero(differs)
        if ys.size == 0:
            return BorderMix.none()
        p = np.column_stack([xs + 0.5, ys + y0 + 0.5])
        k = min(NEAREST, self.tree.n)
        _, near = self.tree.query(p, k=k)
        near = near.reshape(len(p), k)
        a = self.a[near]  # (n, k, 2)
        d = self.d[near]
        w = p[:, None, :] - a
        t = np.clip((w * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
        foot = a + t[..., None] * d
        dist = np.hypot(*(p[:, None, :] - foot).transpose(2, 0, 1))
        best = np.argmin(dist, axis=1)
        rows = np.arange(len(p))
        dmin = dist[rows, best]
        f = foot[rows, best]
        keep = dmin < 0.5
        if not keep.any():
            return BorderMix.none()
        p, f, dmin, ys, xs = p[keep], f[keep], dmin[keep], ys[keep], xs[keep]
        other = self._across(ext, own[ys, xs], p, f, ys, xs, y0)
        ok = other >= 0
        p, dmin, ys, xs, other = p[ok], dmin[ok], ys[ok], xs[ok], other[ok]
        xy = np.column_stack([p[:, 0] / self.kx, p[:, 1] / self.ky])
        return BorderMix(pixels=(ys * W + xs).astype(np.int32), other=other.astype(np.int32),
                         alpha=(0.5 + dmin).astype(np.float32), xy=xy)

    def _across(self, ext, mine, p, f, ys, xs, y0):
        """Region at each pixel's mirror image in its nearest outline, else the nearest 4-neighbour of another region."""
        h, W = ext.shape[0] - 2, ext.shape[1] - 2
        q = 2.0 * f - p
        qx = np.clip(np.floor(q[:, 0]).astype(np.int64) - xs, -1, 1)
        qy = np.clip(np.floor(q[:, 1]).astype(np.int64) - (ys + y0), -1, 1)
        other = ext[1 + ys + qy, 1 + xs + qx]
        bad = (other == mine) | (other < 0)
        if bad.any():
            # the mirror point fell in the pixel's own region (an outline corner): the
            # 8-neighbour of another region whose centre is nearest the mirror point
            ib = np.flatnonzero(bad)
            best = np.full(len(ib), np.inf)
            pick = np.full(len(ib), -1, np.int64)
            for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
                r = ext[1 + ys[ib] + dy, 1 + xs[ib] + dx]
                c = np.column_stack([xs[ib] + dx + 0.5, ys[ib] + y0 + dy + 0.5])
                dd = np.hypot(*(c - q[ib]).T)
                take = (r != mine[ib]) & (r >= 0) & (dd < best)
                best[take] = dd[take]
                pick[take] = r[take]
            other = other.copy()
            other[ib] = pick
        return other


__all__ = ["BorderMix", "Borders", "MAX_PIECES", "NEAREST", "PIECE_PX"]
