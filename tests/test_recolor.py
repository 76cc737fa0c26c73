"""Colour editing (tpsv.edit.recolor, paper VII-B): selection, operations, far side kept, round trips."""

from __future__ import annotations

import numpy as np
import pytest

from editfixtures import BACKGROUND, DISC, DISC_C, PANEL, photo_model, same_model, scene_model
from tpsv import codec
from tpsv.edit import recolor
from tpsv.edit.common import copy_model
from tpsv.errors import TpsvError
from tpsv.model import CURVILINEAR, GRADATION
from tpsv.rendering.pixelmap import region_index
from tpsv.rendering.raster import render


@pytest.fixture(scope="module")
def model():
    return scene_model()


@pytest.fixture(scope="module")
def base_render(model):
    # one region per pixel: the selection's pixels are exactly its region's
    return render(model, antialias=False)


def unchanged_outside(model, new, mask):
    """Features outside ``mask`` are bit-identical in every field."""
    f, g = model.features, new.features
    for k in ("region", "st", "kind", "pair"):
        assert np.array_equal(getattr(f, k), getattr(g, k))
    assert np.array_equal(f.lab[~mask], g.lab[~mask])


def test_select_by_colour_region_and_radius(model):
    f = model.features
    red = recolor.select(model, color=(0.85, 0.15, 0.1), tolerance=25)
    assert red.any() and np.all(f.region[red] == DISC)
    everything = recolor.select(model)
    assert everything.all()
    panel = recolor.select(model, region=PANEL)
    assert np.array_equal(panel, f.region == PANEL)
    near = recolor.select(model, at=DISC_C, radius=5, tolerance=200)
    from tpsv.edit.common import feature_xy

    xy = feature_xy(model)
    assert np.array_equal(near, np.hypot(*(xy - DISC_C).T) <= 5)


def test_select_at_seed_uses_nearest_feature_of_region_under_point(model):
    f = model.features
    from tpsv.edit.common import feature_xy, region_at

    p = (50.0, 30.0)
    assert region_at(model, p) == PANEL
    sel = recolor.select(model, at=p, tolerance=0.0)
    xy = feature_xy(model)
    cand = np.flatnonzero(f.region == PANEL)
    seed = cand[np.argmin(np.hypot(*(xy[cand] - p).T))]
    assert sel[seed]
    assert np.all(np.linalg.norm(f.lab[sel] - f.lab[seed], axis=1) == 0)


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(at=(64.0, 3.0)), "outside"),
        (dict(at=(-1, 3)), "outside"),
        (dict(region=7), "does not exist"),
        (dict(radius=3.0), "seed point"),
        (dict(at=(3, 3), radius=-1.0), "positive"),
        (dict(color=(2.0, 0, 0)), "sRGB"),
        (dict(tolerance=-1), ">= 0"),
    ],
)
def test_select_errors(model, kw, message):
    with pytest.raises(TpsvError, match=message):
        recolor.select(model, **kw)


def test_hue_rotation_changes_selection_only_and_keeps_lightness_chroma(model, base_render):
    mask = recolor.select(model, region=DISC)
    new = recolor.recolor_features(model, mask, hue=120)
    unchanged_outside(model, new, mask)
    a, b = model.features.lab[mask].astype(np.float64), new.features.lab[mask].astype(np.float64)
    assert np.allclose(a[:, 0], b[:, 0])
    assert np.allclose(np.hypot(a[:, 1], a[:, 2]), np.hypot(b[:, 1], b[:, 2]), atol=1e-3)
    ha = np.degrees(np.arctan2(a[:, 2], a[:, 1]))
    hb = np.degrees(np.arctan2(b[:, 2], b[:, 1]))
    big = np.hypot(a[:, 1], a[:, 2]) > 5
    assert np.allclose((hb - ha)[big] % 360.0, 120.0, atol=0.01)
    # pixels of the regions not edited render identically
    out = render(new, antialias=False)
    idx = region_index(model, model.width, model.height)
    assert np.array_equal(out[idx != DISC], base_render[idx != DISC])
    assert not np.array_equal(out[idx == DISC], base_render[idx == DISC])


