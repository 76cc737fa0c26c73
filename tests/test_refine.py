"""Edge-preserving refinement of a magnified picture (tpsv.rendering.refine)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tpsv import metrics
from tpsv.rendering import refine as rf
from tpsv.rendering.magnify import magnify_raster


def _disc(size: int, supersample: int = 8) -> np.ndarray:
    """A dark disc on a light ground with a colour gradient, area-sampled (float32 RGB)."""
    n = size * supersample
    yy, xx = (np.mgrid[:n, :n] + 0.5) / supersample
    inside = (xx - 0.52 * size) ** 2 + (yy - 0.47 * size) ** 2 < (0.3 * size) ** 2
    img = np.empty((n, n, 3), np.float32)
    img[...] = (0.85, 0.8, 0.7)
    img[..., 0] -= 0.3 * xx / size
    img[inside] = (0.15, 0.25, 0.45)
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


def _area(img: np.ndarray, shape) -> np.ndarray:
    return cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def test_refinement_keeps_the_area_average_and_sharpens_an_edge():
    truth = _disc(96)
    small = _area(truth, (24, 24))
    start = np.clip(cv2.resize(small, (96, 96), interpolation=cv2.INTER_CUBIC), 0, 1)
    out = rf.refine_magnified(start, small, 40)
    assert out.dtype == np.float32 and out.shape == truth.shape
    assert out.min() >= 0 and out.max() <= 1
    assert np.abs(_area(out, small.shape) - small).max() < 0.01
    # closer to the sharp truth than the smooth start, by a clear margin, in PSNR and GMSD
    assert metrics.psnr(truth, out) > metrics.psnr(truth, start) + 2.0
    assert metrics.gmsd(truth, out) < 0.7 * metrics.gmsd(truth, start)


def test_flat_picture_stays_flat_and_zero_steps_only_clip():
    small = np.full((5, 7, 3), 0.4, np.float32)
    big = np.full((20, 28, 3), 0.4, np.float32)
    assert np.allclose(rf.refine_magnified(big, small, 10), 0.4, atol=1e-6)
    wild = np.linspace(-0.5, 1.5, 20 * 28 * 3, dtype=np.float32).reshape(20, 28, 3)
    assert np.array_equal(rf.refine_magnified(wild, small, 0), np.clip(wild, 0, 1))


def test_tv_step_keeps_each_channel_mean_and_lowers_the_variation():
    rng = np.random.default_rng(3)
    x = rng.random((37, 23, 3), dtype=np.float32)
    out = rf._tv_step(x, rf.EPS, rf.STEP)
    assert np.allclose(out.mean((0, 1)), x.mean((0, 1)), atol=1e-6)
    tv = lambda a: np.abs(np.diff(a, axis=0)).sum() + np.abs(np.diff(a, axis=1)).sum()  # noqa: E731
    assert tv(out) < tv(x)


def test_device_step_is_the_reference_step():
    wp = pytest.importorskip("warp")
    from tpsv.gpu import refine as gr

    rng = np.random.default_rng(4)
    x = rng.random((29, 41, 3), dtype=np.float32)
    xd = wp.array(x, dtype=wp.vec3f, device="cpu")
    out = wp.empty_like(xd)
    wp.launch(gr._tv, dim=(29, 41), inputs=[xd, 0, rf.EPS**2, rf.STEP * rf.EPS, out], device="cpu")
    np.testing.assert_allclose(out.numpy(), rf._tv_step(x, rf.EPS, rf.STEP), atol=1e-6)


@pytest.mark.parametrize("big,small", [(96, 24), (100, 37), (301, 100), (13, 13), (7, 3)])
def test_area_taps_are_opencvs_inter_area(big, small):
    from tpsv.gpu.refine import area_taps

    col = np.random.default_rng(big).random((big, 4)).astype(np.float32)
    start, tap, weight = area_taps(big, small)
    mine = np.stack([(weight[start[i]:start[i + 1], None] * col[tap[start[i]:start[i + 1]]]).sum(0)
                     for i in range(small)])
    np.testing.assert_allclose(mine, cv2.resize(col, (4, small), interpolation=cv2.INTER_AREA), atol=1e-6)


def test_refinement_is_the_same_in_bands_of_host_threads(every_band):
    truth = _disc(96)
    small = _area(truth, (32, 32))
    start = np.clip(cv2.resize(small, (96, 96), interpolation=cv2.INTER_CUBIC), 0, 1)
    one = rf.refine_magnified(start, small, 5, threads=1)
    np.testing.assert_array_equal(rf.refine_magnified(start, small, 5, threads=2), one)
    # the host's OpenCV resizes give the same picture to rounding
    x = start.copy()
    for _ in range(5):
        x = rf._tv_step(x, rf.EPS, rf.STEP)
        x += cv2.resize(small - _area(x, small.shape), (96, 96), interpolation=cv2.INTER_CUBIC)
    np.testing.assert_allclose(one, np.clip(x, 0, 1), atol=1e-5)


def test_input_larger_than_the_picture_is_refused():
    with pytest.raises(ValueError, match="larger than the picture"):
        rf.refine_magnified(np.zeros((4, 4, 3)), np.zeros((5, 4, 3)), 1)


def test_magnify_raster_refines_and_reports_progress(small_rgb):
    h, w = small_rgb.shape[:2]
    size = (3 * w, 3 * h)
    calls = []
    model, plain = magnify_raster(small_rgb, size, iterations=2, refine_iterations=0)
    _, sharp = magnify_raster(small_rgb, size, iterations=2, refine_iterations=5,
                              progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (7, 7) and [d for d, _ in calls] == sorted(d for d, _ in calls)
    assert not np.allclose(plain, sharp)
    # both average back to the input; the refinement does not lose that
    for pic in (plain, sharp):
        assert metrics.psnr(small_rgb, _area(pic, (h, w))) > 35
    # same size as the input, or smaller: nothing to sharpen, the model's render is the picture
    _, same = magnify_raster(small_rgb, (w, h), iterations=1, refine_iterations=5,
                             progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (1, 1)
    _, less = magnify_raster(small_rgb, (w // 2, h // 2 + 1), iterations=1)
    assert less.shape == (h // 2 + 1, w // 2, 3)
