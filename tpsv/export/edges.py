"""Region borders for the PDF: which region lies across each outline edge, and soft-edge ribbons.

The renderer (``tpsv.rendering.borders``) mixes the region across into every
pixel a border crosses, with the box-filter coverage of a sharp step, or of
the step blurred by the border's edge width ``sigma`` (``Model.blur``). In
the PDF a sharp border is the anti-aliased edge of a clip path. A soft border
is a soft mask: the region is painted through a luminosity mask that is 1
inside, 0 outside and, across each soft edge, the blurred step
``Phi(d / sigma)`` (``d`` the distance inside the outline), drawn as a
Gouraud-shaded ribbon (PDF shading type 5, a lattice: one row per outline
vertex, one column per ring of constant offset, :data:`RINGS`).

Which region lies across an edge: outlines of neighbouring regions share
their border's vertices (the file stores each border once,
``tpsv.codec.chains``), so an edge is matched to the other region's edge with
the same two end points (to 1/64 px). An edge matched to none (the image
frame, or a gap between outlines) is sharp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.edgewidth import map_at

#: Ring offsets across a soft edge, in units of its sigma, outward (Phi(-k) at ring k).
RINGS = np.linspace(-3.0, 3.0, 13)
#: Largest turn of the ring normal between two rows of a ribbon (radians): joins at corners are round.
JOIN_STEP = np.pi / 8
#: Spacing (px) of the outline points the medial-axis test measures to.
DENSITY_PX = 0.25
#: Most outline points held for that test.
MAX_POINTS = 1 << 22
#: End points of shared edges are matched on this grid (1/px).
_KEY = 64.0


@dataclass
class Ribbon:
    """One run of soft edges of an outline as a lattice of rings.

    Attributes
    ----------
    xy : ndarray (rows, cols, 2) float64
        Ring points of each row (a vertex of the run, or a step of a join),
        model pixels.
    value : ndarray (rows, cols) float64
        Mask value at each point (the blurred step).
    """

    xy: np.ndarray
    value: np.ndarray


def edge_sigmas(model) -> tuple[list[list[np.ndarray]], list[list[np.ndarray]]]:
    """Edge width and region across of every outline edge: per region, per polygon, ``(k,)`` arrays.

    Edge ``i`` of a polygon runs from vertex ``i`` to vertex ``i + 1`` (the
    last one back to vertex 0).

    Parameters
    ----------
    model : Model

    Returns
    -------
    sigmas : list of list of ndarray (k,) float64
        Edge width (source px, 0: sharp): the pair's, or with a blur map
        (``Model.blur_map``) the map's at the edge's middle.
    across : list of list of ndarray (k,) int64
        Region across the edge (-1: none, the image frame or a gap).
    """
    R = len(model.regions)
    polys = [(r, k, np.asarray(p, np.float64)) for r, reg in enumerate(model.regions)
             for k, p in enumerate(reg.outline) if len(p) >= 2]
    out = [[np.zeros(len(p)) for p in reg.outline] for reg in model.regions]
    out_across = [[np.full(len(p), -1, np.int64) for p in reg.outline] for reg in model.regions]
    if not polys:
        return out, out_across
    a = np.concatenate([p for _, _, p in polys])
    b = np.concatenate([np.roll(p, -1, axis=0) for _, _, p in polys])
    reg = np.concatenate([np.full(len(p), r) for r, _, p in polys])
    qa = np.round(a * _KEY).astype(np.int64)
    qb = np.round(b * _KEY).astype(np.int64)
    # an undirected key: the smaller end point first
    first = (qa[:, 0] < qb[:, 0]) | ((qa[:, 0] == qb[:, 0]) & (qa[:, 1] <= qb[:, 1]))
    key = np.where(first[:, None], np.hstack([qa, qb]), np.hstack([qb, qa]))
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    order = np.lexsort((reg, group))
    g, rr = group[order], reg[order]
    across = np.full(len(reg), -1, np.int64)
    # in each group of equal edges, the first and last entries of other regions face each other
    same_next = (g[:-1] == g[1:]) & (rr[:-1] != rr[1:])
    i = np.flatnonzero(same_next)
    across[order[i]] = rr[i + 1]
    across[order[i + 1]] = rr[i]
    sigma = np.zeros(len(reg))
    blur = np.asarray(model.blur, np.float64).reshape(-1, 3)
    bmap = getattr(model, "blur_map", None)
    if bmap is not None:
        # the map's width at each edge's middle (the renderer's at every point of it)
        mid = 0.5 * (a + b)
        width = map_at(np.asarray(bmap.sigma, np.float64), float(bmap.cell), float(bmap.cell), mid[:, 0], mid[:, 1])
        sigma = np.where(across >= 0, np.maximum(width, 0.0), 0.0)
    elif blur.size and R:
        # look the pair (a < b) up in the sorted keys a * R + b of the blur table
        bk = blur[:, 0].astype(np.int64) * R + blur[:, 1].astype(np.int64)
        order_b = np.argsort(bk)
        bk, bs = bk[order_b], blur[order_b, 2]
        ek = np.minimum(reg, across) * R + np.maximum(reg, across)
        j = np.clip(np.searchsorted(bk, ek), 0, bk.size - 1)
        sigma = np.where((across >= 0) & (bk[j] == ek), np.maximum(bs[j], 0.0), 0.0)
    start = 0
    for r, k, p in polys:
        out[r][k] = sigma[start:start + len(p)]
        out_across[r][k] = across[start:start + len(p)]
        start += len(p)
    return out, out_across


def reach(sigmas: list[list[np.ndarray]], sharp_px: float) -> np.ndarray:
    """Pixels beyond its outline each region's paint must reach: ``3 sigma`` of its softest edge, plus ``sharp_px``."""
    return np.array([3.0 * max((float(s.max()) for s in reg if s.size), default=0.0) + sharp_px for reg in sigmas])


