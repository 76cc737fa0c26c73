"""Curvilinear pairs and gradation features (tpsv.encode.features)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tpsv.color import srgb_to_lab
from tpsv.encode.features import FeatureExtractor, FeatureSet, curvilinear_features, extract_features, gradation_features
from tpsv.model import CURVILINEAR, GRADATION

A = np.array([0.9, 0.2, 0.1], np.float32)
B = np.array([0.1, 0.3, 0.8], np.float32)


def step_image(h=20, w=24, col=12):
    rgb = np.empty((h, w, 3), np.float32)
    rgb[:, :col] = A
    rgb[:, col:] = B
    return rgb


def disc_image(n=40, r=11.3, cx=19.7, cy=20.2):
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    rgb = np.where(inside[..., None], A, B).astype(np.float32)
    return rgb, inside, (cx, cy)


def textured(h=48, w=64, seed=1):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack(
        [0.5 + 0.4 * np.sin(6 * xx + 3 * yy), 0.5 + 0.4 * np.cos(5 * yy), 0.3 + 0.5 * xx * yy], -1
    )
    base += 0.04 * rng.standard_normal(base.shape)
    base[h // 3 : h // 2, w // 4 : w // 2] = [0.9, 0.9, 0.1]
    return np.clip(base, 0, 1).astype(np.float32)


def containing_region(index, xy):
    h, w = index.shape
    c = np.clip(np.floor(xy[:, 0]).astype(int), 0, w - 1)
    r = np.clip(np.floor(xy[:, 1]).astype(int), 0, h - 1)
    return index[r, c]


def check_pairs(fs: FeatureSet):
    n = len(fs)
    p = fs.pair
    has = p >= 0
    assert np.all(p[has] < n)
    assert np.all(p[p[has]] == np.nonzero(has)[0])
    assert np.all(fs.kind[has] == CURVILINEAR)
    assert np.all(p[fs.kind == GRADATION] == -1)


# --------------------------------------------------------------------- curvilinear


def test_pairs_straddle_vertical_step_and_region_border():
    rgb = step_image()
    index = np.zeros(rgb.shape[:2], np.int32)
    index[:, 12:] = 1
    fs = curvilinear_features(rgb, index, 20.0)
    assert len(fs) > 0 and len(fs) % 2 == 0
    assert np.all(fs.kind == CURVILINEAR)
    assert np.array_equal(fs.pair, np.arange(len(fs)) ^ 1)  # stored adjacently
    lab_a, lab_b = srgb_to_lab(A), srgb_to_lab(B)
    for k in range(0, len(fs), 2):
        i, j = k, k + 1
        left, right = (i, j) if fs.xy[i, 0] < fs.xy[j, 0] else (j, i)
        # opposite sides of x = 12, 1 px apart along the gradient (x)
        assert fs.xy[left, 0] < 12.0 < fs.xy[right, 0]
        assert np.hypot(*(fs.xy[left] - fs.xy[right])) == pytest.approx(1.0, abs=1e-9)
        assert fs.xy[left, 1] == pytest.approx(fs.xy[right, 1])
        assert np.allclose(fs.lab[left], lab_a, atol=1e-4)
        assert np.allclose(fs.lab[right], lab_b, atol=1e-4)
        assert fs.region[left] == 0 and fs.region[right] == 1
    # every row of the step has an edge pixel
    assert len(fs) // 2 >= rgb.shape[0] - 2


def test_pairs_straddle_disc_edge():
    rgb, inside, (cx, cy) = disc_image()
    fs = curvilinear_features(rgb, None, 20.0)
    assert len(fs) >= 40
    lab_a, lab_b = srgb_to_lab(A), srgb_to_lab(B)
    assert np.all(fs.region == 0)
    for k in range(0, len(fs), 2):
        i, j = k, k + 1
        ci = np.allclose(fs.lab[i], lab_a, atol=1e-3)
        cj = np.allclose(fs.lab[j], lab_a, atol=1e-3)
        assert ci != cj, "the two halves must carry the two distinct colours"
        inn, out = (i, j) if ci else (j, i)
        assert np.allclose(fs.lab[out], lab_b, atol=1e-3)
        d_in = np.hypot(fs.xy[inn, 0] - cx, fs.xy[inn, 1] - cy)
        d_out = np.hypot(fs.xy[out, 0] - cx, fs.xy[out, 1] - cy)
        assert d_in < d_out
        assert np.hypot(*(fs.xy[i] - fs.xy[j])) == pytest.approx(1.0, abs=1e-9)


def test_step_not_on_region_border_keeps_one_region():
    rgb = step_image()
    fs = curvilinear_features(rgb, np.zeros(rgb.shape[:2], np.int32), 20.0)
    assert len(fs) > 0 and np.all(fs.region == 0)


def test_threshold_and_step_reduce_pairs():
    rgb = textured()
    fe = FeatureExtractor(rgb, None)
    n = [len(fe.curvilinear(t)) for t in (20, 60, 200, 2000)]
    assert n[0] >= n[1] >= n[2] >= n[3]
    assert n[3] == 0
    n1 = len(fe.curvilinear(20, step=1))
    n3 = len(fe.curvilinear(20, step=3))
    assert 0 < n3 < n1
    check_pairs(fe.curvilinear(20, step=3))


def test_uniform_image_has_no_edges():
    rgb = np.full((16, 16, 3), 0.4, np.float32)
    assert len(curvilinear_features(rgb, None, 10.0)) == 0


# ----------------------------------------------------------------------- gradation


def tiny_regions_case():
    rng = np.random.default_rng(3)
    h, w = 30, 40
    rgb = np.clip(0.5 + 0.2 * rng.standard_normal((h, w, 3)), 0, 1).astype(np.float32)
    index = np.zeros((h, w), np.int32)
    index[5, 5] = 1  # single pixel
    index[10, 3:30] = 2  # horizontal 1-px line
    for k in range(12):  # diagonal 1-px line
        index[14 + k, 8 + k] = 3
    index[2, 20:22] = 4  # two pixels
    index[20, 30] = index[21, 30] = index[21, 31] = 5  # L of 3 pixels
    index[0, 0:3] = 6  # line along the frame
    index[24:26, 34:36] = 7  # 2x2 square
    index[:, 38] = 8  # vertical line (full height)
    return rgb, index


def assert_coverage(fs: FeatureSet, index: np.ndarray):
    npix = np.bincount(index.ravel())
    for r in np.nonzero(npix)[0]:
        pts = fs.xy[fs.region == r]
        if npix[r] >= 3:
            assert len(pts) >= 3, f"region {r}: {len(pts)} features"
            d = pts - pts.mean(0)
            cov = d.T @ d / len(pts)
            assert np.linalg.det(cov) > 1e-6, f"region {r}: collinear features"
        else:
            assert len(pts) >= 1, f"region {r} has no feature"


def test_every_region_covered_gradation_and_merged():
    rgb, index = tiny_regions_case()
    for t_super in (1.0, 20.0, 400.0):
        g = gradation_features(rgb, index, t_super)
        assert_coverage(g, index)
        assert np.array_equal(containing_region(index, g.xy), g.region)
    fs = extract_features(rgb, index, 40.0, 20.0)
    assert_coverage(fs, index)
    assert np.array_equal(containing_region(index, fs.xy), fs.region)


def test_single_pixel_and_two_pixel_images():
    for shape in ((1, 1), (1, 2), (2, 1), (1, 7), (3, 3)):
        rgb = np.full(shape + (3,), 0.3, np.float32)
        fs = extract_features(rgb, None, 40.0, 20.0)
        assert len(fs) >= 1
        if shape[0] * shape[1] >= 3:
            assert_coverage(fs, np.zeros(shape, np.int32))


def test_gradation_features_colour_and_position():
    rgb = textured()
    index = np.zeros(rgb.shape[:2], np.int32)
    index[:, 40:] = 1
    g = gradation_features(rgb, index, 10.0)
    assert np.all(g.kind == GRADATION) and np.all(g.pair == -1)
    c = np.floor(g.xy).astype(int)
    assert np.allclose(g.xy, c + 0.5)  # pixel centres (no anchors needed here)
    assert np.allclose(g.lab, srgb_to_lab(rgb)[c[:, 1], c[:, 0]])
    assert np.array_equal(index[c[:, 1], c[:, 0]], g.region)


def test_smaller_t_super_gives_more_gradation_features():
    rgb = textured(64, 80)
    fe = FeatureExtractor(rgb, None)
    ts = [400.0, 60.0, 30.0, 15.0, 8.0, 4.0, 2.0, 1.0]
    counts = [len(fe.gradation(t)) for t in ts]
    assert all(a <= b for a, b in zip(counts, counts[1:])), counts
    assert counts[-1] > 2 * counts[0], counts
    # the boundary sets are nested: a smaller threshold refines the cells
    prev = fe.boundary(ts[0])
    for t in ts[1:]:
        cur = fe.boundary(t)
        assert np.all(cur[prev])
        prev = cur


def test_variance_threshold_honoured():
    rgb = textured(64, 80)
    fe = FeatureExtractor(rgb, None, min_cell=32)
    lab255 = fe.lab255.reshape(-1, 3).astype(np.float64)
    hier = fe.hierarchy()
    for t in (30.0, 10.0):
        cells = fe.cells(t).ravel()
        _, inv = np.unique(cells, return_inverse=True)
        n = inv.max() + 1
        cnt = np.bincount(inv, minlength=n)
        var = sum(
            np.bincount(inv, lab255[:, c] ** 2, n) / cnt - (np.bincount(inv, lab255[:, c], n) / cnt) ** 2
            for c in range(3)
        )
        rms = np.sqrt(np.maximum(var, 0))
        # a cell above the threshold is one the hierarchy could not split further
        over = rms > t + 1e-3
        assert np.all(cnt[over] < 4 * fe.min_cell), (t, cnt[over], rms[over])
        assert len(hier.labels) >= 3


# -------------------------------------------------------------------------- merged


def test_extract_sorted_dedup_and_pairs():
    rgb = textured()
    index = np.zeros(rgb.shape[:2], np.int32)
    index[:, 30:] = 1
    index[30:, :] = 2
    fe = FeatureExtractor(rgb, index)
    fs = fe.extract(40.0, 12.0)
    assert np.all(np.diff(fs.region) >= 0)
    check_pairs(fs)
    assert np.array_equal(containing_region(index, fs.xy), fs.region)
    cur = fs.kind == CURVILINEAR
    grad = ~cur
    assert cur.sum() > 0 and grad.sum() > 0
    # no gradation feature within 0.5 px of a curvilinear one of its region
    for r in range(3):
        c = fs.xy[cur & (fs.region == r)]
        g = fs.xy[grad & (fs.region == r)]
        if len(c) and len(g):
            d = np.min(np.hypot(*(g[:, None, :] - c[None, :, :]).transpose(2, 0, 1)), axis=1)
            assert np.all(d > 0.5)
    # the curvilinear features are those of curvilinear(), reordered
    alone = fe.curvilinear(40.0)
    assert cur.sum() == len(alone)
    # pairs stay pairs: partner positions are 1 px apart (less only where
    # clipped to the image frame)
    i = np.nonzero(cur)[0]
    d = np.hypot(*(fs.xy[i] - fs.xy[fs.pair[i]]).T)
    h, w = index.shape
    edge = (fs.xy == 0) | (fs.xy == [w, h])
    on_frame = np.any(edge[i] | edge[fs.pair[i]], axis=1)
    assert np.all(d <= 1.0 + 1e-9)
    assert np.allclose(d[~on_frame], 1.0)


def test_extractor_reuse_matches_plain_functions_and_is_deterministic():
    rgb = textured()
    index = np.zeros(rgb.shape[:2], np.int32)
    index[20:, 10:50] = 1
    fe = FeatureExtractor(rgb, index)
    for tc, ts in ((30.0, 8.0), (90.0, 25.0), (30.0, 8.0)):
        a = fe.extract(tc, ts)
        b = extract_features(rgb, index, tc, ts)
        for f in ("xy", "region", "lab", "kind", "pair"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
    c = curvilinear_features(rgb, index, 30.0)
    assert np.array_equal(c.xy, fe.curvilinear(30.0).xy)


def test_uint8_input_and_bad_shapes():
    rgb8 = (textured() * 255).astype(np.uint8)
    fs = extract_features(rgb8, None, 40.0, 20.0)
    assert len(fs) > 0
    with pytest.raises(ValueError):
        extract_features(rgb8, np.zeros((3, 3), np.int32), 40.0, 20.0)
    with pytest.raises(ValueError):
        extract_features(rgb8[..., 0], None, 40.0, 20.0)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    h=st.integers(1, 24),
    w=st.integers(1, 24),
    blocks=st.integers(1, 6),
    seed=st.integers(0, 2**16),
    tc=st.floats(8, 300),
    ts=st.floats(1, 100),
)
def test_property_region_colours_and_coverage(h, w, blocks, seed, tc, ts):
    rng = np.random.default_rng(seed)
    rgb = rng.random((h, w, 3)).astype(np.float32)
    # blocky random regions, relabelled to 0..R-1
    by, bx = rng.integers(1, 5, 2)
    coarse = rng.integers(0, blocks, ((h + by - 1) // by, (w + bx - 1) // bx))
    lab_map = np.kron(coarse, np.ones((by, bx), int))[:h, :w]
    _, index = np.unique(lab_map, return_inverse=True)
    index = index.reshape(h, w).astype(np.int32)
    fs = extract_features(rgb, index, tc, ts)
    check_pairs(fs)
    assert np.all(np.diff(fs.region) >= 0)
    assert np.all((fs.xy >= 0) & (fs.xy <= [w, h]))
    assert np.array_equal(containing_region(index, fs.xy), fs.region)
    # each colour is the colour of a pixel of the feature's own region nearby
    lab = srgb_to_lab(rgb)
    for k in range(len(fs)):
        x, y = fs.xy[k]
        r0, r1 = max(int(y) - 2, 0), min(int(y) + 3, h)
        c0, c1 = max(int(x) - 2, 0), min(int(x) + 3, w)
        win = lab[r0:r1, c0:c1].reshape(-1, 3)
        reg = index[r0:r1, c0:c1].ravel()
        ok = np.all(np.abs(win - fs.lab[k]) < 1e-4, axis=1) & (reg == fs.region[k])
        assert ok.any(), k
    assert_coverage(fs, index)


# ------------------------------------------------------------------ lattice gradation


def lattice_for(rgb, labels):
    from tpsv.encode.vectorize import build_geometry

    g = build_geometry(labels)
    return g, g.lattice(srgb_to_lab(rgb))


def test_lattice_monotone_covering_and_in_range():
    from tpsv.encode.features import LatticeGradation

    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 40:] = 1
    g, lat = lattice_for(rgb, labels)
    assert isinstance(lat, LatticeGradation)
    prev_n, prev_pick = None, None
    for t in (0.5, 5.0, 20.0, 60.0, 1e6):
        fs = lat.features(t)
        pick = lat.region_spacing(t)
        assert fs.st is not None and np.all((fs.st >= 0) & (fs.st <= 1))
        assert set(np.unique(fs.region)) == {0, 1}
        assert np.all(fs.kind == GRADATION) and np.all(fs.pair == -1)
        if prev_n is not None:
            assert len(fs) <= prev_n and np.all(pick >= prev_pick)
        prev_n, prev_pick = len(fs), pick
    assert len(lat.features(0.5)) > len(lat.features(1e6))
    # the coarsest: one spacing of LATTICE_PX per region, a feature per non-empty cell
    top = len(lat.spacings) - 1
    assert np.all(lat.region_spacing(1e6) == top)
    # standing alone: the coarsest with 3 non-collinear cells of its own, every coarser one has fewer
    finest = lat.spacings.index(4.0)  # finer lattices are the pure vector ladder's (min_spacing)
    for r, j in enumerate(lat.region_spacing(1e6, standalone=True)):
        assert j == finest or lat._stands(j, np.array([r]))[0]
        assert not any(lat._stands(k, np.array([r]))[0] for k in range(j + 1, top + 1))


def test_lattices_finer_than_4_px_only_when_asked():
    """Below 4 px (FINE_LATTICE_PX) only a ``min_spacing`` lets a region go, and then to no
    spacing finer than it: the threshold modes and the detail layer's base keep 4 px at most."""
    from tpsv.encode.features import FINE_LATTICE_PX, LATTICE_PX

    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 40:] = 1
    g, lat = lattice_for(rgb, labels)
    spacing = np.asarray(lat.spacings)
    assert lat.spacings == FINE_LATTICE_PX + LATTICE_PX
    assert np.all(spacing[lat.region_spacing(0.0)] == 4.0)  # nothing passes: the finest allowed
    assert np.all(spacing[lat.region_spacing(0.0, min_spacing=2.0)] == 2.0)
    assert np.all(spacing[lat.region_spacing(0.0, min_spacing=3.2)] == 3.5)
    for t in (0.5, 3.0, 6.0, 20.0):
        for least in (2.0, 2.5, 3.0, 4.0):
            assert np.all(spacing[lat.region_spacing(t, min_spacing=least)] >= least)
            assert np.all(lat.region_spacing(t, min_spacing=least) <= lat.region_spacing(t))
    counts = [len(lat.features(t, min_spacing=2.0)) for t in (20.0, 6.0, 3.0, 0.5)]
    assert counts == sorted(counts) and counts[-1] > 3 * len(lat.features(0.5))
    # standing alone, the finest allowed lattice always qualifies
    assert np.all(spacing[lat.region_spacing(0.0, standalone=True, min_spacing=2.0)] == 2.0)


