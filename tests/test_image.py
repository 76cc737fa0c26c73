"""Image input is read safely: header first, budgets before decoding, one line per failure.

Every hostile file is generated here (numpy, OpenCV and hand-written bytes),
small and fast.
"""

from __future__ import annotations

import os
import re
import struct
import time
import tracemalloc
import zlib

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import image
from tpsv.errors import TpsvError
from tpsv.image import MAX_PIXELS, read_header, read_image, read_image_alpha, read_labels, read_strokes

FORMAT_LIST = "unsupported image format; tpsv reads PNG, JPEG, WebP, TIFF, BMP and PNM"


# --------------------------------------------------------------------------- file builders


def _chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))


def png_bytes(width, height, depth=8, colour=2, idat=b"", extra=()) -> bytes:
    """A PNG with the given IHDR (CRCs sealed) and raw IDAT payload."""
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    chunks = [_chunk(b"IHDR", ihdr), *extra, _chunk(b"IDAT", idat), _chunk(b"IEND", b"")]
    return b"\x89PNG\r\n\x1a\n" + b"".join(chunks)


def palette_png(indices: np.ndarray, palette: np.ndarray, alpha: bytes | None = None) -> bytes:
    """An 8-bit palette PNG (OpenCV cannot write one)."""
    h, w = indices.shape
    rows = b"".join(b"\0" + row.astype(np.uint8).tobytes() for row in indices)
    extra = [_chunk(b"PLTE", palette.astype(np.uint8).tobytes())]
    if alpha is not None:
        extra.append(_chunk(b"tRNS", alpha))
    return png_bytes(w, h, 8, 3, zlib.compress(rows), extra)


def encode(ext: str, img: np.ndarray, params=()) -> bytes:
    ok, buf = cv2.imencode(ext, img, list(params))
    assert ok
    return buf.tobytes()


def _segment(marker: int, payload: bytes) -> bytes:
    return bytes([0xFF, marker]) + struct.pack(">H", len(payload) + 2) + payload


def flat_jpeg(blocks: np.ndarray, adobe: bool = False) -> bytes:
    """A baseline JPEG of flat 8x8 blocks, ``blocks`` (BH, BW, N) with N in 1, 3, 4.

    Written by hand because OpenCV cannot write CMYK: every block is its DC
    term alone (quantiser 1, a 4-bit DC code per category, EOB coded as '0').
    """
    blocks = np.asarray(blocks, np.int64)
    bh, bw, n = blocks.shape
    out = [b"\xff\xd8"]
    if adobe:  # Photoshop's marker: CMYK stored inverted, no colour transform
        out.append(_segment(0xEE, b"Adobe" + struct.pack(">HHHB", 100, 0, 0, 0)))
    out.append(_segment(0xDB, b"\x00" + b"\x01" * 64))
    components = b"".join(bytes([i + 1, 0x11, 0]) for i in range(n))
    out.append(_segment(0xC0, struct.pack(">BHHB", 8, bh * 8, bw * 8, n) + components))
    out.append(_segment(0xC4, b"\x00" + bytes([0, 0, 0, 12] + [0] * 12) + bytes(range(12))))
    out.append(_segment(0xC4, b"\x10" + bytes([1] + [0] * 15) + b"\x00"))
    out.append(_segment(0xDA, bytes([n]) + b"".join(bytes([i + 1, 0]) for i in range(n)) + b"\x00\x3f\x00"))
    bits, prev = [], [0] * n
    for block in blocks.reshape(-1, n):
        for c in range(n):
            dc = 8 * (int(block[c]) - 128)
            d, prev[c] = dc - prev[c], dc
            cat = abs(d).bit_length()
            bits.append(format(cat, "04b"))
            if cat:
                bits.append(format(d if d > 0 else d + (1 << cat) - 1, f"0{cat}b"))
            bits.append("0")
    s = "".join(bits)
    s += "1" * (-len(s) % 8)
    scan = int(s, 2).to_bytes(len(s) // 8, "big").replace(b"\xff", b"\xff\x00")
    return b"".join(out) + scan + b"\xff\xd9"


def tiff_bytes(entries, big: bool = False) -> bytes:
    """A big-endian TIFF of one IFD (at the start) of ``(tag, type, value)`` entries, no pixels."""
    count, entry, value = (">Q", ">HHQ", 8) if big else (">H", ">HHI", 4)
    ifd = struct.pack(count, len(entries)) + b"".join(
        struct.pack(entry, tag, kind, 1) + struct.pack(">I" if kind == 4 else ">H", v).ljust(value, b"\0")
        for tag, kind, v in entries) + struct.pack(count.replace("H", "I"), 0)
    head = b"MM\0+" + struct.pack(">HHQ", 8, 0, 16) if big else b"MM\0*" + struct.pack(">I", 8)
    return head + ifd


def with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """Insert an APP1 Exif segment (IFD0 with tag 0x0112) right after SOI."""
    tiff = b"MM\0*" + struct.pack(">IH", 8, 1) + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0)
    return jpeg[:2] + _segment(0xE1, b"Exif\0\0" + tiff + b"\0\0\0\0") + jpeg[2:]


