"""Rendering in bands of rows: identical pixels, bounded memory, a streaming PNG, size limits."""

from __future__ import annotations

import tracemalloc
import zlib

import cv2
import numpy as np
import pytest

from tpsv import png
from tpsv.edit import deform
from tpsv.errors import TpsvError
from tpsv.geometry import outline
from tpsv.geometry.regions import build_regions
from tpsv.model import Features, Model, Params, Region
from tpsv.rendering import raster as render
from tpsv.rendering.pixelmap import BandMaps, pixel_map, region_index

from conftest import rect_patch


def traced_model(w=40, h=30, n=7, feats=10, seed=0) -> Model:
    """Regions traced from a Voronoi label map: simplified outlines leave gaps between neighbours."""
    rng = np.random.default_rng(seed)
    pts = rng.random((n, 2)) * (w, h)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    labels = np.argmin((xx[..., None] - pts[:, 0]) ** 2 + (yy[..., None] - pts[:, 1]) ** 2, axis=-1)
    regions, _ = build_regions(labels)
    F = len(regions) * feats
    lab = rng.random((F, 3)) * (100, 60, 60) - (0, 30, 30)
    features = Features(np.repeat(np.arange(len(regions)), feats).astype(np.int32), rng.random((F, 2)),
                        lab.astype(np.float32), np.zeros(F, np.uint8), np.full(F, -1, np.int32))
    return Model(w, h, regions, features, Params(kernel_size=8))


def one_rect_model(w, h) -> Model:
    """One region covering a ``w x h`` canvas, four features."""
    st = np.array([[0.1, 0.1], [0.9, 0.2], [0.2, 0.8], [0.7, 0.9]])
    lab = np.array([[30, 10, 0], [60, -20, 20], [80, 0, -30], [50, 30, 30]], np.float32)
    outline_ = [np.array([[0, 0], [w, 0], [w, h], [0, h]], float)]
    region = Region(0, outline_, rect_patch(0, 0, w, h))
    return Model(w, h, [region], Features(np.zeros(4, np.int32), st, lab, np.zeros(4, np.uint8), np.full(4, -1, np.int32)),
                 Params(kernel_size=8))


def assemble(bands):
    bands = list(bands)
    assert [y0 for y0, _ in bands] == list(np.cumsum([0] + [r.shape[0] for _, r in bands[:-1]]))
    return np.concatenate([r for _, r in bands])


# --------------------------------------------------------------------------- identical pixels


@pytest.fixture(scope="module")
def traced():
    return traced_model()


