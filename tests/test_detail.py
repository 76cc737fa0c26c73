"""The texture detail layer and rate control (issue 11): tpsv.encode.rate, tpsv.encode.detail,
tpsv.codec.detail, tpsv.gpu.detail."""

from __future__ import annotations

import dataclasses
import json
import struct

import cv2
import msgpack
import numpy as np
import pytest
import zstandard
from click.testing import CliRunner

from tpsv import codec, metrics
from tpsv.cli import main
from tpsv.codec import detail as detail_codec
from tpsv.codec import layout
from tpsv.edit.crossmap import crossmap
from tpsv.edit.deform import move_points
from tpsv.edit.recolor import recolor_selected
from tpsv.edit.stylize import abstract
from tpsv.encode import rate
from tpsv.encode.rate import encode_quality, smooth_fills
from tpsv.errors import TpsvError, TpsvFormatError
from tpsv.image import to_uint8
from tpsv.model import CURVILINEAR, DETAIL_FULL, DETAIL_LUMA, DETAIL_OFF
from tpsv.rendering.live import LiveImage
from tpsv.rendering.raster import render, render_bands

from conftest import small_sample


@pytest.fixture(scope="module")
def photo():
    rgb = small_sample("coffee", 64)
    labels = np.zeros(rgb.shape[:2], np.int32)
    labels[:, 26:] = 1
    return rgb, labels


@pytest.fixture(scope="module")
def ladder(photo):
    """Encodings at rising qualities, with and without the detail layer."""
    rgb, labels = photo
    return {(q, d): encode_quality(rgb, labels, quality=q, detail=d) for q in (10, 40, 75, 95) for d in (True, False)}


@pytest.fixture(scope="module")
def textured(ladder):
    return ladder[(75, True)]


def psnr(a, b) -> float:
    return 10 * np.log10(1.0 / metrics.mse(a, b))


# ------------------------------------------------------------------ rate control


@pytest.mark.parametrize("detail", [True, False])
def test_bytes_and_psnr_rise_with_quality(ladder, detail):
    runs = [ladder[(q, detail)] for q in (10, 40, 75, 95)]
    sizes = [len(r.data) for r in runs]
    quality = [r.psnr for r in runs]
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes), sizes
    assert quality == sorted(quality), quality
    assert [r.quality for r in runs] == [10, 40, 75, 95]


def test_the_pure_vector_ladder_keeps_within_the_files_feature_limit(photo, ladder, monkeypatch):
    """On a large photo the 2 px lattices of the top qualities would pass the format's 2^20
    features: the ladder's finest spacing is held where its features fit (here a limit of 400
    on 64 x 64 px, where quality 95 makes more), and the curvilinear pairs of quality 100 are
    left out where they would not fit."""
    rgb, labels = photo
    assert len(ladder[(95, False)].model.features) > 400
    top = encode_quality(rgb, labels, quality=100, detail=False)
    monkeypatch.setattr(rate, "FEATURE_LIMIT", 400)
    assert rate.finest_lattice(64, 64) == pytest.approx(np.sqrt(1.25 * 64 * 64 / 400))
    held = encode_quality(rgb, labels, quality=95, detail=False)
    assert 0 < len(held.model.features) <= 400
    assert codec.decode(held.data).features.st.shape[0] == len(held.model.features)
    # the top qualities' curvilinear pairs are left out where they would not fit
    assert np.any(top.model.features.kind == CURVILINEAR)
    monkeypatch.setattr(rate, "FEATURE_LIMIT", len(top.model.features) - 1)
    plain = encode_quality(rgb, labels, quality=100, detail=False)
    assert np.all(plain.model.features.kind != CURVILINEAR)
    assert len(plain.model.features) <= len(top.model.features) - 1


def test_the_top_qualities_make_their_features_once(photo, monkeypatch):
    """Quality 100 makes its features to see whether its pairs fit the file, and its evaluation
    takes those (it made them again: 0.2-0.3 s of astronaut's 7 s)."""
    from tpsv.encode import vectorize

    rgb, labels = photo
    made = []
    real = vectorize.make_model
    monkeypatch.setattr(vectorize, "make_model", lambda *a, **k: made.append(1) or real(*a, **k))
    top = encode_quality(rgb, labels, quality=100, detail=False)
    assert np.any(top.model.features.kind == CURVILINEAR)
    assert len(made) == 1


def test_detail_pays_rule():
    # 1 dB per doubling of the file: +1 dB for twice the bytes is the edge
    assert rate.detail_pays(1e-3, 1e-3 / 10 ** 0.1, 1000, 2000)
    assert not rate.detail_pays(1e-3, 1e-3 / 10 ** 0.099, 1000, 2000)
    assert not rate.detail_pays(1e-3, 1.01e-3, 1000, 1001)  # a texture that makes the picture worse
    assert not rate.detail_pays(0.0, 0.0, 1000, 1300)  # the base alone is exact
    assert rate.detail_pays(1e-3, 1e-5, 1000, 8000)  # 20 dB for three doublings


def test_a_flat_drawing_gets_no_texture_a_textured_one_keeps_it():
    """A texture that holds nothing the picture needs costs an AVIF file (some 300 bytes) for no
    gain: flat colour patches come back as the vector base alone, at every quality, with the
    quality recorded; the photo beside them keeps its texture."""
    from tpsv.bench.drawings import drawing

    rgb = drawing("frames")
    runs = [encode_quality(rgb, None, quality=q) for q in (20, 75, 95)]
    for q, r in zip((20, 75, 95), runs):
        m = codec.decode(r.data)
        assert m.detail is None and m.params.extra["quality"] == q
        assert r.psnr == pytest.approx(psnr(rgb, render(m)), abs=0.02)
    assert len({len(r.data) for r in runs}) == 1
    assert psnr(rgb, render(codec.decode(runs[0].data))) > 50.0


