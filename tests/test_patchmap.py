"""The Warp inverse map agrees with tpsv.geometry.patch.inverse."""

import numpy as np
import pytest

from tpsv.model import Patch
from tpsv.geometry.outline import rasterize_regions, trace_outline
from tpsv.geometry.patch import adini_twist, build_patch, inverse, normalize


@pytest.fixture(scope="module")
def pm():
    from tpsv.gpu import patchmap

    # compile once per session (tiny launch)
    p = build_patch(np.ones((4, 4), bool))
    patchmap.inverse_map_numpy([p], np.zeros((2, 2), np.int32), (4, 4))
    return patchmap


def _scene():
    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    lab = np.zeros((h, w), np.int32)
    d = np.hypot(xx - 24, yy - 24)
    lab[(d < 18) & (d > 7)] = 1
    lab[d <= 7] = 2
    lab[(xx > 44) & (yy > 10)] = 3
    lab[3, 60] = 4
    masks = [lab == k for k in range(5)]
    patches = [build_patch(m, trace_outline(m)) for m in masks]
    # bend the ring's patch
    ctrl = build_patch(masks[1], grid=(4, 4)).ctrl.copy()
    ctrl[1, 2, 0] += [2.5, -1.5]
    ctrl[2, 1, 1] *= 1.15
    ctrl[..., 3, :] = adini_twist(ctrl)
    patches[1] = Patch(ctrl=ctrl)
    outlines = [trace_outline(m) for m in masks]
    return lab, patches, outlines


def _reference(patches, idx, src):
    H, W = idx.shape
    Y, X = np.mgrid[0:H, 0:W]
    xy = np.stack([(X + 0.5) * src[0] / W, (Y + 0.5) * src[1] / H], -1)
    out = np.zeros((H, W, 2))
    for k, p in enumerate(patches):
        sel = idx == k
        out[sel] = normalize(p, inverse(p, xy[sel]))
    return out


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_warp_matches_numpy(pm, scale):
    lab, patches, outlines = _scene()
    h, w = lab.shape
    W, H = int(w * scale), int(h * scale)
    idx = rasterize_regions(outlines, W, H, (w, h))
    got = pm.inverse_map_numpy(patches, idx, (w, h), device="cpu")
    assert got.shape == (H, W, 2) and got.dtype == np.float32
    ref = _reference(patches, idx, (w, h))
    assert np.abs(got - ref).max() < 1e-4  # measured ~1e-7


def test_device_array_and_points(pm):
    lab, patches, outlines = _scene()
    wp = pm.wp
    idx = lab.astype(np.int32)
    arr = pm.inverse_map(patches, idx, (lab.shape[1], lab.shape[0]), device="cpu")
    assert isinstance(arr, wp.array) and arr.shape == lab.shape
    rng = np.random.default_rng(0)
    reg = rng.integers(0, 5, 200).astype(np.int32)
    xy = rng.uniform(0, 40, (200, 2))
    st = pm.inverse_points(patches, reg, xy, device="cpu")
    ref = np.stack([normalize(patches[r], inverse(patches[r], q)) for r, q in zip(reg, xy)])
    assert np.abs(st - ref).max() < 1e-4
    # negative index: (-1, -1)
    idx2 = idx.copy()
    idx2[0, 0] = -1
    got = pm.inverse_map_numpy(patches, idx2, (lab.shape[1], lab.shape[0]))
    assert np.allclose(got[0, 0], -1)


def test_patch_set_built_with_a_cache_is_the_same():
    """A cached build flattens only new patches and uploads the same arrays."""
    from conftest import rect_patch
    from tpsv.gpu import patchmap as pm

    a, b = rect_patch(0, 0, 20, 10), rect_patch(20, 0, 15, 10, M=4)
    moved = rect_patch(21, 1, 15, 10, M=4)
    cache = {}
    for patches in ([a, b], [a, b], [a, moved]):
        plain = pm.PatchSet.build(patches)
        cached = pm.PatchSet.build(patches, cache=cache)
        for field in ("pos", "coef", "reg_i", "reg_f"):
            assert np.array_equal(getattr(plain.arrays, field).numpy(), getattr(cached.arrays, field).numpy())
        assert len(cache) == 2