def write(tmp_path, name: str, data: bytes):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def error_of(fn, *args) -> str:
    with pytest.raises(TpsvError) as info:
        fn(*args)
    return str(info.value)


@pytest.fixture
def no_decode(monkeypatch):
    """OpenCV must not see the data: any imdecode call fails the test."""
    def refuse(*_):
        raise AssertionError("cv2.imdecode was called")
    monkeypatch.setattr(image.cv2, "imdecode", refuse)


_Y, _X = np.mgrid[0:24, 0:32]
RGB = np.dstack([_X * 8, _Y * 10, 128 + (_X - _Y) * 3]).astype(np.uint8)  # smooth: JPEG keeps it


# --------------------------------------------------------------------------- header reader


@pytest.mark.parametrize("ext,fmt,channels", [
    (".png", "PNG", 3), (".jpg", "JPEG", 3), (".webp", "WebP", 3), (".tiff", "TIFF", 3),
    (".bmp", "BMP", 3), (".ppm", "PNM", 3), (".pgm", "PNM", 1),
])
def test_header_of_opencv_files(ext, fmt, channels):
    img = RGB[:, :, 0] if ext == ".pgm" else RGB
    h = read_header(encode(ext, img))
    assert (h.format, h.width, h.height, h.bit_depth, h.channels) == (fmt, 32, 24, 8, channels)
    assert h.frames == 1 and h.orientation == 1 and not h.truncated


def test_header_webp_lossless_with_alpha_and_16bit_png():
    rgba = np.dstack([RGB, np.full(RGB.shape[:2], 9, np.uint8)])
    h = read_header(encode(".webp", rgba, [cv2.IMWRITE_WEBP_QUALITY, 101]))
    assert (h.width, h.height, h.channels) == (32, 24, 4)
    h = read_header(encode(".png", RGB.astype(np.uint16) * 257))
    assert (h.bit_depth, h.channels) == (16, 3)


def test_header_plain_pnm_with_comments_and_bigtiff():
    h = read_header(b"P3\n# made by hand\n3 # width\n2\n255\n" + b"0 " * 18)
    assert (h.format, h.width, h.height, h.channels) == ("PNM", 3, 2, 3)
    assert read_header(b"P1 4 3\n" + b"0" * 12).bit_depth == 1
    assert read_header(b"P5 4 3 65535\n" + b"\0" * 24).bit_depth == 16
    # BigTIFF: width as LONG, height as SHORT, 8 bits, 3 samples.
    h = read_header(tiff_bytes([(256, 4, 70000), (257, 3, 5), (258, 3, 8), (277, 3, 3)], big=True))
    assert (h.format, h.width, h.height, h.channels) == ("TIFF", 70000, 5, 3)


def test_header_frames_of_animations_and_pages():
    frames = [np.full((20, 30, 3), v, np.uint8) for v in (10, 200, 90)]
    if hasattr(cv2, "imencodeanimation"):
        anim = cv2.Animation()
        anim.frames, anim.durations = frames, [100] * 3
        for ext in (".webp", ".png"):
            ok, buf = cv2.imencodeanimation(ext, anim)
            assert ok and read_header(buf.tobytes()).frames == 3
    ok, buf = cv2.imencodemulti(".tiff", frames)
    assert ok and read_header(buf.tobytes()).frames == 3


