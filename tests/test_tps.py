"""TPS: numpy reference, grouping/packing, device build + solve, blending weights."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from tpsv import codec, tps
from tpsv.tps import blend
from tpsv.errors import TpsvError
from tpsv.gpu import tps as gtps
from tpsv.model import Features, Model, Params, Region

from conftest import rect_patch


def rect_model(rects, feats, width, height, **params) -> Model:
    """Regions = rectangles (x0, y0, w, h); feats = list of (region, st (n, 2), values (n, 3))."""
    regions = []
    for i, (x0, y0, w, h) in enumerate(rects):
        poly = np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]], float)
        regions.append(Region(i, [poly], rect_patch(x0, y0, w, h)))
    reg = np.concatenate([np.full(len(s), r, np.int32) for r, s, _ in feats]) if feats else np.zeros(0, np.int32)
    st = np.concatenate([s for _, s, _ in feats]) if feats else np.zeros((0, 2))
    lab = np.concatenate([v for _, _, v in feats]).astype(np.float32) if feats else np.zeros((0, 3), np.float32)
    n = len(reg)
    F = Features(reg, st.astype(np.float64), lab, np.zeros(n, np.uint8), np.full(n, -1, np.int32))
    # the kernel size and overlap these tests were written for (the paper's), whatever Params() defaults to
    return Model(width, height, regions, F, Params(**{"kernel_size": 64, "overlap": 0.5, **params}))


def one_region(st, values, w=40.0, h=30.0, **params) -> Model:
    return rect_model([(0.0, 0.0, w, h)], [(0, np.asarray(st), np.asarray(values))], int(w), int(h), **params)


def local_eval(ks, pts, w, b, k, st):
    """float64 evaluation of kernel k's device coefficients at st (n, 2)."""
    loc = ks.local(k, st)
    m = int(ks.count[k])
    r2 = ((loc[:, None, :] - pts[k, None, :m]) ** 2).sum(-1)
    return tps.tps_phi(r2) @ w[k, :m] + b[k, 0] + loc[:, :1] * b[k, 1] + loc[:, 1:] * b[k, 2]


# --------------------------------------------------------------------------- numpy reference


def test_reference_matches_scipy():
    rng = np.random.default_rng(1)
    p = rng.random((40, 2)) * [40, 30]
    v = rng.random((40, 3))
    q = rng.random((500, 2)) * [40, 30]
    for lam in (0.0, 0.5):
        ref = RBFInterpolator(p, v, kernel="thin_plate_spline", smoothing=lam)(q)
        out = tps.tps_eval(tps.tps_fit(p, v, smoothing=lam), p, q)
        assert np.abs(out - ref).max() < 1e-9
    coef = tps.tps_fit(p, v)
    assert np.abs(tps.tps_eval(coef, p, p) - v).max() < 1e-9
    assert np.abs(coef[:40].sum(0)).max() < 1e-8  # side conditions
    assert np.abs(coef[:40].T @ p).max() < 1e-6


def test_reference_rejects_bad_input():
    with pytest.raises(ValueError):
        tps.tps_fit(np.zeros((2, 2)), np.zeros((2, 1)))
    with pytest.raises(ValueError):
        tps.tps_fit(np.zeros((5, 3)), np.zeros((5, 1)))


# --------------------------------------------------------------------------- device solve


@pytest.fixture(scope="module")
def random_kernel():
    rng = np.random.default_rng(0)
    n = 50
    st = rng.random((n, 2))
    val = rng.random((n, 3)).astype(np.float32).astype(np.float64)  # the model stores float32 Lab
    m = one_region(st, val, kernel_size=64)
    ks = tps.group_kernels(m)
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    return st, val, ks, dk


def test_one_kernel_matches_rbf(random_kernel):
    st, val, ks, dk = random_kernel
    assert ks.n_kernels == 1 and ks.count[0] == len(st)
    pts, w, b, status = gtps.coefficients(dk)
    assert status[0] == 0
    rng = np.random.default_rng(5)
    q = rng.random((2000, 2)).astype(np.float32).astype(np.float64)  # the device gets float32 (S, T)
    ref = RBFInterpolator(st * [40, 30], val, kernel="thin_plate_spline", smoothing=0)(q * [40, 30])
    # the same points as the kernel sees them (local frame, float32-rounded): float64 agreement
    m = ks.count[0]
    ref_local = RBFInterpolator(pts[0, :m], val[ks.index[0, :m]], kernel="thin_plate_spline", smoothing=0)(ks.local(0, q))
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref_local).max() < 1e-9
    # against the exact positions, float64 coefficients and the device's float32 evaluation
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref).max() < 1e-4
    assert np.abs(gtps.eval_points(dk, 0, q) - ref).max() < 1e-4
    assert np.abs(gtps.eval_points(dk, 0, q, kernel=0) - ref).max() < 1e-4


