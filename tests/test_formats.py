"""Image formats in and out: outputs by extension, 16-bit, quality, and files treated as users expect.

Every image here is tiny: 60x40 renders of a model vectorised once from a 48x32
synthetic photo, or a few dozen synthetic pixels.
"""

from __future__ import annotations

import os
import stat
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import codec
from tpsv.cli import main
from tpsv.cli import render as cli_render
from tpsv.errors import TpsvError
from tpsv.image import (MAX_PIXELS, OUTPUT_QUALITY, OutputFormat, encode_image, output_format, read_image,
                        to_uint8, to_uint16, write_image)
from tpsv.png import PngWriter, png_chunks
from tpsv.rendering.raster import render

W, H = 60, 40
ROOT_USER = os.geteuid() == 0


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    """A .tpsv vectorised from a 48x32 photo: smooth ramps, a rectangle and a disc (a few regions)."""
    d = tmp_path_factory.mktemp("formats")
    yy, xx = np.mgrid[0:32, 0:48] / 32.0
    rgb = np.dstack([xx / 1.5, yy, 0.5 + 0.3 * np.sin(3 * xx)]).astype(np.float32)
    rgb[8:24, 10:22] = (0.9, 0.2, 0.1)
    rgb[(xx - 1.0) ** 2 + (yy - 0.5) ** 2 < 0.06] = (0.1, 0.3, 0.9)
    (d / "photo.png").write_bytes(encode_image(rgb))
    code, _, lines = run("vectorize", d / "photo.png", "-o", d / "model.tpsv")
    assert code == 0, lines
    return d / "model.tpsv"


@pytest.fixture(scope="module")
def model(model_path):
    return codec.load(model_path)


@pytest.fixture(scope="module")
def pixels(model):
    """The float render every CLI output below encodes."""
    return render(model, width=W, height=H)


def run(*args):
    """``tpsv ARGS`` in-process: (exit status, stdout bytes, stderr lines)."""
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout_bytes, r.stderr.splitlines()


