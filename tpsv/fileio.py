"""Atomic output: write to a temporary file beside the target, then rename.

A failed run leaves no partial file and never clobbers a good one.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; ``-`` writes to stdout.

    Parameters
    ----------
    path : str or path-like
        Destination. Its directory must exist.
    data : bytes
        The whole content.
    """
    if str(path) == "-":
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
        return
    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def read_bytes(path: str | os.PathLike, limit: int | None = None) -> bytes:
    """Read a whole file (``-`` reads stdin), refusing more than ``limit`` bytes."""
    if str(path) == "-":
        data = sys.stdin.buffer.read(-1 if limit is None else limit + 1)
    else:
        with open(path, "rb") as fh:
            data = fh.read(-1 if limit is None else limit + 1)
    if limit is not None and len(data) > limit:
        from .errors import TpsvError

        raise TpsvError(f"{path}: input larger than {limit} bytes")
    return data
