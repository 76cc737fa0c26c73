"""The synthetic shapes of the edge benchmark: consistent across scales, labels that match."""

from __future__ import annotations

import numpy as np
import pytest

from tpsv.bench import shapes as S


def _down(img: np.ndarray, k: int) -> np.ndarray:
    h, w = img.shape[:2]
    return img.reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


@pytest.mark.parametrize("k", [2, 3, 8])
def test_scale_k_area_downscaled_is_scale_1(k):
    one, _ = S.shapes(48, 1, seed=1)
    big, _ = S.shapes(48, k, seed=1)
    assert big.shape == (48 * k, 48 * k, 3) and big.dtype == np.float32
    assert np.abs(_down(big, k) - one).max() < 1 / 255


def test_deterministic_variants_in_range():
    a, la = S.shapes(40, 1, seed=0)
    b, lb = S.shapes(40, 1, seed=0)
    c, _ = S.shapes(40, 1, seed=1)
    assert np.array_equal(a, b) and np.array_equal(la, lb)
    assert np.abs(a - c).max() > 0.1
    assert a.min() >= 0 and a.max() <= 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_labels_agree_with_shapes(seed):
    size = 96
    sc = S.scene(size, seed)
    rgb, labels = S.shapes(size, 1, seed)
    assert labels.shape == (size, size)
    assert set(np.unique(labels)) == {S.BACKGROUND, S.DISC, S.SQUARE, S.RING}
    yc, xc = np.mgrid[:size, :size] + 0.5
    cx, cy, r = sc.disc
    rad = np.hypot(xc - cx, yc - cy)
    assert np.array_equal(labels == S.DISC, rad < r)
    assert abs((labels == S.DISC).sum() - np.pi * r * r) < 2 * np.pi * r  # area within a perimeter
    cx, cy, ro, ri = sc.ring
    rad = np.hypot(xc - cx, yc - cy)
    assert np.array_equal(labels == S.RING, (rad < ro) & (rad >= ri))
    assert (labels[rad < ri - 1] == S.BACKGROUND).all()  # the hole shows the background
    qx, qy, h, ang = sc.square
    u = (xc - qx) * np.cos(ang) + (yc - qy) * np.sin(ang)
    v = -(xc - qx) * np.sin(ang) + (yc - qy) * np.cos(ang)
    inside = (np.abs(u) < h - 0.01) & (np.abs(v) < h - 0.01)
    outside = (np.abs(u) > h + 0.01) | (np.abs(v) > h + 0.01)
    assert (labels[inside] == S.SQUARE).all() and (labels[outside] != S.SQUARE).all()
    assert abs((labels == S.SQUARE).sum() - 4 * h * h) < 8 * h


def test_interior_pixels_are_the_affine_fill():
    sc = S.scene(64, 0)
    rgb, labels = S.draw(sc, 1)
    yc, xc = np.mgrid[:64, :64] + 0.5
    far = sc.boundary_distance(xc, yc) > 1
    for k, fill in enumerate(sc.fills):
        m = far & (labels == k)
        assert m.any()
        assert np.abs(rgb[m] - fill(xc[m], yc[m])).max() < 1e-6


def test_border_pixels_mix_both_sides():
    sc = S.scene(64, 0)
    rgb, labels = S.draw(sc, 1)
    cx, cy, r = sc.disc
    # a pixel the disc's border crosses through its centre is about half of each
    y = int(cy)
    x = int(np.floor(cx + r))
    inside = sc.fills[S.DISC](np.array([x + 0.5]), np.array([y + 0.5]))[0]
    outside = sc.fills[S.BACKGROUND](np.array([x + 0.5]), np.array([y + 0.5]))[0]
    lo, hi = np.minimum(inside, outside), np.maximum(inside, outside)
    assert ((rgb[y, x] >= lo - 1e-6) & (rgb[y, x] <= hi + 1e-6)).all()
    assert np.abs(rgb[y, x] - inside).max() > 1e-3 and np.abs(rgb[y, x] - outside).max() > 1e-3