def decode(data: bytes) -> np.ndarray:
    """RGB array of an image file's bytes, at its own depth."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return img[:, :, ::-1]


def psnr(a, b, top=255.0) -> float:
    mse = np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(top * top / mse)


def header_only_png(width: int, height: int) -> bytes:
    """The signature and an IHDR (8-bit RGB) claiming ``width x height``, and nothing else."""
    ihdr = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + ihdr + struct.pack(">I", zlib.crc32(ihdr))


def one_error(lines, code, want_code=1) -> str:
    """The one error line of a failed command (``tpsv: error:`` at exit 1, click's ``Error:`` at 2)."""
    assert code == want_code, lines
    if want_code == 1:
        assert len(lines) == 1 and lines[0].startswith("tpsv: error: "), lines
        return lines[0][len("tpsv: error: "):]
    errors = [line for line in lines if line.startswith("Error: ")]
    assert len(errors) == 1 and not any("Traceback" in line for line in lines), lines
    return errors[0][len("Error: "):]


# --------------------------------------------------------------------------- choosing the format


@pytest.mark.parametrize("path, name, depth, quality, want", [
    ("out.png", None, 8, None, ("PNG", 8, OUTPUT_QUALITY)),
    ("OUT.PNG", None, 16, None, ("PNG", 16, OUTPUT_QUALITY)),
    ("a/b.v2/out.jpg", None, 8, 40, ("JPEG", 8, 40)),
    ("out.JPEG", None, 8, None, ("JPEG", 8, OUTPUT_QUALITY)),
    ("out.webp", "webp", 8, 100, ("WebP", 8, 100)),
    ("out.tif", None, 16, None, ("TIFF", 16, OUTPUT_QUALITY)),
    ("out.tiff", "TIF", 8, None, ("TIFF", 8, OUTPUT_QUALITY)),
    ("-", None, 8, None, ("PNG", 8, OUTPUT_QUALITY)),
    ("-", "jpg", 8, 70, ("JPEG", 8, 70)),
    ("/dev/null", None, 16, None, ("PNG", 16, OUTPUT_QUALITY)),
])
def test_output_format_by_extension_then_name(path, name, depth, quality, want):
    f = output_format(path, name, depth, quality)
    assert (f.name, f.depth, f.quality) == want


@pytest.mark.parametrize("path, name, depth, quality, message", [
    ("out.gif", None, 8, None, "out.gif: tpsv does not write .gif images; name the file .png, .jpg/.jpeg, .webp or "
                               ".tif/.tiff"),
    ("model.tpsv", None, 8, None, "model.tpsv: tpsv does not write .tpsv images; name the file .png, .jpg/.jpeg, "
                                  ".webp or .tif/.tiff"),
    ("out.png", "jpeg", 8, None, "out.png names a PNG file, but the format asked for is JPEG"),
    ("-", "gif", 8, None, "unknown image format 'gif'; tpsv writes png, jpeg, webp or tiff"),
    ("out.jpg", None, 16, None, "JPEG holds 8 bits a sample; 16-bit output needs a PNG or TIFF file"),
    ("out.webp", None, 16, None, "WebP holds 8 bits a sample; 16-bit output needs a PNG or TIFF file"),
    ("out.png", None, 8, 90, "a quality applies to JPEG and WebP output; PNG is lossless"),
    ("out.tiff", None, 8, 90, "a quality applies to JPEG and WebP output; TIFF is lossless"),
    ("out.jpg", None, 8, 0, "quality 0 is not in 1-100"),
    ("out.png", None, 12, None, "image depth 12 bits; tpsv writes 8 or 16 bits a sample"),
])
def test_output_format_refusals_are_one_line(path, name, depth, quality, message):
    with pytest.raises(TpsvError) as info:
        output_format(path, name, depth, quality)
    assert str(info.value) == message


# --------------------------------------------------------------------------- round trips through the CLI


@pytest.mark.parametrize("name, args", [
    ("out.png", ()), ("out.png", ("--depth", "16")), ("out.tif", ()), ("out.TIFF", ("--depth", "16")),
    ("out.webp", ("--quality", "100")),
])
def test_lossless_outputs_are_the_render_rounded(tmp_path, pixels, name, args, model_path):
    out = tmp_path / name
    code, _, lines = run("render", model_path, "-o", out, "--size", f"{W}x{H}", *args)
    assert code == 0, lines
    got = decode(out.read_bytes())
    want = to_uint16(pixels) if "16" in args else to_uint8(pixels)
    assert got.dtype == want.dtype and np.array_equal(got, want)
    if "16" in args:  # round(v * 65535), the stated rule
        assert np.array_equal(got, np.rint(pixels.astype(np.float64) * 65535).astype(np.uint16))


# Measured on this render: JPEG 39.5 dB (4:4:4 from quality 90), WebP 27.5 dB (lossy WebP is always 4:2:0,
# which the saturated region borders of a 60x40 render feel; at 240x160, 33.4 dB).
@pytest.mark.parametrize("name, min_psnr", [("out.jpg", 36.0), ("out.jpeg", 36.0), ("out.webp", 25.0)])
def test_lossy_outputs_are_close_at_the_default_quality(tmp_path, pixels, name, min_psnr, model_path):
    out = tmp_path / name
    code, _, lines = run("render", model_path, "-o", out, "--size", f"{W}x{H}")
    assert code == 0, lines
    data = out.read_bytes()
    assert data.startswith(b"\xff\xd8") if "jp" in name else data[8:12] == b"WEBP"
    got = decode(data)
    assert got.shape == (H, W, 3) and psnr(got, to_uint8(pixels)) >= min_psnr


def test_quality_trades_size_for_fidelity(tmp_path, pixels, model_path):
    sizes, errors = {}, {}
    for q in (20, 60, 95):
        out = tmp_path / f"q{q}.jpg"
        code, _, lines = run("render", model_path, "-o", out, "--size", f"{W}x{H}", "--quality", q)
        assert code == 0, lines
        sizes[q] = len(out.read_bytes())
        errors[q] = psnr(decode(out.read_bytes()), to_uint8(pixels))
    assert sizes[20] < sizes[60] < sizes[95]
    assert errors[20] < errors[60] < errors[95]
    # the default is the stated one
    code, _, _ = run("render", model_path, "-o", tmp_path / "default.jpg", "--size", f"{W}x{H}")
    assert (tmp_path / "default.jpg").read_bytes() == encode_image(pixels, OutputFormat("JPEG", 8, OUTPUT_QUALITY))


def test_stdout_is_png_unless_format_says(tmp_path, pixels, model_path):
    code, data, lines = run("render", model_path, "-o", "-", "--size", f"{W}x{H}")
    assert code == 0 and data.startswith(b"\x89PNG\r\n\x1a\n") and np.array_equal(decode(data), to_uint8(pixels))
    code, data, _ = run("render", model_path, "-o", "-", "--size", f"{W}x{H}", "--format", "tiff", "--depth", "16")
    assert code == 0 and data[:4] == b"II*\0" and np.array_equal(decode(data), to_uint16(pixels))
    code, data, _ = run("render", model_path, "-o", "-", "--size", f"{W}x{H}", "--format", "jpeg", "--quality", "50")
    assert code == 0 and data.startswith(b"\xff\xd8")


def test_write_image_by_extension(tmp_path, pixels):
    write_image(tmp_path / "a.tif", pixels, depth=16)
    assert np.array_equal(decode((tmp_path / "a.tif").read_bytes()), to_uint16(pixels))
    write_image(tmp_path / "a.webp", pixels, quality=100)
    assert np.array_equal(decode((tmp_path / "a.webp").read_bytes()), to_uint8(pixels))
    with pytest.raises(TpsvError, match="does not write .bmp images"):
        write_image(tmp_path / "a.bmp", pixels)
    assert not (tmp_path / "a.bmp").exists()


def test_uint8_to_16_bits_is_exact():
    v = np.arange(256, dtype=np.uint8)
    assert np.array_equal(to_uint16(v), to_uint16(v.astype(np.float32) / 255))


# --------------------------------------------------------------------------- 16-bit PNG streamed


def test_16bit_png_streamed_equals_one_piece(model, pixels):
    fmt = OutputFormat("PNG", 16)
    whole = b"".join(cli_render.render_file(model, W, H, fmt))
    streamed = b"".join(cli_render.render_file(model, W, H, fmt, max_pixels=W * 7))  # 6 bands of 7 rows
    assert whole != streamed  # OpenCV's encoder for one piece, tpsv.png for bands
    assert np.array_equal(decode(whole), decode(streamed))
    assert np.array_equal(decode(streamed), to_uint16(pixels))
    eight = b"".join(cli_render.render_file(model, W, H, max_pixels=W * 7))
    assert np.array_equal(decode(eight), to_uint8(pixels))


def test_png_writer_16bit_is_big_endian_and_exact():
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 65536, (9, 5, 3)).astype(np.uint16)
    rows[0, 0] = (0x0102, 0xFF00, 0x00FF)  # high and low bytes distinct
    data = b"".join(png_chunks(5, 9, [(0, rows[:4]), (4, rows[4:])], depth=16))
    assert data[24] == 16  # IHDR bit depth
    assert np.array_equal(decode(data), rows)
    with pytest.raises(TpsvError, match="PNG rows must be uint16"):
        PngWriter([].append, 5, 9, depth=16).write(rows.astype(np.uint8))