def test_the_pure_vector_ladder():
    """``vector_params``: up to quality 60 the 4 px lattices (T_super 70 * (4/70)^((Q-1)/99))
    at colour steps 16/8, then T_super, the colour steps and the finest spacing fall, to 2 px
    lattices, with curvilinear pairs from quality 96."""
    from tpsv.encode.rate import vector_params

    ladder = [vector_params(q) for q in range(1, 101)]
    for q in range(1, 61):
        v = ladder[q - 1]
        assert v["t_super"] == pytest.approx(70.0 * (4.0 / 70.0) ** ((q - 1) / 99.0), rel=2e-3)
        assert (v["l_step"], v["ab_step"], v["min_spacing"]) == (16, 8, 4.0)
    for a, b in zip(ladder, ladder[1:]):
        assert b["t_super"] < a["t_super"] and b["min_spacing"] <= a["min_spacing"]
        assert b["l_step"] <= a["l_step"] and b["ab_step"] <= a["ab_step"]
        assert b["t_canny"] <= a["t_canny"]
    assert ladder[-1]["min_spacing"] == 2.0 and ladder[-1]["t_super"] == pytest.approx(2.0)
    assert all(v["t_canny"] >= 1e9 for v in ladder[:95])  # curvilinear pairs only at the top
    assert ladder[-1]["t_canny"] < 1e9


