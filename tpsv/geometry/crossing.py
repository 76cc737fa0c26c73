"""Where a polygon crosses itself.

An outline is a closed polygon whose inside is its region; one that crosses
itself has no such inside (which side of the crossing is the region's
depends on the fill rule), so the decoder refuses it and the encoder
mends what it would otherwise write (``tpsv.geometry.subpixel``).

Only *proper* crossings count: two edges that are not neighbours along the
polygon and whose interiors cross, each edge's ends strictly on opposite
sides of the other's line. A polygon may touch itself at a vertex (a region
pinched to one point between two diagonal pixels keeps that point twice),
and zero-length edges are harmless; neither is a crossing.

Edges are bucketed on a grid of cells about as wide as the mean edge is
long (a longer edge in every cell along it), and only the edges sharing a
cell are compared, so a polygon of ``n``
vertices costs about ``O(n)``, not ``O(n^2)``. The comparisons are bounded
(:data:`MAX_PAIRS`): an outline that would need more is hostile and reported
as too complex.
"""

from __future__ import annotations

import numpy as np

from ..errors import TpsvError

#: Most edge pairs compared for one polygon (a hostile file cannot make the check slow).
MAX_PAIRS = 20_000_000
#: Most crossings :func:`mend` cuts off one polygon (each costs a check of the whole polygon).
MAX_MENDS = 64


def _orient(ax, ay, bx, by, cx, cy):
    """Sign of the turn a -> b -> c (positive: counter-clockwise in x-right, y-up axes)."""
    return np.sign((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))