# --------------------------------------------------------------------------- every command that writes a picture


def test_magnify_stylize_and_edits_write_by_extension(tmp_path, model_path):
    code, _, lines = run("magnify", model_path, "-o", tmp_path / "m.tif", "--factor", "0.5", "--depth", "16")
    assert code == 0, lines
    assert decode((tmp_path / "m.tif").read_bytes()).dtype == np.uint16
    code, _, lines = run("stylize", model_path, "-o", tmp_path / "s.webp", "--scale", "0.5", "--quality", "60")
    assert code == 0, lines
    assert (tmp_path / "s.webp").read_bytes()[8:12] == b"WEBP"
    code, _, lines = run("recolor", model_path, "-o", tmp_path / "r.tpsv", "--hue", "30", "--render", tmp_path / "r.png",
                         "--scale", "0.5", "--depth", "16")
    assert code == 0, lines
    r = decode((tmp_path / "r.png").read_bytes())
    assert r.dtype == np.uint16 and r.shape == (16, 24, 3)
    code, _, lines = run("deform", model_path, "-o", tmp_path / "d.tpsv", "--affine", "0:1,0,1,0,1,0",
                         "--render", tmp_path / "d.jpg", "--scale", "0.5", "--quality", "80")
    assert code == 0, lines
    assert (tmp_path / "d.jpg").read_bytes().startswith(b"\xff\xd8")


