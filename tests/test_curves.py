"""Outlines drawn as curves: which vertices break the curve, the curve itself, and what the encoder keeps."""

import numpy as np
import pytest

from tpsv import codec
from tpsv.geometry import curves


def circle(n, r=20.0, c=(32.0, 32.0), phase=0.1):
    t = phase + np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([c[0] + r * np.cos(t), c[1] + r * np.sin(t)])


def test_a_circle_is_smooth_and_a_square_has_four_corners():
    sq = np.array([[10, 10], [30, 10], [30, 30], [20, 30], [10, 30]], float)  # one vertex mid-side
    brk_c, brk_s = curves.breaks([circle(16), sq], 64, 64)
    assert not brk_c.any()
    assert brk_s.tolist() == [True, True, True, False, True]
    # the square's sides stay straight: the mid-side vertex's curve runs along the side
    drawn = curves.densify(sq, brk_s, 0.25)
    on_top = drawn[(drawn[:, 1] > 29) & (drawn[:, 0] > 10) & (drawn[:, 0] < 30)]
    assert np.abs(on_top[:, 1] - 30).max() < 1e-9


def test_junctions_and_the_frame_break_the_curve():
    # two regions sharing a border that bends gently at (22, 20): smooth there, broken on the frame
    left = np.array([[0, 0], [20, 0], [22, 20], [20, 40], [0, 40]], float)
    right = np.array([[20, 0], [40, 0], [40, 40], [20, 40], [22, 20]], float)
    bl, br = curves.breaks([left, right], 40, 40)
    assert bl.tolist() == [True, True, False, True, True] and br.tolist() == [True, True, True, True, False]
    # a third outline leaving the border at (5, 5) and (25, 5) makes them junctions
    a = np.array([[5, 5], [15, 4], [25, 5], [26, 15], [25, 25], [15, 26], [5, 25], [4, 15]], float)
    b = np.array([[25, 5], [15, 4], [5, 5], [10, 0]], float)  # shares the edges 5,5 - 15,4 - 25,5
    ba, _ = curves.breaks([a, b], 100, 100)
    assert ba[0] and ba[2] and not ba[1]  # (5,5) and (25,5) are junctions; (15,4) has two neighbours


def test_the_curve_passes_through_the_vertices_and_follows_a_circle():
    p = circle(16)
    brk = curves.breaks([p], 64, 64)[0]
    drawn = curves.densify(p, brk, 0.001)
    for v in p:
        assert np.hypot(*(drawn - v).T).min() == 0.0
    assert np.abs(np.hypot(drawn[:, 0] - 32, drawn[:, 1] - 32) - 20).max() < 0.015
    # a polygon of the same 16 vertices is 0.38 px inside the circle at its chords' middles
    mid = 0.5 * (p + np.roll(p, -1, axis=0))
    assert np.abs(np.hypot(mid[:, 0] - 32, mid[:, 1] - 32) - 20).max() > 0.3


def test_reversed_outline_gives_the_same_curve():
    rng = np.random.default_rng(2)
    p = circle(12) + rng.normal(0, 0.3, (12, 2))
    p[5] += [3, 0]  # a corner
    brk = curves.breaks([p], 64, 64)[0]
    fwd = curves.densify(p, brk, 0.2)
    rev = curves.densify(p[::-1], brk[::-1], 0.2)
    # the same points, run backwards (each segment is cut the same way)
    assert len(fwd) == len(rev)
    d = np.array([np.hypot(*(rev - q).T).min() for q in fwd])
    assert d.max() < 1e-9


def test_simplify_keeps_few_vertices_within_the_tolerance():
    dense = circle(400)[::-1]  # an open arc of the circle: its first 200 points
    arc = dense[:200]
    tol = np.full(len(arc), 0.04)
    kept = curves.simplify_open(arc, tol, np.array([0, len(arc) - 1]))
    assert kept[0] == 0 and kept[-1] == len(arc) - 1
    v = arc[kept]
    brk = np.zeros(len(v), bool)
    brk[0] = brk[-1] = True
    # its curve (closed back along a straight chord, which is a break at both ends) stays on the circle
    drawn = curves.densify(v, brk, 0.001)
    on_arc = drawn[np.hypot(drawn[:, 0] - 32, drawn[:, 1] - 32) > 19]
    assert np.abs(np.hypot(on_arc[:, 0] - 32, on_arc[:, 1] - 32) - 20).max() <= 0.041
    # a polygon needs chords of at most sqrt(8 r tol) = 2.5 px: 26 vertices for this half circle; the curve far fewer
    assert len(kept) <= 12