@pytest.mark.parametrize("size, max_pixels", [((120, 90), 120 * 7 + 5), ((97, 131), 97 * 13), ((40, 30), 40)])
def test_bands_identical_to_one_piece(traced, size, max_pixels):
    W, H = size
    whole = render.render(traced, width=W, height=H)
    maps = BandMaps(traced, W, H)
    # the uncovered pixels are the hard part: make sure there are some
    assert (maps.outlines.coverage_device().numpy() < 0).any()
    floats = assemble(render._bands(traced, W, H, "cpu", None, None, True, max_pixels))
    assert floats.dtype == np.float32 and np.array_equal(floats, whole)
    bands = list(render.render_bands(traced, width=W, height=H, max_pixels=max_pixels))
    assert len(bands) == -(-H // max(1, max_pixels // W))
    assert np.array_equal(assemble(bands), render.to_uint8(whole))


def test_band_maps_equal_pixel_map(traced):
    W, H = 150, 111
    pm = pixel_map(traced, W, H)
    maps = BandMaps(traced, W, H)
    for a, b in ((0, 9), (9, 10), (50, 111)):
        band = maps.band(a, b)
        assert np.array_equal(band.index, pm.index[a:b])
        assert np.array_equal(band.st, pm.st[a:b])


def test_bands_follow_the_draw_order():
    """A region moved over its neighbours (drawn on top) and the hole it leaves: still identical."""
    m = traced_model(seed=3)
    m = deform.affine(m, len(m.regions) - 1, [1, 0, -5.3, 0, 1, -3.1])
    assert m.params.extra.get("front")
    W, H = 100, 75
    plain = outline.rasterize_regions(m.regions, W, H, src_size=(m.width, m.height))
    idx = region_index(m, W, H)
    assert (plain != idx).any()
    maps = BandMaps(m, W, H)
    assert np.array_equal(np.concatenate([maps.index(a, min(a + 8, H)) for a in range(0, H, 8)]), idx)
    whole = render.render(m, width=W, height=H)
    assert np.array_equal(assemble(render._bands(m, W, H, "cpu", None, None, True, W * 6)), whole)


def test_render_assembles_bands_above_the_tile_size(traced, monkeypatch):
    whole = render.render(traced, width=90, height=60)
    monkeypatch.setattr(render, "ONE_PIECE_PIXELS", 90 * 4)
    monkeypatch.setattr(render, "TILE_PIXELS", 90 * 4)
    assert np.array_equal(render.render(traced, width=90, height=60), whole)


# --------------------------------------------------------------------------- coverage and gap fill


def _reference_coverage(regions, width, height, src_size):
    """The fill region by region, as rasterize_regions did it before it filled all regions at once."""
    kx, ky = width / float(src_size[0]), height / float(src_size[1])
    out = np.full((height, width), -1, np.int32)
    for idx, polys in enumerate(regions):
        if not len(polys):
            continue
        outer = polys[0]
        x0 = max(int(np.floor(outer[:, 0].min() * kx - 0.5)) - 1, 0)
        x1 = min(int(np.ceil(outer[:, 0].max() * kx - 0.5)) + 2, width)
        y0 = max(int(np.floor(outer[:, 1].min() * ky - 0.5)) - 1, 0)
        y1 = min(int(np.ceil(outer[:, 1].max() * ky - 0.5)) + 2, height)
        if x1 <= x0 or y1 <= y0:
            continue
        sub = outline._fill_polys((y1 - y0, x1 - x0), list(polys), offset=(x0 / kx, y0 / ky), scale=(kx, ky))
        view = out[y0:y1, x0:x1]
        view[(sub != 0) & (view < 0)] = idx
    return out


def _random_outlines(rng, Ws, Hs):
    regions = []
    for _ in range(rng.integers(1, 12)):
        polys = []
        for k in range(rng.integers(1, 3)):
            n = rng.integers(3, 12)
            c = rng.uniform(-5, [Ws + 5, Hs + 5])
            ang = np.sort(rng.uniform(0, 2 * np.pi, n)) * (1 if k == 0 else -1)
            r = rng.uniform(0.3, 25) * rng.uniform(0.2, 1.0, n)
            p = np.stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)], 1)
            if rng.random() < 0.3:
                p = np.round(p * 2) / 2  # vertices on the half-pixel lattice, as traced outlines
            if rng.random() < 0.2:
                p = rng.uniform(-3, [Ws + 3, Hs + 3], (n, 2))  # self-intersecting
            polys.append(p)
        regions.append(polys)
    return regions


def test_coverage_matches_region_by_region_fill(monkeypatch):
    rng = np.random.default_rng(7)
    # tiny crossing and overlap batches: every chunked path runs
    monkeypatch.setattr(outline, "FILL_CROSSINGS_PER_BAND", 40)
    monkeypatch.setattr(outline, "_OVERLAP_PIXELS", 9)
    for _ in range(60):
        Ws, Hs = rng.integers(5, 50, 2)
        regions = _random_outlines(rng, Ws, Hs)
        W, H = int(rng.integers(1, 90)), int(rng.integers(1, 90))
        ref = _reference_coverage(regions, W, H, (Ws, Hs))
        cov = outline.Coverage(regions, W, H, (Ws, Hs))
        assert np.array_equal(cov.rows(0, H), ref)
        a = int(rng.integers(0, H))
        assert np.array_equal(cov.rows(a, H), ref[a:])


class _Given:
    """A coverage stand-in: rows of a given index map."""

    def __init__(self, index, n_regions=None):
        self.index = index
        self.height, self.width = index.shape
        self.n_regions = int(index.max()) + 1 if n_regions is None else n_regions

    def rows(self, a, b):
        return self.index[a:b].copy()


