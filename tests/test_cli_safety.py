"""The command line never loses a file and never prints more than one line (issue 14, "Why" 1, 2, 5, 6, 7).

Every failure a user can cause ends as exit 1 (one line, "tpsv: error: ...") or
a usage error (exit 2, click's usage text); no earlier output is touched and no
temporary is left behind.
"""

from __future__ import annotations

import errno
import json
import os
import shutil

import click
import numpy as np
import pytest
from click.testing import CliRunner

import tpsv.cli as cli
from tpsv import codec
from tpsv.cli import main
from tpsv.errors import TpsvError


def run(*args, input=None):
    return CliRunner().invoke(main, ["--quiet", *map(str, args)], input=input)


def one_line(r, code=1) -> str:
    """The single stderr line of a failed run (exit ``code``), with no traceback and no internal error."""
    assert r.exit_code == code, (r.exit_code, r.output, r.exception)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr
    assert err[0].startswith("tpsv: error: ") and "internal error" not in err[0], err[0]
    assert ".tmp" not in err[0]
    return err[0]


def usage_error(r) -> str:
    assert r.exit_code == 2, (r.exit_code, r.output)
    err = r.stderr.strip().splitlines()
    assert err[0].startswith("Usage: ") and err[-1].startswith("Error: "), r.stderr
    return err[-1]


def leftovers(directory) -> list[str]:
    return sorted(n for n in os.listdir(directory) if n.endswith(".tmp"))


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_png, small_labels):
    """A photo, its label map, strokes and a .tpsv, made once."""
    d = tmp_path_factory.mktemp("safety")
    img = d / "photo.png"
    shutil.copy(small_png, img)
    import cv2

    cv2.imwrite(str(d / "labels.png"), small_labels.astype(np.uint8))
    strokes = np.zeros((*small_labels.shape, 3), np.uint8)
    strokes[5:8, 5:20] = (255, 0, 0)
    strokes[30:33, 30:50] = (0, 255, 0)
    cv2.imwrite(str(d / "strokes.png"), strokes)
    r = run("vectorize", img, "-o", d / "model.tpsv", "--no-search")
    assert r.exit_code == 0, r.output
    grid = json.loads(run("deform", d / "model.tpsv", "--export-grid", "0", "-o", "-").stdout)
    (d / "grid.json").write_text(json.dumps(grid))
    return d


@pytest.fixture
def work(tmp_path, files):
    """A fresh copy of the inputs for one test (the test may try to overwrite them)."""
    for f in files.iterdir():
        shutil.copy(f, tmp_path / f.name)
    return tmp_path


@pytest.fixture
def no_reads(monkeypatch):
    """Inputs cannot be read: a command that gets past its output checks fails loudly."""

    def refuse(*a, **k):
        raise AssertionError("an input was read before the outputs were checked")

    import tpsv.cli.info
    import tpsv.cli.outputs
    import tpsv.codec.container
    import tpsv.image

    for mod in (tpsv.image, tpsv.codec.container, tpsv.cli.outputs, tpsv.cli.info):
        monkeypatch.setattr(mod, "read_bytes", refuse)


# ------------------------------------------------------------------ Why 1: -o equal to an input