def test_exact_at_features(random_kernel):
    st, val, ks, dk = random_kernel
    pts, w, b, _ = gtps.coefficients(dk)
    # exact at the float32-rounded local positions the kernel was solved for
    m = ks.count[0]
    order = ks.index[0, :m]
    loc = pts[0, :m]
    phi = tps.tps_phi(((loc[:, None] - loc[None]) ** 2).sum(-1))
    fit = phi @ w[0, :m] + b[0, 0] + loc[:, :1] * b[0, 1] + loc[:, 1:] * b[0, 2]
    assert np.abs(fit - val[order]).max() < 1e-9
    assert np.abs(local_eval(ks, pts, w, b, 0, st) - val).max() < 1e-4
    assert np.abs(gtps.eval_points(dk, 0, st) - val).max() < 1e-4


def test_side_conditions(random_kernel):
    st, val, ks, dk = random_kernel
    pts, w, b, _ = gtps.coefficients(dk)
    m = ks.count[0]
    assert np.abs(w[0, :m].sum(0)).max() < 1e-6
    assert np.abs(w[0, :m].T @ pts[0, :m]).max() < 1e-6


@pytest.mark.parametrize("K", [16, 64])
def test_smoothing_matches_rbf(K):
    rng = np.random.default_rng(2)
    st = rng.random((K, 2))
    val = (rng.random((K, 3)) * 50).astype(np.float32).astype(np.float64)
    m = one_region(st, val, kernel_size=K, smoothing=0.3)
    ks = tps.group_kernels(m)
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    pts, w, b, status = gtps.coefficients(dk)
    assert status[0] == 0
    q = rng.random((300, 2))
    ref = RBFInterpolator(st * [40, 30], val, kernel="thin_plate_spline", smoothing=0.3)(q * [40, 30])
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref).max() < 1e-4
    # smoothing is in pixel units: in the local frame it is scaled by c^2 (c = local / pixel)
    c = ks.frame[0, 2] / ks.scale[0, 0]
    ref_local = RBFInterpolator(pts[0, :K], val[ks.index[0]], kernel="thin_plate_spline", smoothing=0.3 * c * c)(ks.local(0, q))
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref_local).max() < 1e-9


def test_close_pairs_are_stable():
    """Curvilinear-like pairs 0.3 px apart across an edge, sharp colour step."""
    rng = np.random.default_rng(3)
    t = rng.random(30)
    left = np.column_stack([np.full(30, 0.5 - 0.15 / 40), t])
    right = np.column_stack([np.full(30, 0.5 + 0.15 / 40), t])
    st = np.vstack([left, right, rng.random((4, 2))])
    val = np.vstack([np.tile([20.0, 0, 0], (30, 1)), np.tile([80.0, 10, -10], (30, 1)), rng.random((4, 3)) * 50])
    val = val.astype(np.float32).astype(np.float64)
    m = one_region(st, val)
    ks = tps.group_kernels(m)
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    pts, w, b, status = gtps.coefficients(dk)
    assert status[0] == 0
    q = rng.random((300, 2))
    m = ks.count[0]
    ref = RBFInterpolator(pts[0, :m], val[ks.index[0, :m]], kernel="thin_plate_spline")(ks.local(0, q))
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref).max() < 1e-8 * np.abs(ref).max()
    ref_px = RBFInterpolator(st * [40, 30], val, kernel="thin_plate_spline")(q * [40, 30])
    assert np.abs(local_eval(ks, pts, w, b, 0, q) - ref_px).max() < 1e-4 * np.abs(ref).max()
    assert np.abs(local_eval(ks, pts, w, b, 0, st) - val).max() < 1e-3


