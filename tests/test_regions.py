"""Regions of a label map; points between pixel space and patch space (tpsv.geometry.regions)."""

from __future__ import annotations

import numpy as np
import pytest

from tpsv.edit.common import feature_xy
from tpsv.errors import TpsvError
from tpsv.geometry import subpixel
from tpsv.geometry.regions import build_regions, region_borders, to_patch_space, to_pixel_space
from tpsv.model import GRADATION, Features, Model


def two_labels(h=24, w=32):
    labels = np.zeros((h, w), np.int32)
    labels[4:12, 3:14] = 3
    labels[15:22, 20:30] = 3  # the same label, not connected
    labels[0:3, 25:] = 5
    return labels


def test_build_regions_splits_disconnected_labels_and_rasterises_them():
    labels = two_labels()
    regions, index = build_regions(labels)
    assert sorted(r.label for r in regions) == [0, 3, 3, 5]
    assert index.shape == labels.shape
    assert np.array_equal(np.array([r.label for r in regions])[index], labels)  # pixel-aligned shapes
    assert len(np.unique(index[labels == 3])) == 2


def test_build_regions_keeps_a_single_pixel_region():
    labels = np.zeros((9, 9), np.int32)
    labels[4, 4] = 1
    regions, index = build_regions(labels)
    assert len(regions) == 2 and (index == index[4, 4]).sum() == 1


def test_build_regions_needs_a_region():
    with pytest.raises(TpsvError):
        build_regions(np.zeros((0, 0), np.int32))


def test_patch_space_round_trip_at_pixel_centres():
    regions, index = build_regions(two_labels())
    patches = [r.patch for r in regions]
    h, w = index.shape
    yy, xx = np.mgrid[:h, :w]
    xy = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], 1)
    region = index.ravel()
    st = to_patch_space(patches, xy, region)
    assert np.all((st >= 0) & (st <= 1))
    assert np.abs(to_pixel_space(patches, region, st) - xy).max() < 1e-6


def test_feature_positions_are_computed_once():
    """edit.common.feature_xy and the lattice's feature positions are to_pixel_space."""
    from tpsv.color import srgb_to_lab
    from tpsv.encode.vectorize import build_geometry

    labels = two_labels()
    regions, _ = build_regions(labels)
    rng = np.random.default_rng(2)
    n = 40
    f = Features(region=np.sort(rng.integers(0, len(regions), n)).astype(np.int32), st=rng.random((n, 2)),
                 lab=np.zeros((n, 3), np.float32), kind=np.full(n, GRADATION, np.uint8), pair=np.full(n, -1, np.int32))
    model = Model(width=labels.shape[1], height=labels.shape[0], regions=regions, features=f)
    patches = [r.patch for r in regions]
    assert np.array_equal(feature_xy(model), to_pixel_space(patches, f.region, f.st))
    g = build_geometry(labels)
    rgb = rng.random(labels.shape + (3,)).astype(np.float32)
    fs = g.lattice(srgb_to_lab(rgb)).features(5.0)
    assert np.array_equal(fs.xy, to_pixel_space([r.patch for r in g.regions], fs.region, fs.st))


def test_region_borders_marks_both_sides():
    index = np.array([[0, 0, 1],
                      [0, 2, 1],
                      [0, 0, 0]])
    want = np.array([[0, 1, 1],
                     [1, 1, 1],
                     [0, 1, 1]], bool)
    assert np.array_equal(region_borders(index), want)
    assert not region_borders(np.zeros((3, 4), int)).any()


def test_membership_smoothing_is_scipys_gaussian():
    """The fitted outlines' smoothing (OpenCV's separable filter) gives scipy's gaussian_filter, nearest
    edges, to rounding: the outlines do not depend on which library smoothed them."""
    from scipy import ndimage

    from tpsv.geometry.subpixel import SMOOTH_SIGMA, _gaussian

    m = (np.random.default_rng(2).random((61, 47)) > 0.5).astype(np.float64)
    for sigma in (SMOOTH_SIGMA, 1.3):
        assert np.abs(_gaussian(m, sigma) - ndimage.gaussian_filter(m, sigma, mode="nearest")).max() < 1e-12


def test_four_regions_meeting_crosswise_share_the_pixel_corner():
    """Where four regions meet crosswise (a grid) the fitted outlines all pass through the pixel
    corner, with no point of their own near it (the diagonal pair's contours used to cut across
    the saddle each their own way: a notch and a slanted border when magnified)."""
    labels = np.zeros((32, 32), np.int32)
    labels[:16, 16:], labels[16:, :16], labels[16:, 16:] = 1, 2, 3
    colours = np.array([[0.8, 0.25, 0.15], [0.15, 0.35, 0.85], [0.25, 0.8, 0.25], [0.9, 0.85, 0.25]], np.float32)
    rgb = colours[labels]
    regions, index = build_regions(labels, rgb=rgb)
    assert np.array_equal(index, labels)
    for r in regions:
        pts = np.concatenate(r.outline)
        at = np.abs(pts - 16.0).max(axis=1)
        assert (at == 0).sum() == 1, (r.label, pts[at < 1].tolist())  # the corner, once
        assert not ((at > 0) & (at <= subpixel.CROSSING)).any(), pts[at < 1].tolist()


