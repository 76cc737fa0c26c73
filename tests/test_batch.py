"""``tpsv batch``: many files through one subcommand on Dask (issue 13, item 2).

One 2-worker LocalCluster serves the module: the library tests pass its
client, the command-line tests its address (``--scheduler``); one test runs
the real ``tpsv`` with its own embedded cluster and interrupts it.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import batch, codec
from tpsv.cli import main
from tpsv.errors import TpsvError

from conftest import small_sample

GOOD = ["chelsea", "coffee", "astronaut", "rocket"]


def write_image(path: Path, name: str, width: int) -> Path:
    rgb = small_sample(name, width)
    cv2.imwrite(str(path), np.round(rgb[:, :, ::-1] * 255).astype(np.uint8))
    return path


@pytest.fixture(scope="module")
def client():
    with batch.connect(jobs=2) as c:
        yield c


@pytest.fixture()
def photos(tmp_path) -> list[Path]:
    """Six tiny photos (24-48 px wide) in ``tmp_path/in``."""
    d = tmp_path / "in"
    d.mkdir()
    return [write_image(d / f"{name}{i}.png", name, 24 + 8 * ((i + k) % 4))
            for i in range(2) for k, name in enumerate(GOOD[:3])]


@pytest.fixture()
def bad(tmp_path) -> list[Path]:
    """A text file named .png and a PNG cut in half."""
    d = tmp_path / "in"
    d.mkdir(exist_ok=True)
    text = d / "notes.png"
    text.write_text("not an image\n")
    whole = write_image(d / "whole.png", "rocket", 40).read_bytes()
    cut = d / "cut.png"
    cut.write_bytes(whole[: len(whole) // 2])
    (d / "whole.png").unlink()
    return [text, cut]


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def leftovers(directory) -> list[str]:
    return sorted(n for n in os.listdir(directory) if n.endswith(".tmp"))


# --------------------------------------------------------------------------- task list


def test_plan_names_outputs_by_command(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "sub" / "b.tpsv"
    for cmd, ext in [("vectorize", ".tpsv"), ("render", ".png"), ("magnify", ".png"), ("export", ".pdf")]:
        tasks = batch.plan(cmd, [str(a), str(b)], "out")
        assert tasks == [batch.Task(str(a), os.path.join("out", "a" + ext)),
                         batch.Task(str(b), os.path.join("out", "b" + ext))]
    # the same path twice runs once
    assert len(batch.plan("vectorize", [str(a), str(a), str(tmp_path / "." / "a.png")], "out")) == 1
    with pytest.raises(TpsvError, match="would both write"):
        batch.plan("vectorize", [str(a), str(tmp_path / "x" / "a.jpg")], "out")
    with pytest.raises(TpsvError, match="stdin"):
        batch.plan("vectorize", ["-"], "out")
    with pytest.raises(TpsvError, match="not segment"):
        batch.plan("segment", [str(a)], "out")
    # --format names the picture format, and so the extension
    for name, ext in [("jpeg", ".jpg"), ("JPG", ".jpg"), ("webp", ".webp"), ("tiff", ".tif"), ("png", ".png")]:
        assert batch.plan("render", [str(b)], "out", ["--scale", "2", "--format", name])[0].output == \
            os.path.join("out", "b" + ext)


def test_same_stem_refused_before_any_work(tmp_path, photos):
    other = tmp_path / "other"
    other.mkdir()
    twin = write_image(other / photos[0].name, "rocket", 24)
    out = tmp_path / "out"
    r = cli("batch", "vectorize", photos[0], photos[1], twin, "--out", out, "--scheduler", "tcp://127.0.0.1:9")
    assert r.exit_code == 1, r.output
    assert r.stderr.strip().splitlines() == [
        f"tpsv: error: {photos[0]} and {twin} would both write {out / photos[0].stem}.tpsv; "
        "rename one, or batch them into different --out directories"]
    assert not out.exists()  # nothing made, no cluster contacted


def test_orphan_temporaries_removed(tmp_path):
    """The hidden temporary of a worker killed mid-file goes; live writers' and other files stay."""
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    dead, alive = int(gone.stdout), os.getpid()
    names = [f".a.tpsv.tpsv-{dead}-0123abcd.tmp", f".b.tpsv.tpsv-{alive}-0123abcd.tmp",
             f".other.tpsv.tpsv-{dead}-0123abcd.tmp", "a.tpsv"]
    for n in names:
        (tmp_path / n).write_bytes(b"x")
    tasks = [batch.Task("a.png", str(tmp_path / "a.tpsv")), batch.Task("b.png", str(tmp_path / "b.tpsv"))]
    assert batch.remove_orphan_temporaries(tasks) == 1
    assert sorted(os.listdir(tmp_path)) == sorted(names[1:])


