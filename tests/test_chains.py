"""Shared borders stored once: tpsv.codec.chains (docs/FORMAT.md, version 2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tpsv.codec import chains
from tpsv.errors import TpsvFormatError
from tpsv.geometry import outline


def round_trip(polys):
    chain_list, refs = chains.decompose(polys)
    counts = np.array([len(c) for c in chain_list], np.int64)
    xy = np.concatenate(chain_list) if chain_list else np.zeros((0, 2), np.int32)
    flat = np.array([r for rs in refs for r in rs], np.int64)
    assert np.array_equal(chains.ref_values(chains.ref_codes(flat)), flat)
    vert_counts, back = chains.assemble(counts, xy, np.array([len(r) for r in refs], np.int64), flat,
                                        sum(len(p) for p in polys))
    got = np.split(back, np.cumsum(vert_counts)[:-1])
    assert len(got) == len(polys)
    for a, b in zip(polys, got):
        assert np.array_equal(np.asarray(a, np.int32), b)
    return chain_list, refs


def square(x0, y0, x1, y1, step=1):
    """Counter-clockwise (y down: x right, then up) square with a vertex every ``step``."""
    bottom = [(x, y1) for x in range(x0, x1, step)]
    right = [(x1, y) for y in range(y1, y0, -step)]
    top = [(x, y0) for x in range(x1, x0, -step)]
    left = [(x0, y) for y in range(y0, y1, step)]
    return np.array(bottom + right + top + left, np.int32)


def _partners_by_dict(polys):
    """The rule of ``chains.partners``, edge by edge with a dictionary."""
    seen = {}
    for p, poly in enumerate(polys):
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            seen.setdefault((*a, *b), []).append((p, i))
    out = []
    for p, poly in enumerate(polys):
        part = np.full((len(poly), 2), -1, np.int64)
        for i in range(len(poly)):
            a, b = tuple(poly[i]), tuple(poly[(i + 1) % len(poly)])
            twin = seen.get((*b, *a), ())
            if a != b and len(twin) == 1 and len(seen[(*a, *b)]) == 1 and twin[0][0] != p:
                part[i] = twin[0]
        out.append(part)
    return out


def test_partners_follow_the_rule_edge_by_edge():
    """One sort of all edges finds the same twins as the rule read edge by edge: shared, repeated
    (three polygons on one edge), zero-length and self-reversing edges, empty polygons, 64-bit keys."""
    rng = np.random.default_rng(3)
    cases = [[rng.integers(0, 4, (int(rng.integers(0, 7)), 2)) for _ in range(int(rng.integers(0, 5)))]
             for _ in range(400)]
    big = [rng.integers(-2**40, 2**40, (30, 2)) for _ in range(3)]
    cases.append(big + [big[0][::-1].copy(), big[0][::-1].copy()])
    cases.append(big + [big[1][::-1].copy()])
    for polys in cases:
        got, want = chains.partners(polys), _partners_by_dict([p.tolist() for p in polys])
        assert len(got) == len(want)
        for g, w in zip(got, want):
            assert g.dtype == np.int64 and np.array_equal(g, w)


def test_a_border_between_two_regions_is_one_chain():
    a = square(0, 0, 8, 8)
    b = square(8, 0, 16, 8)
    chain_list, refs = round_trip([a, b])
    # the common side x = 8 (8 edges) is stored once, read forwards by one and backwards by the other
    shared = [k for k, c in enumerate(chain_list) if np.all(c[:, 0] == 8) and len(c) == 9]
    assert len(shared) == 1
    k = shared[0]
    assert 2 * k in refs[0] + refs[1] and 2 * k + 1 in refs[0] + refs[1]
    stored = sum(len(c) for c in chain_list)
    assert stored < len(a) + len(b)


def test_an_island_is_stored_once():
    outer = square(0, 0, 12, 12)
    hole = square(4, 4, 8, 8)[::-1]  # a hole runs clockwise
    island = square(4, 4, 8, 8)
    chain_list, refs = round_trip([outer, hole, island])
    # plus at most two cut points and one short run kept by both sides
    assert sum(len(c) for c in chain_list) <= len(outer) + 1 + len(island) + 4
    # the island reads the hole's long chain backwards
    assert any(r % 2 == 1 and len(chain_list[r >> 1]) >= 15 for r in refs[2])


def test_short_shared_runs_stay_with_each_side():
    # the squares touch along one edge only: sharing it would cost more than it saves
    a = square(0, 0, 4, 4, step=4)
    b = square(4, 0, 8, 4, step=4)
    chain_list, refs = round_trip([a, b])
    assert len(chain_list) == 2 and refs == [[0], [2]]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 9), st.integers(2, 9), st.integers(2, 5))
def test_traced_label_maps_round_trip(seed, h, w, k):
    """Outlines of random label maps (shared borders, holes, touching corners) come back vertex for vertex."""
    rng = np.random.default_rng(seed)
    labels = rng.integers(0, k, (h, w))
    from tpsv.geometry import segment

    comp = segment.split_connected(labels, min_size=1)
    polys = []
    for i in range(int(comp.max()) + 1):
        mask = comp == i
        if mask.any():
            polys += [np.rint(p * 8).astype(np.int32) for p in outline.trace_outline(mask)]
    round_trip(polys)


def test_repeated_and_odd_vertices_round_trip():
    # a repeated vertex, a zero-length edge, an edge shared by three polygons, a polygon sharing with itself
    polys = [
        np.array([[0, 0], [0, 0], [4, 0], [4, 4]], np.int32),
        np.array([[4, 4], [4, 0], [0, 0], [0, 4]], np.int32),
        np.array([[4, 0], [0, 0], [2, -3]], np.int32),
        np.array([[0, 0], [5, 0], [0, 0], [0, 5]], np.int32),
    ]
    round_trip(polys)


def hostile(counts, xy, ref_counts, refs, vertices):
    with pytest.raises(TpsvFormatError) as info:
        chains.assemble(np.array(counts), np.array(xy, np.int32).reshape(-1, 2), np.array(ref_counts),
                        np.array(refs, np.int64), vertices)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_hostile_chains_are_refused_in_one_line():
    tri = [[0, 0], [4, 0], [0, 4], [0, 0]]
    assert "chain ends do not meet" in hostile([4], tri[:3] + [[1, 1]], [1], [0], 3)
    assert "used 3 times" in hostile([4], tri, [3], [0, 0, 0], 9)
    assert "used 0 times" in hostile([4, 2], tri + [[0, 0], [1, 1]], [1], [0], 3)
    assert "to chain 7" in hostile([4], tri, [1], [14], 3)
    assert "at least 2" in hostile([1], tri[:1], [1], [0], 0)
    assert "header says 5" in hostile([4], tri, [1], [0], 5)
    assert "refers to no chain" in hostile([4], tri, [0, 1], [0], 3)
