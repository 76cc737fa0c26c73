"""Outlines drawn as smooth curves through their vertices.

A model with ``curves`` set (format version 6, header flag 4) draws each
outline polygon not as straight edges but as a centripetal Catmull-Rom
spline through its vertices, broken at its corners: the curve passes through
every vertex, a circle needs about a third of the vertices a polygon needs
for the same precision (0.04 px at radius 20: 16 vertices, not 50), and
magnified borders show no facets.

Which vertices are breaks (the curve may turn sharply there) is decided by
the geometry alone, so both regions along a shared border, which pass
through the same vertices in opposite directions, draw the same curve:

* a vertex where the outline turns by more than :data:`CORNER_TURN` degrees
  between its two edges (a corner the encoder put back);
* a vertex with other than two distinct neighbours among all the outlines'
  edges (a junction of three regions, where each region's outline goes on
  to a different vertex);
* a vertex on the image frame.

Between two smooth vertices the segment is the cubic Hermite curve of the
centripetal Catmull-Rom spline (knots spaced by the square root of the
chord lengths: no cusp or loop within a segment); at a break the segment's
tangent is the quadratic end condition ``2 (p2 - p1) - m2`` (the parabola
through the two ends with the other end's tangent), and a segment between
two breaks is straight. Reversing a polygon gives the same curve, run
backwards.

The drawn outlines (:func:`drawn_regions`) are polygons fine enough for the
output (within :data:`DRAWN_TOL` output pixels of the curve); every stage that
rasterises outlines (region map, border coverage, the encoder's maps) takes
them, so what is fitted is what is drawn.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from .. import memo

#: A vertex turning by more than this (degrees) between its two edges is a corner.
CORNER_TURN = 35.0
#: How far (output pixels) a drawn curve's pieces may pass from the curve. The pieces of a
#: segment follow from its Bezier points (Wang's bound), so a nearly straight segment is one
#: piece and magnifying costs pieces only as the square root of the scale.
DRAWN_TOL = 0.01
#: Most pieces of all drawn curves of one output (a hostile file's far-flung vertices get coarser pieces).
MAX_DRAWN = 1 << 22


def _keys(p: np.ndarray) -> np.ndarray:
    # the same vertex in two outlines, up to the last bits of arithmetic, is one key
    return np.rint(np.asarray(p, np.float64) * 2**20).astype(np.int64)


def breaks(polys: list[np.ndarray], width: float, height: float) -> list[np.ndarray]:
    """Which vertices of each polygon are breaks of its curve (module doc).

    Parameters
    ----------
    polys : list of ndarray (n, 2)
        Every outline polygon of the model (all regions: junctions are found
        among them).
    width, height : float
        The model's pixel space (its frame).

    Returns
    -------
    list of ndarray (n,) bool
    """
    polys = [np.asarray(p, np.float64).reshape(-1, 2) for p in polys]
    sizes = [len(p) for p in polys]
    if not sum(sizes):
        return [np.ones(0, bool) for _ in polys]
    k = _keys(np.concatenate(polys))
    # one id per distinct vertex (a sort of the key pairs; np.unique(axis=0) is many times slower)
    order = np.lexsort((k[:, 1], k[:, 0]))
    ks = k[order]
    new = np.ones(len(ks), bool)
    new[1:] = (ks[1:] != ks[:-1]).any(axis=1)
    vid = np.empty(len(ks), np.int64)
    vid[order] = np.cumsum(new) - 1
    nv = int(new.sum())
    # every undirected edge once (zero-length ones left out), then each vertex's distinct neighbours
    size = np.repeat(sizes, sizes)
    start = np.repeat(np.cumsum(sizes) - sizes, sizes)
    local = np.arange(len(k)) - start
    prev_i = start + (local - 1) % size
    next_i = start + (local + 1) % size
    a, b = vid, vid[next_i]
    real = a != b
    edges = np.unique(np.minimum(a, b)[real] * nv + np.maximum(a, b)[real])
    degree = np.bincount(np.concatenate([edges // nv, edges % nv]), minlength=nv)
    # corners, frame vertices and junctions, for all polygons at once
    p = np.concatenate(polys)
    u = p - p[prev_i]
    v = p[next_i] - p
    norm = np.hypot(*u.T) * np.hypot(*v.T)
    cos = (u * v).sum(axis=1) / np.maximum(norm, 1e-300)
    corner = (norm == 0) | (cos < np.cos(np.radians(CORNER_TURN)))
    frame = (p[:, 0] <= 0) | (p[:, 0] >= width) | (p[:, 1] <= 0) | (p[:, 1] >= height)
    brk = corner | frame | (degree[vid] != 2) | (size < 3)
    return np.split(brk, np.cumsum(sizes)[:-1])


def hermite(p: np.ndarray, brk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents of every segment ``i -> i+1`` of a closed polygon's curve, per unit of its parameter.

    Parameters
    ----------
    p : ndarray (n, 2)
    brk : ndarray (n,) bool
        From :func:`breaks`.

    Returns
    -------
    m0, m1 : ndarray (n, 2)
        Tangent at the start and at the end of segment ``i`` (from vertex
        ``i`` to vertex ``i + 1``).
    """
    p = np.asarray(p, np.float64)
    n = len(p)
    return _hermite(p, np.asarray(brk, bool), (np.arange(n) - 1) % n, (np.arange(n) + 1) % n)


