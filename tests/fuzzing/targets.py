"""What each fuzz input is run through, and how an outcome is classified.

Library targets call the functions the CLI calls, with simple arguments:
``encode`` (model family only), ``decode``, ``info``, ``render`` at 48x32,
``recolor``, ``crossmap``, ``deform``, ``stylize`` (each edit's result encoded
as the CLI does). The ``cli`` target runs one command in-process through
click's ``CliRunner`` and judges what a user would see.

Outcomes (:data:`OUTCOMES`): ``ok``; ``clean`` (a TpsvError in one line, or a
ValueError from ``encode``: the documented refusals; for the CLI exit 1 or 2
with one stderr line that is not an "internal error"); ``crash`` (anything
else); ``memory`` (MemoryError, or the CLI's "out of memory"); ``skip`` (the
target needs a decoded model and there is none). ``hang`` and the RSS check
are the runner's (:mod:`tests.fuzzing.runner`).
"""

from __future__ import annotations

import re
import tempfile
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path

from tpsv import codec
from tpsv.errors import TpsvError

from .mutate import Case

OUTCOMES = ("ok", "clean", "crash", "hang", "memory", "skip")

#: Output size of ``render`` and, through the scale, of ``stylize``: small, so
#: that a run measures the model's cost rather than the pixels'.
RENDER_SIZE = (48, 32)

#: Characters a file's strings must never bring to a terminal unescaped (issue 14: ``info``).
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f\x9b]")


@dataclass
class Result:
    """What one target did with one input."""

    outcome: str
    detail: str = ""

    @classmethod
    def from_exception(cls, exc: BaseException, refusals: tuple = (TpsvError,)) -> "Result":
        msg = str(exc)
        if isinstance(exc, MemoryError):  # the traceback says which allocation
            return cls("memory", "".join(traceback.format_exception(exc)))
        if isinstance(exc, refusals) and msg and "\n" not in msg:
            return cls("clean", f"{type(exc).__name__}: {msg}")
        return cls("crash", "".join(traceback.format_exception(exc)))


class State:
    """The input as it moves through the targets: file bytes, then the decoded model."""

    def __init__(self, case: Case, workdir: Path):
        self.case = case
        self.data = case.data
        self.model = None
        self.workdir = workdir


# ------------------------------------------------------------------ library targets


#: Returned by a target that does not apply to the input.
SKIP = "skip"


def t_encode(s: State):
    if s.case.model is None:
        return SKIP
    s.data = s.case.data = codec.encode(s.case.model)


def t_decode(s: State):
    if s.data is None:
        return SKIP
    s.model = codec.decode(s.data)
    if s.case.family == "model":  # our encoder's file: re-encoding must give it back (issue 14)
        again = codec.encode(s.model)
        if again != s.data:
            raise AssertionError(f"encode(decode(file)) differs from the file ({len(again)} vs {len(s.data)} bytes)")


def t_info(s: State):
    if s.data is None:
        return SKIP
    from tpsv.cli.info import summary
    summary(s.data)


def _needs_model(fn):
    def run(s: State):
        if s.model is None:
            return SKIP
        return fn(s)
    run.__name__ = fn.__name__
    return run


def _encode_edited(model) -> None:
    """The edited model stored as the CLI stores it (a refusal is a TpsvError there)."""
    from tpsv.cli.outputs import encode_model
    encode_model(model)


@_needs_model
def t_render(s: State):
    from tpsv.rendering.raster import render
    render(s.model, width=RENDER_SIZE[0], height=RENDER_SIZE[1])


@_needs_model
def t_recolor(s: State):
    from tpsv.edit import recolor as rc
    mask = rc.select(s.model, region=0 if s.model.regions else None)
    done = rc.recolor_selected(s.model, mask, hue=40.0, lightness=5.0)
    _encode_edited(done.model)


@_needs_model
def t_crossmap(s: State):
    from tpsv.edit import crossmap as cm
    last = max(len(s.model.regions) - 1, 0)
    _encode_edited(cm.crossmap(s.model, 0, s.model, last, rotate=90))