def _frames_and_bar():
    """Nested frames of flat colours crossed by a bar 2 px wide (columns 23-24), and its label map."""
    labels = np.zeros((48, 48), np.int32)
    labels[6:42, 6:42] = 1
    labels[12:36, 12:36] = 2
    labels[18:30, 18:30] = 3
    labels[2:46, 23:25] = 4
    colours = np.array([[0.94, 0.94, 0.9], [0.16, 0.35, 0.78], [0.9, 0.7, 0.16], [0.98, 0.98, 0.98],
                        [0.78, 0.12, 0.16]], np.float32)
    return labels, colours[labels]


def test_a_bar_two_pixels_wide_keeps_straight_sides_through_its_junctions():
    """The curves coming into a junction are straight lines up to where the contour turns: around a
    bar 2 px wide the contour turns back within the reach of the lines, and a line through the
    turn put every junction of the bar 0.3-0.6 px inside it (a bar pinched at each crossing and a
    square cut slanted, at 8x)."""
    labels, rgb = _frames_and_bar()
    regions, index = build_regions(labels, rgb=rgb)
    assert np.array_equal(np.array([r.label for r in regions])[index], labels)
    step = 1.0 / subpixel.GRID
    bar = [r for r in regions if r.label == 4][0]
    pts = np.concatenate(bar.outline)
    side = (pts[:, 1] >= 4.0) & (pts[:, 1] <= 44.0)
    # on its pixel edges, junctions included (their lines' crossing, 0.04 px off, is put on the pixel corner)
    assert (np.minimum(np.abs(pts[side, 0] - 23.0), np.abs(pts[side, 0] - 25.0)) <= 1e-9).all(), pts.tolist()
    # its ends square: the caps' corners (a cap 2 px wide has no straight run for the corner test)
    for corner in ((23.0, 2.0), (25.0, 2.0), (23.0, 46.0), (25.0, 46.0)):
        assert np.hypot(*(pts - corner).T).min() <= step, (corner, pts.tolist())
    # the halves of the centre square: their corners and the junctions with the bar on the pixel corners
    for r in regions:
        if r.label == 3:
            box = np.concatenate(r.outline)
            x0, x1 = (18.0, 23.0) if box[:, 0].min() < 20 else (25.0, 30.0)
            for corner in ((x0, 18.0), (x1, 18.0), (x0, 30.0), (x1, 30.0)):
                assert np.hypot(*(box - corner).T).min() <= 1e-9, (corner, box.tolist())


def test_squares_between_one_pixel_lines_keep_their_pixel_outlines():
    """A line one pixel wide between two regions is read against both: its pixels used to say nothing
    of the second border, which the smoothed mask put 0.2 px into the line (squares of a grid grew,
    rounded, into their gutters)."""
    from tpsv.bench.drawings import grid_labels

    labels = grid_labels(4)
    colours = np.random.default_rng(3).uniform(0.0, 1.0, (17, 3)).astype(np.float32)
    regions, index = build_regions(labels, rgb=colours[labels])
    assert np.array_equal(index, labels)
    for r in regions:
        if r.label == 0:
            continue
        (ys, xs), = [np.nonzero(labels == r.label)]
        square = np.array([[xs.min(), ys.min()], [xs.max() + 1, ys.min()], [xs.max() + 1, ys.max() + 1],
                           [xs.min(), ys.max() + 1]], np.float64)
        pts = r.outline[0]
        assert len(r.outline) == 1
        # every vertex on the square's sides, and its four corners among them
        on_side = np.minimum(np.abs(pts[:, :1] - square[[0, 1], 0]).min(axis=1),
                             np.abs(pts[:, 1:] - square[[0, 2], 1]).min(axis=1))
        assert on_side.max() <= 1e-9, (r.label, pts.tolist())
        for corner in square:
            assert np.hypot(*(pts - corner).T).min() <= 1e-9, (r.label, corner, pts.tolist())


