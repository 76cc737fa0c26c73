"""Incremental rebuild (tpsv.rendering.live): only kernels whose features changed are solved, results bit-identical."""

from __future__ import annotations

import numpy as np
import pytest

from editfixtures import DISC, PANEL, photo_model, scene_model
from tpsv.edit import crossmap, deform, recolor
from tpsv import tps
from tpsv.gpu import tps as gtps
from tpsv.rendering.live import LiveImage, kernel_keys, same_grouping
from tpsv.rendering.raster import render


@pytest.fixture(scope="module")
def model():
    return scene_model()


def kernels_holding(ks, changed: np.ndarray) -> int:
    """Kernels with at least one active slot on a changed feature."""
    idx = ks.index
    hit = np.where(idx >= 0, changed[np.maximum(idx, 0)], False)
    return int(hit.any(axis=1).sum())


def test_initial_build_equals_render(model):
    live = LiveImage(model)
    assert np.array_equal(live.image, render(model))
    assert live.stats.solved == live.stats.kernels == tps.group_kernels(model).n_kernels


def test_recolor_rebuilds_only_touched_kernels(model):
    live = LiveImage(model)
    new = recolor.recolor(model, region=DISC, hue=90)
    st = live.update(new)
    changed = (new.features.lab != model.features.lab).any(axis=1)
    assert changed.any()
    assert not st.regrouped and not st.geometry
    assert st.solved == kernels_holding(live.kernels, changed)
    assert 0 < st.solved < st.kernels
    assert 0 < st.pixels < model.width * model.height
    assert np.array_equal(live.image, render(new))
    # the reused kernel set is the one a full grouping gives
    full = tps.group_kernels(new)
    for name in ("index", "count", "frame", "lab", "fill", "grid"):
        assert np.array_equal(getattr(full, name), getattr(live.kernels, name)), name


def test_timed_updates_split_their_stages_and_draw_the_same(model):
    """A timed LiveImage reports each stage of an update; an untimed one (the default: its stages are not
    synchronised apart) only the total, and its pictures are the same."""
    new = deform.affine(model, PANEL, [[1, 0, 3], [0, 1, 2]])
    plain, timed = LiveImage(model), LiveImage(model, timed=True)
    a, b = plain.update(new), timed.update(new)
    assert set(a.seconds) == {"total"} and a.seconds["total"] > 0
    stages = {"geometry", "group", "match", "solve", "rasterise", "borders", "detail"}
    assert set(b.seconds) == stages | {"total"}
    assert sum(b.seconds[k] for k in stages) <= b.seconds["total"]
    assert (a.solved, a.pixels, a.geometry) == (b.solved, b.pixels, b.geometry)
    assert np.array_equal(plain.image, timed.image)
    assert np.array_equal(plain.image, render(new))


def test_noop_update_rebuilds_nothing(model):
    live = LiveImage(model)
    before = live.image
    st = live.update(recolor.recolor(model, region=DISC, lightness=0.0, hue=0.0))
    assert st.solved == 0 and st.pixels == 0
    assert np.array_equal(live.image, before)


def test_chain_of_edits_bit_identical_at_scale_2(model):
    live = LiveImage(model, scale=2)
    m = model
    steps = [
        lambda m: recolor.recolor(m, region=PANEL, shift_ab=(-30, 10)),
        lambda m: deform.affine(m, DISC, [1, 0, 5, 0, 1, -3]),
        lambda m: deform.move_points(m, [(PANEL, 0, 0, -3, 2)]),
        lambda m: crossmap.crossmap(m, PANEL, m, DISC),
        lambda m: recolor.recolor(m, at=(40, 30), tolerance=30, hue=-40),
    ]
    for step in steps:
        m = step(m)
        st = live.update(m)
        assert np.array_equal(live.image, render(m, scale=2)), st
    assert live.image.shape == (2 * model.height, 2 * model.width, 3)


def test_deform_translation_reuses_every_kernel(model):
    live = LiveImage(model)
    new = deform.affine(model, DISC, [1, 0, 4, 0, 1, 0])
    st = live.update(new)
    # a translation keeps every kernel's frame and features, and the patches' pixel scales: no regrouping
    assert st.geometry and st.solved == 0 and not st.regrouped
    assert np.array_equal(live.image, render(new))
    # a scaling changes the pixel scales: the features are grouped again
    bigger = deform.affine(new, DISC, [1.25, 0, 0, 0, 1.25, 0])
    assert not same_grouping(new, bigger)
    st = live.update(bigger)
    assert st.regrouped and np.array_equal(live.image, render(bigger))


