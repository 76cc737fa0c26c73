"""Options, value types and helpers shared by the subcommands (after rasterio's ``rio`` options).

Each value syntax of the command line is a click :class:`~click.ParamType`
(``POINT``, ``COLOR``, ``MATRIX``, ``MOVE``, ``AFFINE``, ``GRID``, ``SIZE``,
``PAIR``, the number ranges ``POSITIVE``...), so a malformed value is a usage
error (exit 2, "Invalid value for '--at': ...") raised before any work, and
command bodies receive parsed values. Options several commands share
(``-o/--output``, ``--json``, ``--device``, ``--render``/``--scale``, the
image outputs' ``--format``/``--quality``/``--depth``) are defined here once.
"""

from __future__ import annotations

import json
import math
import re

import click

from . import settings
from .. import codec
from ..errors import TpsvError
from ..fileio import display
from ..gpu import resolve_device
from ..image import OUTPUT_NAMES, OUTPUT_QUALITY, OutputFormat, output_format
from ..rendering.limits import MAX_SIDE

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


# --------------------------------------------------------------------------- value types


class _Syntax(click.ParamType):
    """A value written in a fixed syntax; ``metavar`` shows it in --help."""

    metavar = "VALUE"

    def get_metavar(self, param, ctx=None) -> str:
        return self.metavar

    def numbers(self, text: str, n: int | None, what: str, param, ctx) -> list[float]:
        """``n`` comma-separated finite numbers of ``text``; a usage error naming ``what`` otherwise."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            self.fail(f"{text!r} is not {what}", param, ctx)
        if (n is not None and len(vals) != n) or not all(math.isfinite(v) for v in vals):
            self.fail(f"{text!r} is not {what}", param, ctx)
        return vals

    def region_prefix(self, text: str, what: str, param, ctx) -> tuple[int, str]:
        """``R:REST`` -> (R, REST)."""
        m = re.fullmatch(r"\s*(\d+)\s*:(.*)", str(text), re.S)
        if not m:
            self.fail(f"{text!r} is not {what}", param, ctx)
        return int(m.group(1)), m.group(2)


class NumberTuple(_Syntax):
    """``A,B,...``: a fixed number of finite numbers -> tuple of floats."""

    def __init__(self, n: int, metavar: str, name: str) -> None:
        self.n, self.metavar, self.name = n, metavar, name

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        return tuple(self.numbers(value, self.n, self.metavar, param, ctx))


class ColorType(_Syntax):
    """``#rrggbb`` (``#`` optional) or ``R,G,B`` with 0-255 values -> sRGB triple in [0, 1]."""

    name, metavar = "color", "#RRGGBB"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        t = value.strip()
        m = re.fullmatch(r"#?([0-9a-fA-F]{6})", t)
        if m:
            h = m.group(1)
            return tuple(int(h[i : i + 2], 16) / 255.0 for i in (0, 2, 4))
        vals = self.numbers(t, 3, "a colour (#rrggbb or R,G,B with 0-255 values)", param, ctx)
        if min(vals) < 0 or max(vals) > 255:
            self.fail(f"{value!r}: R,G,B values must lie in 0..255", param, ctx)
        return tuple(v / 255.0 for v in vals)


class MatrixType(_Syntax):
    """``a,b,c;d,e,f;g,h,i`` (or 9 comma-separated numbers) -> 3 x 3 nested list."""

    name, metavar = "matrix", "'a,b,c;d,e,f;g,h,i'"
    what = "a 3x3 matrix 'a,b,c;d,e,f;g,h,i'"

    def convert(self, value, param, ctx):
        if isinstance(value, list):
            return value
        rows = str(value).split(";")
        if len(rows) == 3:
            return [self.numbers(r, 3, self.what, param, ctx) for r in rows]
        vals = self.numbers(value, 9, self.what, param, ctx)
        return [vals[0:3], vals[3:6], vals[6:9]]


class MoveType(_Syntax):
    """``R:I,J:DX,DY`` -> (R, I, J, DX, DY): move control point (I, J) of region R."""

    name, metavar = "move", "R:I,J:DX,DY"
    what = "REGION:I,J:DX,DY (e.g. 2:1,3:10,-4.5)"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        r, rest = self.region_prefix(value, self.what, param, ctx)
        m = re.fullmatch(r"\s*(\d+)\s*,\s*(\d+)\s*:\s*(" + _NUM + r")\s*,\s*(" + _NUM + r")\s*", rest)
        if not m:
            self.fail(f"{value!r} is not {self.what}", param, ctx)
        return r, int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4))