def test_curvilinear_far_side_is_kept(model):
    f = model.features
    mask = recolor.select(model, region=DISC)
    new = recolor.recolor(model, region=DISC, shift_ab=(-40, 30), lightness=10)
    cur = np.flatnonzero(mask & (f.kind == CURVILINEAR) & (f.pair >= 0))
    far = f.pair[cur][f.region[f.pair[cur]] == BACKGROUND]
    assert far.size > 10  # the disc's border pairs
    assert np.array_equal(new.features.lab[far], f.lab[far])  # background side unchanged
    near = cur[f.region[f.pair[cur]] == BACKGROUND]
    assert np.all((new.features.lab[near] != f.lab[near]).any(axis=1))  # disc side changed
    # both halves of a selected pair change when both are selected
    both = cur[mask[f.pair[cur]]]
    assert np.all((new.features.lab[f.pair[both]] != f.lab[f.pair[both]]).any(axis=1))


def test_matrix_acts_on_gradation_features_only(model):
    sepia = [[0.393, 0.769, 0.189], [0.349, 0.686, 0.168], [0.272, 0.534, 0.131]]
    new = recolor.recolor(model, matrix=sepia)
    f = model.features
    grad = f.kind == GRADATION
    assert np.array_equal(new.features.lab[~grad], f.lab[~grad])
    assert (new.features.lab[grad] != f.lab[grad]).any(axis=1).mean() > 0.9
    same = recolor.recolor(model, matrix=np.eye(3), matrix_space="lab")
    assert np.allclose(same.features.lab, f.lab)
    swap = recolor.recolor(model, region=PANEL, matrix=[[1, 0, 0], [0, -1, 0], [0, 0, -1]], matrix_space="lab")
    g = (f.region == PANEL) & grad
    assert np.allclose(swap.features.lab[g][:, 1:], -f.lab[g][:, 1:], atol=1e-4)
    with pytest.raises(TpsvError, match="9 finite"):
        recolor.recolor(model, matrix=[1, 2, 3])
    with pytest.raises(TpsvError, match="matrix space"):
        recolor.recolor(model, matrix=np.eye(3), matrix_space="hsv")


def test_harmonic_templates_and_fit():
    assert set(recolor.TEMPLATES) == {"i", "V", "L", "I", "T", "Y", "X"}
    widths = {k: sum(w for _, w in v) for k, v in recolor.TEMPLATES.items()}
    assert widths["i"] == 18 and widths["V"] == 93.6 and widths["T"] == 180
    # two opposite hue clusters: the I template (two opposite narrow sectors) fits exactly
    hues = np.radians(np.array([40.0, 42.0, 44.0, 220.0, 222.0, 224.0]))
    lab = np.column_stack([np.full(6, 60.0), 40 * np.cos(hues), 40 * np.sin(hues)])
    name, rot, cost = recolor.harmonic_template(lab, "auto")
    assert name == "I" and cost == 0.0
    # a spread of hues is pulled into the chosen template's sectors
    rng = np.random.default_rng(1)
    h = np.radians(rng.uniform(0, 360, 200))
    lab = np.column_stack([np.full(200, 50.0), 30 * np.cos(h), 30 * np.sin(h)])
    for t in ("i", "V", "L", "I", "Y", "X", "T"):
        name, rot, _ = recolor.harmonic_template(lab, t)
        out = recolor.harmonize_hues(lab, name, rot)
        assert np.allclose(np.hypot(out[:, 1], out[:, 2]), 30.0)
        assert np.allclose(out[:, 0], 50.0)
        hh = np.degrees(np.arctan2(out[:, 2], out[:, 1]))
        dist = np.min([np.maximum(np.abs((hh - (rot + off) + 180) % 360 - 180) - w / 2, 0)
                       for off, w in recolor.TEMPLATES[t]], axis=0)
        assert dist.max() < 1e-6, t
    with pytest.raises(TpsvError, match="template"):
        recolor.harmonic_template(lab, "Q")


def test_harmonize_edit(model):
    new = recolor.recolor(model, harmonize="auto")
    assert (new.features.lab != model.features.lab).any()
    assert np.allclose(new.features.lab[:, 0], model.features.lab[:, 0], atol=1e-4)


def test_input_not_mutated_and_round_trip():
    m = photo_model()
    before = copy_model(m)
    new = recolor.recolor(m, color=(0.2, 0.15, 0.1), tolerance=40, hue=45, lightness=-5)
    assert same_model(m, before)
    assert (new.features.lab != m.features.lab).any()
    assert same_model(codec.decode(codec.encode(new)), codec.quantize(new))
