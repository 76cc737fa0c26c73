"""Bjontegaard delta PSNR and the rate-distortion table of ``tpsv bench`` (tpsv.bench.rd)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import small_sample
from tpsv.bench.rd import COMPARISONS, CURVES, bd_psnr, rd_table, rd_table_text

# A codec-like curve: PSNR rising and flattening with log rate.
RATE = np.array([0.1, 0.2, 0.4, 0.8, 1.6, 3.2])
PSNR = np.array([24.0, 27.5, 30.5, 33.0, 35.0, 36.5])


def test_bd_psnr_of_a_curve_against_itself_is_zero():
    assert bd_psnr(RATE, PSNR, RATE, PSNR) == pytest.approx(0.0, abs=1e-12)


def test_bd_psnr_of_a_shifted_curve_is_the_shift():
    assert bd_psnr(RATE, PSNR, RATE, PSNR + 1.5) == pytest.approx(1.5, abs=1e-6)
    assert bd_psnr(RATE, PSNR + 1.5, RATE, PSNR) == pytest.approx(-1.5, abs=1e-6)
    # point order does not matter
    perm = [3, 0, 5, 1, 4, 2]
    assert bd_psnr(RATE[perm], PSNR[perm], RATE, PSNR + 1.5) == pytest.approx(1.5, abs=1e-6)


def test_bd_psnr_of_a_cheaper_curve_is_positive():
    assert bd_psnr(RATE, PSNR, RATE * 0.9, PSNR) > 0
    assert bd_psnr(RATE * 0.9, PSNR, RATE, PSNR) < 0


def test_bd_psnr_is_nan_without_overlap_or_points():
    assert math.isnan(bd_psnr([0.1, 0.2], [20, 25], [0.5, 1.0], [30, 35]))
    assert math.isnan(bd_psnr(RATE, PSNR, [0.5], [30]))
    # a range outside both curves
    assert math.isnan(bd_psnr(RATE, PSNR, RATE, PSNR + 1, lo=5.0, hi=10.0))
    # only one usable point left: non-finite PSNR and non-positive rates are dropped
    assert math.isnan(bd_psnr(RATE, PSNR, [0.0, 0.5, 1.0], [20, 30, np.inf]))


def test_bd_psnr_duplicate_rates_keep_the_best_point():
    r = np.r_[RATE, 0.8]
    p = np.r_[PSNR, 20.0]  # a worse second point at rate 0.8 is ignored
    assert bd_psnr(RATE, PSNR, r, p) == pytest.approx(0.0, abs=1e-12)


def test_bd_psnr_bpp_range():
    # Both linear in log10 rate, so PCHIP is exact: b - a = 10 log10(rate).
    r = np.geomspace(0.1, 10, 9)
    a = 30 + 10 * np.log10(r)
    b = 30 + 20 * np.log10(r)
    assert bd_psnr(r, a, r, b) == pytest.approx(0.0, abs=1e-9)
    assert bd_psnr(r, a, r, b, lo=1.0) == pytest.approx(5.0, abs=1e-9)
    assert bd_psnr(r, a, r, b, hi=1.0) == pytest.approx(-5.0, abs=1e-9)
    assert bd_psnr(r, a, r, b, lo=1.0, hi=10.0) == pytest.approx(5.0, abs=1e-9)
    # a range wider than the curves is clipped to their overlap
    assert bd_psnr(r, a, r, b, lo=0.01, hi=1000) == pytest.approx(0.0, abs=1e-9)


def test_rd_table_small():
    rng = np.random.default_rng(0)
    h = w = 48
    yy, xx = np.mgrid[0:h, 0:w] / 47.0
    rgb = np.stack([xx, yy, 0.5 + 0.3 * np.sin(6 * xx)], axis=-1)
    rgb[12:36, 12:36] = [0.9, 0.2, 0.1]
    rgb = np.clip(rgb + rng.normal(0, 0.02, rgb.shape), 0, 1).astype(np.float32)
    labels = np.zeros((h, w), np.int32)
    labels[12:36, 12:36] = 1

    rd = rd_table(rgb, labels, qualities=(20, 80), codec_qualities=(20, 80))
    assert set(rd["curves"]) == set(CURVES)
    for name, pts in rd["curves"].items():
        assert [p["quality"] for p in pts] == [20, 80], name
        for p in pts:
            assert p["bytes"] > 0 and p["bpp"] == pytest.approx(8 * p["bytes"] / (h * w))
            assert p["psnr"] > 10
        assert pts[1]["bytes"] > pts[0]["bytes"], name
    assert rd["bd_range"] == [0.25, 2.0]
    assert set(rd["bd_psnr"]) == {key for key, _, _ in COMPARISONS}
    for v in rd["bd_psnr"].values():
        assert set(v) == {"range", "overlap"}
        assert all(isinstance(x, float) and (math.isfinite(x) or math.isnan(x)) for x in v.values())
    text = rd_table_text("tiny", rd)
    assert "tpsv no-detail" in text and "WebP" in text and "BD-PSNR" in text


def test_detail_codec_table_compares_against_the_stored_codec():
    """``tpsv bench --codecs``: every codec's curve rises, and the chosen one is the reference."""
    from tpsv.bench.codecs import QUALITIES, detail_codec_table

    rgb = small_sample("rocket", 40)
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 20:] = 1
    table = detail_codec_table(rgb, labels)
    assert set(table["codecs"]) == set(QUALITIES)
    assert table["codecs"]["avif-planes"]["bd_vs_avif_planes"] == pytest.approx(0.0, abs=1e-9)
    for name, c in table["codecs"].items():
        psnr = [p["psnr"] for p in c["points"]]
        assert psnr[-1] > psnr[0], name
        assert all(p["bytes"] > table["base_bytes"] for p in c["points"])
