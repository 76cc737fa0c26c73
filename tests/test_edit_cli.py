"""The editing commands: recolor, crossmap, deform, stylize (pipelines, --render, --json, errors)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from editfixtures import BACKGROUND, DISC, PANEL, same_model, scene_model
from tpsv import codec
from tpsv.edit import crossmap, deform, recolor, stylize
from tpsv.edit.common import clip_lab
from tpsv.cli import main
from tpsv.image import encode_png


def run(*args, input=None):
    return CliRunner().invoke(main, [str(a) for a in args], input=input, catch_exceptions=False)


def assert_one_line_error(result, code):
    assert result.exit_code == code, result.output
    err = result.stderr.strip().splitlines()
    assert "Traceback" not in result.output
    if code == 1:
        assert len(err) == 1 and err[0].startswith("tpsv: error:"), result.stderr


@pytest.fixture(scope="module")
def src(tmp_path_factory):
    path = tmp_path_factory.mktemp("edit") / "scene.tpsv"
    codec.save(scene_model(), path)
    return path


def test_help_lists_edit_commands():
    r = run("--help")
    for cmd in ("recolor", "crossmap", "deform", "stylize"):
        assert cmd in r.output


def test_recolor_matches_library_and_renders(tmp_path, src):
    out, png = tmp_path / "r.tpsv", tmp_path / "r.png"
    r = run("recolor", src, "-o", out, "--region", DISC, "--hue", 90, "--lightness", 5, "--render", png,
            "--scale", 2, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    for key in ("width", "height", "regions", "features", "bytes", "selected", "changed", "render", "seconds"):
        assert key in s
    m = codec.load(src)
    want = codec.quantize(recolor.recolor(m, region=DISC, hue=90, lightness=5))
    assert same_model(codec.load(out), want)
    assert s["bytes"] == out.stat().st_size and s["selected"] == int((m.features.region == DISC).sum())
    assert cv2.imread(str(png)).shape[:2] == (2 * m.height, 2 * m.width)


def test_recolor_reports_the_template_it_used(tmp_path, src):
    out = tmp_path / "h.tpsv"
    r = run("recolor", src, "-o", out, "--color", "#d92619", "--tolerance", 60, "--hue", 30, "--harmonize", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    m = codec.load(src)
    mask = recolor.select(m, color=(217 / 255, 38 / 255, 25 / 255), tolerance=60)
    # the template fitted to the selection's colours after the hue step, as harmonize documents
    pre = recolor.recolor_features(m, mask, hue=30)
    name, rot, _ = recolor.harmonic_template(clip_lab(pre.features.lab[mask]), "auto")
    assert (s["template"], s["rotation"]) == (name, rot)
    assert s["selected"] == int(mask.sum()) > 0
    want = recolor.recolor_features(m, mask, hue=30, harmonize="auto")
    assert s["changed"] == int((want.features.lab != m.features.lab).any(axis=1).sum())
    assert same_model(codec.load(out), codec.quantize(want))
    # an empty selection still names the template harmonic_template gives for no colours
    r = run("recolor", src, "-o", out, "--color", "#00ff00", "--tolerance", 0, "--harmonize", "X", "--json")
    s = json.loads(r.stdout)
    assert (s["selected"], s["changed"], s["template"]) == (0, 0, "X")
    assert s["rotation"] == recolor.harmonic_template(np.zeros((0, 3)), "X")[1]


def test_stylize_writes_the_library_image(tmp_path, src):
    png, ab = tmp_path / "s.png", tmp_path / "s.tpsv"
    r = run("stylize", src, "-o", png, "--level", 2, "--scale", 1.5, "--stroke-width", 2, "--abstract-out", ab,
            "--json")
    assert r.exit_code == 0, r.output
    m = codec.load(src)
    assert png.read_bytes() == encode_png(stylize.stylize(m, level=2, scale=1.5, stroke_width=2))
    a = stylize.abstract(m, 2)
    assert same_model(codec.load(ab), codec.quantize(a))
    assert json.loads(r.stdout)["strokes"] == len(stylize.stroke_chains(a)) > 0


def test_pipeline_through_stdin_and_stdout(tmp_path, src):
    r1 = CliRunner().invoke(main, ["recolor", str(src), "-o", "-", "--color", "#d92619", "--tolerance", "30",
                                   "--shift-ab", "-20,40"])
    assert r1.exit_code == 0, r1.stderr
    r2 = CliRunner().invoke(main, ["deform", "-", "-o", "-", "--affine", f"{DISC}:1,0,4,0,1,-2"], input=r1.stdout_bytes)
    assert r2.exit_code == 0, r2.stderr
    out = tmp_path / "p.tpsv"
    r3 = CliRunner().invoke(main, ["crossmap", "-", "-o", str(out), "--target-region", str(PANEL), "--source-region",
                                   str(DISC), "--rotate", "90", "--alpha", "0.5"], input=r2.stdout_bytes)
    assert r3.exit_code == 0, r3.stderr
    m = codec.load(src)
    m = codec.quantize(recolor.recolor(m, color=(217 / 255, 38 / 255, 25 / 255), tolerance=30, shift_ab=(-20, 40)))
    m = codec.quantize(deform.affine(m, DISC, [1, 0, 4, 0, 1, -2]))
    m = codec.quantize(crossmap.crossmap(m, PANEL, m, DISC, rotate=90, alpha=0.5))
    assert same_model(codec.load(out), m)
    png = tmp_path / "s.png"
    r4 = CliRunner().invoke(main, ["stylize", str(out), "-o", "-", "--level", "1", "--scale", "2"])
    assert r4.exit_code == 0 and r4.stdout_bytes[:8] == b"\x89PNG\r\n\x1a\n"
    png.write_bytes(r4.stdout_bytes)
    assert cv2.imread(str(png)).shape[:2] == (2 * m.height, 2 * m.width)


def test_crossmap_other_source_and_stylize_json(tmp_path, src):
    out = tmp_path / "c.tpsv"
    r = run("crossmap", src, "-o", out, "--target-region", PANEL, "--source", src, "--source-region", DISC, "--flip",
            "--match-stats", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["mode"] == "replace" and s["target_features"] == s["mapped"]
    png, ab = tmp_path / "s.png", tmp_path / "a.tpsv"
    r = run("stylize", out, "-o", png, "--no-strokes", "--level", 3, "--abstract-out", ab, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["strokes"] == 0 and s["features"] == len(codec.load(ab).features)
    assert cv2.imread(str(png)).shape[:2] == (s["height"], s["width"])


def test_deform_moves_grid_export_and_render(tmp_path, src):
    grid = tmp_path / "g.json"
    r = run("deform", src, "-o", grid, "--export-grid", BACKGROUND)
    assert r.exit_code == 0, r.output
    doc = json.loads(grid.read_text())
    doc["positions"][1][0][1] += 2.0
    grid.write_text(json.dumps(doc))
    out, png = tmp_path / "d.tpsv", tmp_path / "d.png"
    r = run("deform", src, "-o", out, "--grid", f"{BACKGROUND}:{grid}", "--move", f"{PANEL}:1,1:2,-1.5",
            "--move", f"{PANEL}:0,0:-1,0", "--render", png, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["deformed"] == [BACKGROUND, PANEL]
    m = codec.load(src)
    want = deform.set_grid(m, BACKGROUND, doc)
    want = deform.move_points(want, [(PANEL, 1, 1, 2, -1.5), (PANEL, 0, 0, -1, 0)])
    assert same_model(codec.load(out), codec.quantize(want))
    assert png.exists()


@pytest.mark.parametrize(
    "args",
    [
        ("recolor", "--region", 9, "--hue", 10),
        ("recolor", "--at", "100,3", "--hue", 10),
        ("crossmap", "--target-region", 7),
        ("crossmap", "--target-region", PANEL, "--source-region", 5),
        ("deform", "--move", f"{BACKGROUND}:1,0:300,0"),
        ("deform", "--move", "9:0,0:1,1"),
        ("deform", "--move", f"{PANEL}:4,0:1,1"),
        ("deform", "--affine", f"{DISC}:1,1,0,1,1,0"),
        ("deform", "--grid", f"{PANEL}:/nonexistent/grid.json"),
    ],
)
def test_data_errors_exit_1_without_output(tmp_path, src, args):
    out = tmp_path / "o.tpsv"
    png = tmp_path / "o.png"
    r = run(args[0], src, "-o", out, *args[1:], "--render", png)
    assert_one_line_error(r, 1)
    assert not out.exists() and not png.exists()
    assert not list(tmp_path.glob(".o.*"))


@pytest.mark.parametrize(
    "args",
    [
        ("recolor", "--hue", "x"),
        ("recolor",),  # nothing to do
        ("recolor", "--at", "1,2", "--color", "#ffffff", "--hue", 3),
        ("recolor", "--radius", 4, "--hue", 3),
        ("recolor", "--color", "#12345", "--hue", 3),
        ("recolor", "--matrix", "1,2,3;4,5,6", "--hue", 3),
        ("recolor", "--shift-ab", "1", "--hue", 3),
        ("recolor", "--harmonize", "Q"),
        ("crossmap",),  # no --target-region
        ("crossmap", "--target-region", PANEL, "--rotate", 45),
        ("crossmap", "--target-region", PANEL, "--alpha", 2),
        ("deform",),  # nothing to do
        ("deform", "--move", "1:2:3"),
        ("deform", "--affine", "1:1,0,0,1"),
        ("deform", "--grid", "nope"),
        ("stylize", "--level", 12),
        ("stylize", "--stroke-width", 0),
        ("stylize", "--scale", -1),
    ],
)
def test_usage_errors_exit_2(tmp_path, src, args):
    out = tmp_path / ("o.png" if args[0] == "stylize" else "o.tpsv")
    r = run(args[0], src, "-o", out, *args[1:])
    assert_one_line_error(r, 2)
    assert not out.exists()


def test_same_output_and_render_is_usage_error(tmp_path, src):
    out = tmp_path / "x.tpsv"
    assert run("recolor", src, "-o", out, "--hue", 3, "--render", out).exit_code == 2
    assert run("recolor", src, "-o", "-", "--hue", 3, "--json").exit_code == 2


def test_bad_input_file_never_clobbers(tmp_path):
    bad = tmp_path / "bad.tpsv"
    bad.write_bytes(b"TPSV nonsense")
    out = tmp_path / "keep.tpsv"
    out.write_bytes(b"precious")
    for args in (("recolor", "--hue", 5), ("deform", "--affine", "0:1,0,1,0,1,0"), ("crossmap", "--target-region", 0)):
        assert_one_line_error(run(args[0], bad, "-o", out, *args[1:]), 1)
    picture = tmp_path / "keep.png"  # stylize writes an image: a .tpsv name is a usage error before reading
    picture.write_bytes(b"precious")
    assert_one_line_error(run("stylize", bad, "-o", picture), 1)
    assert out.read_bytes() == b"precious" and picture.read_bytes() == b"precious"
