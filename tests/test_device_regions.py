"""Render step 1 on a Warp device (tpsv.gpu.regions): the same region map as pixelmap.region_index."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from tpsv.edit import deform
from tpsv.errors import TpsvError
from tpsv.geometry import outline
from tpsv.geometry.regions import build_regions
from tpsv.gpu.regions import SEARCH, DeviceOutlines
from tpsv.model import Features, Model, Params, Region
from tpsv.rendering import raster
from tpsv.rendering.pixelmap import FRONT_KEY, region_index
from tpsv.rendering.raster import render

from conftest import rect_patch

SCALES = (1.0, 3.7, 8.0)


def labels_model(labels: np.ndarray, rgb: np.ndarray | None = None) -> Model:
    """A model of the regions of ``labels`` (outlines fitted to ``rgb`` when given), one feature each."""
    regions, _ = build_regions(labels, rgb)
    R = len(regions)
    features = Features(np.arange(R, dtype=np.int32), np.full((R, 2), 0.5), np.full((R, 3), 50.0, np.float32),
                        np.zeros(R, np.uint8), np.full(R, -1, np.int32))
    h, w = labels.shape
    return Model(w, h, regions, features, Params(kernel_size=8))


def blobs(seed: int, w: int = 37, h: int = 29, k: int = 4):
    """Random smooth blobs (junctions, islands, so holes), and their box-filtered colours."""
    rng = np.random.default_rng(seed)
    noise = ndimage.gaussian_filter(rng.normal(size=(k, h * 4, w * 4)), (0, 14, 14))
    lab = noise.argmax(0)
    rgb = rng.uniform(0.05, 0.95, (k, 3))[lab].reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    return lab[2::4, 2::4].astype(np.int32), rgb.astype(np.float32)


def ring_labels(w: int = 31, h: int = 23) -> np.ndarray:
    """A frame around a disc around a dot: regions with holes, nested."""
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    r = np.hypot(xx - w / 2, yy - h / 2)
    lab = np.zeros((h, w), np.int32)
    lab[r < 9] = 1
    lab[r < 5] = 2
    lab[r < 1.6] = 3
    return lab


def size_at(m: Model, scale: float) -> tuple[int, int]:
    return max(1, int(round(m.width * scale))), max(1, int(round(m.height * scale)))


def check(m: Model, W: int, H: int, **kw) -> DeviceOutlines:
    ref = region_index(m, W, H)
    dev = DeviceOutlines(m, W, H, "cpu", **kw)
    got = dev.index()
    assert got.shape == (H, W) and got.dtype == np.int32
    bad = np.argwhere(got != ref)
    assert bad.size == 0, f"{len(bad)} pixels differ at {W}x{H}, first at (y, x) = {tuple(bad[0])}"
    return dev


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("scale", SCALES)
def test_blobs_equal_host(seed, scale):
    """Traced outlines (half-pixel lattice) leave gaps between neighbours: covered and filled pixels match."""
    labels, _ = blobs(seed)
    m = labels_model(labels)
    check(m, *size_at(m, scale))


@pytest.mark.parametrize("seed", range(2))
@pytest.mark.parametrize("scale", SCALES)
def test_fitted_outlines_equal_host(seed, scale):
    """Sub-pixel outlines fitted to the colours (arbitrary float vertices)."""
    labels, rgb = blobs(seed + 10)
    m = labels_model(labels, rgb)
    check(m, *size_at(m, scale))


@pytest.mark.parametrize("scale", SCALES)
def test_holes_equal_host(scale):
    m = labels_model(ring_labels())
    assert any(len(r.outline) > 1 for r in m.regions)
    check(m, *size_at(m, scale))


@pytest.mark.parametrize("size", [(1, 1), (7, 3), (53, 41), (101, 17), (29, 97)])
def test_odd_sizes_equal_host(size):
    """Odd and anisotropic output sizes (each axis scaled on its own)."""
    labels, _ = blobs(5)
    check(labels_model(labels), *size)


@pytest.mark.parametrize("scale", SCALES)
def test_front_order_equal_host(scale):
    """A region moved over its neighbours and drawn first (params.extra["front"]), leaving a hole."""
    labels, _ = blobs(6)
    m = labels_model(labels)
    m = deform.affine(m, len(m.regions) - 1, [1, 0, -4.3, 0, 1, -3.1])
    assert m.params.extra.get(FRONT_KEY)
    W, H = size_at(m, scale)
    plain = outline.rasterize_regions(m.regions, W, H, src_size=(m.width, m.height))
    dev = check(m, W, H)
    assert (plain != dev.index()).any()  # the draw order mattered


def test_coverage_rows_equal_host():
    """The covered pixels alone (before gap filling) are Coverage.rows, -1 where no polygon covers."""
    labels, _ = blobs(7)
    m = labels_model(labels)
    W, H = size_at(m, 3.7)
    dev = DeviceOutlines(m, W, H, "cpu")
    host = outline.Coverage(m.regions, W, H, (m.width, m.height)).rows(0, H)
    assert (host < 0).any()
    assert np.array_equal(dev.coverage_device().numpy(), host)
    assert np.array_equal(dev.coverage_device(5, 40).numpy(), host[5:40])


def test_bands_equal_whole_frame():
    labels, _ = blobs(8)
    m = labels_model(labels)
    W, H = size_at(m, 3.7)
    dev = DeviceOutlines(m, W, H, "cpu")
    whole = dev.index()
    for step in (1, 7, 40):
        parts = [dev.index(a, min(a + step, H)) for a in range(0, H, step)]
        assert np.array_equal(np.concatenate(parts), whole), step


def test_threads_identical(every_band):
    labels, _ = blobs(9)
    m = labels_model(labels)
    W, H = size_at(m, 8.0)
    one = DeviceOutlines(m, W, H, "cpu", threads=1).index()
    two = DeviceOutlines(m, W, H, "cpu", threads=2).index()
    assert np.array_equal(one, two)
    assert np.array_equal(one, region_index(m, W, H))


def sparse_model(w=40, h=30) -> Model:
    """Two small squares far apart: most pixels lie farther than SEARCH from any outline when magnified."""
    boxes = [(2, 2, 4, 3), (30, 22, 5, 5)]
    regions = [Region(i, [np.array([[x, y], [x + bw, y], [x + bw, y + bh], [x, y + bh]], float)],
                      rect_patch(x, y, bw, bh)) for i, (x, y, bw, bh) in enumerate(boxes)]
    features = Features(np.arange(2, dtype=np.int32), np.full((2, 2), 0.5), np.full((2, 3), 50.0, np.float32),
                        np.zeros(2, np.uint8), np.full(2, -1, np.int32))
    return Model(w, h, regions, features, Params(kernel_size=8))


def test_far_gaps_fall_back_to_the_host():
    m = sparse_model()
    W, H = size_at(m, 3.7)
    assert max(W, H) > 4 * SEARCH
    dev = check(m, W, H)
    assert np.array_equal(np.concatenate([dev.index(a, min(a + 25, H)) for a in range(0, H, 25)]), dev.index())


def test_far_gaps_in_bands_equal_the_frame_and_their_memory_is_bounded():
    """A banded render of a canvas mostly far from any outline: the bands are the one-piece render,
    and the host's fill of the far gaps refuses to pass its memory bound (one sentence)."""
    m = sparse_model()
    W, H = size_at(m, 3.7)
    whole = render(m, width=W, height=H)
    bands = [rows for _, rows in raster._bands(m, W, H, "cpu", None, None, True, W * 9)]
    assert np.array_equal(np.concatenate(bands), whole)
    with pytest.raises(TpsvError, match="outside every region than tpsv can fill in bounded memory"):
        DeviceOutlines(m, W, H, "cpu", max_gap_bytes=1000).index(0, 10)


def test_nothing_covered_and_errors():
    # a region too thin to cover any sample point: every pixel takes region 0, as on the host
    thin = Region(0, [np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 0.01]])], rect_patch(0, 0, 40, 1))
    m = sparse_model()
    m.regions = [thin]
    m.features = Features(np.zeros(1, np.int32), np.full((1, 2), 0.5), np.full((1, 3), 50.0, np.float32),
                          np.zeros(1, np.uint8), np.full(1, -1, np.int32))
    check(m, 13, 9)
    dev = DeviceOutlines(sparse_model(), 20, 10, "cpu")
    with pytest.raises(TpsvError, match="band"):
        dev.index(5, 11)
    with pytest.raises(TpsvError, match="empty"):
        DeviceOutlines(sparse_model(), 0, 10, "cpu")
