"""Cross mapping (tpsv.edit.crossmap, paper VII-C): correspondence, replace, blend, colour statistics."""

from __future__ import annotations

import numpy as np
import pytest

from editfixtures import BACKGROUND, DISC, PANEL, photo_model, same_model, scene_model
from tpsv import codec
from tpsv.edit import crossmap
from tpsv.color import lab_to_srgb
from tpsv.edit.common import copy_model
from tpsv.errors import TpsvError
from tpsv.rendering.pixelmap import region_index
from tpsv.rendering.raster import render


@pytest.fixture(scope="module")
def model():
    return scene_model()


@pytest.fixture(scope="module")
def base_render(model):
    return render(model)


CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


@pytest.mark.parametrize("rotate", [0, 90, 180, 270])
@pytest.mark.parametrize("flip", [False, True])
def test_correspondence_maps_corners_to_corners(rotate, flip):
    out = crossmap.map_st(CORNERS, rotate, flip)
    cidx = {tuple(c): i for i, c in enumerate(CORNERS.tolist())}
    flipped = [1, 0, 3, 2] if flip else [0, 1, 2, 3]  # S -> 1 - S swaps corners 0<->1 and 2<->3
    for i in range(4):
        # each quarter turn moves a corner to the next one in the cycle (0,0) (1,0) (1,1) (0,1)
        assert cidx[tuple(out[i])] == (flipped[i] + rotate // 90) % 4
    rng = np.random.default_rng(0)
    st = rng.random((50, 2))
    assert np.allclose(crossmap.unmap_st(crossmap.map_st(st, rotate, flip), rotate, flip), st)


def test_rotate_90_sends_origin_to_s_corner():
    assert np.array_equal(crossmap.map_st([[0.0, 0.0]], 90), [[1.0, 0.0]])
    assert np.array_equal(crossmap.map_st([[0.0, 0.0]], 0, flip=True), [[1.0, 0.0]])


def test_replace_brings_stripes_onto_flat_target(model, base_render):
    out = crossmap.crossmap(model, PANEL, model, DISC)
    f, g = model.features, out.features
    # the target keeps its shape
    for a, b in zip(model.regions, out.regions):
        assert np.array_equal(a.patch.ctrl, b.patch.ctrl)
        assert all(np.array_equal(p, q) for p, q in zip(a.outline, b.outline))
    assert (g.region == PANEL).sum() == (f.region == DISC).sum()
    # features of the other regions are unchanged (positions and colours)
    for r in (BACKGROUND, DISC):
        assert np.array_equal(g.st[g.region == r], f.st[f.region == r])
        assert np.array_equal(g.lab[g.region == r], f.lab[f.region == r])
    img = render(out)
    idx = region_index(model, model.width, model.height)
    assert np.array_equal(img[idx != PANEL], base_render[idx != PANEL])
    # stripes: the panel's columns now alternate between light and dark red
    inner = (idx == PANEL)
    inner[:, :48] = False
    inner[:18, :] = False
    inner[42:, :] = False
    before = base_render[inner].std(axis=0).max()
    after = img[inner].std(axis=0).max()
    assert before < 0.02 and after > 0.1
    red = img[inner][:, 0] > 2 * img[inner][:, 1]
    assert red.mean() > 0.8
    cols = img[20:40, 48:63, 0].mean(axis=0)  # mean red per column
    assert (np.diff(np.sign(np.diff(cols))) != 0).sum() >= 2  # several light/dark alternations


def test_pairs_to_other_regions_are_dropped_and_valid(model):
    out = crossmap.crossmap(model, PANEL, model, DISC, rotate=90, flip=True)
    g = out.features
    assert np.all(np.diff(g.region) >= 0)
    paired = g.pair >= 0
    assert np.array_equal(g.pair[g.pair[paired]], np.flatnonzero(paired))
    m = g.region == PANEL
    assert np.all(g.region[g.pair[m & paired]] == PANEL)
    assert same_model(codec.decode(codec.encode(out)), codec.quantize(out))


def test_blend_alpha_extremes(model, base_render):
    idx = region_index(model, model.width, model.height)
    a0 = crossmap.crossmap(model, PANEL, model, DISC, alpha=0.0)
    assert (a0.features.region == PANEL).sum() == (model.features.region == PANEL).sum() + (
        model.features.region == DISC).sum()
    diff0 = np.abs(render(a0) - base_render)[idx == PANEL]
    assert diff0.mean() < 0.01
    rep = render(crossmap.crossmap(model, PANEL, model, DISC))
    a1 = render(crossmap.crossmap(model, PANEL, model, DISC, alpha=1.0))
    half = render(crossmap.crossmap(model, PANEL, model, DISC, alpha=0.5))
    d_rep = np.abs(a1 - rep)[idx == PANEL].mean()
    d_tgt = np.abs(a1 - base_render)[idx == PANEL].mean()
    assert d_rep < 0.5 * d_tgt
    mid = np.abs(half - 0.5 * (a1 + render(a0)))[idx == PANEL].mean()
    assert mid < 0.05


def test_match_stats_takes_target_palette(model):
    out = crossmap.crossmap(model, PANEL, model, DISC, match_stats=True)
    tgt = model.features.lab[model.features.region == PANEL].astype(np.float64)
    got = out.features.lab[out.features.region == PANEL].astype(np.float64)
    assert np.allclose(got.mean(0), tgt.mean(0), atol=0.5)
    # the structure is the source's: colours ordered as the source's lightness
    src = model.features.lab[model.features.region == DISC][:, 0]
    assert np.corrcoef(src, got[:, 0])[0, 1] > 0.99


def test_cross_model_source_and_input_untouched(model):
    photo = photo_model()
    before = copy_model(model)
    out = crossmap.crossmap(model, DISC, photo, 0, rotate=180)
    assert same_model(model, before)
    assert (out.features.region == DISC).sum() == (photo.features.region == 0).sum()
    assert np.isfinite(render(out)).all()


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(target_region=5), "target region 5"),
        (dict(source_region=-1), "source region"),
        (dict(rotate=45), "rotation"),
        (dict(alpha=1.5), "alpha"),
    ],
)
def test_errors(model, kw, message):
    args = dict(target=model, target_region=PANEL, source=model, source_region=DISC)
    args.update(kw)
    with pytest.raises(TpsvError, match=message):
        crossmap.crossmap(**args)


def test_match_color_stats_numbers():
    rng = np.random.default_rng(3)
    s = rng.normal([50, 10, -5], [5, 2, 3], (400, 3))
    t = rng.normal([70, -20, 30], [2, 6, 1], (300, 3))
    out = crossmap.match_color_stats(s, t)
    assert np.allclose(out.mean(0), t.mean(0)) and np.allclose(out.std(0), t.std(0))
    assert np.all(lab_to_srgb(np.clip(out, [0, -128, -128], [100, 127, 127])) >= 0)
