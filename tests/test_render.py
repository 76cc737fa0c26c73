"""render: model -> pixels (outline membership, patch map, kernels, blend)."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from tpsv import tps
from tpsv.color import lab_to_srgb, srgb_to_lab
from tpsv.edit import deform
from tpsv.encode import fit
from tpsv.errors import TpsvError
from tpsv.geometry import outline
from tpsv.rendering import raster as render
from tpsv.rendering.pixelmap import region_index
from tpsv.model import Features, Model, Params, Region

from conftest import rect_patch


def rect_model(rects, feats, width, height, **params) -> Model:
    """Regions = rectangles (x0, y0, w, h); feats = list of (region, xy pixels (n, 2), lab (n, 3))."""
    regions = []
    for i, (x0, y0, w, h) in enumerate(rects):
        poly = np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]], float)
        regions.append(Region(i, [poly], rect_patch(x0, y0, w, h)))
    reg, st, lab = [], [], []
    for r, xy, v in feats:
        x0, y0, w, h = rects[r]
        reg.append(np.full(len(xy), r, np.int32))
        st.append((np.asarray(xy, float) - [x0, y0]) / [w, h])
        lab.append(np.asarray(v, np.float32))
    n = sum(len(r) for r in reg)
    F = Features(
        np.concatenate(reg) if reg else np.zeros(0, np.int32),
        np.concatenate(st) if st else np.zeros((0, 2)),
        np.concatenate(lab) if lab else np.zeros((0, 3), np.float32),
        np.zeros(n, np.uint8),
        np.full(n, -1, np.int32),
    )
    # the kernel size and overlap these tests were written for (the paper's), whatever Params() defaults to
    return Model(width, height, regions, F, Params(**{"kernel_size": 64, "overlap": 0.5, **params}))


def field_rgb(x, y):
    """A smooth sRGB field."""
    return np.stack(
        [0.5 + 0.35 * np.sin(x / 11.0) * np.cos(y / 13.0), 0.5 + 0.3 * np.cos((x + y) / 17.0), 0.45 + 0.3 * np.sin(y / 9.0)],
        axis=-1,
    )


def grid_feats(x0, y0, w, h, step=2.0):
    xs = np.arange(x0 + step / 2, x0 + w, step)
    ys = np.arange(y0 + step / 2, y0 + h, step)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    return xy, srgb_to_lab(field_rgb(xy[:, 0], xy[:, 1]))


def psnr(a, b):
    return -10 * np.log10(np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2))


# --------------------------------------------------------------------------- sizes


def test_output_size():
    m = rect_model([(0, 0, 40, 30)], [], 40, 30)
    assert render.output_size(m) == (40, 30)
    assert render.output_size(m, scale=2.5) == (100, 75)
    assert render.output_size(m, width=80) == (80, 60)
    assert render.output_size(m, height=15) == (20, 15)
    assert render.output_size(m, width=7, height=9) == (7, 9)
    for kw in (
        dict(scale=0),
        dict(scale=-1),
        dict(scale=float("nan")),
        dict(scale=float("inf")),
        dict(scale="x"),
        dict(width=0, height=5),
        dict(width=-3),
        dict(width=2.5),
        dict(width=render.MAX_SIDE + 1, height=1),
        dict(scale=1000),
        dict(scale=2, width=10),
        dict(scale=0.001),
    ):
        with pytest.raises(TpsvError):
            render.output_size(m, **kw)


def test_render_rejects_bad_sizes():
    m = rect_model([(0, 0, 40, 30)], [], 40, 30)
    with pytest.raises(TpsvError):
        render.render(m, scale=0)
    with pytest.raises(TpsvError):
        render.render(m, width=20000, height=10)


# --------------------------------------------------------------------------- fidelity


@pytest.fixture(scope="module")
def smooth_model():
    rects = [(0, 0, 32, 48), (32, 0, 32, 48)]
    feats = [(r, *grid_feats(*rects[r])) for r in range(2)]
    return rect_model(rects, feats, 64, 48, kernel_size=32)


def test_smooth_field_reproduced(smooth_model):
    img = render.render(smooth_model)
    assert img.shape == (48, 64, 3) and img.dtype == np.float32
    assert img.min() >= 0 and img.max() <= 1
    yy, xx = np.mgrid[0:48, 0:64] + 0.5
    truth = field_rgb(xx, yy)
    assert psnr(img, truth) > 40
    assert np.abs(img - truth).max() < 0.03


def test_magnified_smooth_field(smooth_model):
    img = render.render(smooth_model, scale=3)
    assert img.shape == (144, 192, 3)
    yy, xx = (np.mgrid[0:144, 0:192] + 0.5) / 3
    assert psnr(img, field_rgb(xx, yy)) > 40


def _seam_model(overlap):
    rng = np.random.default_rng(3)
    xy = rng.random((1600, 2)) * [96, 64]
    lab = srgb_to_lab(field_rgb(xy[:, 0], xy[:, 1])) + rng.normal(0, 3, (1600, 3)).astype(np.float32)
    return rect_model([(0, 0, 96, 64)], [(0, xy, lab)], 96, 64, kernel_size=32, overlap=overlap)


def _border_jumps(img, ks, scale):
    """Horizontal and vertical neighbour jumps straddling sub-patch borders, and all others."""
    gx, gy, _ = ks.grid[0]
    H, W = img.shape[:2]
    dx = np.abs(np.diff(img, axis=1)).max(-1)  # between x and x+1
    dy = np.abs(np.diff(img, axis=0)).max(-1)
    bx = np.zeros(W - 1, bool)
    by = np.zeros(H - 1, bool)
    for i in range(1, gx):
        X = i * W / gx  # border position in output pixels
        bx[int(np.floor(X - 0.5))] = True  # pixel centres x+0.5 < X < x+1.5
    for j in range(1, gy):
        Y = j * H / gy
        by[int(np.floor(Y - 0.5))] = True
    border = np.concatenate([dx[:, bx].ravel(), dy[by, :].ravel()])
    inner = np.concatenate([dx[:, ~bx].ravel(), dy[~by, :].ravel()])
    return border, inner


@pytest.mark.parametrize("overlap", [0.5, 0.25])
def test_no_seam(overlap):
    m = _seam_model(overlap)
    ks = tps.group_kernels(m)
    assert ks.grid[0, 0] >= 3 and ks.grid[0, 1] >= 2
    for scale in (1, 4):
        img = render.render(m, scale=scale, kernels=ks)
        border, inner = _border_jumps(img, ks, scale)
        assert border.max() <= 1.2 * inner.max()
        assert np.median(border) <= 2.0 * np.median(inner)
        assert np.percentile(border, 95) <= 1.5 * np.percentile(inner, 95)


def test_seam_check_is_sensitive():
    """Without blending (overlap 0) the same check sees the seams."""
    m = _seam_model(0.0)
    ks = tps.group_kernels(m)
    img = render.render(m, scale=4, kernels=ks)
    border, inner = _border_jumps(img, ks, 4)
    assert np.percentile(border, 95) > 1.5 * np.percentile(inner, 95)


def test_regions_never_mix():
    rng = np.random.default_rng(5)
    rects = [(0, 0, 30, 40), (30, 0, 26, 40)]
    feats = []
    for r, (x0, y0, w, h) in enumerate(rects):
        xy = rng.random((300, 2)) * [w, h] + [x0, y0]
        feats.append((r, xy, srgb_to_lab(field_rgb(xy[:, 0] * (r + 1), xy[:, 1]))))
    m = rect_model(rects, feats, 56, 40, kernel_size=32)
    for scale in (1, 3):
        a = render.render(m, scale=scale)
        lab = m.features.lab.copy()
        lab[5] = [90.0, -40.0, 60.0]  # a feature of region 0
        lab[17] += 20.0
        m2 = Model(m.width, m.height, m.regions, Features(m.features.region, m.features.st, lab, m.features.kind, m.features.pair), m.params)
        b = render.render(m2, scale=scale)
        W = a.shape[1]
        right = slice(int(np.ceil(30 * scale)), W)
        assert np.array_equal(a[:, right], b[:, right])
        assert not np.array_equal(a[:, : 30 * scale], b[:, : 30 * scale])


def test_region_border_stays_sharp():
    """Two flat regions: at 4x the border is a one-pixel step, with no blending across it."""
    rects = [(0, 0, 20, 16), (20, 0, 12, 16)]
    ca = np.array([30.0, 20.0, -10.0])
    cb = np.array([80.0, -20.0, 40.0])
    feats = [(0, *(lambda xy: (xy, np.tile(ca, (len(xy), 1))))(grid_feats(*rects[0], step=3)[0])),
             (1, *(lambda xy: (xy, np.tile(cb, (len(xy), 1))))(grid_feats(*rects[1], step=3)[0]))]
    m = rect_model(rects, feats, 32, 16, kernel_size=16)
    img = render.render(m, scale=4)
    left = lab_to_srgb(ca)
    right = lab_to_srgb(cb)
    assert np.abs(img[:, :80] - left).max() < 2e-3
    assert np.abs(img[:, 80:] - right).max() < 2e-3


def test_featureless_region_and_empty_model():
    rects = [(0, 0, 20, 16), (20, 0, 12, 16)]
    xy, lab = grid_feats(*rects[0], step=3)
    m = rect_model(rects, [(0, xy, lab)], 32, 16, kernel_size=16)
    img = render.render(m)
    fill = lab_to_srgb(lab.astype(np.float64).mean(0))
    assert np.abs(img[:, 20:] - fill).max() < 2e-3
    assert np.isfinite(img).all()
    empty = rect_model(rects, [], 32, 16)
    img = render.render(empty, scale=2)
    assert img.shape == (32, 64, 3)
    assert np.abs(img - lab_to_srgb(np.array([50.0, 0, 0]))).max() < 2e-3


def test_deterministic(smooth_model):
    a = render.render(smooth_model, scale=2)
    b = render.render(smooth_model, scale=2)
    c = render.render(smooth_model, scale=2, threads=1)
    assert np.array_equal(a, b) and np.array_equal(a, c)


def test_render_timed(smooth_model):
    img, t = render.render_timed(smooth_model, scale=1, repeat=1)
    assert img.shape == (48, 64, 3)
    for key in ("regions", "patchmap", "group", "upload", "solve", "rasterise", "download", "total"):
        assert key in t and t[key] >= 0


def test_kept_on_the_device_is_the_downloaded_render(smooth_model):
    img = render.render(smooth_model, scale=1.7)
    frame = render.render(smooth_model, scale=1.7, keep_on_device=True)
    assert frame.device.is_cpu and frame.shape == img.shape[:2]
    assert np.array_equal(frame.numpy().reshape(img.shape), img)
    with pytest.raises(TpsvError, match="keep_on_device"):
        render.render(smooth_model, alpha=True, keep_on_device=True)


def test_kernels_grouped_once_render_as_fresh_ones(smooth_model):
    ks = tps.group_kernels(smooth_model)
    for scale in (1, 2.5):
        assert np.array_equal(render.render(smooth_model, scale=scale, kernels=ks), render.render(smooth_model, scale=scale))


def test_kernels_must_match_model(smooth_model):
    other = rect_model([(0, 0, 10, 10)], [], 10, 10)
    ks = tps.group_kernels(other)
    with pytest.raises(TpsvError):
        render.render(smooth_model, kernels=ks)


def test_range_clamp():
    """Close pairs across a step make the TPS overshoot; the clamp keeps every kernel in its range."""
    from tpsv.gpu import tps as gtps

    rng = np.random.default_rng(11)
    t = np.arange(0.5, 48)
    a = np.column_stack([t, 16.0 - 0.5 + 0 * t])
    b = np.column_stack([t, 16.0 + 0.5 + 0 * t])
    g = rng.random((40, 2)) * [48, 32]
    xy = np.vstack([a, b, g])
    lab = np.vstack([np.tile([20.0, 30, 0], (48, 1)), np.tile([80.0, -30, 40], (48, 1)),
                     np.where(g[:, 1:] < 16, [20.0, 30, 0], [80.0, -30, 40])]) + rng.normal(0, 2, (136, 3))
    m = rect_model([(0, 0, 48, 32)], [(0, xy, lab)], 48, 32, kernel_size=32)
    ks = tps.group_kernels(m)
    yy, xx = np.mgrid[0:128, 0:192] + 0.5
    st = np.stack([xx / 192, yy / 128], -1).astype(np.float32)
    reg = np.zeros((128, 192), np.int32)
    raw = gtps.render_arrays(ks, reg, st, mode=gtps.MODE_LAB, clamp=False)
    cl = gtps.render_arrays(ks, reg, st, mode=gtps.MODE_LAB, clamp=True)
    lo, hi = ks.lab.min(0), ks.lab.max(0)
    assert (raw < lo - 1).any() or (raw > hi + 1).any()  # the plain TPS overshoots here
    assert (cl >= lo - 1e-3).all() and (cl <= hi + 1e-3).all()
    # where no kernel clamps, both agree
    same = np.abs(cl - raw).max(-1) < 1e-6
    assert same.mean() > 0.1
    # still continuous: no jump larger than the step between the two sides allows
    assert np.abs(np.diff(cl, axis=1)).max() < 20


def test_fit_sees_the_rendered_pixels_of_a_deformed_model(smooth_model):
    """Overlapping regions after a deform: the fit's pixel maps follow the draw order, so the
    fit's design matrix predicts the render at every pixel."""
    m = deform.affine(smooth_model, 1, [1, 0, -10, 0, 1, 0])  # region 1 slides over region 0, on top
    index, st = fit.pixel_maps(m)
    plain = outline.rasterize_regions(m.regions, m.width, m.height, src_size=(m.width, m.height))
    assert ((plain == 0) & (index == 1)).sum() > 100  # pixels that only the draw order gives to region 1
    assert np.array_equal(index, region_index(m, m.width, m.height))
    ks = tps.group_kernels(m)
    inside = index.ravel() >= 0
    des, _ = fit.build_design(ks, index.ravel()[inside], st.reshape(-1, 2)[inside].astype(np.float64))
    predicted = lab_to_srgb(des.forward(ks.lab.astype(np.float64)))
    rendered = render.render(m, clamp=False).reshape(-1, 3)[inside]
    assert np.abs(predicted - rendered).max() < 1e-3


