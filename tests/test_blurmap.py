"""The blur map: an edge width per point of the borders (format version 7)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.test_codec import assert_models_identical, grid_ctrl, patch_header, reject, with_quantized
from tpsv import codec
from tpsv.codec import layout, quant
from tpsv.encode.vectorize import build_geometry, soften_false_steps
from tpsv.geometry.edgewidth import FALSE_SHARE, FALSE_STEP, FLAT_SIGMA, MAP_CELL, border_cells, false_steps, fill_map
from tpsv.gpu.coverage import DeviceBorders
from tpsv.model import BlurMap, Features, Model, Patch, Region
from tpsv.rendering.borders import Borders, blur_at
from tpsv.rendering.pixelmap import region_index


def halves(width: int = 32, height: int = 32) -> Model:
    """Two regions meeting along ``x = width / 2``, no features."""
    h = width / 2
    regions = [
        Region(label=0, outline=[np.array([[0, 0], [h, 0], [h, height], [0, height]], np.float64)],
               patch=Patch(grid_ctrl(2, 2, 0, 0, h, height))),
        Region(label=1, outline=[np.array([[h, 0], [width, 0], [width, height], [h, height]], np.float64)],
               patch=Patch(grid_ctrl(2, 2, h, 0, h, height))),
    ]
    return Model(width=width, height=height, regions=regions, features=Features.empty())


def with_map(model: Model, top: float, bottom: float, cell: int = 4) -> Model:
    """``model`` with a blur map of width ``top`` over its upper half and ``bottom`` over its lower half."""
    gh, gw = -(-model.height // cell), -(-model.width // cell)
    sigma = np.full((gh, gw), top, np.float32)
    sigma[gh // 2:] = bottom
    return dataclasses.replace(model, blur_map=BlurMap(cell=cell, sigma=sigma))


def test_border_cells_follow_the_shared_border_only():
    m = halves()
    cells = border_cells(m.regions, m.width, m.height, 4)
    gw = 8
    # x = 16 lies on the line between cell columns 3 and 4: the points fall in column 4 (floor)
    assert sorted(cells.tolist()) == [i * gw + 4 for i in range(8)]
    # frame edges are no border
    assert border_cells(m.regions[:1], m.width, m.height, 4).size == 0


def test_fill_map_fills_two_rings_around_the_stored_cells():
    bm = fill_map(16, 8, 4, np.array([0, 3]), np.array([1.0, 2.0], np.float32))
    assert bm.sigma.shape == (2, 4) and bm.sigma.dtype == np.float32
    assert bm.sigma.tolist() == [[1.0, 1.0, 2.0, 2.0], [1.0, 1.0, 2.0, 2.0]]
    # a cell between two stored ones takes their mean; beyond two rings nothing is read: 0
    assert fill_map(12, 4, 4, np.array([0, 2]), np.array([1.0, 2.0])).sigma.tolist() == [[1.0, 1.5, 2.0]]
    assert fill_map(32, 4, 4, np.array([0]), np.array([1.0])).sigma.tolist() == [[1.0, 1.0, 1.0] + [0.0] * 5]


def test_blur_at_is_bilinear_between_cell_centres():
    bmap = (np.array([[0.0, 4.0]]), 2.0, 2.0)
    assert blur_at(bmap, np.array([1.0, 2.0, 3.0, 0.0, 9.0]), np.zeros(5)).tolist() == [0.0, 2.0, 4.0, 0.0, 4.0]


def test_a_flat_stretch_is_blurred_and_a_step_keeps_its_width():
    """A label map cuts the picture in two: along the left half the cut follows a red/green step, along
    the right half it crosses a flat grey area. The map is wide over the flat stretch only."""
    n = 64
    rgb = np.empty((n, n, 3), np.float32)
    rgb[:32, :32] = (0.8, 0.1, 0.1)
    rgb[32:, :32] = (0.1, 0.7, 0.2)
    rgb[:, 32:] = 0.5
    labels = np.zeros((n, n), np.int32)
    labels[32:] = 1
    g = build_geometry(labels, rgb)
    assert g.blur_map is not None and g.blur_map.cell == MAP_CELL
    bmap = (np.asarray(g.blur_map.sigma, np.float64), float(MAP_CELL), float(MAP_CELL))
    step = blur_at(bmap, np.array([8.0, 16.0]), np.array([32.0, 32.0]))
    flat = blur_at(bmap, np.array([48.0, 56.0]), np.array([32.0, 32.0]))
    assert (step < 0.5).all(), step
    assert (flat >= FLAT_SIGMA).all(), flat


def test_false_steps_are_vector_steps_the_photo_does_not_share():
    v = np.array([[0.3, 0.0, 0.0]] * 5 + [[0.05, 0.0, 0.0]])
    photo = np.array([[0.3, 0.0, 0.0],  # the same step: a true edge
                      [0.6, 0.1, 0.0],  # a larger one along it: the vector undershoots, no seam
                      [0.0, 0.2, 0.0],  # a step across it only
                      [0.1, 0.0, 0.0],  # a third of it
                      [-0.3, 0.0, 0.0],  # the other way
                      [0.0, 0.0, 0.0]])  # a vector step too small to matter
    assert false_steps(photo, v).tolist() == [False, False, True, True, True, False]
    # the limits themselves
    assert false_steps(np.array([[FALSE_SHARE * FALSE_STEP, 0, 0]]), np.array([[FALSE_STEP, 0, 0]])).tolist() == [False]
    assert false_steps(np.array([[0.0, 0, 0]]), np.array([[FALSE_STEP, 0, 0]])).tolist() == [True]


def strip_picture(n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """``n x n``: dark left, grey right, a label map cut at x = 32, and a white strip 6 px wide along
    the cut on the left over the middle rows (the tests below)."""
    rgb = np.full((n, n, 3), 0.15, np.float32)
    rgb[:, 32:] = 0.6
    rgb[20:44, 26:32] = 1.0
    labels = np.zeros((n, n), np.int32)
    labels[:, 32:] = 1
    return rgb, labels


#: Rows where :func:`cut_widths` samples the map: above the strip, along it, below it.
CUT_ROWS = np.array([4.0, 8.0, 28.0, 32.0, 36.0, 56.0, 60.0])


def cut_widths(blur_map) -> np.ndarray:
    """The map's widths along the strip picture's cut (x = 32) at :data:`CUT_ROWS`."""
    return blur_at((np.asarray(blur_map.sigma, np.float64), float(MAP_CELL), float(MAP_CELL)),
                   np.full(CUT_ROWS.size, 32.0), CUT_ROWS)


def test_a_border_the_vector_image_steps_across_alone_is_softened():
    """A label map cuts the picture in two at x = 32: dark left, grey right, a sharp step. Over the
    middle rows a white strip 6 px wide runs along the cut on the left, so there the photo steps down
    (white to grey), sharply too, while a vector image that cannot hold the strip steps up (dark to
    grey). Those cells get FLAT_SIGMA; the rows where the photo steps as the vector image does keep
    their sharp reading."""
    n = 64
    rgb, labels = strip_picture(n)
    g = build_geometry(labels, rgb)
    read = cut_widths(g.blur_map)
    assert (read < 0.5).all(), read  # from the photo alone: sharp steps all along
    shown = np.where(np.arange(n)[None, :, None] < 32, 0.15, 0.6) * np.ones((n, n, 3))  # the strip left out
    wide = soften_false_steps(rgb, g, shown.astype(np.float32))
    assert wide is not None and wide.cell == MAP_CELL
    sigma = cut_widths(wide)
    assert (sigma[[0, 1, 5, 6]] < 0.5).all(), sigma  # the true step stays sharp
    # the strip's rows are softened: cells along it raised to FLAT_SIGMA (where most points of their
    # 3 x 3 block are false steps), the sample on the border between two columns of cells their mean
    assert (sigma[[2, 3, 4]] >= 1.0).all(), sigma
    assert wide.sigma[3:5].max() == FLAT_SIGMA
    # a vector image that holds the strip steps as the photo does: nothing to soften
    assert soften_false_steps(rgb, g, rgb) is None


def test_the_renderer_follows_the_map_along_one_border():
    """One border, sharp over its upper half and 2 px wide over its lower half: at 8x the upper rows mix
    about one pixel, the lower ones many; host and device agree."""
    m = with_map(halves(), 0.0, 2.0)
    W = H = 256
    index = region_index(m, W, H)
    host = Borders(m, W, H).mix(index)
    dev = DeviceBorders(m, W, H).mix(index)
    order = np.argsort(host.pixels)  # (the host lists the pixels next to a border first)
    assert np.array_equal(host.pixels[order], dev.pixels) and np.array_equal(host.other[order], dev.other)
    assert np.abs(host.alpha[order] - dev.alpha).max() < 1e-5
    rows = host.pixels // W
    mixed_per_row = np.bincount(rows, minlength=H)
    assert mixed_per_row[:96].max() <= 2  # sharp: the one pixel each side of x = 128
    assert mixed_per_row[160:].min() >= 40  # 2 px at 8x: 16 output px; three of them each side
    # the width changes along the border, not as a step: rows around the middle go in between
    middle = mixed_per_row[112:144]
    assert np.all(np.diff(middle) >= 0) and middle[0] < middle[-1]


def test_without_a_map_the_pairs_widths_hold():
    m = dataclasses.replace(halves(), blur=np.array([[0.0, 1.0, 2.0]]))
    W = H = 256
    index = region_index(m, W, H)
    even = with_map(halves(), 2.0, 2.0)
    a, b = Borders(m, W, H).mix(index), Borders(even, W, H).mix(index)
    assert np.array_equal(a.pixels, b.pixels) and np.abs(a.alpha - b.alpha).max() < 1e-6


def test_blur_map_round_trips_exactly():
    m = with_map(halves(), 0.5, 1.25)
    data = codec.encode(m)
    h = layout.parse_header(data)
    assert h.version == layout.VERSION and h.has_blur_map
    back = codec.decode(data)
    assert_models_identical(codec.quantize(m), back)
    # the cells along the border as they were, two rings around them filled, no more
    assert np.array_equal(back.blur_map.sigma[:, 4], m.blur_map.sigma[:, 4])
    assert back.blur_map.sigma[:, 2:7].min() >= 0.5 and back.blur_map.sigma[:, [0, 1, 7]].max() == 0
    assert codec.encode(back) == data
    # a model without a map writes no flag
    assert not layout.parse_header(codec.encode(halves())).has_blur_map


def test_only_the_border_cells_are_stored():
    m = with_map(halves(), 0.5, 1.25)
    q = quant.from_model(m)
    assert q.map_cell == 4 and len(q.map_values) == 8
    assert q.map_values.tolist() == [8] * 4 + [20] * 4


@pytest.mark.parametrize("change, message", [
    (dict(map_values=np.zeros(3, np.uint8)), "blur map: 3 widths for the 8 cells"),
    (dict(map_values=np.zeros(9, np.uint8)), "blur map: 9 widths for the 8 cells"),
    (dict(map_cell=1), "map_cell = 1 not in 2..64"),
    (dict(map_cell=65), "map_cell = 65 not in 2..64"),
])
def test_hostile_blur_maps_are_refused(change, message):
    reject(with_quantized(with_map(halves(), 0.5, 1.25), **change), message)


def test_a_map_without_its_flag_or_a_flag_without_its_map_is_refused():
    data = codec.encode(with_map(halves(), 0.5, 1.25))
    reject(patch_header(data, flags=layout.parse_header(data).flags & ~layout.FLAG_BLUR_MAP), "unknown key")
    plain = codec.encode(halves())
    reject(patch_header(plain, flags=layout.parse_header(plain).flags | layout.FLAG_BLUR_MAP), "missing key")
    reject(patch_header(data, version=6), "unsupported flags")


def test_a_border_moved_off_the_map_reads_its_new_cells():
    """An edit that moves outlines keeps the map: the stored cells are those the borders pass through
    now, and the file holds the map's widths there."""
    m = with_map(halves(), 0.5, 1.25)
    moved = dataclasses.replace(m, regions=[
        dataclasses.replace(r, outline=[p + [4.0, 0.0] * (p[:, 0:1] > 0) * (p[:, 0:1] < 32)])
        for r in m.regions for p in r.outline[:1]
    ])
    back = codec.decode(codec.encode(moved))
    assert back.blur_map.sigma.shape == m.blur_map.sigma.shape
    assert back.blur_map.sigma[:4, 5].tolist() == [0.5] * 4 and back.blur_map.sigma[4:, 5].tolist() == [1.25] * 4
    # no shared border at all: nothing stored, the map decodes to zeros
    apart = dataclasses.replace(m, regions=m.regions[:1])
    assert len(quant.from_model(apart).map_values) == 0
    assert not codec.decode(codec.encode(apart)).blur_map.sigma.any()