def test_a_lattice_needing_anchors_is_not_taken():
    """Standing alone (the pure vector quality ladder), a region too small for 3 cells of a coarse
    lattice takes the coarsest finer one that gives it 3 (a coarse lattice would be padded with up
    to 9 anchors: more features, more bytes), so the features, anchors included, never get fewer
    as T_super falls."""
    from tpsv.encode.features import FeatureExtractor
    from tpsv.encode.vectorize import tpsv_features

    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 40:] = 1  # 24 px wide: one or two cells of the coarsest lattices
    g, lat = lattice_for(rgb, labels)
    ex = FeatureExtractor(rgb, g.index)
    counts = [len(tpsv_features(g, ex, 1e9, t, standalone=True)) for t in (1e6, 60.0, 30.0, 15.0, 8.0, 4.0)]
    assert counts == sorted(counts)
    assert len(ex.anchors(lat.features(1e6, standalone=True))) == 0
    assert len(ex.anchors(lat.features(1e6))) > 0  # the coarsest lattice as it is: anchors fill in


def test_lattices_are_made_only_when_asked():
    """A lattice is a pass over every pixel: the coarsest alone is made for a T_super that every
    lattice passes (the quality modes' base), the finer ones as a smaller T_super asks, and the
    features are those of lattices made all at once."""
    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 40:] = 1
    g, lat = lattice_for(rgb, labels)
    lazy = lat.features(1e6)
    assert sorted(lat._lattices) == [len(lat.spacings) - 1]
    fine = lat.features(5.0)
    assert len(lat._lattices) > 1
    _, eager = lattice_for(rgb, labels)
    for j in range(len(eager.spacings)):
        eager.lattice(j)
    for t, got in ((1e6, lazy), (5.0, fine)):
        want = eager.features(t)
        assert np.array_equal(got.st, want.st) and np.array_equal(got.lab, want.lab)