def test_header_exif_orientation_and_broken_exif_ignored():
    jpeg = encode(".jpg", RGB)
    assert read_header(with_exif_orientation(jpeg, 6)).orientation == 6
    assert read_header(with_exif_orientation(jpeg, 6)).upright_size == (24, 32)
    assert read_header(with_exif_orientation(jpeg, 99)).orientation == 1
    broken = jpeg[:2] + _segment(0xE1, b"Exif\0\0MM\0*\xff\xff\xff\xff") + jpeg[2:]
    assert read_header(broken).orientation == 1


@pytest.mark.parametrize("data,fmt", [
    (png_bytes(0, 10), "PNG"),
    (png_bytes(10, 10, depth=16, colour=3), "PNG"),
    (png_bytes(10, 10)[:30], "PNG"),
    (png_bytes(10, 10)[:20] + b"\xff" + png_bytes(10, 10)[21:], "PNG"),  # IHDR CRC broken
    (b"\xff\xd8\xff", "JPEG"),
    (flat_jpeg(np.zeros((1, 1, 1)))[:40], "JPEG"),
    (b"BM" + b"\0" * 12 + struct.pack("<IiiHH", 40, -5, 5, 1, 24), "BMP"),
    (b"BM" + b"\0" * 12 + struct.pack("<I", 77), "BMP"),
    (b"P6 0 5 255\n", "PNM"),
    (b"P6 5 5 70000\n", "PNM"),
    (b"P6 5 5", "PNM"),
    (b"RIFF\0\0\0\0WEBPVP8 \0\0\0\0\0\0\0\0\0\0", "WebP"),
    (b"RIFF\0\0\0\0WEBPXXXX", "WebP"),
    (b"II*\0\x10\0\0\0", "TIFF"),
    (tiff_bytes([(256, 3, 5)]), "TIFF"),  # no height
    (tiff_bytes([(256, 3, 5), (257, 3, 0)]), "TIFF"),
    (tiff_bytes([(256, 3, 64), (257, 3, 64), (322, 4, 2**16), (323, 4, 2**16)]), "TIFF"),  # tile bomb
])
def test_header_truncated_or_corrupt(data, fmt):
    with pytest.raises(TpsvError, match=rf"^x\.img: truncated or corrupt {fmt} header$"):
        read_header(data, "x.img")


@pytest.mark.parametrize("data", [b"hello, world\n" * 10, b"GIF89a" + b"\0" * 40, b"\0" * 64,
                                  b"RIFF\0\0\0\0AVI LIST"])
def test_unsupported_formats(tmp_path, data):
    path = write(tmp_path, "bad.img", data)
    assert error_of(read_image, path) == f"{path}: {FORMAT_LIST}"


def test_empty_and_missing_files(tmp_path):
    path = write(tmp_path, "empty.png", b"")
    assert error_of(read_image, path) == f"{path}: empty file"
    assert "cannot read" in error_of(read_image, tmp_path / "missing.png")
    assert error_of(read_image, tmp_path).startswith(f"{tmp_path}: ")


def test_file_size_bounded_before_reading(tmp_path, monkeypatch):
    path = write(tmp_path, "big.png", encode(".png", RGB))
    monkeypatch.setattr(image, "MAX_FILE_BYTES", 100)
    assert error_of(read_image, path) == f"{path}: input larger than 100 bytes"


# --------------------------------------------------------------------------- budgets from the header