def test_a_renderer_prepared_once_renders_as_render_at_every_size(smooth_model):
    r = render.Renderer(smooth_model)
    for kwargs in ({"scale": 1}, {"scale": 2.5}, {"scale": 2.5}, {"width": 37, "height": 101}, {"scale": 3, "antialias": False}):
        assert np.array_equal(r.render(**kwargs), render.render(smooth_model, **kwargs)), kwargs
    frame = r.render(scale=2, keep_on_device=True)
    assert np.array_equal(frame.numpy().reshape(96, 128, 3), render.render(smooth_model, scale=2))
    assert r.render(alpha=True).shape == (48, 64, 4)


def test_a_renderer_puts_the_patches_on_the_device_once(smooth_model, monkeypatch):
    """The patches do not depend on the output size: one upload per model, shared by the pixel
    map and the border pixels (each frame built them twice before)."""
    from tpsv.gpu import patchmap

    built = []
    real = patchmap.PatchSet.build.__func__
    monkeypatch.setattr(patchmap.PatchSet, "build", classmethod(lambda cls, *a, **k: built.append(1) or real(cls, *a, **k)))
    r = render.Renderer(smooth_model)
    for scale in (1, 2.5, 3):
        r.render(scale=scale)
    assert len(built) == 1
    render.render(smooth_model, scale=2)
    assert len(built) == 2


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork only")
def test_a_forked_child_renders(smooth_model, every_band):
    """CPU launches share a pool of host threads; a forked child (the fuzzing runner, a
    batch worker) has none of its threads and must make its own instead of waiting forever."""
    before = render.render(smooth_model, scale=2, threads=2)  # in bands (every_band)
    pid = os.fork()
    if pid == 0:  # the child: killed by the alarm if it hangs
        signal.alarm(60)
        same = np.array_equal(render.render(smooth_model, scale=2, threads=2), before)
        os._exit(0 if same else 3)
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0


def test_renders_from_several_threads_at_once_are_one_threads():
    """Callers rendering from several threads of one process get each model's own render: the CPU
    device's tile solve (one static scratch block in Warp) runs one at a time (before, two solves at once
    crashed the process)."""
    import threading

    from conftest import small_sample
    from tpsv.rendering.magnify import dense_model

    models = [dense_model(small_sample(width=w))[0] for w in (40, 48, 56, 64)]
    want = [render.render(m) for m in models]
    got = [[None] * 3 for _ in models]

    def work(i):
        for k in range(3):
            got[i][k] = render.render(models[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(models))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(np.array_equal(g, w) for gs, w in zip(got, want) for g in gs)
