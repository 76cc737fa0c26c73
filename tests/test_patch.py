"""Hermite patches: evaluation, construction (no folds), inverse, LUT."""

import numpy as np
import pytest
from scipy import ndimage as ndi

from tpsv.errors import TpsvError
from tpsv.model import Patch
from tpsv.geometry.outline import trace_outline
from tpsv.geometry.patch import InverseLUT, adini_twist, affine_frame, build_patch, choose_grid, denormalize, fold_free, forward, inverse, jacobian, min_jacobian, normalize


def _grid(n, m=None):
    m = n if m is None else m
    yy, xx = np.mgrid[0:n, 0:m] + 0.5
    return xx, yy


def _shapes():
    out = {}
    xx, yy = _grid(64)
    out["disc"] = np.hypot(xx - 32.2, yy - 31.7) <= 20.3
    d = np.hypot(xx - 32, yy - 32)
    out["ring"] = (d <= 22) & (d >= 10)
    out["cshape"] = (d <= 24) & (d >= 12) & ~((xx > 32) & (np.abs(yy - 32) < 6))
    xx, yy = _grid(96)
    x, y = xx - 48, yy - 48
    r, th = np.hypot(x, y), np.arctan2(y, x)
    m = np.zeros((96, 96), bool)
    for k in range(6):
        rr = 6 / (2 * np.pi) * (th + np.pi + 2 * np.pi * k)
        m |= (np.abs(r - rr) < 1.6) & (rr > 3) & (rr < 46)
    lab, _ = ndi.label(m)
    out["spiral"] = lab == np.argmax(np.bincount(lab.ravel())[1:]) + 1
    m = np.zeros((9, 9), bool)
    m[4, 5] = True
    out["single"] = m
    m = np.zeros((20, 20), bool)
    m[7, 3:15] = True
    out["hline"] = m
    m = np.zeros((20, 20), bool)
    m[2:18, 6] = True
    out["vline"] = m
    m = np.zeros((30, 30), bool)
    np.fill_diagonal(m, True)
    m[1:, :-1] |= np.eye(29, dtype=bool)  # 4-connected diagonal staircase, 2 px
    out["diagonal"] = m
    m = np.zeros((40, 40), bool)
    m[:15, :25] = True
    m[:30, :8] = True
    out["border"] = m
    return out


SHAPES = _shapes()


def _hermite_ref(ctrl, s, t):
    """Direct textbook evaluation, one point at a time (with extrapolation)."""
    M, N = ctrl.shape[:2]
    i = min(max(int(np.floor(s)), 0), M - 2)
    j = min(max(int(np.floor(t)), 0), N - 2)
    u, v = s - i, t - j

    def H(w):
        return np.array([2 * w**3 - 3 * w**2 + 1, -2 * w**3 + 3 * w**2, w**3 - 2 * w**2 + w, w**3 - w**2])

    c = ctrl
    G = np.array(
        [
            [c[i, j, 0], c[i, j + 1, 0], c[i, j, 2], c[i, j + 1, 2]],
            [c[i + 1, j, 0], c[i + 1, j + 1, 0], c[i + 1, j, 2], c[i + 1, j + 1, 2]],
            [c[i, j, 1], c[i, j + 1, 1], c[i, j, 3], c[i, j + 1, 3]],
            [c[i + 1, j, 1], c[i + 1, j + 1, 1], c[i + 1, j, 3], c[i + 1, j + 1, 3]],
        ]
    )
    return np.einsum("a,abk,b->k", H(u), G, H(v))


def _random_patch(rng, M=4, N=3):
    ii, jj = np.meshgrid(np.arange(M), np.arange(N), indexing="ij")
    ctrl = np.zeros((M, N, 4, 2))
    ctrl[..., 0, :] = np.stack([10 * ii, 8 * jj], -1) + rng.normal(0, 1.0, (M, N, 2))
    ctrl[..., 1, :] = [10, 0]
    ctrl[..., 2, :] = [0, 8]
    ctrl[..., 1:3, :] += rng.normal(0, 0.5, (M, N, 2, 2))
    ctrl[..., 3, :] = adini_twist(ctrl)
    return Patch(ctrl=ctrl)


