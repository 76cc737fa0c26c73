"""The benchmark's plumbing on a tiny image (figures themselves are not asserted)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tpsv import metrics
from tpsv.bench.shapes import shapes
from tpsv.bench.drawings import ANTI_ALIASED, DENSITY, NAMES, drawing
from tpsv.bench.tables import GRAPHICS_METHODS, edge_table, edge_table_text, file_magnification_table
from tpsv.cli import main


def test_bench_tiny(tmp_path, small_png):
    out = tmp_path / "bench"
    r = CliRunner().invoke(main, ["bench", str(small_png), "--iterations", "2", "--grid", "2", "--edges", "1",
                                      "--out", str(out)])
    assert r.exit_code == 0, r.output
    for title in ("Table I", "Table II", "Magnification", "GMSD", "Edges: synthetic shapes", "CPU seconds"):
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
    assert all(0 <= m[k]["gmsd"] < 0.5 for k in ("tpsv", "bicubic", "lanczos"))
    fm = img["file_magnification"]
    assert fm["bytes"] > 0 and all(0 <= fm[k]["gmsd"] < 0.5 for k in ("tpsv", "magnify", "file_bicubic", "bicubic"))
    assert "A .tpsv magnified 4x" in r.stdout
    (edge,) = report["edges"]["variants"]
    assert edge["seed"] == 0 and all(edge[k]["psnr"] > 15 for k in ("tpsv", "bicubic", "lanczos"))
    assert "Graphics: flat-colour drawings" in r.stdout
    g = report["graphics"]
    assert g["scale"] == 8 and [d["name"] for d in g["drawings"]] == list(NAMES)
    assert all(15 < d[k]["psnr"] and 0 <= d[k]["gmsd"] < 0.5 for d in g["drawings"] for k in GRAPHICS_METHODS)
    assert all(d["tpsv"]["bytes"] > 0 and d["tpsv"]["regions"] >= 1 for d in g["drawings"])
    assert cv2.imread(str(out / "rd-small.png")) is not None


def test_bench_json_stdout_is_pure_json(small_png):
    r = CliRunner().invoke(main, ["bench", str(small_png), "--iterations", "1", "--grid", "0", "--edges", "0",
                                      "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert report["images"][0]["grid"] == []
    assert report["edges"] is None


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
    assert json.loads(r.stdout)["edges"] is None  # no raster input: no quality tables


def test_edge_table_small():
    e = edge_table(variants=2, size=32, scale=4, iterations=1)
    assert e["size"] == 32 and e["scale"] == 4 and [v["seed"] for v in e["variants"]] == [0, 1]
    for v in e["variants"] + [e["mean"]]:
        for k in ("tpsv", "default", "auto", "bicubic", "lanczos"):
            assert 15 < v[k]["psnr"] < 80 and 0 < v[k]["gmsd"] < 0.5
    assert all(v[k]["bytes"] > 0 for v in e["variants"] for k in ("tpsv", "default", "auto"))
    assert all(v["auto"]["regions"] >= 1 for v in e["variants"])
    text = edge_table_text(e)
    assert "seed 1" in text and "mean" in text and "lanczos" in text and "default" in text and "auto" in text


def test_file_magnification_keeps_drawn_edges_sharper_than_bicubic():
    """Shapes drawn analytically at 4x, area-downscaled, vectorised with their label map and rendered back:
    along the region borders the vector outlines beat bicubic upscaling of the small picture and of the
    file's own scale-1 render."""
    rgb, labels = shapes(24, 4, seed=1)
    t = file_magnification_table(rgb, labels, 4, "cpu")
    assert t["regions"] >= 3 and t["bytes"] > 0
    for k in ("file_bicubic", "bicubic"):
        assert t["tpsv"]["border_psnr"] > t[k]["border_psnr"] + 1.0
        assert t["tpsv"]["gmsd"] < t[k]["gmsd"]


# --------------------------------------------------------------------------- GMSD


def _blurred(rgb, sigma):
    return cv2.GaussianBlur(rgb, (0, 0), sigma) if sigma else rgb


