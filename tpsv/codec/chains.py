"""Shared borders stored once: outline polygons <-> chains (``docs/FORMAT.md``, version 2).

Two regions that meet share a border, and their outlines run along it in
opposite directions through the same vertices. A version-2 file stores every
such run once, as a *chain* (an open polyline), and each polygon as a cyclic
list of chain references, each forwards or backwards. A polygon or a run that
nothing shares is a chain of its own.

Runs are found from the integer outline vertices alone (no tolerance): an
edge ``a -> b`` of one polygon is *shared* when exactly one other polygon has
the edge ``b -> a`` and no third one has either. A polygon is cut at every
vertex where the partner of its edges changes (or where the partner's edges
stop being consecutive), so both sides of a border are cut at the same
vertices. Every polygon is also cut at its vertex 0 (and its partner at the
same point), so that it comes back starting where it started.
"""

from __future__ import annotations

import numpy as np

from ..errors import TpsvFormatError

#: Shared runs of fewer edges are stored by both sides (measured on traced and
#: fitted outlines of the samples: below this a run's cuts and reference cost
#: more than its vertices).
MIN_SHARED = 4


def partners(polys: list[np.ndarray]) -> list[np.ndarray]:
    """For every edge ``i -> i+1`` of every polygon: ``(polygon, edge)`` of its one reverse twin, or ``(-1, -1)``.

    Every directed edge is a key of its four integer coordinates; one sort of
    all edges and their reversals groups equal keys, so a photo's hundreds of
    thousands of contour points cost no Python loop.
    """
    polys = [np.asarray(p).reshape(-1, 2) for p in polys]
    sizes = np.array([len(p) for p in polys], np.int64)
    total = int(sizes.sum())
    if total == 0:
        return [np.full((0, 2), -1, np.int64) for _ in polys]
    a = np.concatenate(polys).astype(np.int64)
    b = np.concatenate([np.roll(p, -1, axis=0) for p in polys]).astype(np.int64)
    poly = np.repeat(np.arange(len(polys)), sizes)
    edge = np.arange(total) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    # group ids of the forward keys (a, b) and of the reversed ones (b, a), from one sort of both
    keys = np.concatenate([np.column_stack([a, b]), np.column_stack([b, a])])
    order = np.lexsort(keys.T[::-1])
    step = np.ones(len(order), bool)
    step[1:] = (keys[order[1:]] != keys[order[:-1]]).any(axis=1)
    gid = np.empty(len(order), np.int64)
    gid[order] = np.cumsum(step) - 1
    fwd, rev = gid[:total], gid[total:]
    count = np.bincount(fwd, minlength=int(gid.max()) + 1)  # edges with each key
    owner = np.full(count.size, -1, np.int64)
    owner[fwd] = np.arange(total)  # the edge of a key that one edge has
    twin = owner[rev]
    ok = (count[rev] == 1) & (count[fwd] == 1) & (a != b).any(axis=1)
    ok &= poly[twin] != poly  # (twin is an edge wherever count[rev] == 1)
    hit = np.flatnonzero(ok)
    res = np.full((total, 2), -1, np.int64)
    res[hit, 0] = poly[twin[hit]]
    res[hit, 1] = edge[twin[hit]]
    starts = np.cumsum(sizes) - sizes
    return [res[s0:s0 + n] for s0, n in zip(starts.tolist(), sizes.tolist())]


def cuts(part: list[np.ndarray], sizes: list[int]) -> list[np.ndarray]:
    """Per polygon, the vertices where it is cut into runs (sorted; vertex 0 always among them).

    A polygon is cut where the partner of its edges changes, where the
    partner's edges stop being consecutive, at its vertex 0, and where a
    partner's vertex 0 lies inside a run they share, so that both sides of a
    border are cut at the same vertices.
    """
    cut = []
    for pt in part:
        prev = np.roll(pt, 1, axis=0)
        same = prev[:, 0] == pt[:, 0]
        free = same & (pt[:, 0] < 0)
        size = np.array([sizes[q] if q >= 0 else 1 for q in pt[:, 0].tolist()], np.int64)
        # the partner runs the other way: its edge twin of ours comes just before the twin of our previous edge
        consecutive = same & (pt[:, 0] >= 0) & (pt[:, 1] == (prev[:, 1] - 1) % size)
        c = ~(free | consecutive)
        c[:1] = True
        cut.append(c)
    for p, pt in enumerate(part):
        if not len(pt):
            continue
        q, j = (int(v) for v in pt[0])
        if q >= 0:
            # our vertex 0 ends the twin of our edge 0 in polygon q
            cut[q][(j + 1) % sizes[q]] = True
    return [np.flatnonzero(c) for c in cut]