def test_bomb_png_refused_from_header_without_allocating(tmp_path, no_decode):
    idat = zlib.compress(b"\0" * 200_000, 9)  # a few hundred bytes standing for 10.8 GB
    path = write(tmp_path, "bomb.png", png_bytes(60000, 60000, idat=idat))
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        msg = error_of(read_image, path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert msg == f"{path} is 60000x60000 px; tpsv accepts at most {MAX_PIXELS} px"
    assert peak < 1 << 20
    assert time.perf_counter() - t0 < 1.0


def _sof_patched(width: int, height: int) -> bytes:
    jpeg = flat_jpeg(np.zeros((1, 1, 1)))
    at = jpeg.index(b"\xff\xc0") + 5
    return jpeg[:at] + struct.pack(">HH", height, width) + jpeg[at + 4:]


@pytest.mark.parametrize("fmt,data", [
    ("PNG", png_bytes(60000, 60000, idat=zlib.compress(b"\0"))),
    ("JPEG", _sof_patched(60000, 60000)),
    ("WebP", b"RIFF\0\0\0\0WEBPVP8X" + struct.pack("<IB3x", 10, 0) + (60000 - 1).to_bytes(3, "little") * 2),
    ("TIFF", tiff_bytes([(256, 4, 60000), (257, 4, 60000)])),
    ("BMP", b"BM" + b"\0" * 12 + struct.pack("<IiiHH", 40, 60000, -60000, 1, 24)),
    ("PNM", b"P6 60000 60000 255\n"),
])
def test_bomb_in_every_format(tmp_path, no_decode, fmt, data):
    path = write(tmp_path, "bomb", data)
    assert read_header(data).format == fmt
    assert error_of(read_image, path) == f"{path} is 60000x60000 px; tpsv accepts at most {MAX_PIXELS} px"


@pytest.mark.parametrize("width,height", [(40000, 40000), (2**31 - 1, 1), (1, 2**31 - 1)])
def test_png_over_opencv_limit_is_one_sentence(tmp_path, no_decode, width, height):
    path = write(tmp_path, "huge.png", png_bytes(width, height, idat=zlib.compress(b"\0")))
    assert error_of(read_image, path) == f"{path} is {width}x{height} px; tpsv accepts at most {MAX_PIXELS} px"
    assert error_of(read_labels, path).startswith(f"{path} is {width}x{height} px")
    assert error_of(read_strokes, path).startswith(f"{path} is {width}x{height} px")


def test_side_budget(tmp_path, no_decode):
    path = write(tmp_path, "strip.png", png_bytes(2_000_000, 2, idat=zlib.compress(b"\0")))
    assert error_of(read_image, path) == f"{path} is 2000000x2 px; tpsv accepts at most 65535 px per side"


def test_pixel_budget_admits_24_megapixel_photos():
    assert 6000 * 4000 <= MAX_PIXELS


def test_16bit_pnm_refused_from_header(tmp_path, no_decode):
    # 16-bit PNG and TIFF are read (tests/test_formats.py); OpenCV swaps the bytes of 16-bit PNM
    path = write(tmp_path, "deep.ppm", b"P6 4 3 65535\n" + b"\0" * 72)
    assert error_of(read_image, path) == f"{path}: 16-bit PNM image; tpsv reads 8-bit images, and 16-bit PNG and TIFF"


def test_float_tiff_with_nan_refused(tmp_path, no_decode):
    img = RGB.astype(np.float32) / 255
    img[3, 4] = np.nan
    path = write(tmp_path, "nan.tiff", encode(".tiff", img))
    assert error_of(read_image, path) == (
        f"{path}: 32-bit floating-point image; tpsv reads 8- and 16-bit integer images only")
    assert "floating-point" in error_of(read_labels, path)


def test_16bit_labels_still_read_and_budgeted(tmp_path, monkeypatch):
    lab = (np.arange(24 * 32).reshape(24, 32) * 97 % 1000).astype(np.uint16)
    path = write(tmp_path, "lab.png", encode(".png", lab))
    np.testing.assert_array_equal(read_labels(path, shape=(24, 32)), lab)
    monkeypatch.setattr(image, "MAX_PIXELS", 100)
    assert error_of(read_labels, path) == f"{path} is 32x24 px; tpsv accepts at most 100 px"


def test_too_small_refused_from_header(tmp_path, no_decode):
    path = write(tmp_path, "dot.png", encode(".png", RGB[:1, :5]))
    assert error_of(read_image, path) == f"{path}: image of 5x1 is too small (at least 2x2)"


# --------------------------------------------------------------------------- decoding


@pytest.mark.parametrize("ext", [".png", ".jpg", ".webp", ".tiff", ".bmp", ".ppm"])
def test_truncated_files_are_one_line(tmp_path, ext, capfd):
    data = encode(ext, RGB)
    for cut in (len(data) // 2, len(data) - 1, 30):
        path = write(tmp_path, f"cut{cut}{ext}", data[:cut])
        assert re.fullmatch(rf"{re.escape(str(path))}: truncated or corrupt \w+ (header|data)",
                            error_of(read_image, path))
    assert capfd.readouterr().err == ""  # libpng, libjpeg and OpenCV kept quiet


def test_corrupt_png_data_and_missing_jpeg_end(tmp_path, capfd):
    png = bytearray(encode(".png", RGB))
    png[-20] ^= 0xFF  # inside IDAT: zlib check fails, libpng would print
    path = write(tmp_path, "crc.png", bytes(png))
    assert error_of(read_image, path) == f"{path}: truncated or corrupt PNG data"
    jpeg = encode(".jpg", RGB)
    path = write(tmp_path, "noeoi.jpg", jpeg[:-2])
    assert error_of(read_image, path) == f"{path}: truncated or corrupt JPEG data"
    assert capfd.readouterr().err == ""


def test_opencv_log_level_and_stderr_restored(tmp_path, capfd):
    level = cv2.utils.logging.getLogLevel()
    path = write(tmp_path, "cut.png", encode(".png", RGB)[:-5])
    error_of(read_image, path)
    assert cv2.utils.logging.getLogLevel() == level
    os.write(2, b"still here\n")
    assert capfd.readouterr().err == "still here\n"


@pytest.mark.parametrize("ext,tol", [(".png", 0), (".bmp", 0), (".ppm", 0), (".tiff", 0),
                                     (".webp", 0), (".jpg", 8)])
def test_rgb_round_trip(tmp_path, ext, tol):
    params = [cv2.IMWRITE_WEBP_QUALITY, 101] if ext == ".webp" else [cv2.IMWRITE_JPEG_QUALITY, 100]
    path = write(tmp_path, f"ok{ext}", encode(ext, RGB, params))
    rgb = read_image(path)
    assert rgb.shape == (24, 32, 3) and rgb.dtype == np.float32
    assert np.abs(rgb * 255 - RGB[:, :, ::-1]).max() <= tol + 1e-3


@pytest.mark.parametrize("ext", [".png", ".jpg", ".pgm"])
def test_grey_becomes_rgb(tmp_path, ext):
    grey = np.tile(np.arange(0, 256, 8, dtype=np.uint8), (24, 1))
    rgb = read_image(write(tmp_path, f"g{ext}", encode(ext, grey)))
    assert rgb.shape == (24, 32, 3)
    assert np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2])