def test_forward_matches_textbook_hermite():
    rng = np.random.default_rng(1)
    p = _random_patch(rng)
    s = rng.uniform(-0.5, 3.5, 50)
    t = rng.uniform(-0.5, 2.5, 50)
    got = forward(p, s, t)
    ref = np.array([_hermite_ref(p.ctrl, a, b) for a, b in zip(s, t)])
    assert np.abs(got - ref).max() < 1e-10
    # interpolates control positions and derivatives
    assert np.allclose(forward(p, 2.0, 1.0), p.ctrl[2, 1, 0])
    J = jacobian(p, 1.0, 2.0)
    assert np.allclose(J[:, 0], p.ctrl[1, 2, 1]) and np.allclose(J[:, 1], p.ctrl[1, 2, 2])


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    p = _random_patch(rng)
    s = rng.uniform(0.1, 2.9, 20)
    t = rng.uniform(0.1, 1.9, 20)
    h = 1e-6
    J = jacobian(p, s, t)
    ds = (forward(p, s + h, t) - forward(p, s - h, t)) / (2 * h)
    dt = (forward(p, s, t + h) - forward(p, s, t - h)) / (2 * h)
    assert np.abs(J[..., 0] - ds).max() < 1e-5
    assert np.abs(J[..., 1] - dt).max() < 1e-5


def test_adini_reproduces_bilinear_twist():
    M, N = 4, 5
    ii, jj = np.meshgrid(np.arange(M, dtype=float), np.arange(N, dtype=float), indexing="ij")
    ctrl = np.zeros((M, N, 4, 2))
    # x = 3 s t + s, y = 2 t: derivatives exact, twist (3, 0)
    ctrl[..., 0, 0] = 3 * ii * jj + ii
    ctrl[..., 0, 1] = 2 * jj
    ctrl[..., 1, 0] = 3 * jj + 1
    ctrl[..., 2, 0] = 3 * ii
    ctrl[..., 2, 1] = 2
    tw = adini_twist(ctrl)
    assert np.allclose(tw[..., 0], 3) and np.allclose(tw[..., 1], 0)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_build_patch_covers_region_without_folds(name):
    m = SHAPES[name]
    polys = trace_outline(m)
    p = build_patch(m, polys)
    M, N = p.shape
    assert M >= 2 and N >= 2
    assert fold_free(p) and min_jacobian(p) > 0
    # s along the longer side, positive orientation
    a, b = p.ctrl[0, 0, 1], p.ctrl[0, 0, 2]
    assert np.linalg.norm(a) * (M - 1) >= np.linalg.norm(b) * (N - 1) - 1e-9
    assert a[0] * b[1] - a[1] * b[0] > 0
    assert np.abs(p.ctrl[..., 3, :]).max() < 1e-9  # Adini twist vanishes on the affine grid
    rr, cc = np.nonzero(m)
    xy = np.stack([cc + 0.5, rr + 0.5], 1)
    for method in ("auto", "search"):
        st = inverse(p, xy, method=method)
        err = np.hypot(*(forward(p, st[:, 0], st[:, 1]) - xy).T)
        assert err.max() < 1e-6  # goal 1e-3, required 0.05; measured < 1e-10
        # inside the domain: every pixel gets exactly one (s, t) on the surface
        assert (st >= 0).all() and (st[:, 0] <= M - 1).all() and (st[:, 1] <= N - 1).all()
        assert len(np.unique(np.round(st, 9), axis=0)) == len(xy)
    # also the outline vertices and every corner of every pixel square lie inside the domain (the
    # builder checks only the corners of the squares' convex hull: the domain is convex)
    corners = np.concatenate([np.stack([cc + dx, rr + dy], 1) for dx in (0, 1) for dy in (0, 1)]).astype(float)
    st = inverse(p, np.concatenate(polys + [corners]))
    assert (st >= -1e-9).all() and (st[:, 0] <= M - 1 + 1e-9).all() and (st[:, 1] <= N - 1 + 1e-9).all()


def test_inverse_of_forward_random_params():
    m = SHAPES["cshape"]
    p = build_patch(m, grid=(5, 4))
    rng = np.random.default_rng(3)
    s = rng.uniform(0, 4, 500)
    t = rng.uniform(0, 3, 500)
    for method in ("auto", "search"):
        st = inverse(p, forward(p, s, t), method=method)
        assert np.abs(st - np.stack([s, t], 1)).max() < 1e-6


def _bent(seed=0):
    m = SHAPES["disc"]
    p = build_patch(m, grid=(5, 5))
    rng = np.random.default_rng(seed)
    ctrl = p.ctrl.copy()
    ctrl[2, 2, 0] += [4.0, -3.0]
    ctrl[1, 3, 0] += rng.normal(0, 2, 2)
    ctrl[3, 1, 1] *= 1.2
    ctrl[..., 3, :] = adini_twist(ctrl)
    return m, Patch(ctrl=ctrl)


