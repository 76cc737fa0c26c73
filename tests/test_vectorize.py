"""The vectorize pipeline: schemes, the colour fit, the search wiring (tpsv.encode.vectorize)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import codec, metrics
from tpsv.encode import search as selection
from tpsv.cli import main
from tpsv.errors import TpsvError
from tpsv.model import Params
from tpsv.encode.features import FeatureExtractor
from tpsv.rendering.raster import render
from tpsv.encode.vectorize import (
    SCHEME_PARAMS, Candidates, build_geometry, finish, label_map, make_model, scan_order, scheme_of, scheme_params,
    search_thresholds, start_thresholds, vectorize,
)
from tpsv.geometry.regions import to_patch_space


@pytest.fixture(scope="module")
def scene(small_rgb, small_labels):
    return small_rgb, small_labels


def test_scheme_params_and_switch():
    p = scheme_params()
    assert scheme_of(p) == "tpsv" and "scheme" not in p.extra
    assert (p.kernel_size, p.overlap, p.st_steps) == (32, 0.25, 2)
    q = scheme_params("paper", kernel_size=None, smoothing=0.5)
    assert scheme_of(q) == "paper" and q.extra == {"scheme": "paper"}
    assert (q.kernel_size, q.overlap, q.st_steps, q.l_step, q.ab_step, q.smoothing) == (64, 0.5, 16, 1, 1, 0.5)
    with pytest.raises(TpsvError, match="unknown feature scheme"):
        scheme_params("nope")
    with pytest.raises(TpsvError, match="unknown feature scheme"):
        scheme_of(replace(p, extra={"scheme": "nope"}))


def test_plain_scheme_reproduces_the_paper_pipeline(scene):
    rgb, labels = scene
    res = vectorize(rgb, labels, search=False, params=scheme_params("paper"))
    m = res.model
    assert scheme_of(m.params) == "paper"
    # the plain scheme as first implemented: extractor.extract, features mapped into
    # the patches, sampled colours, no fit
    g = build_geometry(labels, rgb)
    c0, s0 = selection.initial_thresholds(rgb, g.index)
    fs = FeatureExtractor(rgb, g.index).extract(c0, s0)
    st = to_patch_space([r.patch for r in g.regions], fs.xy, fs.region)
    ref = codec.quantize(replace(m, features=replace(
        m.features, region=fs.region.astype(np.int32), st=st, lab=fs.lab.astype(np.float32),
        kind=fs.kind.astype(np.uint8), pair=fs.pair.astype(np.int32))))
    for name in ("region", "st", "lab", "kind", "pair"):
        assert np.array_equal(getattr(m.features, name), getattr(ref.features, name)), name
    assert (m.params.t_canny, m.params.t_super) == (c0, s0)
    assert res.psnr == pytest.approx(metrics.psnr(rgb, render(m)))


def test_default_scheme_is_fitted_sorted_and_compact(scene):
    rgb, labels = scene
    res = vectorize(rgb, labels, search=False)
    m = res.model
    assert scheme_of(m.params) == "tpsv" and m.params.kernel_size == 32
    f = m.features
    assert np.all(np.diff(f.region) >= 0)
    assert np.array_equal(scan_order(f.region, f.st, f.pair), np.arange(len(f)))
    # the same features with their cells' mean colours (no fit) render worse
    g = build_geometry(labels, rgb)
    unfitted = codec.quantize(make_model(rgb, g, FeatureExtractor(rgb, g.index), m.params, fit=False))
    assert np.array_equal(unfitted.features.st, f.st)
    assert res.psnr > metrics.psnr(rgb, render(unfitted))
    plain = vectorize(rgb, labels, search=False, params=scheme_params("paper"))
    assert len(res.data) < len(plain.data)


def test_scan_order_keeps_pairs_together():
    region = np.array([0, 0, 0, 0, 1, 1])
    st = np.array([[0.9, 0.9], [0.1, 0.9], [0.5, 0.1], [0.4, 0.1], [0.5, 0.5], [0.2, 0.2]])
    pair = np.array([1, 0, -1, -1, -1, -1])
    order = scan_order(region, st, pair)
    assert order.tolist() == [3, 2, 0, 1, 5, 4]


def test_search_never_worse_and_seeded(scene):
    rgb, labels = scene
    a = vectorize(rgb, labels, search=True, iterations=5, seed=3)
    b = vectorize(rgb, labels, search=True, iterations=5, seed=3)
    assert a.data == b.data
    assert [(h.t_canny, h.t_super) for h in a.history] == [(h.t_canny, h.t_super) for h in b.history]
    h, w = rgb.shape[:2]
    start = vectorize(rgb, labels, search=False)
    w_start = metrics.efficiency(start.mse, len(start.data), w, h)
    w_best = metrics.efficiency(a.mse, len(a.data), w, h)
    assert w_best >= w_start
    chosen = (a.model.params.t_canny, a.model.params.t_super)
    start_t = (start.model.params.t_canny, start.model.params.t_super)
    assert chosen == start_t or chosen == max(a.history, key=lambda t: t.w)[:2]
    assert (a.model.params.l_step, a.model.params.ab_step) in {(2, 4), (4, 8), (8, 8), (8, 16), (12, 16), (16, 16)}


def test_cli_plain_flag(tmp_path, small_png):
    runner = CliRunner()
    out = tmp_path / "p.tpsv"
    r = runner.invoke(main, ["vectorize", str(small_png), "-o", str(out), "--no-search", "--plain", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["scheme"] == "paper"
    m = codec.load(out)
    assert m.params.kernel_size == 64 and m.params.extra.get("scheme") == "paper"
    out2 = tmp_path / "d.tpsv"
    r = runner.invoke(main, ["vectorize", str(small_png), "-o", str(out2), "--no-search", "--json"])
    assert r.exit_code == 0, r.output
    s2 = json.loads(r.output)
    assert s2["scheme"] == "tpsv" and s2["bytes"] < s["bytes"]
    assert codec.load(out2).params.kernel_size == 32


# ------------------------------------------------------------------------- the stages


def test_params_defaults_are_the_default_scheme():
    assert scheme_of(Params()) == "tpsv" and scheme_params() == Params()
    paper = scheme_params("paper")
    assert scheme_of(paper) == "paper"
    assert {k: getattr(paper, k) for k in SCHEME_PARAMS["paper"]} == SCHEME_PARAMS["paper"]


def test_label_map_stage(scene):
    rgb, labels = scene
    assert label_map(rgb, labels) is labels
    auto = label_map(rgb, None, seed=0)
    assert auto.shape == labels.shape
    with pytest.raises(TpsvError, match="label map is"):
        label_map(rgb, labels[:, :-1])


def test_start_thresholds_stage_keeps_given_thresholds(scene):
    rgb, labels = scene
    g = build_geometry(labels)
    c0, s0 = start_thresholds(rgb, g)
    assert (c0, s0) == selection.initial_thresholds(rgb, g.index)
    assert start_thresholds(rgb, g, t_canny=77.0) == (77.0, s0)
    assert start_thresholds(rgb, g, t_super=3.5) == (c0, 3.5)


def test_stages_give_vectorize_without_search(scene):
    rgb, labels = scene
    g = build_geometry(label_map(rgb, labels), rgb)
    cands = Candidates(rgb, g, scheme_params())
    out = cands.evaluate(*start_thresholds(rgb, g))
    res = vectorize(rgb, labels, search=False)
    assert out.data == res.data and out.mse == res.mse
    assert out.efficiency() == metrics.efficiency(res.mse, len(res.data), rgb.shape[1], rgb.shape[0])
    # the unfitted colours of stage 4, then the fit of stage 5, give the model's colours
    model = cands.model(*start_thresholds(rgb, g))
    lab, ks = cands.fitted_colours(model, final=True)
    assert np.array_equal(model.features.st, res.model.features.st)
    assert ks.n_kernels > 0 and lab.shape == model.features.lab.shape


def test_stages_give_vectorize_with_search(scene):
    rgb, labels = scene
    g = build_geometry(labels, rgb)
    cands = Candidates(rgb, g, scheme_params())
    start = start_thresholds(rgb, g)
    calls = []
    best, result = search_thresholds(cands, start, iterations=4, seed=5, progress=lambda d, n: calls.append((d, n)))
    assert best == (result.t_canny, result.t_super)
    assert result.history[0][:2] == pytest.approx(start, abs=0.05)  # the search rounds to 0.1
    assert calls == [(k + 1, 4) for k in range(len(result.history))]
    out = finish(cands, best, start, result, choose_steps=True)
    res = vectorize(rgb, labels, search=True, iterations=4, seed=5)
    assert out.data == res.data and res.history == result.history


def test_search_stage_keeps_a_fixed_threshold(scene):
    rgb, labels = scene
    g = build_geometry(labels)
    cands = Candidates(rgb, g, scheme_params("paper"))
    start = start_thresholds(rgb, g, t_canny=90.0)
    best, result = search_thresholds(cands, start, (True, False), iterations=3, seed=1)
    assert best[0] == 90.0 and best[1] == result.t_super


def test_candidates_with_identical_features_share_their_fit(scene):
    rgb, labels = scene
    g = build_geometry(labels)
    cands = Candidates(rgb, g, scheme_params())
    s0 = start_thresholds(rgb, g)[1]
    a = cands.evaluate(1400.0, s0, final=False)  # both above every edge: no curvilinear pair
    b = cands.evaluate(1500.0, s0, final=False)
    assert a.mse == b.mse and a.data != b.data  # the files differ in their params only
    assert np.array_equal(a.model.features.lab, b.model.features.lab)
    assert len(cands._fits) == 1