# {p}: photo.png, {l}: labels.png, {s}: strokes.png, {m}: model.tpsv, {g}: grid.json
SAME_AS_INPUT = [
    "segment {p} -o {p}",
    "segment {p} -o out.png --preview {p}",
    "segment {p} --strokes {s} -o {s}",
    "vectorize {p} -o {p}",
    "vectorize {p} -o out.tpsv --preview {p}",
    "vectorize {p} --labels {l} -o {l}",
    "render {m} -o {m}",
    "magnify {m} -o {m} --factor 2",
    "magnify {p} -o {p} --factor 2",
    "magnify {p} -o out.png --factor 2 --save-model {p}",
    "magnify {p} --labels {l} -o {l} --factor 2",
    "recolor {m} -o {m} --hue 10",
    "recolor {m} -o out.tpsv --hue 10 --render {m}",
    "crossmap {m} -o {g} --source {g} --target-region 0",
    "deform {m} -o {m} --affine 0:1,0,0,0,1,0",
    "deform {m} -o {g} --grid 0:{g}",
    "deform {m} --export-grid 0 -o {m}",
    "stylize {m} -o {m}",
    "stylize {m} -o out.png --abstract-out {m}",
]


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink"])
@pytest.mark.parametrize("line", SAME_AS_INPUT)
def test_output_equal_to_an_input_is_refused_before_any_work(work, line, how, no_reads, monkeypatch):
    monkeypatch.chdir(work)
    names = {"p": "photo.png", "l": "labels.png", "s": "strokes.png", "m": "model.tpsv", "g": "grid.json"}
    before = {f: (work / f).read_bytes() for f in names.values()}
    args = line.format(**names).split()
    if how != "same":  # the clobbering output names the input through a link
        i = max(k for k, a in enumerate(args) if a in names.values() and k > 1 and args[k - 1].startswith("-"))
        link = "link-" + args[i]
        (os.symlink if how == "symlink" else os.link)(args[i], link)
        args[i] = link
    msg = one_line(run(*args))
    assert "is the input file" in msg
    assert {f: (work / f).read_bytes() for f in names.values()} == before
    assert leftovers(work) == [] and not (work / "out.png").exists() and not (work / "out.tpsv").exists()


def test_bench_output_equal_to_an_input_is_refused(work, no_reads):
    out = work / "out"
    out.mkdir()
    shutil.copy(work / "photo.png", out / "bench.json")  # an image, whatever its name
    msg = one_line(run("bench", out / "bench.json", "--out", out, "--grid", "0", "--iterations", "1"))
    assert "is the input file" in msg
    assert (out / "bench.json").read_bytes() == (work / "photo.png").read_bytes()


# ------------------------------------------------------------------ Why 2: a failing run keeps earlier outputs

FAILING_SECOND_OUTPUT = [
    ("vectorize {p} --no-search -o out.tpsv --preview /nodir/p.png", ["out.tpsv"]),
    ("vectorize {p} --no-search -o /nodir/o.tpsv --preview out.png", ["out.png"]),
    ("segment {p} -o out.png --preview /nodir/p.png", ["out.png"]),
    ("stylize {m} -o out.png --abstract-out /nodir/a.tpsv", ["out.png"]),
    ("recolor {m} --hue 10 -o out.tpsv --render /nodir/r.png", ["out.tpsv"]),
    ("magnify {p} --factor 2 --save-model out.tpsv -o /nodir/o.png", ["out.tpsv"]),
    ("deform {m} --affine 0:1,0,0,0,1,0 -o out.tpsv --render /nodir/r.png", ["out.tpsv"]),
    ("crossmap {m} --target-region 0 -o out.tpsv --render /nodir/r.png", ["out.tpsv"]),
]


@pytest.mark.parametrize("line, kept", FAILING_SECOND_OUTPUT)
def test_a_failing_output_leaves_the_others_untouched(work, monkeypatch, line, kept):
    monkeypatch.chdir(work)
    for name in kept:
        (work / name).write_bytes(b"earlier output")
    one_line(run(*line.format(p="photo.png", m="model.tpsv").split()))
    for name in kept:
        assert (work / name).read_bytes() == b"earlier output"
    assert leftovers(work) == []


def test_a_failure_after_staging_removes_the_temporaries(work, monkeypatch):
    """The .tpsv is staged, then the preview fails: neither is written, no temporary stays."""
    monkeypatch.chdir(work)
    (work / "out.tpsv").write_bytes(b"earlier output")
    import tpsv.cli.vectorize as v

    def boom(*a, **k):
        raise TpsvError("preview failed")

    monkeypatch.setattr(v, "draw_preview", boom)
    assert one_line(run("vectorize", "photo.png", "--no-search", "-o", "out.tpsv", "--preview", "p.png")).endswith(
        "preview failed")
    assert (work / "out.tpsv").read_bytes() == b"earlier output"
    assert not (work / "p.png").exists() and leftovers(work) == []