@_needs_model
def t_deform(s: State):
    from tpsv.edit import deform as df
    out = df.affine(s.model, 0, [[1.05, 0.1, 1.0], [0.0, 0.95, -1.0]])
    out = df.move_points(out, [(0, 0, 0, 2.0, 1.0)])
    _encode_edited(out)


def stylize_scale(model) -> float:
    """The scale that makes the stylized image about as large as RENDER_SIZE."""
    return max(RENDER_SIZE) / max(model.width, model.height)


@_needs_model
def t_stylize(s: State):
    from tpsv.edit import stylize as st
    done = st.stylize_model(s.model, 2, with_strokes=True, stroke_width=1.0, scale=stylize_scale(s.model))
    _encode_edited(done.model)


LIBRARY_TARGETS = {
    "encode": t_encode,
    "decode": t_decode,
    "info": t_info,
    "render": t_render,
    "recolor": t_recolor,
    "crossmap": t_crossmap,
    "deform": t_deform,
    "stylize": t_stylize,
}
#: Refusals that count as clean, per target (``encode`` documents ValueError).
REFUSALS = {"encode": (ValueError,)}


def run_library(name: str, s: State) -> Result:
    """Run library target ``name`` on ``s`` and classify what happened."""
    try:
        with warnings.catch_warnings():  # a library's warnings are the CLI's to silence (cli-* targets judge them)
            warnings.simplefilter("ignore")
            done = LIBRARY_TARGETS[name](s)
    except Exception as exc:  # classify everything (MemoryError included): that is the point
        return Result.from_exception(exc, REFUSALS.get(name, (TpsvError,)))
    return Result("skip") if done == SKIP else Result("ok")


# ------------------------------------------------------------------ the CLI in-process


def cli_commands(path: str, out: str, model) -> list[list[str]]:
    """One command line per CLI target, on input file ``path``, writing ``out.*``."""
    last = str(max(len(model.regions) - 1, 0)) if model is not None else "1"
    scale = f"{stylize_scale(model):.6g}" if model is not None else "0.1"
    return [
        ["info", path],
        ["render", path, "-o", out + ".png", "--size", "x".join(map(str, RENDER_SIZE))],
        ["recolor", path, "-o", out + ".tpsv", "--hue", "40"],
        ["crossmap", path, "-o", out + ".tpsv", "--target-region", "0", "--source-region", last],
        ["deform", path, "-o", out + ".tpsv", "--affine", "0:1.05,0.1,1,0,0.95,-1"],
        ["stylize", path, "-o", out + ".png", "--scale", scale],
    ]


def run_cli(s: State, which: int) -> tuple[str, Result]:
    """Command ``which`` of :func:`cli_commands` through click's CliRunner, judged as a user sees it."""
    from click.testing import CliRunner

    from tpsv.cli import main

    if s.data is None:
        return "cli", Result("skip")
    with tempfile.TemporaryDirectory(dir=s.workdir) as tmp:
        path = str(Path(tmp) / "in.tpsv")
        Path(path).write_bytes(s.data)
        args = cli_commands(path, str(Path(tmp) / "out"), s.model)[which % 6]
        try:
            res = CliRunner().invoke(main, ["--quiet", *args], catch_exceptions=True)
        except MemoryError:
            return f"cli-{args[0]}", Result("memory", "MemoryError")
        return f"cli-{args[0]}", judge_cli(res, args[0])


def judge_cli(res, command: str) -> Result:
    """A CliRunner result as an outcome: exceptions, stray stderr lines, unescaped control characters."""
    err = res.stderr.splitlines()
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        if isinstance(res.exception, MemoryError):
            return Result("memory", "MemoryError")
        tb = "".join(traceback.format_exception(res.exception))
        return Result("crash", tb)
    if any("out of memory" in line for line in err):
        return Result("memory", err[-1])
    if res.exit_code == 0:
        if err:
            return Result("crash", f"exit 0 with stderr: {res.stderr[:2000]}")
        if command == "info" and CONTROL.search(res.stdout):
            return Result("crash", f"unescaped control character on stdout: {res.stdout[:300]!r}")
        return Result("ok")
    if res.exit_code in (1, 2) and len(err) == 1 and "internal error" not in err[0]:
        return Result("clean", err[0])
    return Result("crash", f"exit {res.exit_code}, stderr: {res.stderr[:3000]}")
