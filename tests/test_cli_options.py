"""The command line's value types (tpsv.cli.options): accepted syntaxes, and usage errors for the rest."""

from __future__ import annotations

import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from tpsv.cli import main
from tpsv.cli import edit as cli_edit
from tpsv.cli import options as o


def parse(typ, text):
    """The value a one-option command receives for ``--v TEXT`` (exit status, value)."""
    got = {}

    @click.command()
    @click.option("--v", type=typ)
    def cmd(v):
        got["v"] = v

    r = CliRunner().invoke(cmd, ["--v", text])
    return r.exit_code, got.get("v")


@pytest.mark.parametrize(
    "typ, text, want",
    [
        (o.POINT, "10,20.5", (10.0, 20.5)),
        (o.POINT, " -1e2 , .5 ", (-100.0, 0.5)),
        (o.PAIR, "-20,40", (-20.0, 40.0)),
        (o.COLOR, "#ff8000", (1.0, 128 / 255, 0.0)),
        (o.COLOR, "FF8000", (1.0, 128 / 255, 0.0)),
        (o.COLOR, "255, 0, 51", (1.0, 0.0, 0.2)),
        (o.MATRIX, "1,0,0;0,1,0;0,0,1", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        (o.MATRIX, "1,2,3,4,5,6,7,8,9", [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]),
        (o.MOVE, "2:1,3:10,-4.5", (2, 1, 3, 10.0, -4.5)),
        (o.MOVE, " 0 : 0 , 0 : +1e1 , .5 ", (0, 0, 0, 10.0, 0.5)),
        (o.AFFINE, "3:1,0,4,0,1,-2", (3, [[1.0, 0.0, 4.0], [0.0, 1.0, -2.0]])),
        (o.GRID, "1: g.json ", (1, "g.json")),
        (o.GRID, "0:dir/a:b.json", (0, "dir/a:b.json")),
        (o.SIZE, "50x30", (50, 30)),
        (o.SIZE, " 7 X 9 ", (7, 9)),
        (cli_edit.TEMPLATE, "V", "V"),
        (o.POSITIVE, "inf", float("inf")),
        (o.FINITE_NON_NEGATIVE, "0.25", 0.25),
        (o.FINITE, "-3", -3.0),
        (o.SCALE, "16384", 16384.0),
        (o.STROKE_WIDTH, "2", 2.0),
        (o.KERNEL_SIZE, "32", 32),
        (o.NON_NEGATIVE, "0", 0.0),
        (o.UNIT_INTERVAL, "1", 1.0),
    ],
)
def test_accepted_values(typ, text, want):
    code, value = parse(typ, text)
    assert code == 0 and value == want


def test_parsed_values_pass_through():
    # click converts defaults and programmatic values too: already-parsed values are kept
    for typ, value in ((o.POINT, (1.0, 2.0)), (o.COLOR, (0.0, 0.5, 1.0)), (o.MOVE, (1, 0, 0, 1.0, 2.0)),
                       (o.MATRIX, [[1.0] * 3] * 3), (o.SIZE, (4, 5)), (o.GRID, (0, "a.json"))):
        assert typ.convert(value, None, None) == value


REJECTED = [
    # (command and its other arguments, option, bad value)
    (("recolor", "--hue", "3"), "--at", "10"),
    (("recolor", "--hue", "3"), "--at", "1,2,3"),
    (("recolor", "--hue", "3"), "--at", "a,b"),
    (("recolor", "--hue", "3"), "--at", "nan,1"),
    (("recolor", "--hue", "3"), "--at", "inf,1"),
    (("recolor", "--hue", "3"), "--color", "#12345"),
    (("recolor", "--hue", "3"), "--color", "300,0,0"),
    (("recolor", "--hue", "3"), "--color", "red"),
    (("recolor", "--hue", "3"), "--shift-ab", "1"),
    (("recolor", "--hue", "3"), "--matrix", "1,2,3;4,5,6"),
    (("recolor", "--hue", "3"), "--matrix", "1,2,3;4,5,6;7,8,x"),
    (("recolor",), "--harmonize", "Q"),
    (("recolor", "--hue", "3"), "--radius", "0"),
    (("recolor", "--hue", "3"), "--radius", "nan"),
    (("recolor", "--hue", "3"), "--tolerance", "-1"),
    (("recolor", "--hue", "3"), "--scale", "inf"),
    (("crossmap", "--target-region", "0"), "--alpha", "1.5"),
    (("deform",), "--move", "1:2:3"),
    (("deform",), "--move", "1:1,1:2"),
    (("deform",), "--move", "x:1,1:2,3"),
    (("deform",), "--affine", "1:1,0,0,1"),
    (("deform",), "--affine", "1:1,0,0,1,0,nan"),
    (("deform",), "--grid", "nope"),
    (("deform",), "--grid", "2:  "),
    (("render",), "--size", "big"),
    (("render",), "--size", "0x5"),
    (("render",), "--size", "-3x5"),
    (("render",), "--scale", "-1"),
    (("magnify",), "--factor", "0"),
    (("stylize",), "--stroke-width", "0"),
    (("stylize",), "--scale", "nan"),
]


@pytest.mark.parametrize("cmd, option, text", REJECTED)
def test_rejected_values_are_one_line_usage_errors(tmp_path, cmd, option, text):
    out = tmp_path / "out"
    # the input does not exist: a value that parsed would fail later with exit 1
    r = CliRunner().invoke(main, [cmd[0], str(tmp_path / "in.tpsv"), "-o", str(out), *cmd[1:], option, text])
    assert r.exit_code == 2, r.output
    errors = [line for line in r.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and errors[0].startswith(f"Error: Invalid value for '{option}':"), r.stderr
    assert "Traceback" not in r.output and not out.exists()


@pytest.mark.parametrize(
    "args",
    [
        ("recolor", "--at", "10,20", "--radius", "5", "--tolerance", "0", "--hue", "3"),
        ("recolor", "--color", "12,34,56", "--shift-ab", "1,-2", "--matrix", "1,0,0;0,1,0;0,0,1"),
        ("recolor", "--harmonize"),
        ("recolor", "--harmonize", "T", "--scale", "0.5"),
        ("crossmap", "--target-region", "0", "--alpha", "0"),
        ("deform", "--move", "2:1,3:10,-4.5", "--affine", "1:1,0,0,0,1,0", "--grid", "0:g.json"),
        ("render", "--size", "50x30"),
        ("magnify", "--factor", "2.5"),
        ("stylize", "--stroke-width", "2", "--scale", "3"),
    ],
)
def test_accepted_values_reach_the_command(tmp_path, args):
    r = CliRunner().invoke(main, [args[0], str(tmp_path / "in.tpsv"), "-o", str(tmp_path / "out"), *args[1:]])
    assert r.exit_code == 1, r.output  # past parsing: the missing input is a data error
    assert r.stderr.startswith("tpsv: error:") and "in.tpsv" in r.stderr


def test_importing_the_cli_does_not_import_warp():
    # warp costs start-up time; only commands that render or solve load it
    code = "import sys, tpsv.cli; print('warp' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr
