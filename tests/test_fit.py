"""Least-squares colour fit (tpsv.encode.fit)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tpsv import codec, metrics
from tpsv.encode import fit
from tpsv import tps
from tpsv.color import lab_to_srgb, srgb_to_lab
from tpsv.encode.features import FeatureExtractor
from tpsv.rendering.raster import render
from tpsv.encode.vectorize import build_geometry, make_model, scheme_params


def scene(h=40, w=56, seed=0):
    """A smooth gradient with a sharp bright disc, two regions (left / right)."""
    rng = np.random.default_rng(seed)
    yy, xx = (np.mgrid[0:h, 0:w] + 0.5) / max(h, w)
    rgb = np.stack([0.2 + 0.6 * xx, 0.3 + 0.4 * np.sin(4 * yy), 0.5 + 0.3 * xx * yy], -1)
    disc = (xx - 0.3) ** 2 + (yy - 0.35) ** 2 < 0.12**2
    rgb[disc] = [0.95, 0.85, 0.2]
    rgb += 0.01 * rng.standard_normal(rgb.shape)
    labels = np.zeros((h, w), np.int32)
    labels[:, int(w * 0.6):] = 1
    return np.clip(rgb, 0, 1).astype(np.float32), labels


@pytest.fixture(scope="module")
def setup():
    rgb, labels = scene()
    g = build_geometry(labels)
    ex = FeatureExtractor(rgb, g.index)
    p = replace(scheme_params(), t_canny=60.0, t_super=25.0)
    m = codec.quantize(make_model(rgb, g, ex, p, fit=False))
    return rgb, labels, g, m


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    lab = np.column_stack([rng.uniform(10, 90, 300), rng.uniform(-30, 30, 300), rng.uniform(-30, 30, 300)])
    inner = np.all((lab_to_srgb(lab, clip=False) > 0.02) & (lab_to_srgb(lab, clip=False) < 0.98), axis=1)
    J = fit.lab_to_srgb_jacobian(lab)
    eps = 1e-3
    num = np.stack([(lab_to_srgb(lab + eps * np.eye(3)[c]).astype(np.float64)
                     - lab_to_srgb(lab - eps * np.eye(3)[c]).astype(np.float64)) / (2 * eps) for c in range(3)], -1)
    assert np.abs(J - num)[inner].max() < 2e-3


def test_design_is_the_render_and_its_adjoint(setup):
    rgb, _, g, m = setup
    ks = tps.group_kernels(m)
    t = g.fit_target(rgb, 1)
    des, nnz = fit.build_design(ks, t.region, t.st)
    assert nnz > 0
    # forward = the device render in Lab without the range clamp
    from tpsv.gpu import tps as gtps

    lab_img = gtps.render_arrays(ks, g.index, g.pixel_st(), mode=gtps.MODE_LAB, clamp=False)
    ref = lab_img.reshape(-1, 3)[t.rows]
    got = des.forward(m.features.lab.astype(np.float64))
    assert np.abs(got - ref).max() < 2e-2
    # <A x, y> == <x, A^T y>
    rng = np.random.default_rng(2)
    x = rng.standard_normal((len(m.features), 3))
    y = rng.standard_normal((des.n_pix, 3))
    lhs = float((des.forward(x) * y).sum())
    rhs = float((x * des.adjoint(y)).sum())
    assert lhs == pytest.approx(rhs, rel=1e-4)


def test_fit_reduces_error_against_sampled_colours(setup):
    rgb, _, g, m = setup
    # the paper scheme's colours are sampled from the image
    ex = FeatureExtractor(rgb, g.index)
    plain = codec.quantize(make_model(rgb, g, ex, replace(scheme_params("paper"), t_canny=200.0, t_super=40.0)))
    sampled = metrics.mse(rgb, render(plain))
    refit, rep = fit.fit_colors(plain, rgb)
    assert metrics.mse(rgb, render(codec.quantize(refit))) < 0.5 * sampled
    assert rep.iterations >= 1 and rep.residual < rep.residual0
    # the default scheme starts from cell means, already closer; the fit still gains
    before = metrics.mse(rgb, render(m))
    fitted, rep = fit.fit_colors(m, rgb)
    after = metrics.mse(rgb, render(codec.quantize(fitted)))
    assert after < 0.95 * before
    # positions, kinds, pairs untouched; colours inside the stored ranges
    assert np.array_equal(fitted.features.st, m.features.st)
    assert np.array_equal(fitted.features.pair, m.features.pair)
    assert fitted.features.lab.dtype == np.float32
    assert fitted.features.lab[:, 0].min() >= 0 and fitted.features.lab[:, 0].max() <= 100
    # a target on a pixel lattice and kernels from the caller
    sub, rep = fit.fit_colors(m, target=g.fit_target(rgb, 2), kernels=tps.group_kernels(m))
    assert rep.subsample == 2 and rep.residual < rep.residual0


def test_fit_respects_region_separation(setup):
    rgb, labels, g, m = setup
    other = rgb.copy()
    other[labels == 1] = 1.0 - other[labels == 1]  # change region 1 only
    a, _ = fit.fit_colors(m, rgb, iterations=6)
    b, _ = fit.fit_colors(m, other, iterations=6)
    r0 = m.features.region == 0
    assert np.array_equal(a.features.lab[r0], b.features.lab[r0])
    assert not np.allclose(a.features.lab[~r0], b.features.lab[~r0])


def test_recolor_kernels_equals_grouping(setup):
    rgb, _, g, m = setup
    fitted, rep = fit.fit_colors(m, rgb, iterations=3)
    dec = codec.quantize(fitted)
    a = tps.group_kernels(dec)
    b = tps.recolor(rep.kernels, dec.features)
    for name in ("lab", "index", "st", "fill", "frame", "grid"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


def test_empty_model_is_returned_as_is(setup):
    rgb, _, _, m = setup
    empty = replace(m, features=m.features.subset(np.zeros(len(m.features), bool)))
    out, rep = fit.fit_colors(empty, rgb)
    assert out is empty and rep.iterations == 0


def test_fit_target_lab_matches_image():
    rgb, labels = scene(12, 16)
    g = build_geometry(labels)
    t = fit.fit_target(rgb, g.index, g.pixel_st(), 1)
    assert t.rows.size == 12 * 16
    assert np.allclose(t.lab, srgb_to_lab(rgb).reshape(-1, 3), atol=1e-4)
    assert np.all(np.linalg.eigvalsh(t.W) >= -1e-12)


def test_a_grey_picture_is_fitted_grey():
    """The sRGB metric's cross terms let a and b absorb part of the L error: a grey photo came back
    tinted (before the rule, this crop of scikit-image's coins fitted a, b up to 8 without its texture,
    and the pattern below up to 4 with automatic regions). Features fitted to neutral pixels alone are
    grey, and so is the render; a coloured picture keeps its chroma."""
    from skimage.data import coins

    from tpsv.encode.rate import encode_quality

    crop = coins()[100:164, 150:214] / 255.0
    rgb = np.repeat(crop[..., None], 3, axis=2).astype(np.float32)
    labels = (np.mgrid[0:64, 0:64][1] >= 32).astype(np.int32)
    model = encode_quality(rgb, labels, detail=False).model
    assert np.abs(model.features.lab[:, 1:]).max() == 0.0
    shown = render(model)
    assert (shown.max(axis=2) - shown.min(axis=2)).max() < 1e-5
    y, x = np.mgrid[0:48, 0:64]
    pattern = np.repeat((0.5 + 0.3 * np.sin(x / 3.0) * np.cos(y / 5.0))[..., None], 3, axis=2).astype(np.float32)
    assert np.abs(encode_quality(pattern, None).model.features.lab[:, 1:]).max() == 0.0
    tinted = rgb * np.array([1.0, 0.9, 0.8], np.float32)
    assert np.abs(encode_quality(tinted, labels, detail=False).model.features.lab[:, 1:]).max() > 1.0