def test_degenerate_kernels():
    # one feature: constant
    m = one_region([[0.3, 0.4]], [[40.0, 5.0, -5.0]])
    ks = tps.group_kernels(m)
    assert ks.degenerate.all()
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    q = np.random.default_rng(0).random((50, 2))
    assert np.allclose(gtps.eval_points(dk, 0, q), [40.0, 5.0, -5.0], atol=1e-4)
    assert gtps.coefficients(dk)[3][0] == 1
    # two features: linear along the segment, exact at both
    st = np.array([[0.2, 0.2], [0.8, 0.6]])
    val = np.array([[10.0, 0, 0], [70.0, 20, -20]])
    dk = gtps.solve(gtps.upload(tps.group_kernels(one_region(st, val)), "cpu"))
    assert np.abs(gtps.eval_points(dk, 0, st) - val).max() < 1e-3
    mid = gtps.eval_points(dk, 0, [[0.5, 0.4]])
    assert np.abs(mid - val.mean(0)).max() < 1e-3
    # collinear features: least squares along the line, finite everywhere
    t = np.linspace(0.1, 0.9, 7)
    st = np.column_stack([t, 0.5 + 0 * t])
    val = np.column_stack([100 * t, 0 * t, 0 * t])
    ks = tps.group_kernels(one_region(st, val))
    assert ks.degenerate.all()
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    out = gtps.eval_points(dk, 0, q)
    assert np.isfinite(out).all()
    assert np.abs(gtps.eval_points(dk, 0, st) - val).max() < 1e-3


def test_duplicates_are_merged():
    rng = np.random.default_rng(4)
    st = rng.random((20, 2))
    st = np.vstack([st, st[:3]])
    val = rng.random((23, 3)) * 50
    ks = tps.group_kernels(one_region(st, val))
    assert ks.count[0] == 20
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    assert gtps.coefficients(dk)[3][0] == 0
    out = gtps.eval_points(dk, 0, st[:3])
    assert np.abs(out - (val[:3] + val[20:]) / 2).max() < 1e-3