def _simplify_one_at_a_time(p, tol, start):
    """simplify_open as its rule reads: every segment measured on every round, one at a time."""
    keep = np.zeros(len(p), bool)
    keep[start] = True
    keep[0] = keep[-1] = True
    s = (np.arange(33) / 32)[:, None]
    h = (2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2)
    while True:
        k = np.flatnonzero(keep)
        v = p[k]
        m0, m1 = curves.hermite(v, curves.open_breaks(v))
        added = False
        for j in range(len(k) - 1):
            a, b = k[j], k[j + 1]
            if b - a < 2:
                continue
            line = h[0] * v[j] + h[1] * m0[j] + h[2] * v[j + 1] + h[3] * m1[j]
            q, la, d = p[a + 1:b], line[:-1], np.diff(line, axis=0)
            dd = np.maximum((d * d).sum(axis=1), 1e-300)
            t = np.clip(((q[:, None, :] - la[None]) * d[None]).sum(axis=2) / dd[None], 0.0, 1.0)
            dist = np.sqrt(((q[:, None, :] - (la[None] + t[..., None] * d[None])) ** 2).sum(axis=2)).min(axis=1)
            excess = dist - tol[a + 1:b]
            worst = int(np.argmax(excess))
            if excess[worst] > 0:
                keep[a + 1 + worst] = True
                added = True
        if not added:
            return np.flatnonzero(keep)


def test_simplify_measures_segments_in_batches_as_one_at_a_time():
    """The batched, memoised search keeps exactly the vertices of the plain rule (wiggly, cornered, ties)."""
    rng = np.random.default_rng(7)
    for trial in range(60):
        m = int(rng.integers(2, 160))
        turn = np.cumsum(rng.normal(0, 0.25, m))
        p = np.cumsum(np.column_stack([np.cos(turn), np.sin(turn)]), axis=0) + rng.normal(0, 0.05, (m, 2))
        if trial % 4 == 0:
            p[rng.integers(0, m, 3)] += rng.normal(0, 2, (3, 2))
        if trial % 7 == 0:
            p = np.rint(p)  # repeated points and equal distances
        tol = np.full(m, rng.choice([0.01, 0.05, 0.3])) * rng.uniform(0.5, 1.5, m)
        start = np.unique(np.r_[0, m - 1, rng.integers(0, m, 2)])
        assert np.array_equal(curves.simplify_open(p, tol, start), _simplify_one_at_a_time(p, tol, start))


def test_the_flag_survives_the_file_and_old_files_are_polygons():
    from tpsv.model import Features, Model, Patch, Region

    ctrl = np.zeros((2, 2, 4, 2))
    ctrl[..., 0, :] = [[[0, 0], [0, 64]], [[64, 0], [64, 64]]]
    ctrl[..., 1, :] = [64, 0]
    ctrl[..., 2, :] = [0, 64]
    m = Model(width=64, height=64, regions=[Region(0, [circle(16)], Patch(ctrl))], features=Features.empty(),
              curves=True)
    data = codec.encode(m)
    assert data[10] & 4 and codec.decode(data).curves and codec.quantize(m).curves
    plain = codec.encode(Model(width=64, height=64, regions=m.regions, features=Features.empty()))
    assert not plain[10] & 4 and not codec.decode(plain).curves


@pytest.mark.parametrize("scale", [1, 8])
def test_a_curved_model_renders_its_curve(scale):
    """The region map of a disc drawn as 16 vertices follows the circle, not the 16-gon."""
    from tpsv.model import Features, Model, Patch, Region
    from tpsv.rendering.pixelmap import region_index

    ctrl = np.zeros((2, 2, 4, 2))
    ctrl[..., 0, :] = [[[0, 0], [0, 64]], [[64, 0], [64, 64]]]
    ctrl[..., 1, :] = [64, 0]
    ctrl[..., 2, :] = [0, 64]
    frame = np.array([[0, 0], [64, 0], [64, 64], [0, 64]], float)
    disc = circle(16)
    regions = [Region(0, [frame, disc[::-1]], Patch(ctrl)), Region(1, [disc], Patch(ctrl))]
    n = 64 * scale
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / scale
    inside = np.hypot(xx - 32, yy - 32) < 20
    worst = {}
    for curved in (True, False):
        m = Model(width=64, height=64, regions=regions, features=Features.empty(), curves=curved)
        idx = region_index(m, n, n)
        wrong = (idx == 1) != inside
        worst[curved] = np.abs(np.hypot(xx - 32, yy - 32)[wrong] - 20).max(initial=0.0)
    # a pixel centre is on the wrong side only within half a pixel's diagonal of the curve
    assert worst[True] <= 0.015 + 0.71 / scale
    if scale == 8:
        assert worst[False] > 0.3  # the 16-gon's chords


