"""Outlines that cross themselves: found (against a brute force), mended, refused by the decoder."""

import numpy as np
import pytest

from tpsv.errors import TpsvError
from tpsv.geometry.crossing import _proper, crossings, insert_cuts, is_simple, mend


def brute_force(p):
    n = len(p)
    q = np.roll(p, -1, axis=0)
    out = []
    for i in range(n):
        for j in range(i + 1, n):
            if j - i == 1 or (i == 0 and j == n - 1):
                continue
            if _proper(p[i:i + 1], q[i:i + 1], p[j:j + 1], q[j:j + 1])[0]:
                out.append((i, j))
    return np.array(out, np.int64).reshape(-1, 2)


def area(p):
    q = np.roll(p, -1, axis=0)
    return 0.5 * abs(float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum()))


def test_crossings_match_a_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(150):
        # small integer grids: many collinear and touching cases
        p = rng.integers(0, 8, (rng.integers(4, 25), 2)).astype(np.float64)
        assert np.array_equal(crossings(p), brute_force(p))


def test_small_polygons_checked_pair_by_pair_agree_with_the_grid(monkeypatch):
    """Polygons of up to ``SMALL`` edges are first compared pair by pair; what ``crossings`` and
    ``mend`` return (pairs, their order under a limit, the mended polygon) is the grid's."""
    from tpsv.geometry import crossing

    rng = np.random.default_rng(11)
    polys = [rng.integers(0, 8, (int(rng.integers(4, crossing.SMALL + 1)), 2)).astype(np.float64) for _ in range(200)]
    polys += [np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float), np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float)]
    small = [(crossings(p), crossings(p, limit=1), mend(p, step=1.0)) for p in polys]
    monkeypatch.setattr(crossing, "SMALL", 0)  # the grid alone
    for p, (every, first, mended) in zip(polys, small):
        assert np.array_equal(every, crossings(p)) and np.array_equal(every, brute_force(p))
        assert np.array_equal(first, crossings(p, limit=1))
        assert np.array_equal(mended, mend(p, step=1.0))
    assert sum(len(c) > 0 for c, _, _ in small) > 50  # most random polygons cross themselves


def test_touching_and_collinear_are_not_crossings():
    # a region pinched to one point between two diagonal pixels visits it twice
    pinch = np.array([[0, 0], [2, 0], [2, 2], [4, 2], [4, 4], [2, 4], [2, 2], [0, 2]], float)
    assert is_simple(pinch)
    # an edge running along another (a zero-width spike out and back)
    spike = np.array([[0, 0], [4, 0], [4, 2], [8, 2], [4, 2], [4, 4], [0, 4]], float)
    assert is_simple(spike)
    # repeated vertices (zero-length edges)
    square = np.array([[0, 0], [0, 0], [4, 0], [4, 4], [4, 4], [0, 4]], float)
    assert is_simple(square)


def test_a_long_circle_is_simple_and_one_moved_vertex_is_found():
    t = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    c = np.column_stack([np.cos(t), np.sin(t)]) * 500
    assert is_simple(c)
    c[100] = [-600.0, 0.0]  # one long spike across the whole circle
    found = crossings(c)
    assert len(found) and {99, 100} & set(found.ravel().tolist())


def test_mend_cuts_the_smaller_loop_at_the_crossing():
    # a sliver of a square folded over itself: its two sides cross near (11, 5)
    p = np.array([[0, 0], [10, 0], [10, 5], [12, 5.1], [20, 5.5], [12, 4.9], [10, 5.2], [10, 10], [0, 10]])
    assert not is_simple(p)
    cuts = []
    m = mend(p, cuts=cuts)
    assert is_simple(m) and len(m) < len(p)
    assert abs(area(m) - 100.0) < 0.2  # the square stays, the folded sliver goes
    x = m[np.argmax(m[:, 0])]
    assert 10 < x[0] < 12 and 4.9 < x[1] < 5.2
    assert len(cuts) == 2 and all(np.array_equal(c[2], cuts[0][2]) for c in cuts)
    # a bow tie keeps its larger half
    bow = np.array([[0, 0], [10, 10], [10, 0], [0, 10]], float)
    assert is_simple(mend(bow)) and len(mend(bow)) == 3


def test_mend_on_a_grid_always_ends_simple():
    rng = np.random.default_rng(5)
    for _ in range(150):
        p = rng.integers(0, 40, (rng.integers(4, 30), 2)).astype(np.int32)
        m = mend(p, step=1, max_crossings=10**6)
        assert m.dtype == np.int32 and len(m) >= 3
        assert is_simple(m), (p, m)
    simple = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], np.int32)
    assert mend(simple, step=1) is simple


def test_the_other_side_of_a_cut_edge_takes_the_crossing_point():
    other = np.array([[10, 5], [0, 5], [0, 0], [10, 0]], float)
    got = insert_cuts(other, [(np.array([0.0, 5.0]), np.array([10.0, 5.0]), np.array([4.0, 5.0]))])
    assert got.tolist() == [[10, 5], [4, 5], [0, 5], [0, 0], [10, 0]]
    # a cut at an end, or on an edge the polygon lacks, changes nothing
    same = insert_cuts(other, [(np.array([0.0, 5.0]), np.array([10.0, 5.0]), np.array([0.0, 5.0])),
                               (np.array([1.0, 1.0]), np.array([2.0, 2.0]), np.array([1.5, 1.5]))])
    assert np.array_equal(same, other)


def test_hostile_outlines_are_refused_quickly():
    # 200 000 vertices zig-zagging over a few cells: every edge against every other
    n = 200_000
    zig = np.column_stack([np.arange(n) % 2, np.arange(n) * 1e-6]).astype(np.float64)
    with pytest.raises(TpsvError, match="too complex"):
        crossings(zig)
    with pytest.raises(TpsvError, match="not a finite number"):
        crossings(np.array([[0, 0], [1, np.nan], [1, 1], [0, 1]]))
    many = np.column_stack([np.tile([0, 10], 200), np.repeat(np.arange(200), 2)]).astype(np.float64)
    with pytest.raises(TpsvError, match="crosses itself more than"):
        mend(many, max_crossings=8)


def test_mending_stored_outlines_cuts_the_neighbours_as_trying_every_polygon_did():
    """``quant.mend_outlines`` gives a crossing point to the polygons that have both ends of a cut
    edge, found through their vertices; it once tried every polygon for every mend (a fuzzed RGBA
    picture of 1951 regions: 546 000 calls, two of its 141 s)."""
    from tpsv.codec import quant

    def every_polygon(xy, counts):  # the rule as it was written first
        polys = np.split(xy, np.cumsum(counts)[:-1])
        for k in range(len(polys)):
            cuts = []
            mended = mend(polys[k], step=1, cuts=cuts)
            if mended is polys[k]:
                continue
            polys[k] = mended
            for other in range(len(polys)):
                if other != k:
                    polys[other] = insert_cuts(polys[other], cuts)
        return np.concatenate(polys).astype(np.int32), np.array([len(p) for p in polys], np.int64)

    rng = np.random.default_rng(5)
    for _ in range(30):
        # polygons on a small grid: shared edges, and some crossing themselves
        polys = [rng.integers(0, 6, (int(rng.integers(3, 9)), 2)) for _ in range(int(rng.integers(2, 12)))]
        xy = np.concatenate(polys).astype(np.int32)
        counts = np.array([len(p) for p in polys], np.int64)
        got, want = quant.mend_outlines(xy, counts), every_polygon(xy, counts)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