def test_bent_patch_inverts():
    m, p = _bent()
    assert affine_frame(p) is None
    assert fold_free(p)
    rng = np.random.default_rng(4)
    s = rng.uniform(0, 4, 2000)
    t = rng.uniform(0, 4, 2000)
    st = inverse(p, forward(p, s, t))
    assert np.abs(st - np.stack([s, t], 1)).max() < 1e-6
    # every pixel of the region
    rr, cc = np.nonzero(m)
    xy = np.stack([cc + 0.5, rr + 0.5], 1)
    st = inverse(p, xy)
    assert np.hypot(*(forward(p, st[:, 0], st[:, 1]) - xy).T).max() < 1e-6
    # the binary search alone lands close (8 levels, 1/256 cell) except where the
    # straight control-point quads put a point in the wrong cell (Newton fixes
    # those): measured median 0.018 px, 99th percentile 0.10 px
    st0 = inverse(p, xy, newton=0)
    e0 = np.hypot(*(forward(p, st0[:, 0], st0[:, 1]) - xy).T)
    assert np.median(e0) < 0.05 and np.percentile(e0, 95) < 0.5


def test_points_outside_surface_extrapolate():
    m, p = _bent()
    xy = np.array([[-3.0, -4.0], [70.0, 30.0], [30.0, 75.0]])
    st = inverse(p, xy)
    assert np.hypot(*(forward(p, st[:, 0], st[:, 1]) - xy).T).max() < 1e-6
    ST = normalize(p, st)
    assert (ST >= 0).all() and (ST <= 1).all()


def test_folded_patch_detected():
    p = build_patch(SHAPES["disc"], grid=(4, 4))
    ctrl = p.ctrl.copy()
    ctrl[1, 1, 0] += 3 * ctrl[0, 0, 1]  # push a control point past its neighbour
    assert not fold_free(Patch(ctrl=ctrl))


def test_lut_matches_inverse():
    m, p = _bent(1)
    lut = InverseLUT(p, step=2.0)
    rr, cc = np.nonzero(m)
    xy = np.stack([cc + 0.5, rr + 0.5], 1)
    st = lut(xy)
    assert np.hypot(*(forward(p, st[:, 0], st[:, 1]) - xy).T).max() < 1e-6
    assert np.abs(st - inverse(p, xy)).max() < 1e-6


def test_normalize_roundtrip():
    p = build_patch(SHAPES["ring"], grid=(5, 3))
    st = np.array([[0.0, 0.0], [4.0, 2.0], [2.5, 1.2], [-1, 3]])
    ST = normalize(p, st)
    assert np.allclose(ST[:3], [[0, 0], [1, 1], [2.5 / 4, 0.6]])
    assert np.allclose(ST[3], [0, 1])
    assert np.allclose(denormalize(p, ST[:3]), st[:3])


def test_choose_grid_bounds():
    assert choose_grid(1, 3, 3) == (2, 2)
    M, N = choose_grid(512 * 512, 514, 514)
    assert 8 <= M <= 16 and M == N
    assert choose_grid(1e8, 1e5, 1e5) == (32, 32)
    M2, N2 = choose_grid(512 * 512, 514, 514, n_features=200000)
    assert M2 > M
    with pytest.raises(TpsvError):
        build_patch(SHAPES["disc"], grid=(1, 3))


def test_preview_draws_grids_outlines_features():
    from tpsv.model import CURVILINEAR, GRADATION, Features, Model, Region
    from tpsv.rendering.preview import draw_preview

    m = SHAPES["cshape"]
    out = trace_outline(m)
    reg = [Region(label=0, outline=out, patch=build_patch(m, out)), Region(label=1, outline=trace_outline(~m), patch=build_patch(~m))]
    f = Features(
        region=np.array([0, 0, 1], np.int32),
        st=np.array([[0.5, 0.5], [0.52, 0.5], [0.2, 0.8]]),
        lab=np.zeros((3, 3), np.float32),
        kind=np.array([CURVILINEAR, CURVILINEAR, GRADATION], np.uint8),
        pair=np.array([1, 0, -1], np.int32),
    )
    model = Model(width=64, height=64, regions=reg, features=f)
    rgb = np.full((64, 64, 3), 0.5, np.float32)
    img = draw_preview(rgb, model, scale=2)
    assert img.shape == (128, 128, 3) and img.dtype == np.uint8
    plain = draw_preview(rgb, model, scale=2, features=False, grid=False)
    assert (img != plain).any()
    # the gradation feature's dot is green
    p = forward(reg[1].patch, *denormalize(reg[1].patch, f.st[2]))
    c = img[int(round(p[1] * 2)), int(round(p[0] * 2))]
    assert c[1] > 150 and c[0] < 100