def test_disk_full_is_one_line_and_keeps_the_old_output(work, monkeypatch):
    monkeypatch.chdir(work)
    (work / "out.png").write_bytes(b"earlier output")
    real_write = os.write
    calls = []

    def full(fd, data):  # the first chunk half-written, then no space left
        if fd <= 2:
            return real_write(fd, data)
        calls.append(fd)
        if len(calls) == 1:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", full)
    msg = one_line(run("render", "model.tpsv", "-o", "out.png"))
    assert msg == "tpsv: error: cannot write out.png: No space left on device"
    assert (work / "out.png").read_bytes() == b"earlier output"
    assert leftovers(work) == []


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_disk_full_on_a_device_output(work):
    assert one_line(run("render", work / "model.tpsv", "-o", "/dev/full")).endswith("No space left on device")


def test_a_device_output_is_written_not_replaced(work):
    before = os.stat("/dev/null")
    r = run("render", work / "model.tpsv", "-o", "/dev/null")
    assert r.exit_code == 0, r.output
    after = os.stat("/dev/null")
    assert (after.st_mode, after.st_rdev) == (before.st_mode, before.st_rdev)


# ------------------------------------------------------------------ Why 5: output path problems are plain sentences


@pytest.mark.parametrize("out, expected", [
    ("", "output path is empty"),
    ("nodir/x.png", "directory nodir does not exist"),
    ("photo.png/x.png", "photo.png is not a directory"),
    (".", "is a directory"),
])
@pytest.mark.parametrize("command", [
    "render model.tpsv --size 8x8", "vectorize photo.png --no-search", "segment photo.png",
    "recolor model.tpsv --hue 5", "stylize model.tpsv", "deform model.tpsv --export-grid 0",
])
def test_bad_output_paths(work, monkeypatch, command, out, expected):
    monkeypatch.chdir(work)
    r = run(*command.split(), "-o", out)
    msg = usage_error(r) if out == "." else one_line(r)  # click.Path(dir_okay=False) says it first
    assert expected in msg


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_unwritable_directory(work):
    locked = work / "locked"
    locked.mkdir()
    os.chmod(locked, 0o500)
    try:
        assert "permission denied" in one_line(run("render", work / "model.tpsv", "-o", locked / "x.png"))
    finally:
        os.chmod(locked, 0o700)


def test_missing_input_is_tpsv_error_not_click_error(tmp_path):
    for args in (("info", tmp_path / "missing.tpsv"), ("render", tmp_path / "missing.tpsv", "-o", tmp_path / "o.png")):
        assert "cannot read" in one_line(run(*args))


def test_click_file_errors_become_tpsv_errors():
    group = cli.TpsvGroup()

    @group.command()
    def opener():
        raise click.FileError("x.json", "No such file or directory")

    r = CliRunner().invoke(group, ["opener"])
    assert one_line(r) == "tpsv: error: x.json: cannot read (No such file or directory)"


# ------------------------------------------------------------------ Why 5: option values are usage errors