def test_palette_png_decodes_to_rgb(tmp_path):
    palette = np.array([[255, 0, 0], [0, 128, 255], [10, 20, 30]])
    idx = np.arange(6 * 4).reshape(6, 4) % 3
    rgb = read_image(write(tmp_path, "pal.png", palette_png(idx, palette)))
    np.testing.assert_array_equal(np.rint(rgb * 255).astype(int), palette[idx])
    path = write(tmp_path, "pal-t.png", palette_png(idx, palette, alpha=b"\xff\x00\xff"))
    assert "transparency" in error_of(read_image, path)


def test_cmyk_jpeg_decodes_to_rgb(tmp_path):
    # Adobe CMYK is stored inverted (255 = no ink): pure cyan, white, black, yellow.
    cmyk = np.array([[[0, 255, 255, 255], [255, 255, 255, 255], [255, 255, 255, 0], [255, 255, 0, 255]]])
    path = write(tmp_path, "cmyk.jpg", flat_jpeg(cmyk, adobe=True))
    assert read_header(path.read_bytes()).channels == 3
    rgb = np.rint(read_image(path) * 255)[0, ::8]
    np.testing.assert_allclose(rgb, [[0, 255, 255], [255, 255, 255], [0, 0, 0], [255, 255, 0]], atol=2)


def test_rgba_opaque_accepted_transparent_refused_by_the_opaque_reader(tmp_path):
    rgba = np.dstack([RGB, np.full(RGB.shape[:2], 255, np.uint8)])
    rgb = read_image(write(tmp_path, "opaque.png", encode(".png", rgba)))
    np.testing.assert_array_equal(np.rint(rgb * 255), RGB[:, :, ::-1])
    assert read_image_alpha(write(tmp_path, "opaque.png", encode(".png", rgba)))[1] is None
    rgba[5, 5, 3] = 0
    rgba[6, 5, 3] = 128
    path = write(tmp_path, "hole.png", encode(".png", rgba))
    assert error_of(read_image, path) == (
        f"{path}: image has transparent pixels; this command reads opaque images (vectorize keeps transparency): "
        "flatten it onto a background first")
    rgb, alpha = read_image_alpha(path)
    np.testing.assert_array_equal(np.rint(rgb * 255), RGB[:, :, ::-1])  # straight colours, not premultiplied
    assert alpha.shape == RGB.shape[:2] and alpha[5, 5] == 0 and alpha[6, 5] == np.float32(128 / 255)
    assert (alpha == 1).sum() == alpha.size - 2
    # 16-bit RGBA: alpha / 65535
    deep = rgba.astype(np.uint16) * 257
    _, alpha16 = read_image_alpha(write(tmp_path, "deep.png", encode(".png", deep)))
    np.testing.assert_array_equal(alpha16, alpha)