def test_bytes_and_psnr_rise_with_quality_where_the_texture_starts_to_pay():
    """dots: the texture is dropped at low qualities (it gains nothing there) and kept above;
    bytes and PSNR still rise with the quality across the switch."""
    from tpsv.bench.drawings import drawing

    rgb = drawing("dots")
    runs = [encode_quality(rgb, None, quality=q) for q in (20, 50, 75)]
    assert [codec.decode(r.data).detail is None for r in runs] == [True, False, False]
    sizes, quality = [len(r.data) for r in runs], [r.psnr for r in runs]
    assert sizes == sorted(sizes) and quality == sorted(quality)


def test_a_small_photo_takes_fewer_regions_where_they_pay(monkeypatch):
    """rocket area-downscaled 4x (120 x 80): its own segmentation's 10 regions cost more outline
    than they buy; with 3 the file is a third smaller at nearly the same PSNR, and the choice,
    made at the default quality, holds at every quality (bytes and PSNR rise with it). (Regions
    with no edge between them left apart: their join alone takes this photo to 2 regions.)"""
    from tpsv.bench import baseline
    from tpsv.geometry import segment
    from conftest import SAMPLES

    monkeypatch.setattr(segment, "WEAK_BORDER", 0.0)

    rgb = cv2.imread(str(SAMPLES / "rocket.png"))[:, :, ::-1].astype(np.float32) / 255
    small = baseline.downscale_area(rgb[:320, :480], 4)
    low, fewer = encode_quality(small, None, quality=30), encode_quality(small, None)
    monkeypatch.setattr(rate, "FEW_REGIONS_PIXELS", 0)
    own = encode_quality(small, None)
    assert len(fewer.model.regions) < len(own.model.regions)
    assert len(fewer.data) < 0.8 * len(own.data) and rate.fewer_pays(len(own.data), own.mse, len(fewer.data), fewer.mse)
    assert len(low.model.regions) == len(fewer.model.regions)
    assert len(low.data) < len(fewer.data) and low.psnr < fewer.psnr


def test_fewer_regions_pay_by_the_bytes_they_save():
    """A smaller file may read lower by FEW_REGIONS_SLOPE dB per halving; a larger one never pays."""
    from tpsv.metrics import psnr_of_mse

    mse = 1e-4
    at = lambda db: mse / 10 ** (db / 10)  # the MSE of a picture ``db`` dB above
    assert rate.fewer_pays(1000, mse, 500, at(-rate.FEW_REGIONS_SLOPE + 0.01))
    assert not rate.fewer_pays(1000, mse, 500, at(-rate.FEW_REGIONS_SLOPE - 0.01))
    assert rate.fewer_pays(1000, mse, 999, mse)
    assert not rate.fewer_pays(1000, mse, 1000, at(3.0)) and not rate.fewer_pays(1000, mse, 1200, at(3.0))
    assert psnr_of_mse(at(1.0)) > psnr_of_mse(mse)


def test_the_fewer_regions_try_beside_the_own_encoding_writes_the_same_file(monkeypatch):
    """The picture's own encoding is made on a host thread while the coarser one is tried: the file is
    the one a single core writes, one after the other."""
    from tpsv.bench import baseline
    from conftest import SAMPLES

    rgb = cv2.imread(str(SAMPLES / "rocket.png"))[:, :, ::-1].astype(np.float32) / 255
    small = baseline.downscale_area(rgb[:320, :480], 4)
    monkeypatch.setattr(rate, "host_cores", lambda: 2)
    beside = encode_quality(small, None)
    monkeypatch.setattr(rate, "host_cores", lambda: 1)
    alone = encode_quality(small, None)
    assert beside.data == alone.data


def test_drawn_shapes_keep_their_regions():
    """Where the regions hold edges the texture would blur (the edge table's shapes), the
    coarser segmentation reads lower or costs more, and the picture keeps its own."""
    from tpsv.bench.shapes import shapes
    from tpsv.geometry.segment import segment_auto

    rgb, _ = shapes(96, 1, 0)
    res = encode_quality(rgb, None)
    assert len(res.model.regions) == len(np.unique(segment_auto(rgb)))


def test_the_detail_layer_is_what_reaches_high_quality(ladder):
    assert ladder[(95, True)].psnr > 38.0
    assert ladder[(95, True)].psnr > ladder[(95, False)].psnr + 3.0
    assert codec.decode(ladder[(75, False)].data).detail is None


def test_reported_psnr_is_the_render_of_the_file(photo, textured):
    rgb, _ = photo
    model = codec.decode(textured.data)
    assert model.detail is not None and model.params.extra["quality"] == 75
    assert textured.model.detail == model.detail and codec.encode(textured.model) == textured.data
    assert psnr(rgb, render(model)) == pytest.approx(textured.psnr, abs=0.02)


def test_max_bytes_is_never_exceeded(photo, textured):
    rgb, labels = photo
    budget = len(textured.data)
    out = encode_quality(rgb, labels, max_bytes=budget - 1)
    assert len(out.data) <= budget - 1 and out.quality < 75
    at = encode_quality(rgb, labels, max_bytes=budget)
    assert len(at.data) <= budget and at.quality >= 75
    with pytest.raises(TpsvError, match="no quality fits in 100 bytes"):
        encode_quality(rgb, labels, max_bytes=100)


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
def test_quality_search_finds_the_bound_and_codes_the_top_quality_last(workers):
    """The search over qualities gives the brute-force answer for every threshold, on one worker (a
    bisection) or several (qualities tried at once), and tries the top quality (the slowest texture
    to code) only when no lower one holds."""
    for first in list(range(1, 101)) + [None]:
        tried = []
        ok = lambda q: tried.append(q) or (first is not None and q >= first)  # noqa: E731
        assert rate._lowest(ok, workers) == first
        assert len(tried) == len(set(tried))
        if workers == 1:
            assert len(tried) <= rate.MAX_TRIALS
        else:  # rounds of ``workers`` qualities, each leaving 1 / (workers + 1) of the interval open
            rounds = int(np.ceil(np.log(100) / np.log(workers + 1))) + 1
            assert len(tried) <= workers * rounds + 1
        assert (rate.MAX_QUALITY in tried) == (first in (None, rate.MAX_QUALITY))
        fits = lambda q: first is None or q < first  # noqa: E731 (true up to a point)
        assert rate._highest(fits, workers) == (rate.MAX_QUALITY if first is None else (first - 1 or None))


