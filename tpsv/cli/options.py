"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import json
import re

import click

from . import settings
from ..errors import TpsvError


def output_option(help_text: str):
    return click.option(
        "-o", "--output", required=True, type=click.Path(dir_okay=False, allow_dash=True), help=help_text
    )


json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable summary on stdout.")

device_option = click.option(
    "--device", default=None, help="Warp device for this command (overrides the global --device)."
)


def device_for(ctx: click.Context, device: str | None) -> str:
    from ..gpu import resolve_device

    return resolve_device(device or settings(ctx).device)


def emit_json(payload: dict) -> None:
    click.echo(json.dumps(payload, indent=2, sort_keys=True, default=float))


def check_json_target(as_json: bool, *outputs: str | None) -> None:
    if as_json and any(o == "-" for o in outputs):
        raise click.UsageError("--json and an output on stdout ('-') cannot both be used")


def parse_size(text: str | None) -> tuple[int, int] | None:
    """Parse ``WxH``."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise click.BadParameter(f"{text!r} is not WIDTHxHEIGHT", param_hint="--size")
    w, h = int(m.group(1)), int(m.group(2))
    if w < 1 or h < 1:
        raise click.BadParameter("width and height must be positive", param_hint="--size")
    return w, h


def positive(name: str, value: float | None) -> None:
    if value is not None and not value > 0:
        raise click.BadParameter(f"must be positive (got {value})", param_hint=name)


def is_tpsv(path: str) -> bool:
    """Whether a file starts with the .tpsv magic bytes."""
    from .. import codec

    if path == "-":
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(codec.MAGIC))
    except OSError as exc:
        raise TpsvError(f"{path}: cannot read ({exc.strerror})") from None
    return head == codec.MAGIC