BAD_VALUES = [
    "vectorize {p} -o o.tpsv --canny nan", "vectorize {p} -o o.tpsv --canny -1", "vectorize {p} -o o.tpsv --canny inf",
    "vectorize {p} -o o.tpsv --super nan", "vectorize {p} -o o.tpsv --super inf", "vectorize {p} -o o.tpsv --super -1",
    "vectorize {p} -o o.tpsv --smoothing nan", "vectorize {p} -o o.tpsv --smoothing inf",
    "vectorize {p} -o o.tpsv --smoothing -1", "vectorize {p} -o o.tpsv --seed -1",
    "vectorize {p} -o o.tpsv --iterations 0", "vectorize {p} -o o.tpsv --kernel-size 12",
    "vectorize {p} -o o.tpsv --kernel-size 4096", "vectorize {p} -o o.tpsv --kernel-size 3",
    "segment {p} -o o.png --seed -1", "bench {p} --seed -1", "bench {p} --iterations 0",
    "render {m} -o o.png --scale inf", "render {m} -o o.png --scale nan", "render {m} -o o.png --scale 1e300",
    "render {m} -o o.png --scale 0", "render {m} -o o.png --size 16385x10",
    "render {m} -o o.png --size 99999999999999999999999999999999x10", "render {m} -o o.png --size " + "9" * 5000 + "x9",
    "magnify {m} -o o.png --factor 250000", "magnify {m} -o o.png --factor inf",
    "stylize {m} -o o.png --scale 1e300", "stylize {m} -o o.png --stroke-width 1e308",
    "recolor {m} -o o.tpsv --hue nan", "recolor {m} -o o.tpsv --lightness inf",
    "recolor {m} -o o.tpsv --hue 1 --render r.png --scale 1e300",
]


@pytest.mark.parametrize("line", BAD_VALUES, ids=lambda s: s[:60])
def test_bad_option_values_are_usage_errors(work, monkeypatch, line):
    monkeypatch.chdir(work)
    usage_error(run(*line.format(p="photo.png", m="model.tpsv").split()))
    assert leftovers(work) == []


@pytest.mark.parametrize("k", codec.SUPPORTED_KERNEL_SIZES)
def test_every_supported_kernel_size_is_accepted(k):
    from tpsv.cli.options import KERNEL_SIZE

    assert KERNEL_SIZE.convert(str(k), None, None) == k


def test_huge_outputs_are_one_line_before_any_allocation(work, monkeypatch):
    monkeypatch.chdir(work)
    for args in (("render", "model.tpsv", "-o", "o.png", "--scale", "16384"),
                 ("magnify", "photo.png", "-o", "o.png", "--factor", "16000")):
        assert "large" in one_line(run(*args))  # the renderer's size check, before any pixel


@pytest.mark.parametrize("doc", ["[" * 100_000, '{"positions": ' + "[" * 50_000 + "]" * 50_000 + "}", "{nope"])
def test_bad_grid_json_is_one_line(work, monkeypatch, doc):
    monkeypatch.chdir(work)
    (work / "deep.json").write_text(doc)
    msg = one_line(run("deform", "model.tpsv", "-o", "o.tpsv", "--grid", "0:deep.json"))
    assert msg.startswith("tpsv: error: deep.json: ")


# ------------------------------------------------------------------ Why 6: nothing else on stderr


def test_numpy_overflow_in_an_edit_is_one_line(work):
    r = run("deform", work / "model.tpsv", "-o", work / "o.tpsv", "--affine", "0:1e308,0,0,0,1e308,0")
    one_line(r)


def test_render_of_extreme_smoothing_prints_nothing(work):
    model = codec.load(work / "model.tpsv")
    model.params.smoothing = 1.7e308
    codec.save(model, work / "smooth.tpsv")
    r = run("render", work / "smooth.tpsv", "-o", work / "o.png")
    assert r.exit_code == 0 and r.stderr == "", r.stderr


def test_warnings_inside_a_command_stay_off_stderr():
    group = cli.TpsvGroup()

    @group.command()
    def noisy():
        import warnings

        np.ones(2) / np.zeros(2)
        warnings.warn("library chatter", RuntimeWarning)

    r = CliRunner().invoke(group, ["noisy"])
    assert r.exit_code == 0 and r.stderr == ""


