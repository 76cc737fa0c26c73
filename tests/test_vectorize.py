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
from tpsv.encode.features import FeatureExtractor
from tpsv.render.raster import render
from tpsv.encode.vectorize import build_geometry, make_model, scan_order, scheme_of, scheme_params, to_patch_space, vectorize


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
    g = build_geometry(labels)
    c0, s0 = selection.initial_thresholds(rgb, g.index)
    fs = FeatureExtractor(rgb, g.index).extract(c0, s0)
    st = to_patch_space(g, fs.xy, fs.region)
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
    g = build_geometry(labels)
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