def test_previews_by_extension(tmp_path):
    rgb = np.zeros((24, 32, 3), np.uint8)
    rgb[:, 16:] = (200, 40, 10)
    rgb[8:16, 4:12] = (10, 90, 220)
    photo = tmp_path / "photo.png"
    photo.write_bytes(encode_image(rgb))
    code, _, lines = run("segment", photo, "-o", tmp_path / "lab.png", "--regions", "3",
                         "--preview", tmp_path / "p.tif")
    assert code == 0, lines
    from tpsv.geometry.segment import overlay_regions
    from tpsv.image import read_labels
    want = overlay_regions(read_image(photo), read_labels(tmp_path / "lab.png"))
    assert np.array_equal(decode((tmp_path / "p.tif").read_bytes()), want)
    code, _, lines = run("vectorize", photo, "-o", tmp_path / "v.tpsv", "--preview", tmp_path / "v.jpg")
    assert code == 0, lines
    assert (tmp_path / "v.jpg").read_bytes().startswith(b"\xff\xd8")


@pytest.mark.parametrize("args, option", [
    (("render", "{missing}", "-o", "{out}.gif"), "-o"),
    (("render", "{missing}", "-o", "{out}.tpsv"), "-o"),
    (("magnify", "{model}", "-o", "{out}.bmp", "--factor", "2"), "-o"),  # magnify reads PATH's magic first
    (("stylize", "{missing}", "-o", "{out}.svg"), "-o"),
    (("segment", "{missing}", "-o", "{out}.png", "--preview", "{out}.gif"), "--preview"),
    (("vectorize", "{missing}", "-o", "{out}.tpsv", "--preview", "{out}.pdf"), "--preview"),
    (("recolor", "{missing}", "-o", "{out}.tpsv", "--hue", "3", "--render", "{out}.ppm"), "--render"),
])
def test_unknown_extension_is_a_usage_error_before_any_work(tmp_path, args, option, model_path):
    missing, out = tmp_path / "missing-input", tmp_path / "out"
    # the input does not exist: reaching any work would fail with exit 1 instead
    code, _, lines = run(*(a.format(missing=missing, out=out, model=model_path) for a in args))
    msg = one_error(lines, code, want_code=2)
    assert "tpsv does not write" in msg and msg.endswith("name the file .png, .jpg/.jpeg, .webp or .tif/.tiff")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (("render", "{m}", "-o", "{out}.jpg", "--depth", "16"),
     "JPEG holds 8 bits a sample; 16-bit output needs a PNG or TIFF file"),
    (("render", "{m}", "-o", "{out}.png", "--quality", "80"), "a quality applies to JPEG and WebP output; PNG is lossless"),
    (("render", "{m}", "-o", "{out}.png", "--format", "webp"), "{out}.png names a PNG file, but the format asked for is WebP"),
    (("recolor", "{m}", "-o", "{out}.tpsv", "--hue", "3", "--quality", "80"),
     "--quality and --depth describe the --render picture; give --render"),
])
def test_options_that_do_not_fit_the_format_are_usage_errors(tmp_path, args, message, model_path):
    out = tmp_path / "out"
    code, _, lines = run(*(a.format(m=model_path, out=out) for a in args))
    assert one_error(lines, code, want_code=2) == message.format(out=out)
    assert list(tmp_path.iterdir()) == []