class AffineType(_Syntax):
    """``R:a,b,c,d,e,f`` -> (R, [[a, b, c], [d, e, f]]): x' = a x + b y + c, y' = d x + e y + f."""

    name, metavar = "affine", "R:a,b,c,d,e,f"
    what = "REGION:a,b,c,d,e,f (x' = a x + b y + c, y' = d x + e y + f)"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        r, rest = self.region_prefix(value, self.what, param, ctx)
        v = self.numbers(rest, 6, self.what, param, ctx)
        return r, [v[0:3], v[3:6]]


class GridType(_Syntax):
    """``R:GRID.json`` -> (R, path)."""

    name, metavar = "grid", "R:GRID.json"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        r, rest = self.region_prefix(value, "REGION:GRID.json", param, ctx)
        if not rest.strip():
            self.fail(f"{value!r} is not REGION:GRID.json", param, ctx)
        return r, rest.strip()


class SizeType(_Syntax):
    """``WxH`` (``x`` or ``X``, spaces allowed) -> (W, H), both in 1..``MAX_SIDE``."""

    name, metavar = "size", "WIDTHxHEIGHT"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
        if not m:
            self.fail(f"{value!r} is not WIDTHxHEIGHT", param, ctx)
        # compared as text first: int() of a 5000-digit string is refused by Python itself
        if max(len(m.group(1).lstrip("0")), len(m.group(2).lstrip("0"))) > len(str(MAX_SIDE)):
            self.fail(f"width and height must be at most {MAX_SIDE}", param, ctx)
        w, h = int(m.group(1)), int(m.group(2))
        if w < 1 or h < 1:
            self.fail("width and height must be positive", param, ctx)
        if w > MAX_SIDE or h > MAX_SIDE:
            self.fail(f"width and height must be at most {MAX_SIDE}", param, ctx)
        return w, h


class IntChoice(click.ParamType):
    """An integer out of a fixed set (``--kernel-size``)."""

    name = "integer"

    def __init__(self, choices) -> None:
        self.choices = tuple(int(c) for c in choices)

    def get_metavar(self, param, ctx=None) -> str:
        return "[" + "|".join(map(str, self.choices)) + "]"

    def convert(self, value, param, ctx):
        v = click.INT.convert(value, param, ctx)
        if v not in self.choices:
            self.fail(f"must be one of {', '.join(map(str, self.choices))} (got {v})", param, ctx)
        return v


class BoundedFloat(click.ParamType):
    """A float that satisfies a rule (NaN never does); ``rule`` completes "must ... (got X)"."""

    name = "float"

    def __init__(self, ok, rule: str) -> None:
        self.ok, self.rule = ok, rule

    def convert(self, value, param, ctx):
        v = click.FLOAT.convert(value, param, ctx)
        if not self.ok(v):
            self.fail(f"must {self.rule} (got {v})", param, ctx)
        return v


POINT = NumberTuple(2, "X,Y", "point")
PAIR = NumberTuple(2, "DA,DB", "pair")
COLOR = ColorType()
MATRIX = MatrixType()
MOVE = MoveType()
AFFINE = AffineType()
GRID = GridType()
SIZE = SizeType()
#: > 0 (infinity passes: the library says why it does not fit).
POSITIVE = BoundedFloat(lambda v: v > 0, "be positive")
#: >= 0 (infinity passes).
NON_NEGATIVE = BoundedFloat(lambda v: v >= 0, "be >= 0")
#: >= 0 and finite (thresholds, smoothing).
FINITE_NON_NEGATIVE = BoundedFloat(lambda v: 0 <= v < math.inf, "be a finite number >= 0")
#: Any finite number (a hue angle, a lightness offset).
FINITE = BoundedFloat(math.isfinite, "be a finite number")
UNIT_INTERVAL = BoundedFloat(lambda v: 0.0 <= v <= 1.0, "lie in [0, 1]")
#: An output scale or magnification factor: a larger one cannot give an output
#: of at most ``MAX_SIDE`` pixels a side even from a 1-pixel model, and
#: ``tpsv.rendering.raster.output_size`` checks the real size with one line.
SCALE = BoundedFloat(lambda v: 0 < v <= MAX_SIDE, f"be a positive number up to {MAX_SIDE}")
#: A stroke width in pixels at scale 1 (wider strokes cover any image).
STROKE_WIDTH = BoundedFloat(lambda v: 0 < v <= 1000, "be a positive number up to 1000")
#: Features per TPS kernel: the sizes the decoder accepts and the renderer compiles.
KERNEL_SIZE = IntChoice(codec.SUPPORTED_KERNEL_SIZES)
#: Random seeds (numpy's generators take any non-negative integer).
SEED = click.IntRange(0, 2**63 - 1)
#: JPEG and WebP quality of an image output.
IMAGE_QUALITY = click.IntRange(1, 100)
#: Bits a sample of an image output.
DEPTH = IntChoice((8, 16))
#: Image format names (``--format``), for outputs without an extension.
IMAGE_FORMAT = click.Choice(sorted(OUTPUT_NAMES), case_sensitive=False)