def test_lattice_features_are_cell_means_at_cell_centres():
    rgb = textured(32, 40)
    labels = np.zeros(rgb.shape[:2], np.int32)
    g, lat = lattice_for(rgb, labels)
    fs = lat.features(1e6)  # the coarsest lattice for the single region
    d = lat.spacings[-1]
    nx, ny = lat._grid(d)[0]
    assert len(fs) == nx * ny
    st = g.pixel_st().reshape(-1, 2).astype(np.float64)
    lab = srgb_to_lab(rgb).reshape(-1, 3)
    ij = np.minimum((st * [nx, ny]).astype(int), [nx - 1, ny - 1])
    for k in range(len(fs)):
        ix, iy = np.minimum((fs.st[k] * [nx, ny]).astype(int), [nx - 1, ny - 1])
        assert fs.st[k] == pytest.approx([(ix + 0.5) / nx, (iy + 0.5) / ny])
        sel = (ij[:, 0] == ix) & (ij[:, 1] == iy)
        assert np.allclose(fs.lab[k], lab[sel].mean(0), atol=1e-3)


def test_lattice_cells_with_edges_are_subdivided():
    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    g, lat = lattice_for(rgb, labels)
    plain = lat.features(1e6)
    edge = np.arange(10 * rgb.shape[1] + 5, 10 * rgb.shape[1] + 30)  # a row of pixels
    more = lat.features(1e6, edge)
    assert len(more) > len(plain)
    assert np.all((more.st >= 0) & (more.st <= 1))


