"""Blurred borders near geometry finer than an output pixel: spikes of an outline, and sliver regions."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tpsv.geometry.regions import build_regions
from tpsv.gpu.coverage import DeviceBorders
from tpsv.model import Features, Model, Params
from tpsv.rendering.borders import Borders, depth, shares
from tpsv.rendering.pixelmap import region_index


def label_model(labels: np.ndarray, sigma: float) -> Model:
    """Regions traced from ``labels``, every touching pair blurred by ``sigma`` model px."""
    regions, _ = build_regions(labels)
    n = len(regions)
    F = 4 * n
    rng = np.random.default_rng(0)
    features = Features(np.repeat(np.arange(n), 4).astype(np.int32), rng.random((F, 2)),
                        (rng.random((F, 3)) * 50).astype(np.float32), np.zeros(F, np.uint8), np.full(F, -1, np.int32))
    m = Model(labels.shape[1], labels.shape[0], regions, features, Params(kernel_size=8))
    m.blur = np.array([[a, b, sigma] for a in range(n) for b in range(a + 1, n)], np.float64)
    return m


def region_shares(mix, index: np.ndarray, n: int) -> np.ndarray:
    """``(H, W, n)``: the share of each region in every pixel, from a border mix."""
    H, W = index.shape
    out = np.zeros((H * W, n))
    out[np.arange(H * W), index.reshape(-1)] = 1.0
    p = mix.pixels
    own = index.reshape(-1)[p]
    out[p, own] = mix.alpha * mix.alpha2
    np.add.at(out, (p, mix.other), (1.0 - mix.alpha) * mix.alpha2)
    two = mix.other2 >= 0
    np.add.at(out, (p[two], mix.other2[two]), 1.0 - mix.alpha2[two])
    return out.reshape(H, W, n)


def test_a_spike_thinner_than_a_pixel_leaves_no_unmixed_wedge():
    """A 1 px spike drawn at a quarter of the size: the pixels about it mix as they do without it."""
    labels = np.zeros((64, 64), np.int32)
    labels[:, 32:] = 1
    plain = label_model(labels, sigma=8.0)
    labels[32, 32:44] = 0  # the spike, 0.25 output px thick (output pixel centres at model rows 30 and 34)
    m = label_model(labels, sigma=8.0)
    idx = region_index(m, 16, 16)
    assert (idx == region_index(plain, 16, 16)).all()  # no pixel centre samples the spike
    ref = region_shares(DeviceBorders(plain, 16, 16).mix(idx), idx, 2)
    for mix in (DeviceBorders(m, 16, 16).mix(idx), Borders(m, 16, 16).mix(idx)):
        s = region_shares(mix, idx, 2)
        # (from 2 px right of the border on; the pixels beside the border measure to the spike's root,
        # and the spike moves the traced border a little)
        assert np.abs(s[:, 10:] - ref[:, 10:]).max() < 0.01
        assert (s[8, 10:14, 0] > 1e-3).all()  # region 0 mixes in along the spike's row, as beside it


@pytest.mark.parametrize("scale", [2, 3])
def test_a_sliver_mixes_both_neighbours_alike_on_both_sides_of_its_middle(scale):
    """A 4 px band between two regions with edges 3 px wide: shares vary smoothly and mirror each other."""
    labels = np.zeros((40, 64), np.int32)
    labels[:, 30:34] = 1
    labels[:, 34:] = 2
    m = label_model(labels, sigma=3.0)
    W, H = 64 * scale, 40 * scale
    idx = region_index(m, W, H)
    row = H // 2
    for mix in (DeviceBorders(m, W, H).mix(idx), Borders(m, W, H).mix(idx)):
        s = region_shares(mix, idx, 3)[row]
        assert (mix.other2 >= 0).any()
        np.testing.assert_allclose(s.sum(-1), 1.0, atol=1e-6)
        # no step between neighbours steeper than the blurred edge's own slope allows
        slope = 1.0 / (3.0 * scale * np.sqrt(2 * np.pi))
        assert np.abs(np.diff(s, axis=0)).max() < 1.3 * slope + 1e-3
        # the band is symmetric: the left neighbour's share mirrors the right one's
        np.testing.assert_allclose(s[:, 0], s[::-1, 2], atol=2e-3)
        # and the band shows: its own share peaks in its middle
        mid = (32 * scale) - 1
        assert s[mid - 1:mid + 2, 1].max() == pytest.approx(s[:, 1].max())


def test_shares_of_a_strip_and_of_a_nested_border():
    """Facing borders: each neighbour takes what its border leaves; one beyond another: the difference."""
    c1, c2 = np.array([0.7]), np.array([0.8])
    a, a2 = shares(c1, c2, np.array([-1.0]))
    own, across, across2 = a * a2, (1 - a) * a2, 1 - a2
    np.testing.assert_allclose([own[0], across[0], across2[0]], [0.5, 0.3, 0.2])
    a, a2 = shares(c1, c2, np.array([1.0]))
    np.testing.assert_allclose([(a * a2)[0], ((1 - a) * a2)[0], (1 - a2)[0]], [0.7, 0.1, 0.2])


@pytest.mark.parametrize("scale", [2, 3])
def test_a_junction_mixes_its_two_neighbours_without_a_seam(scale):
    """Three regions meeting in a T (region 2 below, 0 and 1 above, split at x = 32) with soft edges.
    Below the junction the nearest border switches from 2|0 to 2|1 along x = 32; above it, from 0|2
    to 0|1 along a diagonal. The two regions share alike about the split, and no pixel's shares step
    from one neighbour to the next by more than twice the blurred edge's slope (a quadrant's blurred
    share steps by up to 1.4 slopes diagonally; the sliver rule, which the region across the second
    border took there before, swapped the shares: steps of 0.38, 6 to 9 slopes)."""
    labels = np.full((48, 64), 2, np.int32)
    labels[:24, :32] = 0
    labels[:24, 32:] = 1
    m = label_model(labels, sigma=3.0)
    # the exact T (the traced outlines cut the junction's corners by half a pixel, unevenly)
    rects = ([(0, 0), (32, 0), (32, 24), (0, 24)], [(32, 0), (64, 0), (64, 24), (32, 24)],
             [(0, 24), (64, 24), (64, 48), (0, 48)])
    m.regions = [replace(r, outline=[np.array(q, np.float64)]) for r, q in zip(m.regions, rects)]
    W, H = 64 * scale, 48 * scale
    idx = region_index(m, W, H)
    mid, y = 32 * scale, 24 * scale
    slope = 1.0 / (3.0 * scale * np.sqrt(2 * np.pi))
    for mix in (DeviceBorders(m, W, H).mix(idx), Borders(m, W, H).mix(idx)):
        s = region_shares(mix, idx, 3)
        below = s[y:y + 9 * scale]
        np.testing.assert_allclose(below[:, :mid, 0], below[:, ::-1][:, :mid, 1], atol=1e-5)
        assert np.abs(np.diff(s[y - 9 * scale:y + 9 * scale], axis=1)).max() < 2 * slope
        assert np.abs(np.diff(s[y - 9 * scale:y], axis=0)).max() < 2 * slope


def test_siblings_share_alike_and_a_border_beyond_keeps_the_sliver_rule():
    c1, c2, dot = np.array([0.8]), np.array([0.8]), np.array([1.0])
    a, a2 = shares(c1, c2, dot, nested=np.array([0.0]))
    first, second = ((1 - a) * a2)[0], (1 - a2)[0]
    assert first == pytest.approx(second) and first == pytest.approx(0.1)
    a, a2 = shares(np.array([0.7]), np.array([0.8]), dot, nested=np.array([0.0]))
    np.testing.assert_allclose([((1 - a) * a2)[0], (1 - a2)[0]], [0.2, 0.1])
    # beyond the region across (a sliver): the region across the first border is a strip
    a, a2 = shares(np.array([0.7]), np.array([0.8]), dot, nested=np.array([1.0]))
    np.testing.assert_allclose([((1 - a) * a2)[0], (1 - a2)[0]], [0.1, 0.2])


def test_depth_of_a_second_border():
    f1 = np.array([[10.0, 5.0], [10.0, 5.0], [10.0, 5.0]])
    n1 = np.array([[0.0, 1.0]] * 3)  # across the first border: down
    f2 = np.array([[10.0, 9.0], [14.0, 5.0], [12.0, 5.5]])  # a sliver 4 px deep, a junction, a notch
    np.testing.assert_allclose(depth(f1, f2, n1, 2.0), [1.0, 0.0, 0.25])