# --------------------------------------------------------------------------- library


def test_mixed_inputs_good_done_bad_failed(tmp_path, client, photos, bad):
    out = tmp_path / "out"
    seen = []
    inputs = [str(p) for p in [photos[0], *bad, *photos[1:]]]
    results = batch.run_batch("vectorize", inputs, str(out), client=client, on_result=seen.append)
    assert [r.input for r in results] == inputs
    assert sorted(r.input for r in seen) == sorted(inputs)
    by_input = {r.input: r for r in results}
    for p in photos:
        r = by_input[str(p)]
        assert r.status == "done" and r.error is None and r.seconds > 0, r
        model = codec.load(r.output)
        assert (model.width, model.height) == cv2.imread(str(p)).shape[1::-1]
        assert r.summary["bytes"] == Path(r.output).stat().st_size  # the command's own --json
    assert by_input[str(bad[0])].status == "failed"
    assert by_input[str(bad[0])].error == f"{bad[0]}: unsupported image format; tpsv reads PNG, JPEG, WebP, " \
                                          "TIFF, BMP and PNM"
    assert by_input[str(bad[1])].status == "failed"
    assert by_input[str(bad[1])].error == f"{bad[1]}: truncated or corrupt PNG data"
    assert sorted(os.listdir(out)) == sorted(p.stem + ".tpsv" for p in photos)
    # both workers of the cluster took files
    assert len({r.worker for r in results}) == 2, [r.worker for r in results]


def test_resume_skips_fresh_outputs(tmp_path, client, photos):
    out = str(tmp_path / "out")
    inputs = [str(p) for p in photos]
    first = batch.run_batch("vectorize", inputs, out, client=client)
    assert {r.status for r in first} == {"done"}
    stamps = {r.output: os.stat(r.output).st_mtime_ns for r in first}
    started = []
    again = batch.run_batch("vectorize", inputs, out, client=client, on_start=started.append)
    assert {r.status for r in again} == {"skipped"} and started == []  # nothing to run, no cluster asked
    assert all(r.seconds == 0 and r.worker is None for r in again)
    assert {r.output: os.stat(r.output).st_mtime_ns for r in again} == stamps
    # an input edited after its output: redone, the others left alone
    later = time.time() + 5
    os.utime(photos[2], (later, later))
    third = batch.run_batch("vectorize", inputs, out, client=client)
    assert [r.status for r in third] == ["skipped", "skipped", "done", "skipped", "skipped", "skipped"]
    # a missing output is made again
    os.unlink(third[4].output)
    assert batch.run_batch("vectorize", inputs, out, client=client)[4].status == "done"
    forced = batch.run_batch("vectorize", inputs, out, client=client, force=True)
    assert {r.status for r in forced} == {"done"}
    assert all(os.stat(r.output).st_mtime_ns > stamps[r.output] for r in forced)


def test_same_bytes_as_the_single_file_command(tmp_path, client, photos):
    out = tmp_path / "out"
    opts = ["--quality", "20", "--no-detail", "--seed", "3"]
    results = batch.run_batch("vectorize", [str(p) for p in photos[:2]], str(out), opts, client=client)
    assert {r.status for r in results} == {"done"}
    for p, r in zip(photos, results):
        single = tmp_path / f"single-{p.stem}.tpsv"
        assert cli("--quiet", "vectorize", p, "-o", single, *opts).exit_code == 0
        assert Path(r.output).read_bytes() == single.read_bytes()