def test_unavailable_cuda_device_is_one_line(work, capfd):
    from tpsv.gpu import warp

    try:
        warp().get_device("cuda")
        pytest.skip("a CUDA device is present")
    except Exception:
        pass
    capfd.readouterr()
    for args in (("--device", "cuda", "render", work / "model.tpsv", "-o", work / "o.png"),
                 ("render", work / "model.tpsv", "-o", work / "o.png", "--device", "cuda:1")):
        r = CliRunner().invoke(main, list(map(str, args)))
        assert one_line(r).endswith("is not available here (no CUDA GPU?)")
        assert capfd.readouterr().err == ""  # Warp's own CUDA lines, written to fd 2, are kept off


def test_error_lines_are_escaped():
    group = cli.TpsvGroup()

    @group.command()
    def multi():
        raise TpsvError("first\nsecond \x1b[2J")

    assert one_line(CliRunner().invoke(group, ["multi"])) == "tpsv: error: first\\x0asecond \\x1b[2J"


# ------------------------------------------------------------------ Why 7: info prints file strings escaped


@pytest.fixture
def hostile_model(work):
    model = codec.load(work / "model.tpsv")
    model.params.extra = {"t_canny": 999.0, "kernel_size": 7, "title": "\x1b]0;pwn\x07\x1b[2J\rX\u202eY\x9b\\",
                          "k\x1b[31m": 1}
    path = work / "hostile.tpsv"
    codec.save(model, path)
    return path, model


def test_info_escapes_stored_strings(hostile_model):
    path, _ = hostile_model
    r = run("info", path)
    assert r.exit_code == 0, r.output
    for ch in "\x1b\x07\r\x9b\u202e":
        assert ch not in r.stdout
    assert "title=\\x1b]0;pwn\\x07\\x1b[2J\\x0dX\\u202eY\\x9b\\\\" in r.stdout
    assert "k\\x1b[31m=1" in r.stdout


def test_info_extra_keys_cannot_spoof_parameters(hostile_model):
    path, model = hostile_model
    text = run("info", path).stdout
    params = next(line for line in text.splitlines() if line.strip().startswith("params"))
    extra = next(line for line in text.splitlines() if line.strip().startswith("extra"))
    assert f"t_canny={model.params.t_canny}" in params and "999" not in params
    assert f"kernel_size={model.params.kernel_size}" in params and "kernel_size=7" in extra
    s = json.loads(run("info", path, "--json").stdout)
    assert s["params"]["t_canny"] == model.params.t_canny
    assert s["params"]["extra"]["t_canny"] == 999.0 and s["params"]["extra"]["kernel_size"] == 7


def test_info_escapes_the_path(work):
    odd = work / "a\x1b[2Jb.tpsv"
    shutil.copy(work / "model.tpsv", odd)
    r = run("info", odd)
    assert r.exit_code == 0 and "\x1b" not in r.stdout and "a\\x1b[2Jb.tpsv" in r.stdout


def test_more_regions_than_a_file_holds_is_one_line_before_the_outlines(tmp_path, monkeypatch):
    """A label map (or a transparent part) of more connected parts than ``codec.MAX_REGIONS`` is
    refused as soon as its regions are counted: a fuzzed RGBA picture with salt-noise alpha (5879
    regions) failed only after 40 s of outline fitting, at the file's encoder."""
    import cv2

    import tpsv.geometry.regions as regions

    rgb = np.full((12, 12, 3), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "in.png"), rgb)
    labels = (np.indices((12, 12)).sum(0) % 2).astype(np.uint8)  # a checkerboard: 144 one-pixel regions
    cv2.imwrite(str(tmp_path / "labels.png"), labels)
    monkeypatch.setattr(codec, "MAX_REGIONS", 100)
    monkeypatch.setattr(regions.patch, "build_patch", lambda *a: pytest.fail("a patch was built"))
    for how in ([], ["--outlines", "traced"]):
        r = run("vectorize", tmp_path / "in.png", "--labels", tmp_path / "labels.png", "-o", tmp_path / "out.tpsv", *how)
        assert "144 regions" in one_line(r) and "100" in one_line(r)
        assert not (tmp_path / "out.tpsv").exists() and not leftovers(tmp_path)