def test_incoming_lines_stop_where_a_precise_contour_turns_back():
    u_turn = np.array([[23.0, 42.5], [23.0, 43.5], [23.0, 44.5], [23.0, 45.5], [23.5, 46.0], [24.5, 46.0],
                       [25.0, 45.5], [25.0, 44.5]])
    assert subpixel._incoming(u_turn, True) == 4
    # a border the label map places wavers on its own: it keeps every point within the reach
    assert subpixel._incoming(u_turn, False) == 5  # 2 JUNCTION px along it
    straight = np.stack([np.zeros(10), np.arange(10.0)], axis=1)
    assert subpixel._incoming(straight, True) == 2 * subpixel.JUNCTION + 1


@pytest.mark.parametrize("width", [1, 2, 3, 4])
def test_the_ends_of_bars_are_square(width):
    """A bar of flat colour 1-4 px wide ends in two corners of the pixel lattice, not in a round blob."""
    labels = np.zeros((24, 24), np.int32)
    labels[4:20, 10:10 + width] = 1
    rgb = np.array([[0.95, 0.93, 0.9], [0.2, 0.25, 0.6]], np.float32)[labels]
    regions, _ = build_regions(labels, rgb=rgb)
    pts = np.concatenate([r for r in regions if r.label == 1][0].outline)
    for corner in ((10.0, 4.0), (10.0 + width, 4.0), (10.0, 20.0), (10.0 + width, 20.0)):
        assert np.hypot(*(pts - corner).T).min() <= 1.0 / subpixel.GRID, (corner, pts.tolist())


def test_a_staircase_keeps_its_cuts():
    """Steps of a staircase go the same way on both sides of a cut: no cap, the cuts stay (a diagonal
    of pixels is read as the slanted border it stands for)."""
    stairs = np.array([[0.0, 0.5], [0.0, 1.5], [0.0, 2.5], [0.5, 3.0], [1.5, 3.0], [2.0, 3.5], [2.0, 4.5],
                       [2.0, 5.5], [6.0, 5.5], [6.0, 0.5]])
    assert subpixel._caps(stairs, np.zeros(len(stairs)), subpixel.TOLERANCE) == []


def _wave(noise: float, seed: int = 0):
    """Two regions of 64 x 64 split by the wave ``y = 32 + 6 sin(2 pi x / 40)``, anti-aliased (4 x 4
    supersampled), with Gaussian noise of ``noise`` (sRGB) on both sides; its label map."""
    yy, xx = (np.mgrid[0:256, 0:256] + 0.5) / 4.0
    below = (yy >= 32.0 + 6.0 * np.sin(2 * np.pi * xx / 40.0)).astype(np.float64)
    cover = below.reshape(64, 4, 64, 4).mean(axis=(1, 3))
    rgb = cover[..., None] * np.array([0.8, 0.3, 0.2]) + (1 - cover[..., None]) * np.array([0.2, 0.4, 0.7])
    rgb = rgb + np.random.default_rng(seed).normal(0.0, noise, rgb.shape)
    return (cover >= 0.5).astype(np.int32), np.clip(rgb, 0.0, 1.0).astype(np.float32)


def test_a_textured_border_is_fitted_with_fewer_vertices_and_a_clean_one_keeps_its_own(monkeypatch):
    """Texture on a border's sides raises its tolerance to the reading's own uncertainty (the
    sides' spread relative to the contrast, at most TEXTURED_TOLERANCE): the noisy wave's border
    keeps fewer vertices, still on the wave, while the clean wave's border is the same."""
    def border(noise, floor):
        monkeypatch.setattr(subpixel, "TEXTURED_TOLERANCE", floor)
        labels, rgb = _wave(noise)
        regions, _ = build_regions(labels, rgb=rgb)
        p = [r for r in regions if r.label == 1][0].outline[0]
        return p[(p[:, 0] > 0) & (p[:, 0] < 64) & (p[:, 1] < 63)]  # the wave, not the frame

    floor = subpixel.TEXTURED_TOLERANCE
    clean = border(0.0, 0.0)
    assert np.array_equal(border(0.0, floor), clean)
    tight, loose = border(0.06, 0.0), border(0.06, floor)
    assert len(loose) < 0.8 * len(tight), (len(loose), len(tight))
    off = loose[:, 1] - (32.0 + 6.0 * np.sin(2 * np.pi * loose[:, 0] / 40.0))
    assert np.abs(off).max() < 0.35, off


def test_the_reading_s_grain_is_the_sides_spread_relative_to_the_contrast():
    """near_grain: about 0 along a clean border, about the noise's spread over the contrast along a
    noisy one, and 1e9 away from any border."""
    for noise, lo, hi in ((0.0, 0.0, 0.01), (0.06, 0.07, 0.3)):
        labels, rgb = _wave(noise)
        reading = subpixel.BorderReading(labels, rgb)
        on = reading.across >= 0
        assert lo <= np.median(reading.near_grain[on]) <= hi, np.median(reading.near_grain[on])
        assert reading.near_grain[0, 0] == np.float32(1e9)