def decompose(polys: list[np.ndarray]) -> tuple[list[np.ndarray], list[list[int]]]:
    """Chains and references of integer outline polygons.

    Parameters
    ----------
    polys : list of ndarray (k, 2) int
        All polygons of all regions, in file order.

    Returns
    -------
    chains : list of ndarray (n, 2) int32
        Chains of at least 2 vertices.
    refs : list of list of int
        Per polygon, its chains in order from its vertex 0, each ``2 * chain
        + backwards``.
    """
    polys = [np.ascontiguousarray(p, np.int32) for p in polys]
    sizes = [len(p) for p in polys]
    part = partners(polys)
    cut_at = cuts(part, sizes)
    # a short shared run saves fewer bytes than its two extra cuts cost: both sides keep it as their own
    demoted = False
    for p, c in enumerate(cut_at):
        for a, b in zip(c.tolist(), c[1:].tolist() + [sizes[p]]):
            if b - a < MIN_SHARED and part[p][a, 0] >= 0:
                q, j = part[p][a:b].T
                part[q[0]][j] = -1
                part[p][a:b] = -1
                demoted = True
    if demoted:
        cut_at = cuts(part, sizes)
    chains: list[np.ndarray] = []
    refs: list[list[int]] = []
    mirror: dict[tuple[int, int], int] = {}  # (polygon, start vertex) -> code of a stored chain
    for p, poly in enumerate(polys):
        n = sizes[p]
        own = []
        c = cut_at[p].tolist()
        # (an empty polygon, which only a hostile file has, refers to no chain)
        for a, b in zip(c, c[1:] + [n]):
            if (p, a) in mirror:
                own.append(mirror[(p, a)])
                continue
            own.append(2 * len(chains))
            q, j = (int(v) for v in part[p][b - 1])
            if q > p:
                # the twin run starts, in polygon q, at our run's last vertex (its vertex j)
                mirror[(q, j)] = 2 * len(chains) + 1
            chains.append(poly[np.arange(a, b + 1) % n])
        refs.append(own)
    return chains, refs


def ref_codes(refs: np.ndarray) -> np.ndarray:
    """Stored codes of references: 0 for the next chain not yet referenced, forwards; else ``1 + ref``.

    Chains are stored in the order polygons first use them, so all but the
    second sides of shared borders code as 0.
    """
    codes = np.asarray(refs, np.int64) + 1
    seen = np.full(int(codes.max(initial=0)) // 2 + 1, False)
    nxt = 0
    for i, r in enumerate(refs.tolist()):
        if r == 2 * nxt:
            codes[i] = 0
        if not seen[r >> 1]:
            seen[r >> 1] = True
            nxt += 1
    return codes


def ref_values(codes: np.ndarray) -> np.ndarray:
    """References from stored codes (:func:`ref_codes` inverted); 0 past the last chain stays out of range."""
    refs = np.asarray(codes, np.int64) - 1
    nxt = 0
    seen: set[int] = set()
    for i, code in enumerate(codes.tolist()):
        if code == 0:
            refs[i] = 2 * nxt
        c = int(refs[i]) >> 1
        if c not in seen:
            seen.add(c)
            nxt += 1
    return refs


def assemble(chain_counts: np.ndarray, chain_xy: np.ndarray, ref_counts: np.ndarray,
             refs: np.ndarray, vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Polygons from chains and references, checking every rule of the format.

    Parameters
    ----------
    chain_counts : ndarray (K,) int
        Vertices per chain.
    chain_xy : ndarray (sum(chain_counts), 2) int32
    ref_counts : ndarray (P,) int
        References per polygon.
    refs : ndarray (sum(ref_counts),) int
        ``2 * chain + backwards``.
    vertices : int
        Vertices the polygons must hold in all (the header's ``V``), checked
        before anything of that size is built.

    Returns
    -------
    vert_counts : ndarray (P,) int64
    xy : ndarray (V, 2) int32

    Raises
    ------
    TpsvFormatError
        A chain of fewer than 2 vertices, a reference to no chain, a chain
        used more than twice or never, a polygon whose chains do not meet end
        to start, a vertex total other than ``vertices``.
    """
    name = "section regions"
    k = chain_counts.size
    bad = np.flatnonzero(chain_counts < 2)
    if bad.size:
        raise TpsvFormatError(f"{name}: chain {bad[0]} has {chain_counts[bad[0]]} vertices (at least 2)")
    bad = np.flatnonzero(ref_counts < 1)
    if bad.size:
        raise TpsvFormatError(f"{name}: polygon {bad[0]} refers to no chain")
    chain = refs >> 1
    bad = np.flatnonzero(chain >= k)
    if bad.size:
        raise TpsvFormatError(f"{name}: reference {bad[0]} to chain {chain[bad[0]]}, but there are {k}")
    used = np.bincount(chain, minlength=k)
    bad = np.flatnonzero((used < 1) | (used > 2))
    if bad.size:
        raise TpsvFormatError(f"{name}: chain {bad[0]} is used {used[bad[0]]} times (a border has one or two sides)")
    start = np.concatenate([[0], np.cumsum(chain_counts)[:-1]])
    back = (refs & 1).astype(bool)
    first = np.where(back, start[chain] + chain_counts[chain] - 1, start[chain])
    last = np.where(back, start[chain], start[chain] + chain_counts[chain] - 1)
    # each chain's end is where the next one of its polygon starts (cyclically)
    poly_start = np.concatenate([[0], np.cumsum(ref_counts)[:-1]])
    nxt = np.arange(refs.size) + 1
    ends = poly_start + ref_counts
    nxt[ends - 1] = poly_start
    bad = np.flatnonzero(np.any(chain_xy[last] != chain_xy[first[nxt]], axis=1))
    if bad.size:
        p = int(np.searchsorted(poly_start, bad[0], side="right")) - 1
        raise TpsvFormatError(f"{name}: polygon {p}: chain ends do not meet")
    # each reference gives its chain minus the last vertex (the next chain's first)
    length = chain_counts[chain] - 1
    if int(length.sum()) != vertices:
        raise TpsvFormatError(f"{name}: polygons hold {int(length.sum())} vertices, header says {vertices}")
    vert_counts = np.add.reduceat(length, poly_start) if refs.size else np.zeros(0, np.int64)
    step = np.where(back, -1, 1)
    offset = np.arange(int(length.sum())) - np.repeat(np.cumsum(length) - length, length)
    idx = np.repeat(first, length) + np.repeat(step, length) * offset
    return vert_counts.astype(np.int64), chain_xy[idx]


__all__ = ["MIN_SHARED", "assemble", "cuts", "decompose", "partners", "ref_codes", "ref_values"]