def test_large_non_png_outputs_refused_before_rendering(tmp_path, monkeypatch, model_path):
    monkeypatch.setattr(cli_render, "MAX_ARRAY_PIXELS", W * H - 1)
    out = tmp_path / "big.jpg"
    code, _, lines = run("render", model_path, "-o", out, "--size", f"{W}x{H}")
    assert one_error(lines, code) == (f"a {W}x{H} px JPEG is encoded whole, and tpsv holds at most {W * H - 1:,} px "
                                      "in memory; write a PNG, which is streamed at any size")
    assert not out.exists()
    code, _, lines = run("render", model_path, "-o", tmp_path / "big.png", "--size", f"{W}x{H}", "--depth", "16")
    assert code == 0, lines
    code, _, lines = run("render", model_path, "-o", tmp_path / "wide.webp", "--size", "16384x2")
    assert one_error(lines, code) == "a WebP image is at most 16383 px a side, not 16384x2 px; write PNG, JPEG or TIFF"


# --------------------------------------------------------------------------- 16-bit input


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_16bit_input_read_as_value_over_65535(tmp_path, ext):
    rng = np.random.default_rng(7)
    deep = rng.integers(0, 65536, (6, 5, 3)).astype(np.uint16)
    deep[0, 0] = (0, 1, 65535)
    path = tmp_path / f"deep{ext}"
    assert cv2.imwrite(str(path), deep[:, :, ::-1])
    rgb = read_image(path)
    assert rgb.dtype == np.float32
    assert np.array_equal(rgb, deep.astype(np.float32) / np.float32(65535))
    assert np.array_equal(to_uint16(rgb), deep)  # nothing lost before an encoder
    # grey; and an 8-bit image stored in 16 bits (v * 257) reads as the same floats
    grey = deep[:, :, 1]
    assert cv2.imwrite(str(tmp_path / f"grey{ext}"), grey)
    g = read_image(tmp_path / f"grey{ext}")
    assert np.array_equal(g, np.repeat(grey[:, :, None] / np.float32(65535), 3, axis=2).astype(np.float32))
    eight = (deep >> 8).astype(np.uint8)
    assert cv2.imwrite(str(tmp_path / f"e8{ext}"), eight)
    assert cv2.imwrite(str(tmp_path / f"e16{ext}"), eight.astype(np.uint16) * 257)
    assert np.array_equal(read_image(tmp_path / f"e8{ext}"), read_image(tmp_path / f"e16{ext}"))


def test_16bit_alpha_opaque_read_transparent_refused(tmp_path):
    rgba = np.full((4, 4, 4), 65535, np.uint16)
    rgba[..., 0] = 1000
    assert cv2.imwrite(str(tmp_path / "opaque.png"), rgba)
    assert np.allclose(read_image(tmp_path / "opaque.png")[..., 2], 1000 / 65535)
    rgba[1, 2, 3] = 65534
    path = tmp_path / "hole.png"
    assert cv2.imwrite(str(path), rgba)
    with pytest.raises(TpsvError) as info:
        read_image(path)
    assert str(info.value) == (f"{path}: image has transparent pixels; this command reads opaque images "
                               "(vectorize keeps transparency): flatten it onto a background first")


def test_float_signed_and_other_depths_still_refused(tmp_path):
    img = np.zeros((4, 4, 3), np.float32)
    cases = {"float.tif": (img, "32-bit floating-point image; tpsv reads 8- and 16-bit integer images only"),
             "signed.tif": (img.astype(np.int16), "16-bit signed image; tpsv reads 8- and 16-bit unsigned images only"),
             "deep.ppm": (img.astype(np.uint16), "16-bit PNM image; tpsv reads 8-bit images, and 16-bit PNG and TIFF")}
    for name, (arr, message) in cases.items():
        path = tmp_path / name
        assert cv2.imwrite(str(path), arr)
        with pytest.raises(TpsvError) as info:
            read_image(path)
        assert str(info.value) == f"{path}: {message}"


# --------------------------------------------------------------------------- files as users expect


@pytest.mark.parametrize("umask", [0o022, 0o077])
@pytest.mark.parametrize("name", ["new.png", "new.jpg", "new.tif"])
def test_new_outputs_get_what_open_gives_under_the_umask(tmp_path, umask, name, model_path):
    old = os.umask(umask)
    try:
        with open(tmp_path / "by-open", "w"):
            pass
        code, _, lines = run("render", model_path, "-o", tmp_path / name, "--scale", "0.5")
    finally:
        os.umask(old)
    assert code == 0, lines
    want = stat.S_IMODE(os.stat(tmp_path / "by-open").st_mode)
    assert want == 0o666 & ~umask
    assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == want


