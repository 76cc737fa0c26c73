"""Threshold selection: histogram statistics, VI-A start, Monte Carlo search."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tpsv.encode.features import FeatureExtractor
from tpsv.encode.search import CANNY_RANGE, SUPER_RANGE, efficiency, gradient_stats, initial_thresholds, monte_carlo_search, thresholds_from_stats


def small_sample(name: str, long_side: int = 128) -> np.ndarray:
    import skimage.data

    im = getattr(skimage.data, name)()
    if im.ndim == 2:
        im = np.stack([im] * 3, -1)
    im = im[..., :3]
    h, w = im.shape[:2]
    s = long_side / max(h, w)
    im = cv2.resize(im, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
    return im.astype(np.float32) / 255.0


# ---------------------------------------------------------------------- efficiency


def test_efficiency_formula():
    w = efficiency(0.001, 3000, 100, 50)
    assert w == pytest.approx(1.0 / (0.001 * 3000 / (100 * 50 * 3)))
    assert efficiency(0.0, 100, 10, 10) == math.inf
    with pytest.raises(ValueError):
        efficiency(0.1, 10, 0, 5)


# -------------------------------------------------------------- histogram and start


def test_interpolation_of_vi_a():
    # mu <= C_canny: t = 1
    assert thresholds_from_stats(20.0, 10.0) == pytest.approx((max(15.0, CANNY_RANGE[0]), 8.0))
    # mu >= C_super: t = 0
    assert thresholds_from_stats(70.0, 20.0) == pytest.approx((90.0, 5.0))
    # halfway
    tc, ts = thresholds_from_stats(45.0, 20.0)
    assert tc == pytest.approx(0.5 * (45 - 10) + 0.5 * (45 + 20))
    assert ts == pytest.approx(0.5 * 16 + 0.5 * 5)
    # degenerate statistics are clamped into the valid ranges
    tc, ts = thresholds_from_stats(0.0, 0.0)
    assert tc == CANNY_RANGE[0] and ts == SUPER_RANGE[0]


def test_flat_image_stats_and_start():
    rgb = np.full((20, 20, 3), 0.5, np.float32)
    assert gradient_stats(rgb) == (0.0, 0.0)
    tc, ts = initial_thresholds(rgb)
    assert CANNY_RANGE[0] <= tc <= CANNY_RANGE[1] and SUPER_RANGE[0] <= ts <= SUPER_RANGE[1]


def test_step_scale_and_region_border_option():
    # a step of height h (0-255 units of 2.55 L) has Sobel magnitude 4 h
    g = np.zeros((10, 20, 3), np.float32)
    g[:, 10:] = 1.0  # black -> white: L 0 -> 100, i.e. 255 units
    mu, sigma = gradient_stats(g)
    # only the two columns beside the step are non-flat, each 4 * 255
    assert mu == pytest.approx(4 * 255, rel=1e-3)
    # textured left region + a strong region border: the border is left out
    rng = np.random.default_rng(0)
    rgb = np.clip(0.5 + 0.05 * rng.standard_normal((30, 40, 3)), 0, 1).astype(np.float32)
    rgb[:, 20:] = 1.0
    index = np.zeros((30, 40), np.int32)
    index[:, 20:] = 1
    mu_all, _ = gradient_stats(rgb)
    assert gradient_stats(rgb, index) == (mu_all, _)  # default: whole image
    mu_in, _ = gradient_stats(rgb, index, exclude_borders=True)
    assert mu_in < mu_all
    with pytest.raises(ValueError):
        gradient_stats(rgb, index[:, :5])


@pytest.mark.parametrize("name", ["chelsea", "coffee", "astronaut", "rocket"])
def test_initial_thresholds_in_usable_range(name):
    rgb = small_sample(name)
    index = np.zeros(rgb.shape[:2], np.int32)
    mu, sigma = gradient_stats(rgb, index)
    assert 10 < mu < 200 and sigma > 0
    tc, ts = initial_thresholds(rgb, index)
    assert CANNY_RANGE[0] < tc < CANNY_RANGE[1]
    assert SUPER_RANGE[0] < ts < 100
    fe = FeatureExtractor(rgb, index)
    frac = fe.edges(tc).mean()
    assert 0.005 < frac < 0.35, frac  # some edges, not everything
    # T0_super sits inside the range of base-cell deviations: it splits some cells
    hier = fe.hierarchy()
    assert len(hier.labels) >= 2
    n_cells = len(np.unique(fe.cells(ts)))
    assert len(np.unique(fe.cells(SUPER_RANGE[1]))) < n_cells < len(np.unique(fe.cells(SUPER_RANGE[0])))


# -------------------------------------------------------------------------- search


class Counting:
    """A cheap objective with a maximum of w near (120, 25)."""

    def __init__(self, as_w=False):
        self.calls = []
        self.as_w = as_w

    def __call__(self, tc, ts):
        self.calls.append((tc, ts))
        e = 0.01 * (1 + ((tc - 120.0) / 60.0) ** 2)
        c = 0.1 * (1 + ((ts - 25.0) / 20.0) ** 2)
        return 1.0 / (e * c) if self.as_w else (e, c)


def test_search_improves_never_worse_and_is_seeded():
    f = Counting()
    res = monte_carlo_search(f, (60.0, 10.0), iterations=20, seed=3)
    start = res.history[0]
    assert (start.t_canny, start.t_super) == (60.0, 10.0)
    assert res.w >= start.w
    assert res.w == max(h.w for h in res.history)
    assert res.best.w == res.w
    assert len(res.history) == 20 == len(f.calls)
    assert len(set(f.calls)) == len(f.calls)
    assert (res.t_canny, res.t_super) in f.calls  # exact values that were evaluated
    for h in res.history:
        assert CANNY_RANGE[0] <= h.t_canny <= CANNY_RANGE[1]
        assert SUPER_RANGE[0] <= h.t_super <= SUPER_RANGE[1]
        assert h.w == pytest.approx(1.0 / (h.E * h.C))
    again = monte_carlo_search(Counting(), (60.0, 10.0), iterations=20, seed=3)
    assert again.history == res.history
    other = monte_carlo_search(Counting(), (60.0, 10.0), iterations=20, seed=4)
    assert other.history != res.history


def test_search_start_already_best_is_kept():
    res = monte_carlo_search(Counting(), (120.0, 25.0), iterations=15, seed=0)
    assert (res.t_canny, res.t_super) == (120.0, 25.0)


def test_search_mutation_range_is_relative_to_best():
    f = Counting()
    res = monte_carlo_search(f, (50.0, 10.0), iterations=30, seed=1)
    best = res.history[0]
    for h in res.history[1:]:
        assert abs(h.t_canny - best.t_canny) <= abs(best.t_canny) + 0.05
        assert abs(h.t_super - best.t_super) <= abs(best.t_super) + 0.05
        if h.w > best.w:
            best = h


def test_search_cache_no_duplicate_evaluations():
    f = Counting()
    # very coarse rounding and a narrow range force collisions
    res = monte_carlo_search(
        f, (20.0, 5.0), iterations=40, seed=0, canny_range=(10.0, 40.0), super_range=(1.0, 10.0), decimals=-1
    )
    assert len(f.calls) == len(set(f.calls)) == len(res.history) < 40
    assert res.iterations == 40


def test_search_accepts_w_directly_and_zero_iterations():
    f = Counting(as_w=True)
    res = monte_carlo_search(f, (60.0, 10.0), iterations=10, seed=0)
    assert res.w >= res.history[0].w and math.isnan(res.history[0].E)
    ref = monte_carlo_search(Counting(), (60.0, 10.0), iterations=10, seed=0)
    assert [(h.t_canny, h.t_super) for h in res.history] == [(h.t_canny, h.t_super) for h in ref.history]
    none = monte_carlo_search(Counting(), (60.0, 10.0), iterations=0)
    assert none.history == [] and (none.t_canny, none.t_super) == (60.0, 10.0)


def test_search_min_width_lets_small_thresholds_grow_back():
    f = Counting()
    start = (60.0, 10.0)
    res = monte_carlo_search(f, start, iterations=40, seed=2, min_width=start)
    best = res.history[0]
    for h in res.history[1:]:
        assert abs(h.t_canny - best.t_canny) <= max(abs(best.t_canny), start[0]) + 0.05
        assert abs(h.t_super - best.t_super) <= max(abs(best.t_super), start[1]) + 0.05
        if h.w > best.w:
            best = h
    assert res.w >= res.history[0].w
    again = monte_carlo_search(Counting(), start, iterations=40, seed=2, min_width=start)
    assert again.history == res.history
    # from a best near the bottom of the range the draws still reach the start's scale
    low = monte_carlo_search(Counting(), (9.0, 1.5), iterations=30, seed=0, min_width=(60.0, 10.0))
    assert max(h.t_super for h in low.history) > 5.0