def _hermite(p: np.ndarray, brk: np.ndarray, prev_i: np.ndarray, next_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hermite` of vertices whose polygon neighbours are ``p[prev_i]`` and ``p[next_i]``
    (several polygons at once)."""
    prev, nxt = p[prev_i], p[next_i]
    # centripetal knots: intervals are square roots of the chords
    t_in = np.sqrt(np.hypot(*(p - prev).T))
    t_out = np.sqrt(np.hypot(*(nxt - p).T))
    ok = (t_in > 0) & (t_out > 0)
    ti, to = np.where(ok, t_in, 1.0), np.where(ok, t_out, 1.0)
    # derivative of the spline at each vertex in the knot parameter
    d = (p - prev) / ti[:, None] - (nxt - prev) / (ti + to)[:, None] + (nxt - p) / to[:, None]
    smooth = ~brk & ok
    chord = nxt - p
    m0 = np.where(smooth[:, None], d * t_out[:, None], np.nan)
    m1 = np.where(smooth[next_i][:, None], d[next_i] * t_out[:, None], np.nan)
    both = np.isnan(m0[:, 0]) & np.isnan(m1[:, 0])
    m0 = np.where(np.isnan(m0), 2.0 * chord - m1, m0)
    m1 = np.where(np.isnan(m1), 2.0 * chord - m0, m1)
    m0[both] = chord[both]
    m1[both] = chord[both]
    return m0, m1


def _pieces(p: np.ndarray, q: np.ndarray, m0: np.ndarray, m1: np.ndarray, tol: float) -> np.ndarray:
    """Pieces per segment ``p -> q`` that keep a polygon within ``tol`` of each segment's curve.

    Wang's bound for a cubic Bezier ``b0..b3`` cut into ``n`` equal parameter
    steps: the chords stay within ``3/4 max|b_i - 2 b_(i+1) + b_(i+2)| / n^2`` of the curve.
    """
    b1, b2 = p + m0 / 3.0, q - m1 / 3.0
    d = np.maximum(np.hypot(*(p - 2 * b1 + b2).T), np.hypot(*(b1 - 2 * b2 + q).T))
    return np.maximum(1, np.ceil(np.sqrt(0.75 * d / tol))).astype(np.int64)


def densify(p: np.ndarray, brk: np.ndarray, tol: float) -> np.ndarray:
    """The curve of a closed polygon as a polygon within ``tol`` of it.

    Every vertex of ``p`` is a vertex of the result; a straight segment
    (between two breaks) is not cut.
    """
    return _densify_all([np.asarray(p, np.float64).reshape(-1, 2)], [brk], tol, max_pieces=None)[0]


def _basis(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cubic Hermite basis ``h00, h10, h01, h11`` at parameters ``s``."""
    s2, s3 = s**2, s**3
    return 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2


#: Pieces per segment where :func:`simplify_open` measures a curve.
_MEASURE = 32


def open_breaks(v: np.ndarray) -> np.ndarray:
    """Breaks of an open chain's curve (n,) bool: its ends and its corners (a turn over :data:`CORNER_TURN`)."""
    brk = np.zeros(len(v), bool)
    brk[0] = brk[-1] = True
    if len(v) >= 3:
        u, w = v[1:-1] - v[:-2], v[2:] - v[1:-1]
        norm = np.hypot(*u.T) * np.hypot(*w.T)
        cos = (u * w).sum(axis=1) / np.maximum(norm, 1e-300)
        brk[1:-1] = (norm == 0) | (cos < np.cos(np.radians(CORNER_TURN)))
    return brk


#: Points measured against their segments' curves at once in :func:`simplify_open` (memory of a batch).
_BATCH = 1 << 15


def _worst_points(p: np.ndarray, tol: np.ndarray, seg: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per segment, its interior point farthest beyond its tolerance from the segment's curve.

    ``seg`` (k, 2): the index range ``[a, b]`` of each segment's ends in ``p``;
    ``lines`` (k, m, 2): each segment's curve as a polyline. Returns the
    offset of the worst point past ``a`` and its excess, per segment (the
    first of equals). A point's distance is to the nearest of its own
    segment's pieces, in the same arithmetic whatever the batch.
    """
    inner = seg[:, 1] - seg[:, 0] - 1
    owner = np.repeat(np.arange(len(seg)), inner)
    first = np.cumsum(inner) - inner
    idx = np.arange(int(inner.sum())) - np.repeat(first, inner) + np.repeat(seg[:, 0] + 1, inner)
    a, d = lines[:, :-1], np.diff(lines, axis=1)
    dd = np.maximum((d * d).sum(axis=2), 1e-300)
    dist = np.empty(idx.size)
    for lo in range(0, idx.size, _BATCH):
        hi = min(lo + _BATCH, idx.size)
        q, g = p[idx[lo:hi]], owner[lo:hi]
        t = np.clip(((q[:, None, :] - a[g]) * d[g]).sum(axis=2) / dd[g], 0.0, 1.0)
        foot = a[g] + t[..., None] * d[g]
        dist[lo:hi] = np.sqrt(((q[:, None, :] - foot) ** 2).sum(axis=2)).min(axis=1)
    excess = dist - tol[idx]
    best = np.maximum.reduceat(excess, first)
    at = np.flatnonzero(excess == best[owner])
    _, pick = np.unique(owner[at], return_index=True)
    return at[pick] - first, best


def simplify_open(p: np.ndarray, tol: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Vertices of an open chain of points whose curve stays within ``tol`` of every point.

    The curve-aware counterpart of Ramer-Douglas-Peucker: from the vertices
    ``start`` (which must hold both ends), the point farthest beyond its
    tolerance from the curve through the kept vertices (its ends and its
    corners breaks, as :func:`breaks` would find them) is added in every
    segment that has one, until none has.

    Parameters
    ----------
    p : ndarray (m, 2)
        The chain's points, in order.
    tol : ndarray (m,)
        Tolerance of each point.
    start : ndarray of int
        Indices to start from, increasing, with ``0`` and ``m - 1``.

    Returns
    -------
    ndarray of int
        Indices kept, increasing.
    """
    p = np.asarray(p, np.float64)
    keep = np.zeros(len(p), bool)
    keep[np.asarray(start, np.int64)] = True
    keep[0] = keep[-1] = True
    h00, h10, h01, h11 = _basis((np.arange(_MEASURE + 1) / _MEASURE)[:, None])
    # A segment's curve depends on its two vertices and their kept neighbours only: one found
    # within tolerance is not measured again while those four stay (the result is the same).
    settled = set()
    while True:
        k = np.flatnonzero(keep)
        if len(k) < 3 and len(p) <= 2:
            return k
        v = p[k]
        m0, m1 = hermite(v, open_breaks(v))
        kl = k.tolist()
        todo, keys = [], []
        for j in range(len(kl) - 1):
            if kl[j + 1] - kl[j] < 2:
                continue
            key = (kl[j - 1] if j else -1, kl[j], kl[j + 1], kl[j + 2] if j + 2 < len(kl) else -1)
            if key not in settled:
                todo.append(j)
                keys.append(key)
        if not todo:
            return k
        j = np.asarray(todo)
        lines = h00[None] * v[j][:, None] + h10[None] * m0[j][:, None] + h01[None] * v[j + 1][:, None] \
            + h11[None] * m1[j][:, None]
        worst, excess = _worst_points(p, tol, np.column_stack([k[j], k[j + 1]]), lines)
        out = excess > 0
        keep[k[j[out]] + 1 + worst[out]] = True
        settled.update(key for key, o in zip(keys, out.tolist()) if not o)
        if not out.any():
            return k


def drawn_regions(regions: list, width: float, height: float, tol: float, brk: list | None = None,
                  cache: dict | None = None) -> list:
    """``regions`` with each outline replaced by its curve as a fine polygon (:func:`densify`).

    Parameters
    ----------
    regions : list of Region
    width, height : float
        The model's pixel space.
    tol : float
        How far the polygons may pass from the curves, in the model's pixels.
    brk : list of ndarray, optional
        :func:`breaks` of the outlines (they depend on the geometry alone: a
        caller drawing one model at several sizes finds them once).
    cache : dict, optional
        Polygons drawn before, by their outline, breaks and tolerance: an
        editor that moves one region draws only that region's outlines again.
        It is left holding this call's polygons only.

    Returns
    -------
    list of Region
        New regions sharing the patches.
    """
    polys = [np.asarray(p, np.float64).reshape(-1, 2) for r in regions for p in r.outline]
    if brk is None:
        brk = breaks(polys, width, height)
    if cache is None:
        dense = iter(_densify_all(polys, brk, tol))
    else:
        keys = [(float(tol), p.tobytes(), np.asarray(b, bool).tobytes()) for p, b in zip(polys, brk)]
        dense = iter(memo.refresh(cache, keys, lambda idx: _densify_all([polys[i] for i in idx],
                                                                        [brk[i] for i in idx], tol)))
    return [replace(r, outline=[next(dense) for _ in r.outline]) for r in regions]


def _densify_all(polys: list[np.ndarray], brk: list[np.ndarray], tol: float,
                 max_pieces: int | None = MAX_DRAWN) -> list[np.ndarray]:
    """:func:`densify` of every polygon, in one pass over all their vertices (each vertex sees its
    own polygon's neighbours), with the tolerance made coarser where the pieces would pass
    ``max_pieces`` (None: never)."""
    curved = [len(p) >= 3 for p in polys]
    if not any(curved):
        return [p.copy() for p in polys]
    sizes = np.array([len(p) for p, c in zip(polys, curved) if c], np.int64)
    p = np.concatenate([q for q, c in zip(polys, curved) if c])
    b = np.concatenate([q for q, c in zip(brk, curved) if c])
    # each vertex's neighbours within its own polygon (np.roll's of each polygon at once)
    start = np.repeat(np.cumsum(sizes) - sizes, sizes)
    local = np.arange(p.shape[0]) - start
    size = np.repeat(sizes, sizes)
    prev_i = start + (local - 1) % size
    next_i = start + (local + 1) % size
    m0, m1 = _hermite(p, b, prev_i, next_i)
    nxt = p[next_i]
    count = _pieces(p, nxt, m0, m1, tol)
    total = int(count.sum())
    # pieces go as 1 / sqrt(tol): where they would be too many, a coarser tolerance
    if max_pieces is not None and total > max_pieces:
        count = _pieces(p, nxt, m0, m1, tol * (total / max_pieces) ** 2)
    seg = np.repeat(np.arange(p.shape[0]), count)
    s = (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)) / count[seg]
    h00, h10, h01, h11 = _basis(s)
    out = np.empty((s.size, 2))
    for c in range(2):  # a column at a time (contiguous), summed in the order of h00 p + h10 m0 + h01 q + h11 m1
        col = h00 * p[:, c][seg]
        col += h10 * m0[:, c][seg]
        col += h01 * nxt[:, c][seg]
        col += h11 * m1[:, c][seg]
        out[:, c] = col
    at = s == 0
    out[at] = p[seg[at]]  # vertices exactly as stored
    # back into polygons: a polygon's pieces follow its vertices
    ends = np.cumsum(np.add.reduceat(count, np.cumsum(sizes) - sizes))
    pieces = iter(np.split(out, ends[:-1]))
    return [next(pieces) if c else q.copy() for q, c in zip(polys, curved)]


def as_drawn(model, out_width: int | None = None, out_height: int | None = None, brk: list | None = None,
             cache: dict | None = None):
    """``model`` as its outlines are drawn at an output size: itself when it has no curves, else a
    copy whose outlines are polygons within :data:`DRAWN_TOL` output pixels of the curves
    (:func:`drawn_regions`, with its ``brk`` and ``cache``) and ``curves`` off.
    """
    if not getattr(model, "curves", False):
        return model
    k = max(float(out_width or model.width) / model.width, float(out_height or model.height) / model.height)
    out = copy.copy(model)  # (a Model, or anything with its regions, size and curves)
    out.regions = drawn_regions(model.regions, model.width, model.height, DRAWN_TOL / max(k, 1e-9), brk, cache)
    out.curves = False
    return out


__all__ = ["CORNER_TURN", "DRAWN_TOL", "as_drawn", "breaks", "densify", "drawn_regions", "hermite",
           "open_breaks", "simplify_open"]