def test_gmsd_identical_is_zero(small_rgb):
    assert metrics.gmsd(small_rgb, small_rgb) == 0.0
    u8 = np.round(small_rgb * 255).astype(np.uint8)
    assert metrics.gmsd(u8, u8) == 0.0
    # uint8 and float in [0, 1] are the same scale
    assert metrics.gmsd(u8, u8 // 2) == pytest.approx(metrics.gmsd(u8 / 255.0, (u8 // 2) / 255.0))


def test_gmsd_grows_with_blur_and_is_symmetric(small_rgb):
    scores = [metrics.gmsd(small_rgb, _blurred(small_rgb, s)) for s in (0, 0.7, 1.5, 3.0)]
    assert scores[0] == 0 and all(a < b for a, b in zip(scores, scores[1:]))
    b = _blurred(small_rgb, 1.5)
    assert metrics.gmsd(small_rgb, b) == metrics.gmsd(b, small_rgb)


def test_gmsd_hand_checked():
    """Black against a 4x8 grey step (left half 0, right half 90, all channels).

    After the 2x2 average and the downsample: two rows of [0, 0, 90, 90]. Prewitt /3
    with zero padding: |gx| = 2/3 |x[j-1] - x[j+1]| = [0, 60, 60, 60] and |gy| =
    1/3 (x[j-1] + x[j] + x[j+1]) = [0, 30, 60, 60]; so m^2 = [0, 4500, 7200, 7200]
    (both rows) and, against m = 0, GMS = c / (m^2 + c).
    """
    step = np.zeros((4, 8, 3), np.uint8)
    step[:, 4:] = 90
    black = np.zeros_like(step)
    m2 = np.array([0.0, 4500, 7200, 7200])
    gms = 170 / (m2 + 170)
    want = np.sqrt(np.mean((gms - gms.mean()) ** 2))
    assert metrics.gmsd(black, step) == pytest.approx(want, rel=1e-12)
    assert metrics.gmsd(step[..., 0], black[..., 0]) == pytest.approx(want, rel=1e-12)  # grey input
    assert want > 0.4


def test_gmsd_shape_mismatch():
    with pytest.raises(ValueError):
        metrics.gmsd(np.zeros((8, 8, 3)), np.zeros((8, 6, 3)))


def test_device_table_reports_end_to_end_per_size():
    from tests.test_tiles import traced_model
    from tpsv.bench.tables import device_table, device_table_text

    d = device_table(traced_model(), "cpu", sizes=((64, 48), (96, 72)), repeat=1)
    assert [r["size"] for r in d["sizes"]] == [[64, 48], [96, 72]]
    for r in d["sizes"]:
        st = r["stages_ms"]
        assert r["end_to_end_ms"] == pytest.approx(st["total"] - st["download"])
        assert 0 < r["device_ms"] < r["end_to_end_ms"] and r["max_abs_diff_vs_cpu"] == 0.0
        assert r["prepared_ms"] > 0 and r["new_size_ms"] > 0
    text = device_table_text([{"name": "blobs", "device_check": d}], "cpu")
    assert "e2e" in text and "96x72" in text and "zoom" in text


def test_edit_table_at_a_window_size():
    from tests.test_tiles import traced_model
    from tpsv.bench.tables import edit_table, edit_table_text

    m = traced_model()
    at = edit_table(m, "cpu", (80, 60))
    assert set(at) == {"recolor_point", "recolor_region", "deform_translate", "deform_scale"}
    for e in at.values():
        assert e["pixels"] <= 80 * 60 and e["seconds"]["total"] > 0
    text = "\n".join(edit_table_text([{"name": "blobs", "edits": at, "edits_window": at}], "cpu"))
    assert "at the model's size" in text and "at 1920x1080" in text and "deform_scale" in text


def test_scaling_table_measures_each_size_in_a_child(small_rgb):
    from tpsv.bench.scaling import scaling_table, scaling_text

    t = scaling_table(small_rgb, sizes=(48, 64))
    assert [(r["size"], r["mode"]) for r in t["rows"]] == [(48, "default"), (48, "no-detail"), (64, "default"),
                                                           (64, "no-detail")]
    for r in t["rows"]:
        assert r["seconds"] > 0 and r["file_bytes"] > 0 and r["psnr"] > 15
        # a child's peak holds the interpreter, the libraries and Warp at least
        assert r["peak_rss_bytes"] >= 0.5 * t["baseline_rss_bytes"] > 10 * 2**20
        assert r["bytes_per_pixel"] == r["peak_rss_bytes"] / r["pixels"]
    text = scaling_text(t)
    assert "64x64" in text.replace(" ", "") and "no-detail" in text


@pytest.mark.parametrize("name", NAMES)
def test_drawings_magnified_area_average_back_to_themselves(name):
    small = drawing(name)
    for scale in (2, 8):
        big = drawing(name, scale)
        h, w = small.shape[:2]
        assert big.shape == (h * scale, w * scale, 3)
        back = big.reshape(h, scale, w, scale, 3).mean(axis=(1, 3))
        assert np.abs(back - small).max() <= 0.5 / 255 + 1e-6  # scale 1 is rounded to 8 bits
    with pytest.raises(ValueError):
        drawing(name, DENSITY + 1)
    if name not in ANTI_ALIASED:  # drawn on pixel edges: no anti-aliased pixel
        assert np.array_equal(drawing(name, 4), np.repeat(np.repeat(small, 4, 0), 4, 1))
