"""sRGB <-> Lab: the one numpy conversion (``tpsv.color``) and its Jacobian."""

from __future__ import annotations

import numpy as np
from skimage.color import rgb2lab

from tpsv import color


def _rgb_grid(n: int = 17) -> np.ndarray:
    g = np.linspace(0.0, 1.0, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def test_round_trip():
    rgb = _rgb_grid()
    assert np.abs(color.lab_to_srgb(color.srgb_to_lab(rgb)) - rgb).max() < 1e-5


def test_agrees_with_skimage():
    # the same D65 formulas; skimage's constants differ in the last digits (0.005 Lab)
    rgb = _rgb_grid()
    assert np.abs(color.srgb_to_lab(rgb) - rgb2lab(rgb)).max() < 0.01


def test_constants_are_inverse():
    assert np.allclose(color.XYZ2RGB @ color.RGB2XYZ, np.eye(3), atol=1e-12)
    # white is where sRGB (1, 1, 1) lands: L = 100, a = b = 0
    assert np.allclose(color.RGB2XYZ @ np.ones(3), color.WHITE, atol=1e-3)
    assert np.allclose(color.srgb_to_lab(np.ones(3)), [100.0, 0.0, 0.0], atol=0.05)


def test_jacobian_is_zero_where_srgb_clips():
    lab = np.array([[50.0, 0.0, 0.0], [60.0, 120.0, 0.0], [100.0, 0.0, 0.0]])
    J = color.lab_to_srgb_jacobian(lab)
    assert J.shape == (3, 3, 3) and np.abs(J[0]).min() > 0
    raw = color.lab_to_srgb(lab, clip=False)
    clipped = (raw < 0) | (raw > 1)
    assert clipped[1].any()
    assert np.all(J[1][clipped[1]] == 0)
