"""The command line: exit codes, one-line errors, atomic outputs, JSON summaries."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import __version__
from tpsv.cli import main


def run(*args, input=None):
    return CliRunner().invoke(main, [str(a) for a in args], input=input, catch_exceptions=False)


def assert_one_line_error(result, code=1):
    assert result.exit_code == code, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1, result.stderr
    assert "Traceback" not in result.output


@pytest.fixture(scope="module")
def tpsv_file(tmp_path_factory, small_png):
    out = tmp_path_factory.mktemp("cli") / "small.tpsv"
    r = run("vectorize", small_png, "-o", out, "--no-search")
    assert r.exit_code == 0, r.output
    return out


def test_version_and_help():
    r = run("--version")
    assert r.exit_code == 0 and __version__ in r.output
    r = run("--help")
    assert r.exit_code == 0
    for cmd in ("segment", "vectorize", "render", "magnify", "info"):
        assert cmd in r.output


def test_vectorize_json(tmp_path, small_png):
    out = tmp_path / "a.tpsv"
    r = run("vectorize", small_png, "-o", out, "--no-search", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    for key in ("width", "height", "regions", "features", "bytes", "psnr", "seconds"):
        assert key in s
    assert s["bytes"] == out.stat().st_size
    assert s["features"] > 0 and s["psnr"] > 15


def test_info_json(tpsv_file):
    r = run("info", tpsv_file, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["bytes"] == tpsv_file.stat().st_size
    assert s["width"] == 64 and s["regions"] >= 1 and s["features"] > 0
    assert sum(s["sections"].values()) <= s["bytes"]


def test_render_scale_and_size(tmp_path, tpsv_file, small_rgb):
    h, w = small_rgb.shape[:2]
    out = tmp_path / "x2.png"
    assert run("render", tpsv_file, "-o", out, "--scale", 2).exit_code == 0
    assert cv2.imread(str(out)).shape[:2] == (2 * h, 2 * w)
    out = tmp_path / "sized.png"
    assert run("render", tpsv_file, "-o", out, "--size", "50x30").exit_code == 0
    assert cv2.imread(str(out)).shape[:2] == (30, 50)


def test_magnify_raster_and_tpsv(tmp_path, tpsv_file, small_png, small_rgb):
    h, w = small_rgb.shape[:2]
    for src in (tpsv_file, small_png):
        out = tmp_path / "m.png"
        r = run("magnify", src, "-o", out, "--factor", 3)
        assert r.exit_code == 0, r.output
        assert cv2.imread(str(out)).shape[:2] == (3 * h, 3 * w)
    # the refinement's steps: 0 writes the fitted model's render as it is
    plain, sharp = tmp_path / "plain.png", tmp_path / "sharp.png"
    for out, steps in ((plain, 0), (sharp, 10)):
        r = run("magnify", small_png, "-o", out, "--factor", 3, "--fit-iterations", 2, "--refine-iterations", steps)
        assert r.exit_code == 0, r.output
    assert not np.array_equal(cv2.imread(str(plain)), cv2.imread(str(sharp)))
    assert run("magnify", small_png, "-o", plain, "--factor", 3, "--refine-iterations", -1).exit_code == 2


def test_magnify_tpsv_refines_the_render_and_zero_steps_render_it(tmp_path, tpsv_file):
    rendered, plain, sharp = tmp_path / "r.png", tmp_path / "plain.png", tmp_path / "sharp.png"
    assert run("render", tpsv_file, "-o", rendered, "--scale", 3).exit_code == 0
    assert run("magnify", tpsv_file, "-o", plain, "--factor", 3, "--refine-iterations", 0).exit_code == 0
    assert plain.read_bytes() == rendered.read_bytes()
    r = run("magnify", tpsv_file, "-o", sharp, "--factor", 3, "--refine-iterations", 10, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["width"] == cv2.imread(str(rendered)).shape[1]
    assert not np.array_equal(cv2.imread(str(sharp)), cv2.imread(str(rendered)))


def test_usage_errors_exit_2(tmp_path, tpsv_file):
    assert run("render", tpsv_file).exit_code == 2  # no -o
    assert run("render", tpsv_file, "-o", tmp_path / "a.png", "--scale", 2, "--size", "4x4").exit_code == 2
    assert run("render", tpsv_file, "-o", tmp_path / "a.png", "--size", "big").exit_code == 2
    assert run("render", tpsv_file, "-o", tmp_path / "a.png", "--scale", -1).exit_code == 2
    assert run("nonsense").exit_code == 2


def _bad_inputs(tmp_path, small_rgb):
    text = tmp_path / "notes.png"
    text.write_text("this is not an image\n")
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.zeros((1, 1, 3), np.uint8))
    deep = tmp_path / "deep.tiff"  # 16-bit PNG and TIFF are read; floating-point samples are not
    cv2.imwrite(str(deep), small_rgb[:, :, ::-1].astype(np.float32))
    rgba = tmp_path / "rgba.png"
    a = np.dstack([np.round(small_rgb * 255).astype(np.uint8), np.full(small_rgb.shape[:2], 128, np.uint8)])
    cv2.imwrite(str(rgba), a)
    return {"text": text, "tiny": tiny, "deep": deep, "rgba": rgba}


@pytest.mark.parametrize("kind", ["text", "tiny", "deep", "rgba"])
def test_bad_images_one_line_no_output(tmp_path, small_rgb, kind):
    src = _bad_inputs(tmp_path, small_rgb)[kind]
    out = tmp_path / "out.tpsv"
    r = run("vectorize", src, "-o", out, "--no-search")
    assert_one_line_error(r)
    assert not out.exists()
    assert not list(tmp_path.glob(".out.tpsv.*"))


def test_failed_run_never_clobbers(tmp_path, small_rgb):
    src = _bad_inputs(tmp_path, small_rgb)["text"]
    out = tmp_path / "keep.tpsv"
    out.write_bytes(b"precious")
    assert_one_line_error(run("vectorize", src, "-o", out))
    assert out.read_bytes() == b"precious"


def test_wrong_size_labels(tmp_path, small_png):
    lab = tmp_path / "labels.png"
    cv2.imwrite(str(lab), np.zeros((5, 7), np.uint8))
    r = run("vectorize", small_png, "-o", tmp_path / "o.tpsv", "--labels", lab, "--no-search")
    assert_one_line_error(r)
    assert "label map" in r.stderr


def test_labels_with_missing_values(tmp_path, small_png, small_labels):
    lab = tmp_path / "labels.png"
    cv2.imwrite(str(lab), (small_labels * 3).astype(np.uint8))  # values 0 and 3: 1 and 2 are empty
    out = tmp_path / "o.tpsv"
    r = run("vectorize", small_png, "-o", out, "--labels", lab, "--no-search", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["regions"] == 2


@pytest.mark.parametrize("cut", [0, 5, 20, -10])
def test_truncated_tpsv(tmp_path, tpsv_file, cut):
    data = tpsv_file.read_bytes()
    bad = tmp_path / "bad.tpsv"
    bad.write_bytes(data[:cut] if cut >= 0 else data[:cut])
    for args in (("info", bad), ("render", bad, "-o", tmp_path / "r.png"),
                 ("magnify", bad, "-o", tmp_path / "m.png", "--factor", 2)):
        r = run(*args)
        assert_one_line_error(r)
        assert "bad.tpsv" in r.stderr  # the message names the file
    assert not (tmp_path / "r.png").exists() and not (tmp_path / "m.png").exists()


def test_subprocess_end_to_end(tmp_path, tpsv_file):
    r = subprocess.run([sys.executable, "-m", "tpsv", "info", str(tpsv_file), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["bytes"] == tpsv_file.stat().st_size
    r = subprocess.run([sys.executable, "-m", "tpsv", "info", str(tmp_path / "missing.tpsv")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode in (1, 2) and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_render_stdout(tpsv_file):
    r = CliRunner().invoke(main, ["render", str(tpsv_file), "-o", "-"])
    assert r.exit_code == 0
    assert r.stdout_bytes[:8] == b"\x89PNG\r\n\x1a\n"


def test_segment_auto_and_strokes(tmp_path, small_png, small_rgb):
    out = tmp_path / "labels.png"
    prev = tmp_path / "prev.png"
    r = run("segment", small_png, "-o", out, "--regions", 3, "--preview", prev, "--json")
    assert r.exit_code == 0, r.output
    lab = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert lab.shape == small_rgb.shape[:2]
    assert set(np.unique(lab)) == set(range(json.loads(r.stdout)["regions"]))
    assert cv2.imread(str(prev)).shape[:2] == small_rgb.shape[:2]
    h, w = small_rgb.shape[:2]
    strokes = np.zeros((h, w, 3), np.uint8)
    strokes[5:8, 3:20] = (255, 0, 0)
    strokes[30:33, 40:60] = (0, 255, 0)
    sp = tmp_path / "strokes.png"
    cv2.imwrite(str(sp), strokes)
    r = run("segment", small_png, "-o", out, "--strokes", sp)
    assert r.exit_code == 0, r.output
    lab = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert len(np.unique(lab[5:8, 3:20])) == 1 and len(np.unique(lab[30:33, 40:60])) == 1
    assert lab[6, 10] != lab[31, 50]


def test_segment_bad_inputs(tmp_path, small_png, small_rgb):
    out = tmp_path / "labels.png"
    empty = tmp_path / "empty.png"
    cv2.imwrite(str(empty), np.zeros(small_rgb.shape, np.uint8))
    assert_one_line_error(run("segment", small_png, "-o", out, "--strokes", empty))
    notimg = tmp_path / "x.png"
    notimg.write_text("hello")
    assert_one_line_error(run("segment", notimg, "-o", out))
    assert_one_line_error(run("segment", small_png, "-o", out, "--strokes", notimg))
    assert not out.exists()


def test_render_antialias_switch(tmp_path, small_rgb, small_labels):
    """--no-antialias gives one region per pixel: the library's render(antialias=False), byte for byte."""
    from tpsv import codec
    from tpsv.encode.rate import encode_quality
    from tpsv.image import encode_png
    from tpsv.rendering.raster import render

    # two regions: a border to mix (the small photo segmented automatically is one region)
    tpsv_file = tmp_path / "two.tpsv"
    tpsv_file.write_bytes(encode_quality(small_rgb, small_labels).data)
    model = codec.load(tpsv_file)
    for flag, aa in (("--antialias", True), ("--no-antialias", False)):
        out = tmp_path / f"{flag}.png"
        res = run("render", tpsv_file, "-o", out, "--scale", 3, flag)
        assert res.exit_code == 0, res.output
        assert out.read_bytes() == encode_png(render(model, scale=3, antialias=aa))
    assert (tmp_path / "--antialias.png").read_bytes() != (tmp_path / "--no-antialias.png").read_bytes()


