"""Abstraction and stylisation (tpsv.edit.stylize, paper VII-E)."""

from __future__ import annotations

import numpy as np
import pytest

from editfixtures import photo_model, same_model, scene_model
from tpsv import codec
from tpsv.edit import stylize
from tpsv.edit.common import copy_model, feature_xy
from tpsv.errors import TpsvError
from tpsv.model import CURVILINEAR, GRADATION, Features, Model, Params, Region
from tpsv.geometry.patch import build_patch


@pytest.fixture(scope="module")
def model():
    return photo_model()


def test_level_0_is_identity(model):
    assert same_model(stylize.abstract(model, 0), model)


def test_levels_thin_and_quantise(model):
    f = model.features
    counts = []
    for n in range(0, 5):
        a = stylize.abstract(model, n)
        g = a.features
        counts.append(len(g))
        assert np.all(np.diff(g.region) >= 0)
        if n:
            grad = g.kind == GRADATION
            assert np.allclose(np.round(g.lab[grad, 1:] / (stylize.AB_STEP * n)) * stylize.AB_STEP * n, g.lab[grad, 1:], atol=1e-3)
            # curvilinear features kept are a subset of the input's, colours untouched
            cur_in = {(r, s, t, *lab) for r, (s, t), lab in zip(f.region[f.kind == CURVILINEAR], f.st[f.kind == CURVILINEAR],
                                                              map(tuple, f.lab[f.kind == CURVILINEAR]))}
            for r, (s, t), lab in zip(g.region[~grad], g.st[~grad], map(tuple, g.lab[~grad])):
                assert (r, s, t, *lab) in cur_in
            assert same_model(codec.decode(codec.encode(a)), codec.quantize(a))
    assert counts == sorted(counts, reverse=True) and counts[-1] < counts[0] / 3


def test_stylize_size_determinism_and_strokes(model):
    a = stylize.stylize(model, level=2, scale=1.5)
    b = stylize.stylize(model, level=2, scale=1.5)
    assert a.dtype == np.uint8 and a.shape == (round(model.height * 1.5), round(model.width * 1.5), 3)
    assert np.array_equal(a, b)
    plain = stylize.stylize(model, level=2, scale=1.5, with_strokes=False)
    diff = (a != plain).any(axis=2)
    assert diff.any()
    # strokes only touch pixels near curvilinear features of the abstraction
    m = stylize.abstract(model, 2)
    xy = feature_xy(m)[m.features.kind == CURVILINEAR] * 1.5
    ys, xs = np.nonzero(diff)
    d = np.hypot(xs[:, None] + 0.5 - xy[None, :, 0], ys[:, None] + 0.5 - xy[None, :, 1]).min(axis=1)
    assert d.max() < 4.0  # half a 2-px link (scaled), half the width, the anti-aliasing
    wide = stylize.stylize(model, level=2, scale=1.5, stroke_width=3)
    assert (wide != plain).any(axis=2).sum() > diff.sum()


def line_model():
    """One region with a row of curvilinear pairs along y = 10 (light above, dark below)."""
    mask = np.ones((20, 30), bool)
    p = build_patch(mask)
    xs = np.arange(3.0, 27.0, 1.0)
    above = np.column_stack([xs, np.full_like(xs, 9.5)])
    below = np.column_stack([xs, np.full_like(xs, 10.5)])
    from tpsv.geometry.patch import inverse, normalize

    st = normalize(p, inverse(p, np.concatenate([above, below])))
    n = xs.size
    pair = np.concatenate([np.arange(n, 2 * n), np.arange(n)]).astype(np.int32)
    lab = np.concatenate([np.tile([80.0, 0, 0], (n, 1)), np.tile([20.0, 0, 0], (n, 1))]).astype(np.float32)
    f = Features(region=np.zeros(2 * n, np.int32), st=st, lab=lab, kind=np.full(2 * n, CURVILINEAR, np.uint8), pair=pair)
    outline = [np.array([[0, 0], [30, 0], [30, 20], [0, 20]], np.float64)]
    return Model(width=30, height=20, regions=[Region(label=0, outline=outline, patch=p)], features=f, params=Params())


def test_stroke_chains_link_each_side():
    m = line_model()
    chains = stylize.stroke_chains(m)
    assert len(chains) == 2  # one per side of the edge, not zig-zagging across
    n = len(m.features) // 2
    sides = sorted(tuple(sorted(c.tolist())) for c in chains)
    assert sides == [tuple(range(n)), tuple(range(n, 2 * n))]
    for c in chains:
        x = feature_xy(m)[c, 0]
        assert np.all(np.diff(x) > 0) or np.all(np.diff(x) < 0)  # in order along the edge


def test_errors_and_input_untouched():
    m = scene_model()
    before = copy_model(m)
    stylize.stylize(m, level=3)
    assert same_model(m, before)
    with pytest.raises(TpsvError, match="level"):
        stylize.abstract(m, 9)
    with pytest.raises(TpsvError, match="level"):
        stylize.abstract(m, 1.5)
    with pytest.raises(TpsvError, match="width"):
        stylize.stylize(m, stroke_width=0)


def test_linking_a_pile_of_coincident_features_is_bounded():
    """A 745-byte file with one curvilinear feature repeated 50,000 times once asked for 17 GB."""
    import tracemalloc

    from tpsv.edit.stylize import MAX_LINK_NEIGHBOURS, _near_pairs

    xy = np.concatenate([np.zeros((20_000, 2)), np.random.default_rng(0).normal(0, 0.01, (5_000, 2))])
    tracemalloc.start()
    pairs = _near_pairs(xy, 2.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 200 * 2**20
    assert len(pairs) <= len(xy) * (MAX_LINK_NEIGHBOURS + 1)
    assert np.all(pairs[:, 0] < pairs[:, 1])


def test_near_pairs_equal_query_pairs_for_ordinary_density():
    from scipy.spatial import cKDTree

    from tpsv.edit.stylize import _near_pairs

    xy = np.random.default_rng(1).uniform(0, 60, (3000, 2))
    ref = np.unique(np.sort(cKDTree(xy).query_pairs(2.0, output_type="ndarray"), axis=1), axis=0)
    assert np.array_equal(_near_pairs(xy, 2.0), ref)