def test_info_reports_the_map(tmp_path):
    import json

    from click.testing import CliRunner

    from tpsv.cli import main

    path = tmp_path / "m.tpsv"
    path.write_bytes(codec.encode(with_map(halves(), 0.5, 1.25)))
    r = CliRunner().invoke(main, ["info", "--json", str(path)])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["blur_map"] == {"cell": 4, "cells": 8, "min": 0.5, "max": 1.25}
    r = CliRunner().invoke(main, ["info", str(path)])
    assert "blur map  8 cells of 4 px along the borders, edge width 0.5-1.25 px" in r.stdout


def test_borders_are_clipped_to_the_picture():
    """A shared edge running far outside the picture marks only the cells it crosses inside it."""
    m = halves()
    far = [dataclasses.replace(r, outline=[np.where(r.outline[0] == 32.0, 32.0, r.outline[0])
                                           + np.where(r.outline[0][:, 1:] == 32.0, [0.0, 1e6], 0.0)])
           for r in m.regions]
    cells = border_cells(far, m.width, m.height, 4)
    assert sorted(cells.tolist()) == [i * 8 + 4 for i in range(8)]


def test_borders_too_long_to_map_are_refused(monkeypatch):
    from tpsv.geometry import edgewidth

    data = codec.encode(with_map(halves(), 0.5, 1.25))
    monkeypatch.setattr(edgewidth, "MAX_MAP_POINTS", 10)
    reject(data, "blur map: the borders need 65 points to map, more than 10")
    # the encoder then keeps one width per pair
    n = 64
    rgb = np.full((n, n, 3), 0.5, np.float32)
    labels = np.zeros((n, n), np.int32)
    labels[32:] = 1
    assert build_geometry(labels, rgb).blur_map is None