# --------------------------------------------------------------------------- shared options


def output_option(help_text: str):
    """``-o/--output``: the command's main output file ('-': stdout where the help says so)."""
    return click.option(
        "-o", "--output", required=True, type=click.Path(dir_okay=False, allow_dash=True), help=help_text
    )


json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable summary on stdout.")

device_option = click.option(
    "--device", default=None, help="Warp device for this command (overrides the global --device)."
)


def scale_option(help_text: str, default: float | None = 1.0, kind: click.ParamType = SCALE):
    """``--scale`` of a rendered output."""
    return click.option("--scale", type=kind, default=default, show_default=default is not None, help=help_text)


#: What an image output's help says about formats.
IMAGE_HELP = ".png, .jpg/.jpeg, .webp or .tif/.tiff by extension"


def quality_option(what: str = "the output"):
    """``--quality``: JPEG and WebP quality of an image output."""
    return click.option("--quality", type=IMAGE_QUALITY, default=None,
                        help=f"JPEG or WebP quality of {what}, 1-100 (WebP 100: lossless) "
                             f"[default: {OUTPUT_QUALITY}].")


def depth_option(what: str = "the output"):
    """``--depth``: bits a sample of a PNG or TIFF image output."""
    return click.option("--depth", type=DEPTH, default=8, show_default=True,
                        help=f"Bits a sample of {what} (16: PNG and TIFF only).")


def image_options(depth: bool = True):
    """``--format``, ``--quality`` (and ``--depth``) of a command whose ``-o`` is an image."""

    def decorate(f):
        if depth:
            f = depth_option()(f)
        f = quality_option()(f)
        return click.option("--format", "format_name", type=IMAGE_FORMAT, default=None,
                            help="Format of an output without extension, such as '-' (stdout) [default: png].")(f)

    return decorate


def render_options(f):
    """``--render P.png``, ``--scale``, ``--quality`` and ``--depth``: the edits' optional picture of the result."""
    f = depth_option("the --render picture")(f)
    f = quality_option("the --render picture")(f)
    f = scale_option("Scale of the --render picture.")(f)
    f = click.option("--render", "render_path", type=click.Path(dir_okay=False, allow_dash=True), default=None,
                     help=f"Also write a picture of the result: {IMAGE_HELP} ('-': PNG on stdout).")(f)
    return f


# --------------------------------------------------------------------------- helpers


def image_format(path: str | None, name: str | None = None, quality: int | None = None, depth: int = 8,
                 option: str = "-o") -> OutputFormat | None:
    """The format of an image output (:func:`tpsv.image.output_format`), checked before any work.

    Parameters
    ----------
    path : str or None
        The output path; None (an optional output not asked for) refuses a
        ``quality`` or a ``depth`` of 16 given for it.
    name : str, optional
        ``--format``.
    quality, depth : int
        ``--quality`` and ``--depth``.
    option : str
        The output's option, for the messages.

    Returns
    -------
    OutputFormat or None
        None when ``path`` is None.

    Raises
    ------
    click.UsageError
        An extension tpsv does not write, options that do not fit the format.
    """
    if path is None:
        if quality is not None or depth != 8:
            raise click.UsageError(f"--quality and --depth describe the {option} picture; give {option}")
        return None
    try:
        return output_format(path, name, depth, quality)
    except TpsvError as exc:
        raise click.UsageError(str(exc)) from None


def device_for(ctx: click.Context, device: str | None) -> str:
    """The command's ``--device``, else the group's, validated.

    Returns
    -------
    str
        A Warp device name (:func:`tpsv.gpu.resolve_device`).
    """
    return resolve_device(device or settings(ctx).device)


def emit_json(payload: dict) -> None:
    """A JSON summary on stdout (sorted keys; numpy scalars as floats)."""
    click.echo(json.dumps(payload, indent=2, sort_keys=True, default=float))


def check_json_target(as_json: bool, *outputs: str | None) -> None:
    """``--json`` writes to stdout, so no output may go there too."""
    if as_json and any(o == "-" for o in outputs):
        raise click.UsageError("--json and an output on stdout ('-') cannot both be used")


def is_tpsv(path: str) -> bool:
    """Whether a file starts with the .tpsv magic bytes ('-' never: stdin cannot be read twice).

    Returns
    -------
    bool

    Raises
    ------
    TpsvError
        The file cannot be read.
    """
    if path == "-":
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(codec.MAGIC))
    except OSError as exc:
        raise TpsvError(f"{display(path)}: cannot read ({exc.strerror})") from None
    return head == codec.MAGIC
