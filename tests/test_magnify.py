"""Raster magnification: dense model + back-projection."""

from __future__ import annotations

import cv2
import numpy as np

from tpsv import metrics
from tpsv.render.magnify import back_project, dense_model, magnify_raster
from tpsv.render.raster import render


def test_dense_model_has_a_feature_per_pixel(small_rgb, small_labels):
    model, pixel = dense_model(small_rgb, small_labels)
    h, w = small_rgb.shape[:2]
    assert len(model.features) == h * w
    assert np.array_equal(np.sort(pixel), np.arange(h * w))
    # each feature sits in the region of its own pixel
    regions = np.array([r.label for r in model.regions])
    assert np.array_equal(regions[model.features.region], small_labels.ravel()[pixel])


def test_back_projection_fits_the_input(small_rgb):
    h, w = small_rgb.shape[:2]
    size = (3 * w, 3 * h)
    model, pixel = dense_model(small_rgb)

    def residual(m):
        down = cv2.resize(render(m, width=size[0], height=size[1]), (w, h), interpolation=cv2.INTER_AREA)
        return metrics.mse(small_rgb, down)

    before = residual(model)
    fitted = back_project(model, pixel, small_rgb, size, iterations=4)
    after = residual(fitted)
    assert after < 0.5 * before
    # positions and regions untouched, only colours change
    assert np.array_equal(fitted.features.st, model.features.st)
    assert np.array_equal(fitted.features.region, model.features.region)


def test_magnify_raster_size_and_quality(small_rgb):
    h, w = small_rgb.shape[:2]
    model, big = magnify_raster(small_rgb, (2 * w, 2 * h), iterations=3)
    assert big.shape == (2 * h, 2 * w, 3)
    down = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    assert metrics.psnr(small_rgb, down) > 35