def test_search_workers_bounded_by_memory(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # a batch worker's share
    assert rate.search_workers(64 * 64) == 1
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert rate.search_workers(64 * 64) >= 1
    assert rate.search_workers(64 * 64) <= rate.SEARCH_WORKERS
    huge = rate.SEARCH_MEMORY // rate.SEARCH_BYTES_PER_PIXEL + 1  # one more worker would pass the memory
    assert rate.search_workers(huge) == 1 and rate.search_workers(huge * 10) == 1
    assert rate.search_workers(4000 * 3000) == 1


def test_target_psnr_met_or_closest_reported(photo, textured):
    rgb, labels = photo
    out = encode_quality(rgb, labels, target_psnr=textured.psnr)
    assert out.reached and out.psnr >= textured.psnr and out.quality <= 75
    far = encode_quality(rgb, labels, target_psnr=99.0)
    assert not far.reached and far.quality == 100


def test_progress_is_reported_up_to_the_end(photo, textured):
    rgb, labels = photo
    for kwargs in ({"quality": 40}, {"target_psnr": textured.psnr}):
        calls = []
        encode_quality(rgb, labels, progress=lambda done, total: calls.append((done, total)), **kwargs)
        done = [d for d, _ in calls]
        assert done == sorted(done) and calls[-1][0] == calls[-1][1] and len({t for _, t in calls}) == 1


def test_one_target_at_a_time(photo):
    rgb, labels = photo
    with pytest.raises(TpsvError, match="give one of"):
        encode_quality(rgb, labels, quality=50, max_bytes=1000)
    with pytest.raises(TpsvError, match="not in 1..100"):
        encode_quality(rgb, labels, quality=0)


# ------------------------------------------------------------------ codec


def test_detail_survives_encode_decode_bit_exactly(textured):
    model = codec.decode(textured.data)
    d = model.detail
    assert d.texels.dtype == np.uint16 and d.texels.shape == (model.height, model.width, 3)
    assert len(d.payload) == 1 and d.payload[0][4:12] == b"ftypavif"
    assert detail_codec.image_sizes(d.payload[0]) == [(model.width, 3 * model.height)]  # wider than tall: stacked
    again = codec.decode(codec.encode(model))
    assert again.detail == d
    assert codec.encode(model) == textured.data
    assert codec.encode(codec.quantize(model)) == textured.data
    sizes = codec.section_sizes(textured.data)
    # the section holds the image's AV1 bitstream, not its AVIF boxes (version 9)
    assert sum(sizes.values()) == len(textured.data) and sizes["detail"] > len(d.payload[0]) - 269
    assert struct.unpack_from("<HH", textured.data, 8) == (
        layout.VERSION, layout.FLAG_DETAIL | layout.FLAG_CURVES | layout.FLAG_BLUR_MAP)


def test_a_tall_texture_puts_its_planes_side_by_side():
    texels = (np.arange(7 * 3 * 3) % 1024).astype(np.uint16).reshape(7, 3, 3)
    payload = detail_codec.encode_texels(texels, 100)
    assert len(payload) == 1 and detail_codec.image_sizes(payload[0]) == [(9, 7)]
    back = detail_codec.decode_texels(payload, 3, 7)
    assert back.shape == (7, 3, 3) and np.abs(back.astype(int) - texels).max() <= 2


def test_grey_regions_are_those_without_chroma_in_their_residual():
    from tpsv.encode.detail import GREY_PEAK, grey_regions

    texels = np.full((6, 8, 3), 512, np.uint16)
    texels[..., 0] = 300  # luma is not looked at
    index = np.repeat(np.array([0, 0, 1, 1, 2, 2, 3, -1]), 6).reshape(8, 6).T.copy()
    texels[:, 2:4, 1] = 513  # region 1: one level off everywhere: RMS 0.71 texel
    texels[0, 4, 2] = 512 + GREY_PEAK + 1  # region 2: one texel past the peak
    texels[:, 7, 1:] = 0  # no region's pixels
    assert list(grey_regions(texels, index, 5)) == [True, True, False, True, False]  # region 4 has no pixel
    texels[:, 2:4, 1:] = 513  # RMS 1 on both planes: still grey
    assert grey_regions(texels, index, 5)[1]
    texels[:, 2:4, 1] = 514
    assert not grey_regions(texels, index, 5)[1]


def test_a_grey_photo_comes_back_grey_at_every_scale(photo):
    """A region whose residual has no chroma reads its texture's luma alone: the codec's chroma
    error (and, in a small texture's one image of stacked planes, the luma plane's blocks reaching
    into the Cb plane below it) tinted grey photos, R, G and B up to 55 levels apart at quality 20."""
    rgb, labels = photo
    grey = np.repeat(rgb.mean(axis=2, keepdims=True), 3, axis=2)
    h, w = grey.shape[:2]
    for q in (20, 75):
        model = encode_quality(grey, labels, quality=q).model
        assert list(model.detail.mode) == [DETAIL_LUMA, DETAIL_LUMA]
        for scale in (1, 4):
            assert np.ptp(render(model, width=scale * w, height=scale * h), axis=2).max() < 1e-5
    # the colours' residual has chroma: full mode; and a grey region beside a coloured one keeps
    # it too (the mix drawn along their border leaves chroma in the grey side's residual there)
    assert list(encode_quality(rgb, labels, quality=75).model.detail.mode) == [DETAIL_FULL, DETAIL_FULL]
    half = rgb.copy()
    half[:, :26] = grey[:, :26]
    assert list(encode_quality(half, labels, quality=75).model.detail.mode) == [DETAIL_FULL, DETAIL_FULL]


def test_textures_up_to_a_megapixel_are_coded_carefully(monkeypatch):
    """The AVIF encoder's effort: more the smaller a texture in one piece is, the careful speed
    up to CAREFUL_TEXELS texels, the fast one above (a 12-megapixel texture at the careful speed
    would take a minute); the careful speed gives the smaller file."""
    top = detail_codec.CAREFUL_TEXELS
    assert detail_codec.avif_speed(1024, top // 1024) == detail_codec.AVIF_SPEED
    assert detail_codec.avif_speed(1024, top // 1024 + 1) == detail_codec.FAST_AVIF_SPEED
    assert detail_codec.AVIF_SPEED < detail_codec.FAST_AVIF_SPEED
    sizes = [(64, 64), (127, 128), (128, 128), (181, 181), (256, 255), (256, 256), (362, 362), (512, 512),
             (513, 512), (1024, 1024)]
    speeds = [detail_codec.avif_speed(w, h) for w, h in sizes]
    assert speeds == [1, 1, 2, 2, 3, 4, 4, 4, 5, 5] and speeds == sorted(speeds)
    rng = np.random.default_rng(3)
    smooth = np.cumsum(rng.normal(0, 4, (64, 96, 3)), axis=1)
    texels = np.clip(512 + smooth - smooth.mean(), 0, 1023).astype(np.uint16)
    careful = detail_codec.encode_texels(texels, 60)
    monkeypatch.setattr(detail_codec, "CAREFUL_TEXELS", 0)
    assert len(careful[0]) < len(detail_codec.encode_texels(texels, 60)[0])


def _detail_map(data: bytes) -> dict:
    h = layout.parse_header(data)
    at = h.detail_offset + layout.DETAIL_SIZES.size
    return msgpack.unpackb(zstandard.ZstdDecompressor().decompress(data[at:at + h.detail[0]]), raw=False)


def _with_detail(data: bytes, obj=None, raw: bytes | None = None, raw_size: int | None = None) -> bytes:
    """``data`` with its detail section replaced (CRCs fixed, so a check must refuse, not a checksum)."""
    import zlib

    h = layout.parse_header(data)
    raw = msgpack.packb(obj, use_bin_type=True) if raw is None else raw
    comp = zstandard.ZstdCompressor().compress(raw)
    out = bytearray(data[:h.detail_offset] + layout.DETAIL_SIZES.pack(len(comp), raw_size or len(raw)) + comp)
    struct.pack_into("<I", out, 64, zlib.crc32(bytes(out[layout.HEADER_SIZE:])))
    struct.pack_into("<I", out, 68, zlib.crc32(bytes(out[:68])))
    return bytes(out)


def _reject(data: bytes, match: str) -> None:
    with pytest.raises(TpsvFormatError, match=match) as info:
        codec.decode(data)
    assert "\n" not in str(info.value)


def _as_avif(data: bytes) -> dict:
    """The detail section of ``data`` with its images stored as whole AVIF files (codec ``"avif"``,
    which version 9 still reads) instead of bare AV1 bitstreams."""
    files = codec.decode(data).detail.payload
    return {**_detail_map(data), "codec": "avif", "image": files[0] if len(files) == 1 else list(files)}


def _bigger_ispe(image: bytes, w: int, h: int) -> bytes:
    at = image.index(b"ispe")
    return image[:at + 8] + struct.pack(">II", w, h) + image[at + 16:]


def test_a_corrupt_image_is_refused_quietly(textured, capfd):
    """libaom's and OpenCV's own complaints do not reach stderr: the one line is ours."""
    base = _detail_map(textured.data)
    assert base["codec"] == "av1"
    image = bytearray(base["image"])
    image[-40:] = bytes(40)
    capfd.readouterr()
    _reject(_with_detail(textured.data, {**base, "image": bytes(image)}), "cannot be decoded|decodes to")
    assert capfd.readouterr().err == ""


def test_detail_images_are_stored_without_their_avif_boxes(textured, banded):
    """Version 9: each image is the AV1 bitstream of the AVIF file the encoder wrote, which the
    decoder wraps in the same boxes again; an AVIF file that is not that wrapping is stored
    whole (codec "avif"), and either is read."""
    from tpsv.codec import avif

    for data in (textured.data, banded[1]):
        model = codec.decode(data)
        bare = _detail_map(data)
        images = bare["image"] if isinstance(bare["image"], list) else [bare["image"]]
        assert bare["codec"] == "av1" and [avif.HEAD + len(b) for b in images] == [len(f) for f in model.detail.payload]
        for b, f in zip(images, model.detail.payload):
            assert avif.wrap(b, *detail_codec.image_sizes(f)[0]) == f and f.endswith(b)
        whole = _with_detail(data, _as_avif(data))
        assert codec.decode(whole).detail == model.detail
        assert 100 < len(whole) - len(data) <= 269 * len(images)
        assert codec.encode(codec.decode(whole)) == data
    # another layout (a box added after the file type) cannot be dropped: it stays a whole file
    f = codec.decode(textured.data).detail.payload[0]
    odd = f[:28] + struct.pack(">I", 8) + b"free" + f[28:]
    assert avif.unwrap(odd, *detail_codec.image_sizes(f)[0]) is None
    assert avif.unwrap(f[:-1], *detail_codec.image_sizes(f)[0]) is None
    assert avif.sequence_header(b"") is None and avif.sequence_header(b"\x12\x00\x0a") is None
    w, h = detail_codec.image_sizes(f)[0]
    assert avif.sequence_header(f[avif.HEAD:])[1:] == (w, h)
    with pytest.raises(TpsvFormatError, match=f"image is {w}x{h}, the texture's is {w - 1}x{h}"):
        avif.wrap(f[avif.HEAD:], w - 1, h)


def test_hostile_detail_sections_are_refused(textured):
    data = textured.data
    bare = _detail_map(data)
    base = _as_avif(data)
    R = len(codec.decode(data).regions)
    image = base["image"]
    own = bare["image"]
    av1_cases = [
        ({"image": own[:len(own) // 2]}, "cannot be decoded|decodes to"),
        ({"image": own[:3]}, "not an AV1 still picture"),
        ({"image": b"\x12\x00" + bytes(40)}, "not an AV1 still picture"),
        ({"image": b"\x0a\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01"}, "not an AV1 still picture"),
        ({"image": "text"}, "image is not a bin"),
        ({"width": bare["width"] - 1}, "image is 64x129, the texture's is 63x129"),
        ({"codec": "AV1"}, "unknown codec"),
    ]
    for change, match in av1_cases:
        _reject(_with_detail(data, {**bare, **change}), match)
    # bare bitstreams are a version-9 thing
    import zlib

    v8 = bytearray(data)
    struct.pack_into("<H", v8, 8, 8)
    struct.pack_into("<I", v8, 68, zlib.crc32(bytes(v8[:68])))
    _reject(bytes(v8), "unknown codec 'av1'")
    cases = [
        ({"codec": "webp"}, "unknown codec"),
        ({"width": 10**6}, "width = 1000000 not in"),
        ({"height": 0}, "height = 0 not in"),
        ({"quality": 101}, "quality = 101 not in"),
        ({"frame": b"\0" * (24 * R - 4)}, "frame has"),
        ({"mode": b"\3" * R}, "mode 3 not in"),
        ({"mode": b"\1"}, "mode has 1 bytes"),
        ({"image": "text"}, "image is not a bin"),
        ({"image": b"\x89PNG\r\n\x1a\n" + image}, "not an AVIF file"),
        ({"image": image[:40]}, "truncated box|bad size|cannot be decoded|declares no size"),
        ({"image": image[:len(image) // 2]}, "cannot be decoded|bad size"),
        ({"image": _bigger_ispe(image, 60000, 60000)}, "declares 60000x60000"),
        ({"width": base["width"] - 1}, "declares|decodes to"),
    ]
    for change, match in cases:
        _reject(_with_detail(data, {**base, **change}), match)
    extra = dict(base, more=1)
    _reject(_with_detail(data, extra), "unknown key 'more'")
    missing = {k: v for k, v in base.items() if k != "mode"}
    _reject(_with_detail(data, missing), "missing key 'mode'")
    _reject(_with_detail(data, raw=b"\xc1"), "bad msgpack")
    # a bomb: a raw size past what the canvas allows is refused before inflating
    h = layout.parse_header(data)
    _reject(_with_detail(data, base, raw_size=layout.detail_raw_bound(h) + 1), "exceeds the bound")
    # the flag on a version-2 file is not a thing
    import zlib

    v2 = bytearray(data)
    struct.pack_into("<HH", v2, 8, 2, layout.FLAG_DETAIL)
    struct.pack_into("<I", v2, 68, zlib.crc32(bytes(v2[:68])))
    _reject(bytes(v2), "unsupported flags 0x0001")
    _reject(data[:layout.parse_header(data).detail_offset + 3], "truncated")


def test_chroma_planes_are_coded_a_little_below_the_luma(monkeypatch):
    qs = range(1, 101)
    chroma = [detail_codec.chroma_quality(q) for q in qs]
    assert chroma == sorted(chroma) and chroma[0] >= 1
    assert all(detail_codec.avif_quality(q) - detail_codec.CHROMA_STEPS <= c <= detail_codec.avif_quality(q)
               for q, c in zip(qs, chroma))
    assert detail_codec.chroma_quality(100) == detail_codec.avif_quality(100) == detail_codec.MAX_AVIF_QUALITY
    # plane by plane, Cb and Cr are the files of their planes coded at chroma_quality; Y at avif_quality
    rng = np.random.default_rng(3)
    texels = np.clip(512 + np.cumsum(rng.normal(0, 4, (40, 48, 3)), axis=1), 0, 1023).astype(np.uint16)
    monkeypatch.setattr(detail_codec, "ONE_PIECE_TEXELS", 1)
    files = detail_codec.encode_texels(texels, 60)

    def alone(k, q):
        return cv2.imencode(".avif", np.ascontiguousarray(texels[..., k]), [
            cv2.IMWRITE_AVIF_QUALITY, q, cv2.IMWRITE_AVIF_SPEED, detail_codec.avif_speed(48, 40),
            cv2.IMWRITE_AVIF_DEPTH, 10])[1].tobytes()

    assert files[0] == alone(0, detail_codec.avif_quality(60))
    assert files[1:] == (alone(1, detail_codec.chroma_quality(60)), alone(2, detail_codec.chroma_quality(60)))
    assert detail_codec.chroma_quality(60) < detail_codec.avif_quality(60)


def test_a_large_texture_is_coded_plane_by_plane():
    """Small textures in one piece; from 2^17 texels a plane on, a file a plane, whatever the size
    (docs/FORMAT.md, detail); a plane in ``n`` bands of 64-row multiples, the last never empty."""
    assert detail_codec.plane_bands(64, 42) == 0
    assert detail_codec.plane_bands(362, 362) == 0  # 131044 texels a plane
    for w, h in [(363, 362), (451, 300), (512, 512), (4000, 3000), (7300, 5475)]:
        assert detail_codec.plane_bands(w, h) == 1
    for h, n in [(70, 2), (100, 2), (3000, 3), (3000, 5), (65535, 64)]:
        spans = detail_codec.band_rows(h, n)
        assert len(spans) == n and spans[0][0] == 0 and spans[-1][1] == h
        assert all(a < b and b == c for (a, b), (c, _) in zip(spans, spans[1:] + [(h, None)]))
        assert all((b - a) % detail_codec.BAND_ALIGN == 0 for a, b in spans[:-1])
    with pytest.raises(TpsvFormatError, match="cannot be cut into 3 bands"):
        detail_codec.band_rows(128, 3)  # bands of 64 rows: the third would be empty
    with pytest.raises(TpsvFormatError, match="1..341"):
        detail_codec.band_rows(10**6, 342)


@pytest.fixture()
def banded(textured, monkeypatch):
    """The textured file with its texture coded plane by plane (its size made to count as large)."""
    from tpsv.encode.detail import code_texels

    model = codec.decode(textured.data)
    monkeypatch.setattr(detail_codec, "ONE_PIECE_TEXELS", 1)
    payload, texels = code_texels(model.detail.texels, 75)
    assert len(payload) == 3
    model.detail = dataclasses.replace(model.detail, payload=payload, texels=texels)
    return model, codec.encode(model)


def test_a_texture_in_bands_round_trips_bit_exactly(banded, textured):
    model, data = banded
    back = codec.decode(data)
    assert back.detail == model.detail and codec.encode(back) == data
    assert isinstance(_detail_map(data)["image"], list)
    # each plane is an AVIF file of its own (the chroma a few qualities lower, at another speed);
    # together the same texture as in one piece, nearly: within 3 8-bit levels on average
    one = codec.decode(textured.data).detail.texels
    assert np.abs(back.detail.texels.astype(int) - one).mean() < 6
    assert [detail_codec.image_sizes(b)[0] for b in back.detail.payload] == [(model.width, model.height)] * 3
    # a version-7 decoder's rule: the image is one bin there
    import zlib

    v7 = bytearray(_with_detail(data, _as_avif(data)))
    struct.pack_into("<H", v7, 8, 7)
    struct.pack_into("<I", v7, 68, zlib.crc32(bytes(v7[:68])))
    _reject(bytes(v7), "image is not a bin$")


def test_a_plane_in_several_bands_is_read():
    """What the format allows beyond what tpsv writes: a plane of 70 rows in two bands (64 and 6
    rows), 6 files, plane by plane."""
    rng = np.random.default_rng(5)
    texels = np.clip(512 + np.cumsum(rng.normal(0, 3, (70, 40, 3)), axis=1), 0, 1023).astype(np.uint16)
    params = [cv2.IMWRITE_AVIF_QUALITY, 98, cv2.IMWRITE_AVIF_DEPTH, 10]
    files = tuple(cv2.imencode(".avif", np.ascontiguousarray(texels[a:b, :, k]), params)[1].tobytes()
                  for k in range(3) for a, b in [(0, 64), (64, 70)])
    assert [detail_codec.image_sizes(f)[0] for f in files] == [(40, 64), (40, 6)] * 3
    back = detail_codec.decode_texels(files, 40, 70)
    assert back.shape == texels.shape and np.abs(back.astype(int) - texels).max() <= 4
    # the planes' order counts: Cb's bands where Y's were give another texture, of the same size
    swapped = detail_codec.decode_texels(files[2:4] + files[:2] + files[4:], 40, 70)
    assert np.array_equal(swapped[..., 0], back[..., 1]) and np.array_equal(swapped[..., 1], back[..., 0])
    with pytest.raises(TpsvFormatError, match="declares 40x64, the texture's band is 40x6"):
        detail_codec.decode_texels(files[1:2] + files[0:1] + files[2:], 40, 70)


def test_a_payload_of_one_bytes_object_is_the_image_in_one_piece(textured):
    model = codec.decode(textured.data)
    (one,) = model.detail.payload
    model.detail = dataclasses.replace(model.detail, payload=one)
    assert codec.encode(model) == textured.data
    for bad in [(), (one, one)]:
        model.detail = dataclasses.replace(model.detail, payload=bad)
        with pytest.raises(ValueError, match="1 AVIF file, or 3 n"):
            codec.encode(model)


def test_hostile_bands_are_refused(banded):
    _, data = banded
    bare = _detail_map(data)
    for image, match in [(bare["image"] + bare["image"][:1], "4 files, not 3 planes' bands"),
                         (bare["image"][:2], "array of 3..1023 bins"),
                         (bare["image"][:2] + [bare["image"][2][:5]], "not an AV1 still picture"),
                         (bare["image"] * 2, "cannot be cut into 2 bands")]:
        _reject(_with_detail(data, {**bare, "image": image}), match)
    base = _as_avif(data)
    y, cb, cr = base["image"]
    stacked = _detail_map(codec.encode(codec.decode(data)))["image"]
    cases = [
        ([y], "array of 3..1023 bins"),
        ([y, cb, "text"], "array of 3..1023 bins"),
        ([y, cb], "array of 3..1023 bins"),
        ([y, cb, cr, y], "4 files, not 3 planes' bands"),
        ([y] * 1026, "exceeds the bound"),  # refused from the sizes alone
        ([b"x"] * 1026, "array of 3..1023 bins"),
        ([y, cb, cr] * 2, "cannot be cut into 2 bands"),  # 43 rows: bands of 64
        ([y, cb, cr[:len(cr) // 2]], "cannot be decoded|bad size"),
        ([y, cb, _bigger_ispe(cr, 60000, 60000)], "declares 60000x60000"),
    ]
    for image, match in cases:
        _reject(_with_detail(data, {**base, "image": image}), match)


# ------------------------------------------------------------------ rendering


def test_bands_and_live_image_match_the_render_with_detail(textured):
    model = codec.decode(textured.data)
    for scale in (1, 2.5):
        whole = render(model, scale=scale)
        rows = np.concatenate([r for _, r in render_bands(model, scale=scale, max_pixels=1000)])
        assert np.array_equal(rows, to_uint8(whole))  # the one rounding rule (np.round halves to even)
    live = LiveImage(model)
    assert np.array_equal(live.image, render(model))
    edited = recolor_selected(model, np.ones(len(model.features), bool), lightness=10.0).model
    live.update(edited)
    assert np.array_equal(live.image, render(edited))


def test_magnified_detail_is_smooth(textured):
    """At scale 4 the texture is interpolated, not blocky: no 4x4 plateaus of equal pixels."""
    model = codec.decode(textured.data)
    big = render(model, scale=4)
    flat = np.abs(np.diff(big, axis=1)).max(axis=2) < 1e-7
    assert flat.mean() < 0.2


def _ramp(n: int = 48) -> np.ndarray:
    """A purple-to-green ramp, straight in sRGB (so curved in Lab)."""
    t = np.linspace(0.0, 1.0, n, dtype=np.float32)[None, :, None] * np.ones((n, 1, 1), np.float32)
    return (1 - t) * np.array([0.7, 0.2, 0.8], np.float32) + t * np.array([0.1, 0.75, 0.1], np.float32)


def test_smooth_fills_are_told_from_texture():
    ramp = _ramp()
    index = np.zeros(ramp.shape[:2], np.int32)
    flat = np.broadcast_to(ramp.mean((0, 1)), ramp.shape)
    rng = np.random.default_rng(0)
    noise = flat + rng.normal(0.0, 0.1, ramp.shape).astype(np.float32)
    assert smooth_fills(ramp, flat, index).tolist() == [True]
    assert smooth_fills(noise, flat, index).tolist() == [False]  # texture: the detail layer's
    assert smooth_fills(ramp, ramp + 1.0 / 255, index).tolist() == [False]  # too faint to matter
    assert smooth_fills(ramp, flat, index, [True]).tolist() == [False]  # nobody sees it
    # regions are judged apart: a ramp above noise
    two = np.where(np.arange(48)[:, None, None] < 24, ramp, noise)
    index[24:] = 1
    assert smooth_fills(two, flat, index).tolist() == [True, False]


def test_a_large_region_is_never_a_smooth_fill(monkeypatch):
    """The fine lattice costs in proportion to the area: past SMOOTH_FILL_MAX_PX the texture keeps it."""
    from tpsv.encode import rate

    ramp = _ramp()
    index = np.zeros(ramp.shape[:2], np.int32)
    flat = np.broadcast_to(ramp.mean((0, 1)), ramp.shape)
    monkeypatch.setattr(rate, "SMOOTH_FILL_MAX_PX", ramp.shape[0] * ramp.shape[1])
    assert smooth_fills(ramp, flat, index).tolist() == [True]
    monkeypatch.setattr(rate, "SMOOTH_FILL_MAX_PX", ramp.shape[0] * ramp.shape[1] - 1)
    assert smooth_fills(ramp, flat, index).tolist() == [False]


def test_a_gradient_fill_gets_a_finer_base_and_comes_back_smooth(monkeypatch):
    """A ramp the coarsest lattice cannot follow is carried by the vector base, not by the texture:
    more base features, a closer base, and at 4x no blotches (the render stays monotonic along
    the ramp)."""
    rgb = _ramp(64)
    labels = np.zeros(rgb.shape[:2], np.int32)
    res = encode_quality(rgb, labels)
    with monkeypatch.context() as m:
        m.setattr(rate, "SMOOTH_FILL_MIN", np.inf)  # as before smooth fills were found
        coarse = encode_quality(rgb, labels)
    assert len(res.model.features) > len(coarse.model.features)
    # a base with a fill gets the finer colour steps, one without keeps the coarse ones
    steps = lambda r: (r.model.params.l_step, r.model.params.ab_step)  # noqa: E731
    assert steps(res) == rate.SMOOTH_FILL_STEPS and steps(coarse) == rate.BASE_STEPS
    base = lambda r: render(dataclasses.replace(codec.decode(r.data), detail=None))  # noqa: E731
    assert psnr(rgb, base(res)) > psnr(rgb, base(coarse)) + 2.0
    assert res.psnr > coarse.psnr + 1.0 and len(res.data) <= len(coarse.data) * 1.05
    big = render(codec.decode(res.data), scale=4)
    green = big[8:-8, :, 1].mean(axis=0)  # rises along the ramp
    assert (np.diff(green[8:-8]) > -0.5 / 255).all()


# ------------------------------------------------------------------ edits


def test_deform_moves_the_texture_with_the_patch(photo, textured):
    model = codec.decode(textured.data)
    before = render(model)
    M, N = model.regions[1].patch.shape
    moves = [(1, i, j, 3.0, 0.0) for i in range(M) for j in range(N)]
    moved = move_points(model, moves, keep_order=True)
    assert np.array_equal(moved.detail.frame, model.detail.frame)
    after = render(moved)
    # well inside region 1 (x >= 26), the picture is the old one 3 px to the right
    inner = np.s_[8:-8, 34:58]
    shifted = np.s_[8:-8, 37:61]
    assert np.abs(after[shifted] - before[inner]).mean() < 2 / 255


def test_crossmap_carries_the_source_texture(photo, textured):
    rgb, _ = photo
    model = codec.decode(textured.data)
    out = crossmap(model, 1, source_region=0)
    O, dS, dT = out.detail.frame[1]
    assert np.allclose(out.detail.frame[1], model.detail.frame[0]) and out.detail.mode[1] == DETAIL_FULL
    flipped = crossmap(model, 1, source_region=0, flip=True)
    O2, dS2, dT2 = flipped.detail.frame[1]
    assert np.allclose(O2, O + dS) and np.allclose(dS2, -dS) and np.allclose(dT2, dT)
    # from another file: the other texture cannot be pointed into, so region 1 goes plain
    other = dataclasses.replace(model, detail=dataclasses.replace(model.detail, payload=model.detail.payload + (b"x",)))
    assert crossmap(model, 1, source=other, source_region=0).detail.mode[1] == DETAIL_OFF


def test_recolor_keeps_the_luma_of_the_texture(textured):
    model = codec.decode(textured.data)
    sel = model.features.region == 1
    out = recolor_selected(model, sel, hue=120.0).model
    assert list(out.detail.mode) == [DETAIL_FULL, DETAIL_LUMA]
    img = render(out)
    plain = render(dataclasses.replace(out, detail=None))
    added = (img - plain)[:, 40:]
    grey = np.abs(added - added.mean(axis=2, keepdims=True)).max(axis=2)
    clipped = (img[:, 40:] <= 0).any(axis=2) | (img[:, 40:] >= 1).any(axis=2)
    assert grey[~clipped].max() < 2e-3  # the same residual on every channel
    assert np.abs(added).mean() > 1e-3  # and there is one


def test_stylize_drops_the_detail(textured):
    assert abstract(codec.decode(textured.data), 1).detail is None


# ------------------------------------------------------------------ command line


def test_cli_quality_options(tmp_path, small_png):
    out = tmp_path / "q.tpsv"
    r = CliRunner().invoke(main, ["vectorize", str(small_png), "-o", str(out), "--quality", "60", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["quality"] == 60 and s["detail_quality"] == 60 and s["detail_bytes"] > 0 and s["reached"]
    r = CliRunner().invoke(main, ["info", str(out)])
    assert "quality   60" in r.output and "AVIF at quality 60" in r.output
    r = CliRunner().invoke(main, ["vectorize", str(small_png), "-o", str(out), "--max-bytes", "3000", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["bytes"] <= 3000 and out.stat().st_size <= 3000
    r = CliRunner().invoke(main, ["vectorize", str(small_png), "-o", str(out), "--no-detail", "--json"])
    assert json.loads(r.output)["detail_bytes"] == 0
    for bad, match in ((["--quality", "50", "--search"], "do not go with"),
                       (["--quality", "50", "--max-bytes", "9"], "give one of"),
                       (["--max-bytes", "10"], "no quality fits in 10 bytes")):
        gone = tmp_path / "gone.tpsv"
        r = CliRunner().invoke(main, ["vectorize", str(small_png), "-o", str(gone)] + bad)
        assert r.exit_code != 0 and match in r.output and not gone.exists()
        assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1


@pytest.mark.parametrize("module", ["tpsv.image", "tpsv.codec.detail", "tpsv.encode.rate", "tpsv.quiet"])
def test_each_entry_module_imports_first(module):
    """No import cycle: the codec's detail section needs the quiet decoder that image reading uses too."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_a_prepared_renderer_adds_the_detail_as_render_does(textured):
    from tpsv.rendering.raster import Renderer

    model = codec.decode(textured.data)
    r = Renderer(model)
    for scale in (1, 2.5):
        assert np.array_equal(r.render(scale=scale), render(model, scale=scale))


def test_a_sample_on_a_texel_centre_is_that_texel_and_off_it_the_cubic():
    """A pixel of a model at rest at its own size lands on its texel (to float32 rounding) and reads it
    alone; a sample off the centres reads the Keys cubic of the sixteen around it."""
    wp = pytest.importorskip("warp")
    from tpsv.gpu import cubic

    @wp.kernel
    def sample(tex: wp.array2d(dtype=wp.vec3f), pts: wp.array(dtype=wp.vec2f), out: wp.array(dtype=wp.vec3f)):
        i = wp.tid()
        out[i] = cubic.sample(tex, pts[i][0], pts[i][1])

    rng = np.random.default_rng(5)
    tex = rng.normal(size=(6, 7, 3)).astype(np.float32)
    pts = np.array([[3.5, 2.5], [3.5 + 3e-5, 2.5 - 3e-5], [0.5, 0.5], [6.5, 5.5], [3.9, 2.2]], np.float32)
    out = wp.empty(len(pts), dtype=wp.vec3f, device="cpu")
    wp.launch(sample, dim=len(pts), inputs=[wp.array(tex, dtype=wp.vec3f, device="cpu"),
                                            wp.array(pts, dtype=wp.vec2f, device="cpu"), out], device="cpu")
    got = out.numpy()
    for k, (y, x) in enumerate([(2, 3), (2, 3), (0, 0), (5, 6)]):
        assert np.array_equal(got[k], tex[y, x])

    def keys(t):
        a = -0.75
        return np.array([a * t**3 - 2 * a * t**2 + a * t, (a + 2) * t**3 - (a + 3) * t**2 + 1,
                         -(a + 2) * t**3 + (2 * a + 3) * t**2 - a * t, -a * t**3 + a * t**2])

    fx, fy = 3.9 - 0.5, 2.2 - 0.5
    ix, iy = int(np.floor(fx)), int(np.floor(fy))
    wx, wy = keys(fx - ix), keys(fy - iy)
    rows = np.clip(np.arange(iy - 1, iy + 3), 0, 5)
    cols = np.clip(np.arange(ix - 1, ix + 3), 0, 6)
    expect = np.einsum("i,j,ijc->c", wy, wx, tex[rows][:, cols])
    np.testing.assert_allclose(got[4], expect, atol=1e-5)