# ------------------------------------------------------------ shared pieces, written once


def test_feature_set_is_features_with_pixel_positions():
    from tpsv.model import Features

    rgb, index = tiny_regions_case()
    fs = extract_features(rgb, index, 40.0, 20.0)
    assert isinstance(fs, Features) and np.isnan(fs.st).all()  # every feature defined by its pixel
    keep = np.arange(len(fs)) % 3 != 1
    sub = fs.subset(keep)
    assert isinstance(sub, FeatureSet) and np.array_equal(sub.xy, fs.xy[keep])
    check_pairs(sub)
    both = FeatureSet.concat([sub, fs])
    assert np.array_equal(both.xy, np.concatenate([sub.xy, fs.xy]))
    assert np.array_equal(both.pair[len(sub):], np.where(fs.pair >= 0, fs.pair + len(sub), -1))
    assert len(FeatureSet.empty()) == 0 and FeatureSet.empty().xy.shape == (0, 2)


def test_in_patch_space_maps_only_features_defined_by_pixels():
    from tpsv.geometry.regions import to_patch_space

    rgb = textured()
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 40:] = 1
    g, lat = lattice_for(rgb, labels)
    fe = FeatureExtractor(rgb, g.index)
    cur, grad = fe.curvilinear(30.0), lat.features(20.0)
    fs = FeatureSet.concat([cur, grad])
    patches = [r.patch for r in g.regions]
    f = fs.in_patch_space(patches)
    assert np.array_equal(f.st[len(cur):], grad.st)  # lattice positions kept as they are
    assert np.array_equal(f.st[:len(cur)], to_patch_space(patches, cur.xy, cur.region))
    assert f.region.dtype == np.int32 and f.lab.dtype == np.float32 and not hasattr(f, "xy")