def test_render_and_magnify_of_tpsv_inputs(tmp_path, client, photos):
    models = tmp_path / "models"
    made = batch.run_batch("vectorize", [str(p) for p in photos[:3]], str(models), client=client)
    tpsv_files = [r.output for r in made]
    png = tmp_path / "png"
    rendered = batch.run_batch("render", tpsv_files, str(png), ["--scale", "2"], client=client)
    big = tmp_path / "big"
    magnified = batch.run_batch("magnify", [str(p) for p in photos[:3]], str(big), ["--factor", "3"],
                                client=client)
    for p, r, m in zip(photos, rendered, magnified):
        h, w = cv2.imread(str(p)).shape[:2]
        assert r.status == "done" and r.output == str(png / (p.stem + ".png"))
        assert cv2.imread(r.output).shape[:2] == (2 * h, 2 * w)
        assert m.status == "done" and cv2.imread(m.output).shape[:2] == (3 * h, 3 * w)
    jpegs = batch.run_batch("render", tpsv_files, str(tmp_path / "jpg"), ["--format", "jpeg", "--quality", "80"],
                            client=client)
    assert all(r.status == "done" and r.output.endswith(".jpg") for r in jpegs), jpegs
    assert all(open(r.output, "rb").read(3) == b"\xff\xd8\xff" for r in jpegs)


@pytest.mark.skipif(importlib.util.find_spec("tpsv.cli.export") is None, reason="tpsv export not written yet")
def test_export_of_tpsv_inputs(tmp_path, client, photos):
    made = batch.run_batch("vectorize", [str(p) for p in photos[:2]], str(tmp_path / "models"), client=client)
    pdfs = batch.run_batch("export", [r.output for r in made], str(tmp_path / "pdf"), client=client)
    for r in pdfs:
        assert r.status == "done", r.error
        assert r.output.endswith(".pdf") and Path(r.output).read_bytes().startswith(b"%PDF")


# --------------------------------------------------------------------------- command line


def test_cli_summary_failures_and_exit_status(tmp_path, client, photos, bad):
    out = tmp_path / "out"
    addr = client.scheduler.address
    r = cli("batch", "vectorize", *photos[:2], *bad, "--out", out, "--scheduler", addr)
    assert r.exit_code == 1, r.output
    assert r.stdout == ""
    assert r.stderr.splitlines() == [
        "4 files: 2 done, 0 skipped, 2 failed",
        f"tpsv: error: {bad[0]}: unsupported image format; tpsv reads PNG, JPEG, WebP, TIFF, BMP and PNM",
        f"tpsv: error: {bad[1]}: truncated or corrupt PNG data",
    ]
    r = cli("batch", "vectorize", *photos[:3], "--out", out, "--scheduler", addr)
    assert r.exit_code == 0 and r.stderr == "3 files: 1 done, 2 skipped, 0 failed\n", r.output
    r = cli("--quiet", "batch", "vectorize", *photos[:3], "--out", out, "--scheduler", addr, "--force")
    assert r.exit_code == 0 and r.stderr == "" and r.stdout == ""


def test_cli_json_lines(tmp_path, client, photos, bad):
    out = tmp_path / "out"
    args = ["batch", "vectorize", *photos[:3], bad[0], "--out", out, "--scheduler", client.scheduler.address,
            "--json"]
    cli(*args[:3], "--out", out, "--scheduler", client.scheduler.address)  # one done already
    r = cli(*args)
    assert r.exit_code == 1
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(lines) == 4
    assert {k for line in lines for k in line} >= {"input", "output", "status", "seconds", "error"}
    status = {line["input"]: line["status"] for line in lines}
    assert status == {str(photos[0]): "skipped", str(photos[1]): "done", str(photos[2]): "done",
                      str(bad[0]): "failed"}
    for line in lines:
        assert line["output"] == str(out / (Path(line["input"]).stem + ".tpsv"))
        assert (line["error"] is None) == (line["status"] != "failed")
        assert line["seconds"] >= 0
    assert r.stderr.splitlines() == [f"tpsv: error: {bad[0]}: unsupported image format; tpsv reads PNG, JPEG, "
                                     "WebP, TIFF, BMP and PNM"]