def test_a_subcommand_imports_only_its_own_module(tpsv_file, tmp_path):
    """``tpsv --version`` and ``tpsv info`` import no other subcommand, nor Warp, SciPy's spatial and image
    modules or scikit-image; ``tpsv render`` not the dense fit of ``magnify`` (SciPy's image filters,
    scikit-image)."""
    code = ("import sys\n"
            "from click.testing import CliRunner\n"
            "from tpsv.cli import main\n"
            "heavy = sys.argv[1].split(',')\n"
            "assert CliRunner().invoke(main, sys.argv[2:]).exit_code == 0\n"
            "heavy = [m for m in heavy if m in sys.modules]\n"
            "assert not heavy, heavy\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('tpsv.cli.'))))\n")
    light = "warp,scipy.spatial,scipy.ndimage,skimage"
    cases = ((light, ["--version"], set()),
             (light, ["info", str(tpsv_file)], {"tpsv.cli.info", "tpsv.cli.options"}),
             ("tpsv.rendering.magnify,scipy.ndimage,skimage", ["render", str(tpsv_file), "-o", str(tmp_path / "a.png")],
              {"tpsv.cli.render", "tpsv.cli.options", "tpsv.cli.outputs"}))
    for heavy, args, expect in cases:
        r = subprocess.run([sys.executable, "-c", code, heavy, *args], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        assert set(r.stdout.split()) == expect, r.stdout
    r = run("--help")
    assert all(name in r.output for name in ("batch", "bench", "crossmap", "deform", "export", "info", "magnify",
                                             "recolor", "render", "segment", "stylize", "vectorize"))