def test_drop_near_drops_exactly_the_close_gradation_features():
    from tpsv.encode.features import DEDUP_PX, drop_near

    rgb, index = tiny_regions_case()
    fe = FeatureExtractor(rgb, index)
    cur, grad = fe.curvilinear(40.0), fe.boundary_features(1.0)
    kept = drop_near(grad, cur, DEDUP_PX, (fe.w, fe.h))
    assert 0 < len(kept) < len(grad)

    def nearest(fs):
        d = np.hypot(*(fs.xy[:, None, :] - cur.xy[None, :, :]).transpose(2, 0, 1))
        d[fs.region[:, None] != cur.region[None, :]] = np.inf
        return d.min(axis=1)

    assert np.all(nearest(kept) > DEDUP_PX)
    assert np.sum(nearest(grad) <= DEDUP_PX) == len(grad) - len(kept)
    assert drop_near(grad, cur, 0.0, (fe.w, fe.h)) is grad


def test_gradation_and_extract_share_boundary_features_and_anchors():
    from tpsv.encode.features import DEDUP_PX, drop_near

    rgb, index = tiny_regions_case()
    fe = FeatureExtractor(rgb, index)
    boundary = fe.boundary_features(20.0)
    anchors = fe.anchors(boundary)
    assert len(anchors) > 0  # the 1-2 px regions need them
    g = fe.gradation(20.0)
    assert np.array_equal(g.xy, np.concatenate([boundary.xy, anchors.xy]))
    cur = fe.curvilinear(40.0)
    merged = FeatureSet.concat([cur, drop_near(boundary, cur, DEDUP_PX, (fe.w, fe.h)), anchors])
    ref = merged.subset(np.argsort(merged.region, kind="stable"))
    got = fe.extract(40.0, 20.0)
    for name in ("xy", "region", "lab", "kind", "pair"):
        assert np.array_equal(getattr(got, name), getattr(ref, name)), name