def test_densify_of_all_outlines_at_once_is_each_outline_alone():
    """drawn_regions densifies every outline in one pass: the same polygons as one at a time."""
    rng = np.random.default_rng(5)
    polys = []
    for n in (3, 4, 17, 60):
        t = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = 10 + rng.uniform(-2, 2, n)
        polys.append(np.stack([30 + r * np.cos(t), 30 + r * np.sin(t)], 1))
    polys.append(np.array([[1.0, 1.0], [2.0, 2.0]]))  # too short for a curve: kept as is
    brk = curves.breaks(polys, 60, 60)
    for tol in (0.01, 0.001):
        alone = [curves.densify(p, b, tol) for p, b in zip(polys, brk)]
        together = curves._densify_all(polys, brk, tol)
        assert all(np.array_equal(a, b) for a, b in zip(alone, together))


def test_drawn_regions_with_a_cache_draws_the_same_and_keeps_only_what_it_drew():
    from tpsv.geometry.regions import build_regions

    labels = np.zeros((40, 40), np.int32)
    labels[8:30, 5:20] = 1
    labels[12:34, 22:36] = 2
    rgb = np.where(labels[..., None] > 0, 0.2, 0.8).astype(np.float32) * np.ones(3, np.float32)
    regions, _ = build_regions(labels, rgb)
    cache = {}
    plain = curves.drawn_regions(regions, 40, 40, 0.005)
    cached = curves.drawn_regions(regions, 40, 40, 0.005, cache=cache)
    again = curves.drawn_regions(regions, 40, 40, 0.005, cache=cache)
    for a, b, c in zip(plain, cached, again):
        assert all(np.array_equal(p, q) and np.array_equal(p, t) for p, q, t in zip(a.outline, b.outline, c.outline))
    assert len(cache) == sum(len(r.outline) for r in regions)
    # one region moved: its outlines are drawn anew, the entries of the old ones dropped
    moved = list(regions)
    moved[1] = type(regions[1])(label=regions[1].label, outline=[p + 0.25 for p in regions[1].outline],
                                patch=regions[1].patch)
    redrawn = curves.drawn_regions(moved, 40, 40, 0.005, cache=cache)
    fresh = curves.drawn_regions(moved, 40, 40, 0.005)
    for a, b in zip(redrawn, fresh):
        assert all(np.array_equal(p, q) for p, q in zip(a.outline, b.outline))
    assert len(cache) == sum(len(r.outline) for r in moved)


def _breaks_reference(polys, width, height):
    """The break rule read plainly: vertex ids by np.unique of the key rows, edges as a set of pairs."""
    keys = [tuple(k) for k in curves._keys(np.concatenate(polys))]
    ids = {k: i for i, k in enumerate(sorted(set(keys)))}
    vid = np.array([ids[k] for k in keys])
    neighbours = {}
    s0 = 0
    for p in polys:
        n = len(p)
        for i in range(n):
            a, b = vid[s0 + i], vid[s0 + (i + 1) % n]
            if a != b:
                neighbours.setdefault(a, set()).add(b)
                neighbours.setdefault(b, set()).add(a)
        s0 += n
    out, s0 = [], 0
    cos_max = np.cos(np.radians(curves.CORNER_TURN))
    for p in polys:
        n = len(p)
        flags = np.zeros(n, bool)
        for i in range(n):
            u, v = p[i] - p[i - 1], p[(i + 1) % n] - p[i]
            norm = np.hypot(*u) * np.hypot(*v)
            corner = norm == 0 or (u @ v) / norm < cos_max
            frame = p[i, 0] <= 0 or p[i, 0] >= width or p[i, 1] <= 0 or p[i, 1] >= height
            flags[i] = corner or frame or len(neighbours.get(vid[s0 + i], ())) != 2
        out.append(flags if n >= 3 else np.ones(n, bool))
        s0 += n
    return out


@pytest.mark.parametrize("seed", range(12))
def test_breaks_follow_their_rule(seed):
    """Junctions (a vertex with other than two distinct neighbours among all outlines), corners and the
    frame, on random polygons that share vertices and edges, repeat points and touch the frame."""
    rng = np.random.default_rng(seed)
    pool = np.round(rng.uniform(0, 20, (30, 2)) * 16) / 16
    pool[:3, 0] = 0.0  # on the frame
    polys = []
    for _ in range(rng.integers(2, 7)):
        idx = rng.choice(len(pool), rng.integers(3, 12))
        if rng.random() < 0.3:
            idx = np.insert(idx, 1, idx[0])  # a zero-length edge
        polys.append(pool[idx])
    got = curves.breaks(polys, 20, 20)
    want = _breaks_reference(polys, 20, 20)
    assert all(np.array_equal(g, w) for g, w in zip(got, want))