def _outward_normals(poly: np.ndarray, hole: bool) -> np.ndarray:
    """Unit normal of each edge pointing out of the region (into the hole, for a hole)."""
    d = np.roll(poly, -1, axis=0) - poly
    left = np.column_stack([-d[:, 1], d[:, 0]])
    left /= np.maximum(np.hypot(left[:, 0], left[:, 1]), 1e-12)[:, None]
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    inward = left if area > 0 else -left
    return inward if hole else -inward


class Ribbons:
    """The soft-edge ribbons of a model's regions (prepared once for all regions).

    A ring point may not cross the medial axis: where another part of any
    outline is nearer to it than its own edge (a thin region, a spike at a
    junction, the far side of a narrow neighbour), the rings stop at the
    point where both are equally near, with the mask value of that offset.
    There the renderer switches to the other border's mix too.

    Parameters
    ----------
    model : Model
    sigmas : list of list of ndarray
        :func:`edge_sigmas` of the model.
    """

    def __init__(self, model, sigmas):
        from scipy.spatial import cKDTree

        self.model = model
        self.sigmas = sigmas
        polys = [np.asarray(p, np.float64) for reg in model.regions for p in reg.outline if len(p) >= 2]
        self.tree = None
        if polys:
            a = np.concatenate(polys)
            b = np.concatenate([np.roll(p, -1, axis=0) for p in polys])
            seg = np.hypot(*(b - a).T)
            step = max(DENSITY_PX, float(seg.sum()) / MAX_POINTS)
            n = np.maximum(1, np.ceil(seg / step)).astype(np.int64)
            i = np.repeat(np.arange(len(a)), n)
            t = (np.arange(int(n.sum())) - (np.cumsum(n) - n)[i]) / n[i]
            self.step = step
            self.tree = cKDTree(a[i] + t[:, None] * (b - a)[i])

    def region(self, r: int, only: list[np.ndarray] | None = None) -> list[Ribbon]:
        """Region ``r``'s ribbons: two per maximal run of consecutive soft edges (of ``only``, per polygon, if given).

        Each run becomes two lattices, the inner half (rings from ``-3
        sigma`` out to the outline) and the outer half (from ``+3 sigma`` in
        to the outline): a viewer that paints each triangle a little wide
        (PDFium rounds spans outward) then leans both halves toward the
        outline's value 1/2 instead of shifting the whole edge. At a vertex
        where the outline turns by at most :data:`JOIN_STEP` radians one row
        lies on the bisector (a miter); at a sharper corner the rows turn from
        one edge's normal to the other's in steps of at most that (a round
        join), so that no quad folds over.
        """
        out = []
        inner = RINGS <= 0
        outer = RINGS >= 0
        for k, (poly, sig) in enumerate(zip(self.model.regions[r].outline, self.sigmas[r])):
            poly = np.asarray(poly, np.float64)
            n = len(poly)
            soft = (sig > 0) if only is None else (sig > 0) & only[k]
            if n < 3 or not soft.any():
                continue
            nrm = _outward_normals(poly, hole=k > 0)
            ang = np.arctan2(nrm[:, 1], nrm[:, 0])
            for run in _runs(soft):
                pos, nr, sg = [poly[run[0]]], [nrm[run[0]]], [sig[run[0]]]
                for a in range(1, len(run)):
                    e0, e = run[a - 1], run[a]
                    v, s_v = poly[e], 0.5 * (sig[e0] + sig[e])
                    turn = (ang[e] - ang[e0] + np.pi) % (2 * np.pi) - np.pi
                    if abs(turn) <= JOIN_STEP:
                        # a gentle corner: one row on the bisector, long enough to keep the offsets
                        th = ang[e0] + 0.5 * turn
                        pos.append(v)
                        nr.append(np.array([np.cos(th), np.sin(th)]) / np.cos(0.5 * turn))
                        sg.append(s_v)
                        continue
                    # a sharp corner: rows along each edge's own normal, the normal turning between them
                    steps = int(np.ceil(abs(turn) / JOIN_STEP))
                    for t in range(steps + 1):
                        th = ang[e0] + turn * t / steps
                        pos.append(v)
                        nr.append(np.array([np.cos(th), np.sin(th)]))
                        sg.append(s_v)
                end = (run[-1] + 1) % n
                pos.append(poly[end])
                nr.append(nrm[run[-1]])
                sg.append(sig[run[-1]])
                pos, nr, sg = np.array(pos), np.array(nr), np.array(sg)
                off = self._clamp(pos, nr, sg[:, None] * RINGS[None, :])
                xy = pos[:, None, :] + off[..., None] * nr[:, None, :]
                value = 1.0 - _phi(off / sg[:, None])  # k sigma outside: the step blurred, Phi(-k)
                out.append(Ribbon(xy=xy[:, inner], value=value[:, inner]))
                out.append(Ribbon(xy=xy[:, outer][:, ::-1], value=value[:, outer][:, ::-1]))
        return out

    def _clamp(self, pos: np.ndarray, nr: np.ndarray, off: np.ndarray) -> np.ndarray:
        """Offsets ``off`` (rows, rings) along ``nr`` from ``pos``, each side stopped at the medial axis."""
        if self.tree is None:
            return off
        out = off.copy()
        zero = int(np.flatnonzero(RINGS == 0)[0])
        for cols in (np.arange(zero, len(RINGS)), np.arange(zero, -1, -1)):  # outward from the outline
            o = off[:, cols]
            bad = np.logical_or.accumulate(self._crossed(pos, nr, o), axis=1)
            rows = np.flatnonzero(bad.any(axis=1))
            if not rows.size:
                continue
            first = bad[rows].argmax(axis=1)  # >= 1: the outline itself is never crossed
            hi = o[rows, first]
            lo = o[rows, first - 1]
            for _ in range(6):  # the medial axis between the last good ring and the first crossed one
                mid = 0.5 * (lo + hi)
                c = self._crossed(pos[rows], nr[rows], mid[:, None])[:, 0]
                hi = np.where(c, mid, hi)
                lo = np.where(c, lo, mid)
            sub = o[rows]
            out[np.ix_(rows, cols)] = np.sign(sub) * np.minimum(np.abs(sub), np.abs(lo)[:, None])
        return out

    def _crossed(self, pos: np.ndarray, nr: np.ndarray, o: np.ndarray) -> np.ndarray:
        """Whether the points ``pos + o nr`` (rows, m) lie nearer to some outline than ``|o|`` (past a medial axis)."""
        q = pos[:, None, :] + o[..., None] * nr[:, None, :]
        d, _ = self.tree.query(q.reshape(-1, 2), workers=-1)
        return d.reshape(o.shape) < np.abs(o) * 0.95 - 0.5 * self.step


def _runs(soft: np.ndarray) -> list[np.ndarray]:
    """Maximal runs of True in a cyclic boolean array, as edge indices in order."""
    n = soft.size
    if soft.all():
        return [np.arange(n)]
    start = int(np.flatnonzero(~soft)[0])
    idx = (start + np.arange(n)) % n
    s = soft[idx]
    runs, cur = [], []
    for i, on in zip(idx, s):
        if on:
            cur.append(i)
        elif cur:
            runs.append(np.array(cur))
            cur = []
    if cur:
        runs.append(np.array(cur))
    return runs


def _phi(x: np.ndarray) -> np.ndarray:
    from scipy.special import ndtr

    return ndtr(x)


__all__ = ["JOIN_STEP", "RINGS", "Ribbon", "Ribbons", "edge_sigmas", "reach"]