def test_deform_carries_the_widths_with_the_border():
    """A region moved 16 px takes its border's widths along: the moved border reads them where it is now
    (the map held none there before), and the map is what the file will hold."""
    from tpsv.edit.deform import affine

    m = halves(64, 32)
    cells = border_cells(m.regions, 64, 32, 4)
    m = dataclasses.replace(m, blur_map=fill_map(64, 32, 4, cells, np.full(len(cells), 1.25, np.float32)))
    grid = (m.blur_map.sigma.astype(np.float64), 4.0, 4.0)
    assert blur_at(grid, np.array([48.0]), np.array([16.0]))[0] == 0.0  # no width where the border goes
    moved = affine(m, 1, [[1, 0, 16], [0, 1, 0]])
    assert m.blur_map.sigma[:, 12].max() == 0.0  # the caller's model is left alone
    x = max(p[:, 0].max() for p in moved.regions[0].outline)
    assert x == 48.0
    grid = (moved.blur_map.sigma.astype(np.float64), 4.0, 4.0)
    assert np.allclose(blur_at(grid, np.full(5, x), np.linspace(2.0, 30.0, 5)), 1.25)
    assert codec.decode(codec.encode(moved)).blur_map == moved.blur_map


def test_gradient_magnitude_in_bands_is_scipys_sobel_of_the_whole_picture():
    """OpenCV's Sobel over bands of rows (each read with a row either side) gives SciPy's values of
    the whole picture, exactly for 8-bit samples (several bands here) and within 1e-15 for any floats."""
    from scipy import ndimage

    from tpsv.geometry.edgewidth import gradient_magnitude

    def reference(rgb):
        grad = np.zeros(rgb.shape[:2])
        for k in range(3):
            channel = rgb[..., k].astype(np.float64)
            grad += ndimage.sobel(channel, 0) ** 2 + ndimage.sobel(channel, 1) ** 2
        return np.sqrt(grad) / 8.0

    rng = np.random.default_rng(5)
    picture = (rng.integers(0, 256, (301, 400, 3)) / 255).astype(np.float32)  # 120 400 px: two bands
    assert np.array_equal(gradient_magnitude(picture), reference(picture))
    floats = rng.random((9, 13, 3))
    assert np.abs(gradient_magnitude(floats) - reference(floats)).max() < 1e-15