def test_new_patch_survives_codec_quantisation_exactly():
    """A fresh patch lies on the codec's 1/16 px grid, so a decoded one is still affine."""
    from tpsv.codec.quant import CTRL_SCALE
    from tpsv.geometry.patch import GRID_QUANTUM, affine_frame, build_patch

    assert CTRL_SCALE == GRID_QUANTUM
    yy, xx = np.mgrid[:60, :80]
    mask = (xx - 37.3) ** 2 / 900 + (yy - 29.1) ** 2 / 300 < 1 + 0.3 * np.sin(xx / 5.0)
    p = build_patch(mask)
    q = np.round(p.ctrl * CTRL_SCALE) / CTRL_SCALE
    assert np.array_equal(q, p.ctrl)
    assert affine_frame(p) is not None


def test_patch_pixel_scale_is_the_control_polygon_size():
    from conftest import rect_patch

    from tpsv.geometry.patch import MIN_SCALE_PX, patch_pixel_scale

    assert patch_pixel_scale(rect_patch(3, 4, 40, 30)) == pytest.approx((40.0, 30.0))
    assert patch_pixel_scale(rect_patch(3, 4, 40, 30, M=5, N=2)) == pytest.approx((40.0, 30.0))
    flat = rect_patch(0, 0, 10, 0)
    assert patch_pixel_scale(flat) == pytest.approx((10.0, MIN_SCALE_PX))


def test_min_jacobian_matches_pointwise_sampling():
    """The per-cell tensor evaluation equals sampling ``jacobian`` on both sides of every cell border."""
    from tpsv.geometry import patch as hp
    from tpsv.model import Patch

    rng = np.random.default_rng(0)
    for _ in range(20):
        M, N = rng.integers(2, 8, 2)
        ii, jj = np.meshgrid(np.arange(M), np.arange(N), indexing="ij")
        ctrl = np.zeros((M, N, 4, 2))
        ctrl[..., 0, 0] = ii * 10 + rng.normal(0, 3, (M, N))
        ctrl[..., 0, 1] = jj * 10 + rng.normal(0, 3, (M, N))
        ctrl[..., 1, :] = np.array([10.0, 0.0]) + rng.normal(0, 3, (M, N, 2))
        ctrl[..., 2, :] = np.array([0.0, 10.0]) + rng.normal(0, 3, (M, N, 2))
        p = Patch(ctrl=ctrl)
        s = np.linspace(0, M - 1, 8 * (M - 1) + 1)
        t = np.linspace(0, N - 1, 8 * (N - 1) + 1)
        S, T = np.meshgrid(s, t, indexing="ij")
        low = min(hp._det(hp.jacobian(p, S, T)).min(),
                  hp._det(hp.jacobian(p, np.clip(S - 1e-9, 0, M - 1), np.clip(T - 1e-9, 0, N - 1))).min())
        assert hp.min_jacobian(p) == pytest.approx(low, rel=1e-6, abs=1e-9)


def test_coefficients_reproduce_the_hermite_patch_at_cell_corners():
    """The power-basis coefficients (matrix products B G B^T) give the control points and derivatives
    back at every cell corner, for a non-affine patch."""
    from tpsv.geometry.patch import coefficients

    rng = np.random.default_rng(2)
    ctrl = rng.normal(size=(4, 3, 4, 2)) * 7.0
    K = coefficients(Patch(ctrl))
    assert K.shape == (3, 2, 4, 4, 2)
    for i in range(3):
        for j in range(2):
            for du, dv, ci, cj in ((0, 0, i, j), (1, 0, i + 1, j), (0, 1, i, j + 1), (1, 1, i + 1, j + 1)):
                u, v = float(du), float(dv)
                pu, pv = u ** np.arange(4), v ** np.arange(4)
                value = np.einsum("p,pqk,q->k", pu, K[i, j], pv)
                d_u = np.einsum("p,pqk,q->k", np.arange(4) * np.r_[0, pu[:3]], K[i, j], pv)
                d_v = np.einsum("p,pqk,q->k", pu, K[i, j], np.arange(4) * np.r_[0, pv[:3]])
                assert np.allclose(value, ctrl[ci, cj, 0]) and np.allclose(d_u, ctrl[ci, cj, 1])
                assert np.allclose(d_v, ctrl[ci, cj, 2])