def test_replaced_output_keeps_its_mode(tmp_path, model_path):
    out = tmp_path / "old.webp"
    out.write_bytes(b"old")
    os.chmod(out, 0o640)
    code, _, lines = run("render", model_path, "-o", out, "--scale", "0.5")
    assert code == 0, lines
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o640 and out.read_bytes()[8:12] == b"WEBP"


def test_inputs_never_clobbered(tmp_path):
    photo = tmp_path / "in.png"
    photo.write_bytes(encode_image(np.full((8, 8, 3), 0.5, np.float32)))
    before = photo.read_bytes()
    (tmp_path / "link.png").symlink_to(photo)
    for args in (("magnify", photo, "-o", photo, "--factor", "2"),
                 ("magnify", photo, "-o", tmp_path / "link.png", "--factor", "2"),
                 ("segment", photo, "-o", tmp_path / "lab.png", "--preview", photo)):
        code, _, lines = run(*args)
        msg = one_error(lines, code)
        assert "is the input file" in msg and msg.endswith("choose another output path")
        assert photo.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.png", "link.png"]


def test_header_claiming_60000_squared_is_one_sentence(tmp_path):
    path = tmp_path / "huge.png"
    path.write_bytes(header_only_png(60000, 60000))
    sentence = f"{path} is 60000x60000 px; tpsv accepts at most {MAX_PIXELS} px"
    with pytest.raises(TpsvError) as info:
        read_image(path)
    assert str(info.value) == sentence
    for args in (("vectorize", path, "-o", tmp_path / "o.tpsv"), ("segment", path, "-o", tmp_path / "o.png"),
                 ("magnify", path, "-o", tmp_path / "o.png", "--factor", "2")):
        code, _, lines = run(*args)
        assert one_error(lines, code) == sentence
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.png"]


def test_unreadable_inputs_are_one_line(tmp_path):
    missing = tmp_path / "missing.png"
    with pytest.raises(TpsvError) as info:
        read_image(missing)
    assert str(info.value) == f"{missing}: cannot read (No such file or directory)"
    with pytest.raises(TpsvError) as info:
        read_image(tmp_path)
    assert str(info.value) == f"{tmp_path}: is a directory, not a file"
    code, _, lines = run("vectorize", missing, "-o", tmp_path / "o.tpsv")
    assert one_error(lines, code) == f"{missing}: cannot read (No such file or directory)"
    code, _, lines = run("render", missing, "-o", tmp_path / "o.png")
    assert one_error(lines, code).startswith(f"{missing}: ")
    code, _, lines = run("segment", tmp_path, "-o", tmp_path / "o.png")  # click refuses a directory argument
    assert "is a directory" in one_error(lines, code, want_code=2)
    assert not (tmp_path / "o.png").exists() and not (tmp_path / "o.tpsv").exists()


@pytest.mark.skipif(ROOT_USER, reason="root reads and writes regardless of permissions")
def test_no_permission_is_one_line(tmp_path, model_path):
    locked = tmp_path / "locked.png"
    locked.write_bytes(encode_image(np.zeros((4, 4, 3), np.float32)))
    os.chmod(locked, 0)
    shut = tmp_path / "shut"
    shut.mkdir()
    os.chmod(shut, 0o500)
    try:
        with pytest.raises(TpsvError) as info:
            read_image(locked)
        assert str(info.value) == f"{locked}: cannot read (Permission denied)"
        code, _, lines = run("render", model_path, "-o", shut / "o.png", "--scale", "0.5")
        assert one_error(lines, code) == f"cannot write {shut / 'o.png'}: permission denied"
    finally:
        os.chmod(shut, 0o700)
        os.chmod(locked, 0o600)


def test_output_in_a_missing_directory_is_one_line(tmp_path, model_path):
    out = tmp_path / "nodir" / "o.jpg"
    code, _, lines = run("render", model_path, "-o", out, "--scale", "0.5")
    assert one_error(lines, code) == f"cannot write {out}: directory {out.parent} does not exist"
    assert not out.parent.exists()