def test_a_grid_of_sharp_squares_reads_sharp_borders():
    """On borders a few pixels long most points lie near a crossing, whose other borders' gradients
    pulled the reading off the outline (a sharp border read as misplaced, 0.5 px soft): there only
    points whose border runs on both ways are read."""
    from tpsv.geometry.edgewidth import edge_widths
    from tpsv.geometry.regions import build_regions

    n, side = 8, 8
    labels = ((np.arange(n * side)[:, None] // side) * n + np.arange(n * side)[None, :] // side).astype(np.int32)
    colours = np.random.default_rng(0).integers(30, 230, (n * n, 3)) / 255.0
    rgb = colours[labels].astype(np.float32)
    regions, index = build_regions(labels, rgb=rgb)
    assert np.array_equal(index, labels)
    assert len(edge_widths(rgb, regions, index)) == 0  # every border sharp


def test_the_encoder_softens_the_borders_its_vector_base_steps_across_alone():
    """Encoded with its texture (the default), the strip picture keeps a sharp border where the photo
    steps and gets a soft one along the strip, which the vector base cannot hold (a 6 px strip under its
    lattice); without the texture the widths are the photo's alone."""
    from tpsv.encode.rate import encode_quality

    rgb, labels = strip_picture()
    with_detail = cut_widths(encode_quality(rgb, labels).model.blur_map)
    assert (with_detail[[0, 1, 5, 6]] < 0.5).all() and (with_detail[[2, 3, 4]] > 1.0).all(), with_detail
    assert (cut_widths(encode_quality(rgb, labels, detail=False).model.blur_map) < 0.5).all()
