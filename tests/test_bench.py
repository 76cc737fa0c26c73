"""The benchmark's plumbing on a tiny image (figures themselves are not asserted)."""

from __future__ import annotations

import json

import cv2
from click.testing import CliRunner

from tpsv.cli import main


def test_bench_tiny(tmp_path, small_png):
    out = tmp_path / "bench"
    r = CliRunner().invoke(main, ["bench", str(small_png), "--iterations", "2", "--grid", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    for title in ("Table I", "Table II", "Magnification", "CPU seconds"):
        assert title in r.stdout
    report = json.loads((out / "bench.json").read_text())
    (img,) = report["images"]
    assert img["width"] == 64
    assert len(img["grid"]) == 4
    assert 1 <= len(img["history"]) <= 2
    # the search never ends worse than where it started
    assert img["optimal"]["w"] >= img["history"][0]["w"] * (1 - 1e-9)
    for key in ("initial", "optimal", "brute_force"):
        assert img[key]["bytes"] > 0 and img[key]["psnr"] > 10
    jp = img["jpeg"]
    assert jp["same_bytes"]["bytes"] <= max(img["optimal"]["bytes"], jp["sweep"][0]["bytes"])
    assert jp["best_w"]["w"] == max(p["w"] for p in jp["sweep"])
    t = img["timing"]
    assert t["local_packed"]["seconds"] > 0 and t["global_cpu"]["seconds"] > 0
    m = img["magnification"]
    assert set(m) >= {"tpsv", "bicubic", "lanczos"}
    assert cv2.imread(str(out / "rd-small.png")) is not None


def test_bench_json_stdout_is_pure_json(small_png):
    r = CliRunner().invoke(main, ["bench", str(small_png), "--iterations", "1", "--grid", "0", "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert report["images"][0]["grid"] == []


def test_bench_bad_image(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"nope")
    r = CliRunner().invoke(main, ["bench", str(bad)])
    assert r.exit_code == 1
    assert len(r.stderr.strip().splitlines()) == 1


def test_bench_tpsv_input_gives_timing_only(tmp_path, small_png):
    model = tmp_path / "m.tpsv"
    assert CliRunner().invoke(main, ["vectorize", str(small_png), "-o", str(model), "--no-search"]).exit_code == 0
    r = CliRunner().invoke(main, ["bench", str(model), "--json"])
    assert r.exit_code == 0, r.output
    (img,) = json.loads(r.stdout)["images"]
    assert "initial" not in img and img["timing"]["local_packed"]["seconds"] > 0