def test_photo_recolor_counts():
    m = photo_model()
    live = LiveImage(m)
    new = recolor.recolor(m, at=(30, 20), radius=8, tolerance=15, lightness=25)
    st = live.update(new)
    changed = (new.features.lab != m.features.lab).any(axis=1)
    assert st.solved == kernels_holding(live.kernels, changed) < st.kernels
    assert np.array_equal(live.image, render(new))


def test_solve_reusing_matches_full_solve(model):
    ks = tps.group_kernels(model)
    full = gtps.solve(gtps.upload(ks))
    half = np.where(np.arange(ks.n_kernels) % 2 == 0, np.arange(ks.n_kernels), -1)
    dk, solved = gtps.solve_reusing(ks, full, half)
    assert solved == int((half < 0).sum())
    for a, b in zip(gtps.coefficients(full), gtps.coefficients(dk)):
        assert np.array_equal(a, b)
    # keys identify identical systems
    keys = kernel_keys(ks)
    assert len({k.tobytes() for k in keys}) <= ks.n_kernels
    assert np.array_equal(keys, kernel_keys(tps.group_kernels(model)))


def host_dirty(index, st, ks, stale, near):
    """Reference: the dirty pixels (flat bool) as numpy finds them (float32 cell, as the blend)."""
    index = index.ravel()
    out = np.zeros(index.size, bool)
    inside = index >= 0
    out[inside] = stale[index[inside]]
    cand = inside & ~out & (ks.grid[np.maximum(index, 0), 0] != 0)
    pi = np.flatnonzero(cand)
    r = index[pi]
    s = st.reshape(-1, 2)[pi]
    gx, gy = ks.grid[r, 0], ks.grid[r, 1]
    a = np.clip(s[:, 0], np.float32(0), np.float32(1)).astype(np.float32) * gx.astype(np.float32)
    b = np.clip(s[:, 1], np.float32(0), np.float32(1)).astype(np.float32) * gy.astype(np.float32)
    ix = np.clip(np.floor(a).astype(np.int64), 0, gx - 1)
    iy = np.clip(np.floor(b).astype(np.int64), 0, gy - 1)
    out[pi] = near[ks.grid[r, 2] + iy * gx + ix]
    return out


def test_rasterise_dirty_draws_exactly_the_dirty_pixels():
    import warp as wp
    from tpsv.gpu.rasterise import rasterise_dirty
    from tpsv.rendering.pixelmap import pixel_map

    m = photo_model()
    ks = tps.group_kernels(m)
    dk = gtps.solve(gtps.upload(ks))
    pm = pixel_map(m, m.width, m.height, "cpu")
    full = gtps.rasterise(dk, pm.index_d, pm.st_d).numpy()
    rng = np.random.default_rng(3)
    R = ks.grid.shape[0]
    stale = np.zeros(R, bool)
    stale[rng.integers(R)] = True
    near = rng.random(ks.n_kernels) < 0.2
    changed = rng.random(m.width * m.height) < 0.01
    for ch in (None, changed):
        out = wp.full((m.height, m.width), wp.vec3f(-1.0, -1.0, -1.0), dtype=wp.vec3f, device="cpu")
        n = rasterise_dirty(dk, pm.index_d, pm.st_d, out, stale, near, ch)
        want = host_dirty(pm.index, pm.st, ks, stale, near)
        if ch is not None:
            want |= ch
        got = out.numpy().reshape(-1, 3)
        drawn = (got != -1.0).any(axis=1)
        assert 0 < n == int(want.sum()) < want.size
        assert np.array_equal(drawn, want)
        assert np.array_equal(got[want], full.reshape(-1, 3)[want])


def test_edge_widths_and_curves_alone_are_drawn_again():
    """An update that changes only the borders' edge widths (``blur``, ``blur_map``) or only whether the
    outlines are drawn as curves keeps no stale border pixels: the image is ``render``'s (both kept
    the old borders until 2026-11-27, up to 0.16 apart on a photo's model)."""
    from dataclasses import replace

    from tpsv.model import BlurMap

    m = photo_model()
    live = LiveImage(m)
    soft = m.blur.copy()
    soft[:, 2] = soft[:, 2] * 3 + 1.0
    steps = [replace(m, blur=soft),
             replace(m, blur=soft, blur_map=BlurMap(cell=8, sigma=np.full((-(-m.height // 8), -(-m.width // 8)), 2.0,
                                                                          np.float32))),
             replace(m, curves=not m.curves)]
    for new in steps:
        before = live.image
        st = live.update(new)
        assert not st.regrouped and st.solved == 0
        assert np.array_equal(live.image, render(new))
        assert not np.array_equal(live.image, before)