def _stored(upright: np.ndarray, orientation: int) -> np.ndarray:
    """The array a camera stores so that ``orientation`` displays ``upright``."""
    return {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
            5: lambda a: a.swapaxes(0, 1), 6: lambda a: np.rot90(a, 1),
            7: lambda a: np.rot90(a[:, ::-1], -1), 8: lambda a: np.rot90(a, -1)}[orientation](upright)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_applied(tmp_path, orientation):
    # 2x3 blocks of 16 px, each a distinct flat grey: a JPEG keeps them exactly.
    upright = np.kron(np.array([[20, 60, 100], [140, 180, 220]], np.uint8), np.ones((16, 16), np.uint8))
    stored = np.ascontiguousarray(_stored(upright, orientation))
    jpeg = with_exif_orientation(encode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, 100]), orientation)
    rgb = read_image(write(tmp_path, f"o{orientation}.jpg", jpeg))
    assert rgb.shape == (32, 48, 3)
    assert np.abs(rgb[..., 0] * 255 - upright).max() <= 2
    strokes = read_strokes(tmp_path / f"o{orientation}.jpg")
    assert strokes.shape == (32, 48, 3) and np.abs(strokes[..., 0].astype(int) - upright).max() <= 2


def test_animated_webp_gives_first_frame(tmp_path):
    if not hasattr(cv2, "Animation"):
        pytest.skip("OpenCV without animation support")
    anim = cv2.Animation()
    anim.frames = [np.full((20, 30, 3), v, np.uint8) for v in (10, 200, 90)]
    anim.durations = [100] * 3
    ok, buf = cv2.imencodeanimation(".webp", anim, [cv2.IMWRITE_WEBP_QUALITY, 101])
    rgb = read_image(write(tmp_path, "anim.webp", buf.tobytes()))
    assert rgb.shape == (20, 30, 3) and np.all(np.rint(rgb * 255) == 10)


def test_strokes_16bit_converted(tmp_path):
    deep = RGB.astype(np.uint16) * 257
    out = read_strokes(write(tmp_path, "s.png", encode(".png", deep)))
    assert out.dtype == np.uint8 and np.array_equal(out, RGB[:, :, ::-1])


# --------------------------------------------------------------------------- through the CLI


def _hostile_files(tmp_path) -> dict:
    jpeg, webp = encode(".jpg", RGB), encode(".webp", RGB)
    return {
        "bomb.png": png_bytes(60000, 60000, idat=zlib.compress(b"\0" * 1000)),
        "crc.png": encode(".png", RGB)[:-20] + b"\0" * 20,
        "cut.jpg": jpeg[: len(jpeg) // 2],
        "cut.webp": webp[: len(webp) // 2],
        "float.tiff": encode(".tiff", RGB.astype(np.float32)),
        "text.png": b"not an image at all\n",
        "empty.png": b"",
        "magic.png": b"GIF89a" + b"\0" * 100,
    }


def test_cli_hostile_images_one_line_exit_1_no_output(tmp_path, capfd):
    cli = pytest.importorskip("tpsv.cli")
    for name, data in _hostile_files(tmp_path).items():
        bad = write(tmp_path, name, data)
        out = tmp_path / f"{name}.tpsv"
        result = CliRunner().invoke(cli.main, ["vectorize", str(bad), "-o", str(out)])
        lines = result.stderr.splitlines()
        assert result.exit_code == 1, (name, result.output)
        assert len(lines) == 1 and lines[0].startswith("tpsv: error:"), (name, lines)
        assert "internal error" not in lines[0], name
        assert not out.exists()
        assert capfd.readouterr().err == ""  # nothing printed below Python either

