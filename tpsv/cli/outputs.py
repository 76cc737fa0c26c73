"""A command's outputs: claimed before any work, staged while it runs, written together at the end.

Every subcommand opens :func:`claim_outputs` with all its input files and all
the outputs it was asked for, before it reads or computes anything: an output
that is an input (also through a link), two outputs naming one file, or a
place that cannot be written is refused there, with one line. Each output is
then staged as it is produced, and all are renamed into place when the block
ends without an error; a failure (or SIGINT/SIGTERM) leaves every existing
file as it was and no temporary behind (:mod:`tpsv.fileio`).
"""

from __future__ import annotations

import json
import os

import click

from .options import check_json_target
from .. import codec
from ..errors import TpsvError
from ..fileio import Outputs, display, read_bytes

#: Largest JSON input (``deform --grid``) read; a 256 x 256 grid with every
#: derivative takes about 10 MB of JSON.
MAX_JSON_BYTES = 64 * 2**20


def claim_outputs(inputs, *outputs: tuple[str, str | None]) -> Outputs:
    """Claim every output of a command at once, before any work.

    Parameters
    ----------
    inputs : iterable of str or None
        Every file the command reads (None entries: options not given).
    *outputs : (str, str or None)
        ``(option name, path)`` of each output; a None path (not asked for) is
        skipped, ``-`` is stdout.

    Returns
    -------
    Outputs
        To use as a context manager: ``out.write(path, data)`` stages, leaving
        the block without an error commits.

    Raises
    ------
    TpsvError
        An output is an input, is claimed twice, or cannot be written.
    """
    out = Outputs(inputs=[p for p in inputs if p is not None])
    for what, path in outputs:
        out.claim(path, what)
    return out


def check_targets(as_json: bool, output: str, second: str | None, second_name: str = "--render") -> None:
    """Usage errors for outputs that collide: both on stdout, the same file, or stdout and ``--json``.

    Parameters
    ----------
    as_json : bool
    output : str
        The ``-o`` path.
    second : str or None
        A second output (``--render``).
    second_name : str
        Its option name, for the message.
    """
    check_json_target(as_json, output, second)
    if second is not None:
        if second == "-" and output == "-":
            raise click.UsageError(f"-o and {second_name} cannot both be stdout ('-')")
        if second != "-" and output != "-" and os.path.abspath(second) == os.path.abspath(output):
            raise click.UsageError(f"-o and {second_name} name the same file")


def encode_model(model) -> bytes:
    """The .tpsv bytes of a model made or edited by a command.

    Returns
    -------
    bytes

    Raises
    ------
    TpsvError
        A model the format cannot hold (a data error, exit 1).
    """
    try:
        return codec.encode(model)
    except ValueError as exc:
        raise TpsvError(f"the model cannot be stored: {exc}") from None


def read_json(path: str):
    """A JSON input file, parsed; one line for any failure (unreadable, too large, invalid, too deep).

    Parameters
    ----------
    path : str

    Returns
    -------
    object
        The parsed document.

    Raises
    ------
    TpsvError
    """
    data = read_bytes(path, limit=MAX_JSON_BYTES)
    try:
        return json.loads(data)
    except RecursionError:  # the C decoder recurses once per nesting level
        raise TpsvError(f"{display(path)}: JSON nested too deeply") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise TpsvError(f"{display(path)}: not valid JSON ({exc})") from None