def crossings(poly: np.ndarray, limit: int | None = None) -> np.ndarray:
    """Pairs of edges of ``poly`` that cross each other properly.

    Parameters
    ----------
    poly : ndarray (n, 2)
        A closed polygon (the last vertex is not repeated); edge ``i`` runs
        from vertex ``i`` to vertex ``i + 1`` (mod ``n``).
    limit : int, optional
        Stop after this many crossings are found (``1``: is there any).

    Returns
    -------
    ndarray (k, 2) int64
        Edge indices ``(i, j)``, ``i < j``, sorted.

    Raises
    ------
    TpsvError
        A vertex that is not finite, or more than :data:`MAX_PAIRS` edge pairs
        to compare (the outline is too complex).
    """
    p = np.asarray(poly, np.float64).reshape(-1, 2)
    n = len(p)
    none = np.zeros((0, 2), np.int64)
    if n < 4:
        return none
    if not np.isfinite(p).all():
        raise TpsvError("an outline has a vertex that is not a finite number")
    q = np.roll(p, -1, axis=0)
    length = np.hypot(*(q - p).T)
    idx = np.nonzero(length > 0)[0]
    if idx.size < 4:
        return none
    if idx.size <= SMALL and not _any_small(p, q, idx, n):
        return none
    # cells about one mean edge wide; a longer edge is cut into pieces no longer than a cell,
    # each of whose boxes spans at most 2 x 2 cells
    cell = max(float(length[idx].mean()), 1e-9 * float(np.abs(p).max() + 1.0))
    m = np.ceil(length[idx] / cell).astype(np.int64)
    if int(m.sum()) > 4 * idx.size + 1_000_000:
        raise TpsvError(f"outline too complex: {n} vertices")
    e = np.repeat(np.arange(idx.size), m)
    t = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    a = p[idx][e] + (q - p)[idx][e] * (t / m[e])[:, None]
    b = p[idx][e] + (q - p)[idx][e] * ((t + 1) / m[e])[:, None]
    origin = p.min(0)
    c0 = np.floor((np.minimum(a, b) - origin) / cell).astype(np.int64)
    c1 = np.floor((np.maximum(a, b) - origin) / cell).astype(np.int64)
    span = c1 - c0 + 1
    count = span[:, 0] * span[:, 1]
    # one (cell, edge) row per cell a piece's box touches
    e = np.repeat(e, count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    span, c0 = np.repeat(span, count, axis=0), np.repeat(c0, count, axis=0)
    cx = c0[:, 0] + k % span[:, 0]
    cy = c0[:, 1] + k // span[:, 0]
    both = np.unique((cy * (int(cx.max()) + 2) + cx) * idx.size + e)  # sorted by cell, an edge once per cell
    key, e = both // idx.size, both % idx.size
    start = np.r_[0, np.nonzero(np.diff(key))[0] + 1]
    size = np.diff(np.r_[start, key.size])
    if int((size * (size - 1) // 2).sum()) > MAX_PAIRS:
        raise TpsvError(f"outline too complex: {n} vertices crowd too few cells")
    found = []
    total = 0
    # pair every row with the rows after it in its cell, one offset at a time; the rows still
    # paired shrink with the offset, so the work is the pairs compared, however crowded a cell
    row_end = np.repeat(start + size, size)
    a = np.arange(key.size)
    for off in range(1, int(size.max())):
        a = a[a + off < row_end[a]]
        if a.size == 0:
            break
        i, j = idx[e[a]], idx[e[a + off]]
        i, j = np.minimum(i, j), np.maximum(i, j)
        adjacent = (j - i == 1) | ((i == 0) & (j == n - 1))
        i, j = i[~adjacent], j[~adjacent]
        hit = _proper(p[i], q[i], p[j], q[j])
        if hit.any():
            found.append(np.column_stack([i[hit], j[hit]]))
            total += int(hit.sum())
            if limit is not None and total >= limit:
                break
    if not found:
        return none
    pairs = np.unique(np.concatenate(found), axis=0)
    return pairs if limit is None else pairs[:limit]


#: Polygons of at most this many edges are first checked pair by pair, without the grid.
SMALL = 48
_PAIRS = {m: np.triu_indices(m, 1) for m in range(SMALL + 1)}


def _any_small(p: np.ndarray, q: np.ndarray, idx: np.ndarray, n: int) -> bool:
    """Whether any two of the (at most :data:`SMALL`) non-empty edges ``idx`` cross: every pair
    compared. A polygon of a few pixels' outline costs no grid (a label map of 2673 one-pixel
    regions spent 24 s in the grid's set-up); one that crosses itself is then searched as
    any polygon is, so the crossings found, and their order, are the grid's."""
    a, b = _PAIRS[idx.size]
    i, j = idx[a], idx[b]
    apart = (j - i != 1) & ~((i == 0) & (j == n - 1))
    i, j = i[apart], j[apart]
    return bool(_proper(p[i], q[i], p[j], q[j]).any())


def _proper(a, b, c, d) -> np.ndarray:
    """Whether segment ``a b`` crosses segment ``c d`` at a point interior to both."""
    o1 = _orient(a[:, 0], a[:, 1], b[:, 0], b[:, 1], c[:, 0], c[:, 1])
    o2 = _orient(a[:, 0], a[:, 1], b[:, 0], b[:, 1], d[:, 0], d[:, 1])
    o3 = _orient(c[:, 0], c[:, 1], d[:, 0], d[:, 1], a[:, 0], a[:, 1])
    o4 = _orient(c[:, 0], c[:, 1], d[:, 0], d[:, 1], b[:, 0], b[:, 1])
    return (o1 * o2 < 0) & (o3 * o4 < 0)


def is_simple(poly: np.ndarray) -> bool:
    """Whether ``poly`` has no proper self-crossing (:func:`crossings`)."""
    return len(crossings(poly, limit=1)) == 0


def _area(p: np.ndarray) -> float:
    q = np.roll(p, -1, axis=0)
    return 0.5 * abs(float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum()))


def mend(poly: np.ndarray, step: float = 0.0, max_crossings: int = MAX_MENDS, cuts: list | None = None) -> np.ndarray:
    """``poly`` without self-crossings: each crossing's smaller loop is cut off at the crossing point.

    Where edge ``i`` crosses edge ``j`` the polygon is two loops joined at the
    crossing point ``X``: ``X, p[i+1], ..., p[j]`` and ``X, p[j+1], ..., p[i]``.
    The one with the smaller area (a twisted sliver, where a thin part of a
    region folded over after simplification) is dropped and ``X`` takes its
    place, until no crossing is left. The rule depends on the geometry alone,
    so a border two regions share is mended the same way in both outlines.

    Parameters
    ----------
    poly : ndarray (n, 2)
        A closed polygon.
    step : float
        ``X`` is rounded to a multiple of ``step`` (the outline grid: an
        integer polygon keeps integers with ``step`` 1); 0 leaves it exact.
    max_crossings : int
        More crossings than this to mend is refused (a hostile outline).
    cuts : list, optional
        Receives ``(a, b, x)`` for each of the two crossing edges ``a -> b``
        of every mend (``x`` the crossing point): a polygon on the other side
        of such an edge takes ``x`` as a vertex too, so that the border stays
        one run of shared vertices (:func:`insert_cuts`).

    Returns
    -------
    ndarray (m, 2), ``m <= n``, the input's dtype
        ``poly`` itself when it has no crossing.

    Raises
    ------
    TpsvError
        More than ``max_crossings`` crossings, or too complex to check
        (:func:`crossings`).
    """
    p = np.asarray(poly)
    found = len(crossings(p, limit=max_crossings + 1))
    if found == 0:
        return poly
    if found > max_crossings:
        raise TpsvError(f"an outline crosses itself more than {max_crossings} times")
    dtype = p.dtype
    p = p.astype(np.float64)
    for _ in range(len(p)):
        c = crossings(p, limit=1)
        if len(c) == 0 or len(p) < 4:
            break
        i, j = (int(v) for v in c[0])
        a, b = p[i], p[(i + 1) % len(p)]
        c0, d = p[j], p[(j + 1) % len(p)]
        u, v = b - a, d - c0
        t = ((c0[0] - a[0]) * v[1] - (c0[1] - a[1]) * v[0]) / (u[0] * v[1] - u[1] * v[0])
        x = a + t * u
        if step > 0:
            x = np.rint(x / step) * step
        if cuts is not None:
            cuts.extend([(a.copy(), b.copy(), x.copy()), (c0.copy(), d.copy(), x.copy())])
        inner = np.vstack([x, p[i + 1:j + 1]])
        outer = np.vstack([x, p[j + 1:], p[:i + 1]])
        p = outer if _area(inner) <= _area(outer) else inner
        # a rounded crossing point may repeat its neighbour: drop repeats
        keep = np.any(p != np.roll(p, 1, axis=0), axis=1)
        p = p[keep] if keep.sum() >= 3 else p
    return p.astype(dtype)


def insert_cuts(poly: np.ndarray, cuts: list) -> np.ndarray:
    """``poly`` with each cut's point ``x`` inserted into its edge ``a -> b`` (either way round).

    ``x`` lies on the edge (up to rounding), so the polygon's shape is kept;
    a cut whose edge ``poly`` lacks, or whose ``x`` is one of its ends, changes nothing.
    """
    p = np.asarray(poly)
    for a, b, x in cuts:
        if (x == a).all() or (x == b).all():
            continue
        q = np.roll(p, -1, axis=0)
        at = np.nonzero(((p == a).all(1) & (q == b).all(1)) | ((p == b).all(1) & (q == a).all(1)))[0]
        if at.size:
            p = np.insert(p, at[0] + 1, x.astype(p.dtype), axis=0)
    return p


__all__ = ["MAX_MENDS", "MAX_PAIRS", "crossings", "insert_cuts", "is_simple", "mend"]