def test_cell_stats_against_direct_means():
    from tpsv.encode.features import LAB_SCALE, cell_stats

    rng = np.random.default_rng(4)
    col = rng.random((200, 3)) * 50
    cell = rng.integers(0, 7, 200)
    cell[cell == 5] = 6  # an empty cell
    st = cell_stats(cell, 8, col, LAB_SCALE**2)
    for c in range(8):
        sel = cell == c
        assert st["count"][c] == sel.sum()
        if sel.any():
            assert np.allclose(st["lab"][c], col[sel].mean(0))
            assert st["rms"][c] == pytest.approx(LAB_SCALE * np.sqrt(col[sel].var(0).sum()), rel=1e-9)
        else:
            assert st["rms"][c] == 0 and np.all(st["lab"][c] == 0)
    plain = cell_stats(cell, 8, col * LAB_SCALE)
    assert np.allclose(plain["rms"], st["rms"], rtol=1e-9)


def test_threshold_above_any_gradient_traces_nothing_without_the_gradient():
    """The vector base of a quality asks for no pairs (t_canny 1e9): the answer is Canny's (no edge),
    given before the gradient is made."""
    rng = np.random.default_rng(3)
    rgb = rng.random((40, 50, 3)).astype(np.float32)
    rgb[:, 25:] = 1.0 - rgb[:, 25:]
    fe = FeatureExtractor(rgb, None)
    assert not fe.edges(1e9).any() and fe._grad is None
    assert len(fe.curvilinear(1e9)) == 0 and fe._grad is None
    top = 46341.0 / 8.0  # just above the largest magnitude Canny sees, in t_canny units
    assert fe.edges(20.0).any() and not fe.edges(top).any()