def test_gap_fill_matches_opencv_distance_transform():
    """Every uncovered pixel gets the label OpenCV's labelled distance transform gives it (ties included)."""
    rng = np.random.default_rng(1)
    for _ in range(150):
        H, W = rng.integers(1, 30, 2)
        missing = rng.random((H, W)) < rng.uniform(0.3, 0.97)
        if missing.all():
            continue
        index = np.where(missing, -1, np.arange(H * W).reshape(H, W)).astype(np.int32)  # a label per pixel
        _, lab = cv2.distanceTransformWithLabels(missing.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
        expected = index.copy()
        expected[missing] = index[~missing][lab[missing] - 1]
        rows = int(rng.integers(1, 8))
        gaps = outline.GapFill(_Given(index), rows)
        got = np.concatenate([gaps.apply(index[a:a + rows].copy(), a) for a in range(0, H, rows)])
        assert np.array_equal(got, expected)


def test_gap_fill_refuses_beyond_its_budget():
    index = np.full((40, 50), -1, np.int32)
    index[0, 0] = 0
    with pytest.raises(TpsvError, match="outside every region"):
        outline.GapFill(_Given(index), 8, max_bytes=1000)
    # nothing covered: every pixel is the first region (none without regions), as rasterize_regions does
    empty = np.full((40, 50), -1, np.int32)
    for n in (0, 3):
        gaps = outline.GapFill(_Given(empty, n), 8)
        assert gaps.n_gap == 2000
        assert (gaps.apply(empty[5:9].copy(), 5) == (0 if n else -1)).all()


# --------------------------------------------------------------------------- memory


def _traced_peak(fn):
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_banded_render_memory_is_bounded(traced):
    """Host memory of a banded render follows the band, not the output (measured, not timed)."""
    W, H = 1200, 900
    frame = W * H * 12  # one float32 RGB image
    render.render(traced, width=8, height=6)  # Warp loaded and compiled before measuring

    def banded():
        for _ in render.render_bands(traced, width=W, height=H, max_pixels=1 << 14):
            pass

    peak = _traced_peak(banded)
    assert peak < frame / 2, peak
    # the measure sees a whole frame made on the host (RGBA: put together from the device's RGB and the alpha)
    assert _traced_peak(lambda: render.render(traced, width=W, height=H, alpha=True)) > frame


def test_huge_canvas_renders_in_bands():
    """A 16384 x 16384 canvas at scale 1: prepared and rendered band by band in bounded memory."""
    m = one_rect_model(16384, 16384)

    def first_bands():
        gen = render.render_bands(m, max_pixels=1 << 16)
        for _ in range(2):
            y0, rows = next(gen)
            assert rows.shape == (4, 16384, 3) and rows.dtype == np.uint8
        gen.close()

    assert _traced_peak(first_bands) < 64 * 2**20  # a float32 image of that canvas: 3 GiB


# --------------------------------------------------------------------------- limits


def test_output_size_limits_are_one_sentence():
    m = one_rect_model(512, 512)
    with pytest.raises(TpsvError) as err:
        render.output_size(m, width=70000, height=70000)
    assert str(err.value) == (f"output 70000x70000 px is larger than tpsv renders "
                              f"(at most {render.MAX_SIDE} px a side, {render.MAX_PIXELS:,} px in all)")
    with pytest.raises(TpsvError, match="output 262144x262144 px is larger than tpsv renders"):
        render.output_size(m, scale=512)
    with pytest.raises(TpsvError, match="larger than tpsv renders"):
        render.output_size(m, scale=1e308)
    assert render.output_size(m, scale=32) == (16384, 16384)
    assert render.MAX_SIDE**2 <= render.MAX_PIXELS


def test_render_refuses_one_array_beyond_its_limit():
    m = one_rect_model(8, 8)
    # refused before anything is allocated: a band-by-band render is the way
    with pytest.raises(TpsvError, match="render_bands"):
        render.render(m, width=8192, height=8192)


def test_render_png_small_is_the_usual_encoder(traced):
    from tpsv.image import encode_png

    data = b"".join(render.render_png(traced, width=60, height=45))
    assert data == encode_png(render.render(traced, width=60, height=45))
    big = b"".join(render.render_png(traced, width=60, height=45, max_pixels=600))
    dec = cv2.imdecode(np.frombuffer(big, np.uint8), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    assert np.array_equal(dec, render.to_uint8(render.render(traced, width=60, height=45)))


# --------------------------------------------------------------------------- streaming PNG


@pytest.mark.parametrize("W, H, cut", [(1, 1, [1]), (5, 3, [1, 2]), (301, 77, [10, 30, 37]), (2000, 40, [40])])
def test_png_writer_output_decodes_to_the_rows(W, H, cut, monkeypatch):
    monkeypatch.setattr(png, "IDAT_BYTES", 1000)  # several IDAT chunks
    rng = np.random.default_rng(W)
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    img[: H // 2] = np.cumsum(rng.integers(0, 3, (H // 2, W, 3)), axis=1).astype(np.uint8)  # smooth part
    bands, y0 = [], 0
    for n in cut:
        bands.append((y0, img[y0:y0 + n]))
        y0 += n
    data = b"".join(png.png_chunks(W, H, bands))
    assert data.startswith(png.SIGNATURE) and data.endswith(b"IEND\xaeB`\x82")
    dec = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(dec[:, :, ::-1], img)


def _idat(data: bytes) -> bytes:
    """The zlib stream of a PNG: its IDAT chunks' data joined."""
    pos, out = 8, []
    while pos < len(data):
        n = int.from_bytes(data[pos:pos + 4], "big")
        if data[pos + 4:pos + 8] == b"IDAT":
            out.append(data[pos + 8:pos + 8 + n])
        pos += 12 + n
    return b"".join(out)


@pytest.mark.parametrize("depth", [8, 16])
def test_png_blocks_join_into_one_stream_whatever_the_threads(depth, monkeypatch):
    """Blocks deflated apart (each primed with the 32 KiB before it) make one zlib stream whose
    Adler-32 zlib checks; the bytes depend on neither the threads nor the bands' cuts."""
    monkeypatch.setattr(png, "BLOCK_BYTES", 5000)  # blocks of a few rows: many joins
    rng = np.random.default_rng(depth)
    H, W = 61, 97
    img = np.cumsum(rng.integers(0, 3, (H, W, 3)), axis=1).astype(np.uint8 if depth == 8 else np.uint16)
    img[40:] = rng.integers(0, 2**depth, (H - 40, W, 3))  # noise: blocks that do not shrink
    files = set()
    for threads, cuts in [(1, [H]), (2, [1, 20, 40]), (3, [7] * 8 + [5]), (8, [30, 31])]:
        out, y0 = [], 0
        w = png.PngWriter(out.append, W, H, depth=depth, threads=threads)
        for n in cuts:
            w.write(img[y0:y0 + n])
            y0 += n
        w.close()
        files.add(b"".join(out))
    assert len(files) == 1
    data = files.pop()
    raw = zlib.decompress(_idat(data))  # checks the combined Adler-32
    px = 3 * (depth // 8)
    rows = np.frombuffer(raw, np.uint8).reshape(H, W * px + 1)
    assert (rows[:, 0] == 1).all()  # filter Sub on every row
    sub = rows[:, 1:].astype(np.int64)
    for x in range(px, W * px):
        sub[:, x] = (sub[:, x] + sub[:, x - px]) % 256
    back = sub.astype(np.uint8)
    want = img.astype(">u2").view(np.uint8) if depth == 16 else img
    assert np.array_equal(back, want.reshape(H, -1))
    dec = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(dec[:, :, ::-1], img)


def test_png_writer_memory_follows_its_blocks_not_the_image(monkeypatch):
    """Blocks in flight are bounded (two a thread): writing a 4096 x 4096 image band by band holds its
    band and a few blocks, not the image (measured, not timed)."""
    monkeypatch.setattr(png, "BLOCK_BYTES", 1 << 17)
    W, H, band = 4096, 4096, 128
    rows = np.random.default_rng(1).integers(0, 256, (band, W, 3), dtype=np.uint8)

    def write():
        w = png.PngWriter(lambda b: None, W, H, threads=2)
        for _ in range(H // band):
            w.write(rows)
        w.close()

    assert _traced_peak(write) < W * H * 3 / 4


@pytest.mark.parametrize("depth", [8, 16])
def test_bands_rounded_on_the_device_as_the_host_rounds(depth):
    """The device's rounding of a band (float64 product, half to even, clipped) is the host's, value for
    value, at the halves between levels and their neighbours and outside [0, 1]."""
    from tpsv.gpu import warp
    from tpsv.gpu.quantize import to_uint
    from tpsv.image import to_uint8, to_uint16

    top = 2**depth - 1
    halves = ((np.arange(0, top, max(1, top // 600)) + 0.5) / top).astype(np.float32)
    v = np.concatenate([halves, np.nextafter(halves, np.float32(1)), np.nextafter(halves, np.float32(0)),
                        np.float32([-0.1, 1.2, 0.0, 1.0, 1e-12, 1 - 1e-7]),
                        np.random.default_rng(depth).random(3000, np.float32)])
    v = np.resize(v, (len(v) // 21 + 1) * 21 * 3).reshape(-1, 21, 3)
    frame = warp().array(v, dtype=warp().vec3f, device="cpu")
    got = to_uint(frame, depth, threads=2).numpy()
    assert got.dtype == (np.uint8 if depth == 8 else np.uint16)
    assert np.array_equal(got, (to_uint8 if depth == 8 else to_uint16)(v))


def test_device_kernels_are_whole_before_their_first_launch():
    """No kernel of ``tpsv.gpu`` is made at a launch: a generic kernel has its overloads declared at
    import, and launching ``to_uint`` at both depths leaves its module's hash as it was. An overload made
    at a first launch from two host threads at once (the bands of a large render) raced in Warp's module
    hash (a KeyError in about one fresh process in four)."""
    import importlib
    import pkgutil

    import tpsv.gpu
    from tpsv.gpu import warp
    from tpsv.gpu import quantize

    wp = warp()
    kernels = []
    for info in pkgutil.iter_modules(tpsv.gpu.__path__):
        mod = importlib.import_module(f"tpsv.gpu.{info.name}")
        kernels += [k for k in vars(mod).values() if isinstance(k, wp.Kernel)]
    assert len(kernels) > 30
    assert all(k.overloads for k in kernels if k.is_generic)
    module = quantize._to_uint.module
    before = module.get_module_hash()
    frame = wp.array(np.full((64, 5, 3), 0.5, np.float32), dtype=wp.vec3f, device="cpu")
    for depth in (8, 16):
        quantize.to_uint(frame, depth, threads=4)
    assert module.get_module_hash() == before


def test_png_adler32_combine_and_header():
    rng = np.random.default_rng(0)
    data = rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes() + b"\xff" * 70_000
    for cut in (0, 1, 65520, 65521, 100_000, len(data)):
        a, b = data[:cut], data[cut:]
        assert png._adler32_combine(zlib.adler32(a), zlib.adler32(b), len(b)) == zlib.adler32(data)
    for level in range(10):
        assert png._zlib_header(level) == zlib.compress(b"x", level)[:2]


def test_png_writer_refuses_wrong_rows():
    out = []
    w = png.PngWriter(out.append, 4, 2)
    with pytest.raises(TpsvError):
        w.write(np.zeros((1, 5, 3), np.uint8))
    with pytest.raises(TpsvError):
        w.write(np.zeros((1, 4, 3), np.float32))
    w.write(np.zeros((1, 4, 3), np.uint8))
    with pytest.raises(TpsvError, match="1 of 2 rows"):
        w.close()
    with pytest.raises(TpsvError):
        w.write(np.zeros((2, 4, 3), np.uint8))
    with pytest.raises(TpsvError):
        list(png.png_chunks(4, 2, [(1, np.zeros((2, 4, 3), np.uint8))]))


def test_cli_render_streams_large_outputs_into_the_staged_file(traced, tmp_path, monkeypatch):
    """`tpsv render` writes a large output band by band; the file decodes to the one-piece render."""

    from click.testing import CliRunner

    from tpsv import codec
    from tpsv.cli import main
    from tpsv.cli import render as cli_render

    src = tmp_path / "m.tpsv"
    codec.save(traced, src)
    model = codec.load(src)
    calls = []

    def small_tiles(*args, **kw):
        calls.append(1)
        return render.render_png(*args, max_pixels=500, **kw)

    monkeypatch.setattr(cli_render, "render_png", small_tiles)
    out = tmp_path / "big.png"
    res = CliRunner().invoke(main, ["render", str(src), "-o", str(out), "--size", "97x61"])
    assert res.exit_code == 0, res.output
    assert calls
    got = cv2.imdecode(np.frombuffer(out.read_bytes(), np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    assert np.array_equal(got, render.to_uint8(render.render(model, 97, 61)))


def test_sixteen_bit_bands_are_the_render_rounded_to_16_bits(traced):
    from tpsv.image import to_uint16

    whole = render.render(traced, width=50, height=37)
    rows = assemble(render.render_bands(traced, width=50, height=37, max_pixels=50 * 6, depth=16))
    assert rows.dtype == np.uint16 and np.array_equal(rows, to_uint16(whole))
    with pytest.raises(TpsvError, match="8 or 16"):
        next(render.render_bands(traced, width=50, height=37, depth=12))
