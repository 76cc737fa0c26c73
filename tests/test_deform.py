"""Shape manipulation (tpsv.edit.deform, paper VII-D): features ride along, outlines follow, folds refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from skimage.measure import points_in_poly

from editfixtures import BACKGROUND, DISC, PANEL, same_model, scene_model
from tpsv import codec
from tpsv.edit import deform
from tpsv.geometry import patch
from tpsv.edit.common import copy_model
from tpsv.errors import TpsvError
from tpsv.model import Patch
from tpsv.rendering.pixelmap import FRONT_KEY, draw_order, region_index
from tpsv.rendering.raster import render

SHIFT = (8.0, -3.0)


@pytest.fixture(scope="module")
def model():
    return scene_model()


@pytest.fixture(scope="module")
def base_render(model):
    # one region per pixel: these tests follow where regions go, not how borders blend
    return render(model, antialias=False)


def index_of(m):
    return region_index(m, m.width, m.height)


def test_translation_moves_the_object(model, base_render):
    new = deform.affine(model, DISC, [1, 0, SHIFT[0], 0, 1, SHIFT[1]])
    assert np.array_equal(new.features.st, model.features.st)  # features ride along in (S, T)
    assert np.array_equal(new.features.lab, model.features.lab)
    for p, q in zip(model.regions[DISC].outline, new.regions[DISC].outline):
        assert np.array_equal(q, p + SHIFT)
    assert np.array_equal(new.regions[DISC].patch.ctrl[..., 0, :], model.regions[DISC].patch.ctrl[..., 0, :] + SHIFT)
    img = render(new, antialias=False)
    i0, i1 = index_of(model), index_of(new)
    dx, dy = int(SHIFT[0]), int(SHIFT[1])
    moved = np.zeros_like(i0, bool)
    moved[max(dy, 0):i0.shape[0] + min(dy, 0), max(dx, 0):] = (i0 == DISC)[max(-dy, 0):i0.shape[0] - max(dy, 0), :i0.shape[1] - dx]
    assert np.array_equal(moved & (i1 == DISC), moved)  # the disc is where it was moved to
    ys, xs = np.nonzero(moved)
    assert np.abs(img[ys, xs] - base_render[ys - dy, xs - dx]).max() < 2e-3
    # far from the disc nothing changes
    far = np.ones_like(moved)
    far[:, :45] = False
    assert np.array_equal(img[far], base_render[far])


def centroid(p):
    """Area centroid of a polygon (vertex means depend on how a curve is sampled)."""
    p = np.asarray(p, np.float64)
    q = np.roll(p, -1, axis=0)
    cr = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
    return np.array([((p[:, 0] + q[:, 0]) * cr).sum(), ((p[:, 1] + q[:, 1]) * cr).sum()]) / (3.0 * cr.sum())


def test_uncovered_pixels_attached_neighbours_fill_the_gap(model):
    new = deform.affine(model, DISC, [1, 0, SHIFT[0], 0, 1, SHIFT[1]])
    i0, i1 = index_of(model), index_of(new)
    vacated = (i0 == DISC) & (i1 != DISC)
    assert vacated.sum() > 50
    # the background's hole followed the disc: the gap is background, with its own TPS continued
    assert np.all(i1[vacated] == BACKGROUND)
    hole0 = model.regions[BACKGROUND].outline[1]
    hole1 = new.regions[BACKGROUND].outline[1]
    assert np.allclose(centroid(hole1), centroid(hole0) + SHIFT, atol=0.2)
    assert new.params.extra[FRONT_KEY] == str(DISC)


def covered(m, order):
    """First region (in drawing order) whose polygons contain each pixel centre (even-odd), else -1."""
    yy, xx = np.mgrid[0:m.height, 0:m.width] + 0.5
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    out = np.full(pts.shape[0], -1)
    for r in reversed(order):
        inside = np.zeros(pts.shape[0], bool)
        for poly in m.regions[r].outline:
            inside ^= points_in_poly(pts, poly)
        out[inside] = r
    return out.reshape(m.height, m.width)


def test_uncovered_pixels_detached_take_the_nearest_region(model):
    new = deform.affine(model, DISC, [1, 0, SHIFT[0], 0, 1, SHIFT[1]], attach=False)
    assert [np.array_equal(a, b) for a, b in zip(model.regions[BACKGROUND].outline, new.regions[BACKGROUND].outline)] == [True, True]
    cov = covered(new, draw_order(new))
    i1 = index_of(new)
    assert np.array_equal(i1[cov >= 0], cov[cov >= 0])  # covered pixels: the first region in front
    gap = cov < 0
    assert gap.sum() > 50
    # each uncovered pixel takes the region of the nearest covered pixel (where that is unambiguous)
    ys, xs = np.nonzero(gap)
    cy, cx = np.nonzero(~gap)
    d2 = (ys[:, None] - cy[None, :]) ** 2 + (xs[:, None] - cx[None, :]) ** 2
    best = d2.min(axis=1)
    owner = cov[cy, cx]
    regions_at_best = [set(owner[d2[k] == best[k]]) for k in range(len(ys))]
    clear = np.array([len(s) == 1 for s in regions_at_best])
    assert clear.sum() > 20
    got = i1[ys, xs][clear]
    want = np.array([next(iter(s)) for s, c in zip(regions_at_best, clear) if c])
    assert np.array_equal(got, want)
    assert set(np.unique(got)) <= {BACKGROUND, DISC}


def test_front_order_and_keep_order(model):
    front = deform.affine(model, DISC, [1, 0, SHIFT[0], 0, 1, SHIFT[1]], attach=False)
    kept = deform.affine(model, DISC, [1, 0, SHIFT[0], 0, 1, SHIFT[1]], attach=False, keep_order=True)
    assert draw_order(front) == [DISC, BACKGROUND, PANEL]
    assert draw_order(kept) == [BACKGROUND, DISC, PANEL] and FRONT_KEY not in kept.params.extra
    i0, i_front, i_kept = index_of(model), index_of(front), index_of(kept)
    newly = (i_front == DISC) & (i0 != DISC)  # where the moved disc overlaps the background's polygon
    assert newly.sum() > 50
    assert np.all(i_kept[newly] == BACKGROUND)  # drawn first, the background keeps them
    twice = deform.affine(front, PANEL, [1, 0, -2, 0, 1, 0])
    assert draw_order(twice)[:2] == [PANEL, DISC]
    bad = copy_model(model)
    bad.params.extra = {FRONT_KEY: "1,1"}
    with pytest.raises(TpsvError, match="front"):
        draw_order(bad)


def affine_grid(M, N):
    ctrl = np.zeros((M, N, 4, 2))
    ii, jj = np.meshgrid(np.arange(M), np.arange(N), indexing="ij")
    a, b = np.array([10.0, 1.0]), np.array([-2.0, 8.0])
    ctrl[..., 0, :] = 5 + ii[..., None] * a + jj[..., None] * b
    ctrl[..., 1, :] = a
    ctrl[..., 2, :] = b
    return ctrl


def test_catmull_rom_refresh_is_local_and_exact_on_affine_grids():
    ctrl = affine_grid(5, 5)
    Ds, Dt = deform.catmull_rom(ctrl[..., 0, :])
    assert np.allclose(Ds, ctrl[..., 1, :]) and np.allclose(Dt, ctrl[..., 2, :])
    moved = np.zeros((5, 5), bool)
    moved[2, 2] = True
    new = ctrl.copy()
    new[2, 2, 0] += (3.0, -2.0)
    out = deform.refresh_derivatives(new, moved)
    P = out[..., 0, :]
    assert np.allclose(out[1, 2, 1], (P[2, 2] - P[0, 2]) / 2)
    assert np.allclose(out[2, 2, 1], (P[3, 2] - P[1, 2]) / 2)
    assert np.allclose(out[2, 3, 2], (P[2, 4] - P[2, 2]) / 2)
    # derivatives change only next to the moved point (its stencil), positions only at it
    changed = (out != ctrl).any(axis=-1)  # (5, 5, 4)
    assert np.array_equal(np.argwhere(changed[..., 0]), [[2, 2]])
    assert set(map(tuple, np.argwhere(changed[..., 1]))) <= {(1, 2), (2, 2), (3, 2)}
    assert set(map(tuple, np.argwhere(changed[..., 2]))) <= {(2, 1), (2, 2), (2, 3)}
    far = np.ones((5, 5), bool)
    far[:, 1:4] = False
    far[1:4, :] = False
    assert np.array_equal(out[far], ctrl[far])


def test_move_points(model):
    old = model.regions[BACKGROUND].patch
    new = deform.move_points(model, [(BACKGROUND, 1, 0, 2.0, 3.0), (BACKGROUND, 1, 0, 1.0, 0.0)])
    p = new.regions[BACKGROUND].patch
    assert np.allclose(p.ctrl[1, 0, 0], old.ctrl[1, 0, 0] + (3.0, 3.0))
    assert patch.fold_free(p)
    assert np.array_equal(new.features.st, model.features.st)
    keep = deform.move_points(model, [(BACKGROUND, 1, 0, 2.0, 3.0)], derivatives="keep")
    d = keep.regions[BACKGROUND].patch.ctrl - old.ctrl
    assert np.count_nonzero(d) == 2 and np.allclose(d[1, 0, 0], (2.0, 3.0))
    # outline vertices follow the surface: map them back through the new patch's inverse
    v = new.regions[BACKGROUND].outline[0]
    st_new = patch.inverse(p, v)
    assert np.abs(patch.forward(p, st_new[:, 0], st_new[:, 1]) - v).max() < 1e-6
    v_old = patch.forward(old, st_new[:, 0], st_new[:, 1])
    assert np.abs(v_old - v).max() <= 3.0 * np.sqrt(2) + 1e-9
    assert np.isfinite(render(new)).all()


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda m: deform.move_points(m, [(BACKGROUND, 1, 0, 200.0, 0.0)]), "folds"),
        (lambda m: deform.move_points(m, [(9, 0, 0, 1.0, 0.0)]), "does not exist"),
        (lambda m: deform.move_points(m, [(PANEL, 5, 0, 1.0, 0.0)]), "control points"),
        (lambda m: deform.move_points(m, [(PANEL, 0, 0, 1.0, 0.0)], derivatives="cubic"), "derivatives"),
        (lambda m: deform.affine(m, DISC, [1, 2, 0, 2, 4, 0]), "singular"),
        (lambda m: deform.affine(m, DISC, [1, 0, 0]), "6 finite"),
        (lambda m: deform.affine(m, DISC, np.eye(2), about="corner"), "about"),
        (lambda m: deform.set_grid(m, PANEL, {"positions": [[[0, 0]]]}), "within"),
        (lambda m: deform.set_grid(m, PANEL, {"positions": [[[0, 0], [0, 9]], [[9, 0], [9, 9]]], "bogus": 1}), "unknown"),
        (lambda m: deform.set_grid(m, PANEL, "{not json"), "JSON"),
        (lambda m: deform.set_grid(m, PANEL, {"positions": [[[0, 0], [9, 0]], [[0, 9], [9, 9]]]}), "folds"),
    ],
)
def test_errors(model, call, message):
    before = copy_model(model)
    with pytest.raises(TpsvError, match=message):
        call(model)
    assert same_model(model, before)


def test_reflection_keeps_a_positive_jacobian(model, base_render):
    new = deform.affine(model, DISC, [-1, 0, 0, 0, 1, 0])
    p = new.regions[DISC].patch
    assert patch.fold_free(p)
    sel = model.features.region == DISC
    assert np.allclose(new.features.st[sel, 0], 1.0 - model.features.st[sel, 0])
    img = render(new, antialias=False)
    i0 = index_of(model)
    ys, xs = np.nonzero(i0 == DISC)
    assert np.abs(img[ys, 43 - xs] - base_render[ys, xs]).mean() < 0.03


def outline_area(p):
    from tpsv.geometry.outline import signed_area

    return signed_area(np.asarray(p, np.float64))


def max_gap(a, b):
    """Farthest vertex of polygon ``a`` from the closed polyline ``b``."""
    a = np.asarray(a, np.float64)
    p, q = np.asarray(b, np.float64), np.roll(np.asarray(b, np.float64), -1, axis=0)
    d = q - p
    w = a[:, None, :] - p[None]
    u = np.clip((w * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0, 1)
    return float(np.hypot(*(w - u[..., None] * d[None]).transpose(2, 0, 1)).min(axis=1).max())


def test_grid_json_round_trip(model, tmp_path):
    doc = deform.grid_to_json(model, BACKGROUND)
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(doc))
    for grid in (doc, json.dumps(doc), str(path)):
        new = deform.set_grid(model, BACKGROUND, grid, keep_order=True)
        assert np.array_equal(new.regions[BACKGROUND].patch.ctrl, model.regions[BACKGROUND].patch.ctrl)
        for a, b in zip(new.regions[BACKGROUND].outline, model.regions[BACKGROUND].outline):
            # the identity map gives the same curve (re-simplified at deform.SIMPLIFY_PX)
            assert abs(outline_area(a) - outline_area(b)) < 0.01 * abs(outline_area(b))
            assert max_gap(a, b) <= deform.SIMPLIFY_PX + 1e-6 and max_gap(b, a) <= deform.SIMPLIFY_PX + 1e-6
    # positions only: derivatives by Catmull-Rom, twist by Adini; a finer grid is fine
    ctrl = model.regions[PANEL].patch.ctrl
    pos = patch.forward(model.regions[PANEL].patch, *np.meshgrid(np.linspace(0, 1, 4), np.linspace(0, 1, 3), indexing="ij"))
    new = deform.set_grid(model, PANEL, {"positions": pos.tolist()})
    assert new.regions[PANEL].patch.shape == (4, 3) and ctrl.shape[:2] == (2, 2)
    assert np.allclose(new.features.st, model.features.st)
    a = render(new, antialias=False)
    b = render(model, antialias=False)
    i0 = index_of(model)
    assert np.abs(a - b)[i0 == PANEL].max() < 2e-3  # the same surface, resampled


def test_round_trip_and_input_untouched(model):
    before = copy_model(model)
    new = deform.move_points(model, [(DISC, 1, 1, 2.5, -1.25)])
    new = deform.affine(new, PANEL, [0.9, 0.1, 0, -0.1, 0.9, 0])
    assert same_model(model, before)
    assert same_model(codec.decode(codec.encode(new)), codec.quantize(new))
    assert isinstance(new.regions[DISC].patch, Patch)


def test_islands_are_carried_along(model):
    assert deform.enclosed_regions(model, [BACKGROUND]) == [DISC]
    assert deform.enclosed_regions(model, [DISC]) == [] and deform.enclosed_regions(model, [PANEL]) == []
    # affine: the disc (an island of the background) gets the same map, exactly
    new = deform.affine(model, BACKGROUND, [1, 0, 3, 0, 1, 2])
    assert np.array_equal(new.regions[DISC].patch.ctrl[..., 0, :], model.regions[DISC].patch.ctrl[..., 0, :] + (3, 2))
    assert draw_order(new)[:2] == [DISC, BACKGROUND]
    alone = deform.affine(model, BACKGROUND, [1, 0, 3, 0, 1, 2], attach=False)
    assert np.array_equal(alone.regions[DISC].patch.ctrl, model.regions[DISC].patch.ctrl)
    # a control-point move: the island follows the background's map; its features stay on the content
    from tpsv.edit.common import feature_xy

    moved = deform.move_points(model, [(BACKGROUND, 1, 0, 4.0, 3.0), (BACKGROUND, 1, 1, 4.0, 3.0)])
    phi = deform.patch_mapper(model.regions[BACKGROUND].patch, moved.regions[BACKGROUND].patch)
    sel = model.features.region == DISC
    want = phi(feature_xy(model)[sel])
    got = feature_xy(moved)[sel]
    assert np.abs(want - feature_xy(model)[sel]).max() > 1.0  # the disc really moved
    assert np.abs(got - want).max() < 0.25
    for p, q in zip(model.regions[DISC].outline, moved.regions[DISC].outline):
        assert patch.fold_free(moved.regions[DISC].patch)
        # the outline's area centroid (its vertices' mean depends on where they were kept)
        assert abs(centroid(q) - centroid(phi(p))).max() < 0.5


def test_outlines_too_long_are_refused_before_any_work():
    """A hostile zig-zag outline (a few kB in a file) once cost 5.8 GB and 51 s."""
    import copy

    from tpsv.edit import deform as df

    m = copy.deepcopy(scene_model())
    n = 4000
    zig = np.column_stack([np.linspace(1, m.width - 1, n), np.where(np.arange(n) % 2 == 0, 1.0, m.height - 1.0)])
    m.regions[0].outline = [zig] + list(m.regions[0].outline[1:])
    with pytest.raises(TpsvError, match="outlines too long to deform"):
        df.affine(m, 1, [[1.1, 0, 0], [0, 1.1, 0]])


def test_a_region_too_long_to_deform_is_refused_before_any_work():
    """Fuzz finding (seed 100): a 100k-vertex outline of the deformed region took 25 s."""
    import copy

    m = copy.deepcopy(scene_model())
    n = 3000
    # a comb inside the canvas: long (n * height px) but within the whole-model budget of a big canvas
    m.width = m.height = 4096
    comb = np.column_stack([np.repeat(np.linspace(1, 4000, n // 2), 2),
                            np.tile([1.0, 200.0, 200.0, 1.0], n // 4)])
    m.regions[DISC].outline = [comb]
    with pytest.raises(TpsvError, match="outlines to deform are too long"):
        deform.affine(m, DISC, [[1.1, 0, 0], [0, 1.1, 0]])


def test_piecewise_simplification_stays_within_tolerance():
    """Douglas-Peucker runs in pieces (a 10^5-point zig-zag took 10 s): every input point stays within tol."""
    import cv2

    rng = np.random.default_rng(3)
    t = np.linspace(0, 2 * np.pi, 5000, endpoint=False)
    poly = np.column_stack([100 + 60 * np.cos(t), 100 + 40 * np.sin(t)]) + rng.normal(0, 0.02, (len(t), 2))
    tol = 1.0 / 16
    out = deform._approx(poly, tol)
    assert len(out) < len(poly) / 4
    # output points are input points (float32-rounded), in order, and the first is kept
    assert np.abs(out[0] - poly[0]).max() < 1e-4

    def worst(simple):  # farthest input point from the simplified closed polyline
        a, b = simple, np.roll(simple, -1, axis=0)
        d = b - a
        w = poly[:, None, :] - a[None]
        u = np.clip((w * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0, 1)
        return np.hypot(*(w - u[..., None] * d[None]).transpose(2, 0, 1)).min(axis=1).max()

    # Douglas-Peucker bounds the distance to each chord's line; to its segment
    # a noisy point may lie a little farther: as far as one whole-polygon pass goes
    whole = cv2.approxPolyDP(poly.reshape(-1, 1, 2).astype(np.float32), tol, True).reshape(-1, 2)
    assert worst(out) <= max(worst(whole), tol) + 0.02


def test_mapper_jacobian_matches_finite_differences():
    ctrl = affine_grid(5, 5)
    old = Patch(ctrl=ctrl.copy())
    bent = ctrl.copy()
    bent[2, 2, 0] += (4.0, -3.0)
    moved = np.zeros((5, 5), bool)
    moved[2, 2] = True
    new = Patch(ctrl=deform.refresh_derivatives(bent, moved))
    phi = deform.patch_mapper(old, new)
    xy = old.ctrl[1:4, 1:4, 0, :].reshape(-1, 2) + 0.3
    got, J = phi.with_jacobian(xy)
    assert np.allclose(got, phi(xy), atol=1e-9)
    h = 1e-4
    fd = np.stack([(phi(xy + (h, 0)) - phi(xy - (h, 0))) / (2 * h),
                   (phi(xy + (0, h)) - phi(xy - (0, h))) / (2 * h)], axis=-1)
    assert np.abs(J - fd).max() < 1e-5


def test_inverse_on_a_large_bent_grid_starts_near_and_converges():
    """The walk once started from the corners' guess: hundreds of steps on a 256-wide grid."""
    M = N = 64
    ctrl = affine_grid(M, N)
    rng = np.random.default_rng(0)
    moved = np.zeros((M, N), bool)
    moved[::7, ::5] = True
    bent = ctrl.copy()
    bent[moved, 0, :] += rng.uniform(-2, 2, (moved.sum(), 2))
    p = Patch(ctrl=deform.refresh_derivatives(bent, moved))
    assert patch.fold_free(p)
    st = rng.uniform(0, [M - 1, N - 1], (2000, 2))
    xy = patch.forward(p, st[:, 0], st[:, 1])
    back = patch.inverse(p, xy)
    assert np.abs(patch.forward(p, back[:, 0], back[:, 1]) - xy).max() < 1e-6