def test_cli_quality_passed_through(tmp_path, client, photos):
    sizes = {}
    for q in (20, 90):
        out = tmp_path / f"q{q}"
        r = cli("batch", "vectorize", *photos[:3], "--out", out, "--scheduler", client.scheduler.address,
                "--quality", str(q))
        assert r.exit_code == 0, r.output
        sizes[q] = [(out / (p.stem + ".tpsv")).stat().st_size for p in photos[:3]]
    assert all(a < b for a, b in zip(sizes[20], sizes[90])), sizes


def test_cli_help_lists_the_commands_and_their_options():
    r = cli("batch", "--help")
    assert r.exit_code == 0
    for name in ("vectorize", "render", "magnify"):
        assert name in r.stdout
    r = cli("batch", "vectorize", "--help")
    assert r.exit_code == 0
    for option in ("--quality", "--no-detail", "--labels", "--out", "--jobs", "--scheduler", "--force", "--json"):
        assert option in r.stdout, option
    assert "--preview" not in r.stdout and "--output" not in r.stdout


def test_cli_global_device_reaches_the_workers(tmp_path, client, photos):
    r = cli("--device", "tpu", "batch", "vectorize", *photos[:2], "--out", tmp_path / "out", "--scheduler",
            client.scheduler.address)
    assert r.exit_code == 1
    assert r.stderr.splitlines()[1:] == [f"tpsv: error: {p}: unknown device 'tpu'; use cpu or cuda"
                                         for p in photos[:2]]


def test_cli_usage_errors_before_any_work(tmp_path, photos):
    out = tmp_path / "out"
    for args, message in [
        (["--quality", "500"], "500 is not in the range 1<=x<=100"),
        (["--outlines", "wavy"], "Invalid value for '--outlines'"),
        (["--preview", "p.png"], "--preview writes one more file per input; batch does not take it"),
        (["-o", "x.tpsv"], "batch names each output itself (DIR/STEM); give the directory with --out"),
        (["--jobs", "0"], "0 is not in the range x>=1"),
        (["--jobs", "2", "--scheduler", "tcp://127.0.0.1:9"], "--jobs sizes the embedded cluster"),
    ]:
        r = cli("batch", "vectorize", photos[0], "--out", out, *args)
        assert r.exit_code == 2, (args, r.output)
        assert message in r.stderr, (args, r.stderr)
    r = cli("batch", "magnify", photos[0], "--out", out)
    assert r.exit_code == 2 and "Missing option '--factor'" in r.stderr
    r = cli("batch", "segment", photos[0], "--out", out)
    assert r.exit_code == 2 and "No such command 'segment'" in r.stderr
    assert not out.exists()


def test_cli_unreachable_scheduler(tmp_path, photos, monkeypatch):
    monkeypatch.setattr(batch, "CONNECT_TIMEOUT", 1.0)
    r = cli("batch", "vectorize", photos[0], "--out", tmp_path / "out", "--scheduler", "tcp://127.0.0.1:9")
    assert r.exit_code == 1
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpsv: error: cannot connect to the scheduler at tcp://127.0.0.1:9: ")


def test_embedded_cluster_interrupted_leaves_complete_files_only(tmp_path):
    """The real command with its own 2-worker cluster; Ctrl-C (SIGINT to the process group) after the first file."""
    src = tmp_path / "in"
    src.mkdir()
    inputs = [write_image(src / f"{name}{i}.png", name, 96) for i in range(4) for name in GOOD]
    out = tmp_path / "out"
    tpsv = Path(sys.executable).with_name("tpsv")
    proc = subprocess.Popen([str(tpsv), "batch", "vectorize", *map(str, inputs), "--out", str(out), "--jobs", "2",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        first = json.loads(proc.stdout.readline())
        os.killpg(proc.pid, signal.SIGINT)
        rest, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert first["status"] == "done"
    assert proc.returncode == 130, err
    assert err.decode() == "tpsv: interrupted\n"
    done = [json.loads(line) for line in rest.decode().splitlines()]
    assert len(done) < len(inputs) - 1  # stopped before the end
    assert leftovers(out) == []
    for name in os.listdir(out):  # whatever was written is whole
        codec.load(str(out / name))