def test_duplicate_groups_pinned():
    """One merge of coincident features serves grouping, recolouring and the fit's spread, bit for bit."""
    rng = np.random.default_rng(5)
    st0 = rng.random((12, 2))
    # region 0: features 12 and 13 repeat 2, feature 14 repeats 5; region 1 holds 2's position too (not merged)
    st = np.vstack([st0, st0[[2, 2, 5]], st0[[2]], rng.random((6, 2))])
    reg = np.array([0] * 15 + [1] * 7)
    val = (rng.random((22, 3)) * 60).astype(np.float32)
    m = rect_model([(0, 0, 20, 16), (20, 0, 20, 16)], [(r, st[reg == r], val[reg == r]) for r in (0, 1)], 40, 16)
    dup = tps.Duplicates.of_features(m.features)
    assert np.array_equal(np.flatnonzero(~dup.keep), [12, 13, 14])
    merged = dup.merge_lab(m.features.lab)
    want = val.copy()
    want[2] = (val[[2, 12, 13]].astype(np.float64).sum(0) / 3).astype(np.float32)
    want[5] = (val[[5, 14]].astype(np.float64).sum(0) / 2).astype(np.float32)
    assert np.array_equal(merged, want)
    assert np.array_equal(dup.fill(merged), want[dup.keep].astype(np.float64).mean(0))
    spread = dup.spread(merged)
    assert np.array_equal(spread[[12, 13, 14]], merged[[2, 2, 5]]) and np.array_equal(spread[:12], merged[:12])
    # the grouping uses exactly these groups: representatives only, with the merged colours
    ks = tps.group_kernels(m)
    assert np.array_equal(ks.lab, merged) and not np.isin([12, 13, 14], ks.index).any()
    assert np.array_equal(ks.fill[0], dup.fill(merged).astype(np.float32))
    # recolouring a kernel set equals grouping the recoloured model
    new = replace(m, features=replace(m.features, lab=(val[::-1] + 1.0).astype(np.float32)))
    a, b = tps.recolor(ks, new.features), tps.group_kernels(new)
    for name in ("lab", "fill", "index", "frame"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    # no duplicates: nothing to merge or spread
    single = tps.Duplicates.of_features(replace(m.features, st=st + np.arange(22)[:, None] * 1e-3))
    assert single.keep.all() and np.array_equal(single.spread(val), val)


# --------------------------------------------------------------------------- grouping


def smooth_lab(xy, rng, noise=1.0):
    """A smooth Lab field at pixel positions (n, 2), plus a little noise."""
    x, y = xy[:, 0], xy[:, 1]
    lab = np.column_stack([50 + 30 * np.sin(x / 17.0) * np.cos(y / 23.0), 20 * np.cos((x + y) / 19.0), 15 * np.sin(y / 13.0)])
    return lab + noise * rng.standard_normal(lab.shape)


@pytest.fixture(scope="module")
def grouped():
    rng = np.random.default_rng(7)
    st0 = rng.random((3000, 2))
    feats = [(0, st0, smooth_lab(st0 * [120, 80], rng))]
    # a line of curvilinear-like pairs across an edge in region 1 (one pair per pixel, 0.8 px apart)
    t = (np.arange(120) + 0.5) / 120
    st1 = np.column_stack([np.concatenate([t, t]), np.concatenate([0.5 + 0 * t, 0.52 + 0 * t])])
    lab1 = np.vstack([np.tile([30.0, 10, 0], (120, 1)), np.tile([70.0, -10, 20], (120, 1))]) + rng.standard_normal((240, 3))
    feats.append((1, st1, lab1))
    st1b = rng.random((600, 2))
    feats.append((1, st1b, np.where(st1b[:, 1:] < 0.51, [30.0, 10, 0], [70.0, -10, 20]) + rng.standard_normal((600, 3))))
    feats.append((2, rng.random((10, 2)), rng.random((10, 3)) * 50))
    m = rect_model([(0, 0, 120, 80), (0, 80, 120, 40), (120, 0, 8, 120)], feats, 128, 120, kernel_size=32)
    m.regions.append(Region(3, [np.array([[120.0, 110], [128, 110], [128, 120], [120, 120]])], rect_patch(120, 110, 8, 10)))
    return m, tps.group_kernels(m)


def test_grouping_structure(grouped):
    m, ks = grouped
    K = ks.kernel_size
    assert ks.index.shape == (ks.n_kernels, K)
    assert ks.grid[3, 0] == 0 and ks.grid[3, 1] == 0  # no features: no kernels
    assert ks.grid[2, 0] * ks.grid[2, 1] == 1  # 10 < K features: one kernel
    total = 0
    for r in range(3):
        gx, gy, k0 = ks.grid[r]
        assert k0 == total
        total += gx * gy
        n_r = int((m.features.region == r).sum())
        for k in range(k0, k0 + gx * gy):
            idx = ks.index[k]
            c = ks.count[k]
            assert c == min(K, n_r)
            assert (idx[:c] >= 0).all() and (idx[c:] == -1).all()
            assert (m.features.region[idx[:c]] == r).all()
            assert len(set(idx[:c].tolist())) == c
            assert ks.region[k] == r
    assert total == ks.n_kernels
    # cells: sx x sy px square-ish cells for region 0 (120 x 80 px)
    gx, gy, _ = ks.grid[0]
    assert abs((120 / gx) / (80 / gy) - 1) < 0.35
    # the dense line forced a finer grid in region 1 than density alone
    assert not ks.degenerate[ks.region < 2].any()


def test_packing_is_nearest_chebyshev(grouped):
    m, ks = grouped
    for k in range(0, ks.n_kernels, 7):
        r = ks.region[k]
        if ks.grid[r, 0] * ks.grid[r, 1] == 1:
            continue
        sx, sy = ks.scale[r]
        sel = np.nonzero(m.features.region == r)[0]
        cen = ks.frame[k, :2]
        d = np.abs((m.features.st[sel] - cen) * [sx, sy]).max(1)
        inside = np.isin(sel, ks.index[k, : ks.count[k]])
        assert d[inside].max() <= d[~inside].min() + 1e-9


def test_anchors_spread(grouped):
    m, ks = grouped
    ok = ~ks.degenerate
    for k in np.nonzero(ok)[0][::5]:
        p = ks.local(k, ks.st[ks.index[k, :3]])
        e1, e2 = p[1] - p[0], p[2] - p[0]
        area = abs(e1[0] * e2[1] - e1[1] * e2[0]) / 2
        allp = ks.local(k, ks.st[ks.index[k, : ks.count[k]]])
        hull_scale = np.ptp(allp, axis=0).prod()
        assert area > 0.05 * hull_scale


def test_group_validates_params():
    m = one_region(np.random.default_rng(0).random((10, 2)), np.zeros((10, 3)))
    with pytest.raises(TpsvError):
        tps.group_kernels(m, kernel_size=2)
    # only the sizes the decoder accepts (each is a separately compiled Warp kernel)
    with pytest.raises(TpsvError, match="kernel size 20 is not one tpsv renders"):
        tps.group_kernels(m, kernel_size=20)
    for K in codec.SUPPORTED_KERNEL_SIZES:
        assert tps.group_kernels(m, kernel_size=K).kernel_size == K
    with pytest.raises(TpsvError):
        tps.group_kernels(m, overlap=0.7)
    with pytest.raises(TpsvError):
        tps.group_kernels(m, smoothing=-1.0)


# --------------------------------------------------------------------------- blending


@pytest.mark.parametrize("overlap", [0.5, 0.25])
def test_partition_of_unity(grouped, overlap):
    m, _ = grouped
    ks = tps.group_kernels(m, overlap=overlap)
    rng = np.random.default_rng(8)
    st = np.vstack([rng.random((4000, 2)), rng.random((200, 2)) * 1.2 - 0.1])  # some slightly outside
    for r in range(3):
        kid, w = tps.blend_weights(ks, np.full(len(st), r), st)
        assert np.allclose(w.sum(1), 1.0, atol=1e-12)
        assert (w >= 0).all()
        assert (kid[w > 0] >= ks.grid[r, 2]).all() and (kid[w > 0] < ks.grid[r, 2] + ks.grid[r, 0] * ks.grid[r, 1]).all()
        # the device computes the same weights
        dkid, dw = gtps.device_weights(gtps.upload(ks, "cpu"), r, st)
        order = np.argsort(np.where(kid < 0, 1 << 30, kid), 1)
        dorder = np.argsort(np.where(dkid < 0, 1 << 30, dkid), 1)
        assert (np.take_along_axis(kid, order, 1) == np.take_along_axis(dkid, dorder, 1)).all()
        assert np.abs(np.take_along_axis(w, order, 1) - np.take_along_axis(dw, dorder, 1)).max() < 1e-5


@pytest.mark.parametrize("overlap", [0.5, 0.25])
def test_weight_vanishes_at_support_border(overlap):
    g = np.array([5.0])
    half = 0.5 + overlap
    for i in range(5):
        # the unnormalised weight of cell i along an axis: bump((a - (i+0.5)) / half)
        for a_border in (i + 0.5 - half, i + 0.5 + half):
            for eps in (0.0, 1e-4):
                z = (a_border + np.sign(i + 0.5 - a_border) * eps - (i + 0.5)) / half
                assert tps.bump(z) <= 16 * (eps / half) ** 2 + 1e-15  # zero with zero slope
        # inside the support it is positive
        a = np.linspace(i + 0.5 - half + 1e-6, i + 0.5 + half - 1e-6, 101)
        assert (tps.bump((a - (i + 0.5)) / half) > 0).all()
    # and the normalised blend weight of a kernel goes to zero continuously at its border
    _, _, wi, wj = blend._axis_cover(np.array([2.0 + overlap - 1e-9, 2.0 + overlap + 1e-9]), g, overlap)
    assert np.all(np.minimum(wi, wj) < 1e-12 + 1e-3 * overlap)


def test_affine_colours_blend_exactly(grouped):
    """Every kernel reproduces an affine colour field, so any partition of unity gives it back."""
    m, ks = grouped
    st = m.features.st
    xy = st * ks.scale[m.features.region]
    lab = np.column_stack([20 + 0.3 * xy[:, 0] + 0.2 * xy[:, 1], 5 - 0.1 * xy[:, 0], 0.05 * xy[:, 1] - 3])
    m2 = Model(m.width, m.height, m.regions, Features(m.features.region, st, lab.astype(np.float32), m.features.kind, m.features.pair), m.params)
    ks2 = tps.group_kernels(m2)
    dk = gtps.solve(gtps.upload(ks2, "cpu"))
    rng = np.random.default_rng(9)
    for r in range(3):
        q = rng.random((2000, 2))
        out = gtps.eval_points(dk, r, q)
        qxy = q * ks2.scale[r]
        ref = np.column_stack([20 + 0.3 * qxy[:, 0] + 0.2 * qxy[:, 1], 5 - 0.1 * qxy[:, 0], 0.05 * qxy[:, 1] - 3])
        assert np.abs(out - ref).max() < 2e-3


def test_device_blend_matches_reference(grouped):
    m, ks = grouped
    dk = gtps.solve(gtps.upload(ks, "cpu"))
    pts, w, b, status = gtps.coefficients(dk)
    assert (status == 0).all()
    rng = np.random.default_rng(10)
    for r in range(3):
        q = rng.random((3000, 2)).astype(np.float32).astype(np.float64)  # the device gets float32 (S, T)
        ref = tps.blend_reference(ks, pts, w, b, np.full(len(q), r), q)
        assert np.abs(gtps.eval_points(dk, r, q) - ref).max() < 1e-3  # Lab units, values up to 50
    # no features: the fill colour
    assert np.allclose(gtps.eval_points(dk, 3, [[0.5, 0.5]]), ks.fill[3], atol=1e-6)


def test_solve_deterministic(grouped):
    m, ks = grouped
    a = gtps.coefficients(gtps.solve(gtps.upload(ks, "cpu"), threads=1))
    b = gtps.coefficients(gtps.solve(gtps.upload(ks, "cpu"), threads=2))
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
