"""NVIDIA Warp kernels: TPS kernel construction, solve, inverse patch map, rasterisation.

The same kernels run on Warp's ``cpu`` device (CI) and on ``cuda``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys

from ..errors import TpsvError

_initialised = False


@contextlib.contextmanager
def _stderr_silenced():
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def warp():
    """Import and initialise Warp once, quietly; return the module."""
    global _initialised
    import warp as wp

    if not _initialised:
        # Warp's banner and "module loaded" lines would break one-line errors and
        # --json on stdout; TPSV_WARP_VERBOSE=1 brings them back for debugging.
        verbose = bool(os.environ.get("TPSV_WARP_VERBOSE"))
        wp.config.quiet = not verbose
        wp.config.log_level = logging.INFO if verbose else logging.WARNING
        if verbose:
            wp.init()
        else:
            # The native library warns on stderr when a machine has no CUDA driver;
            # that is the normal case on CPU-only machines, not news for the user.
            with _stderr_silenced():
                wp.init()
        _initialised = True
    return wp


def resolve_device(name: str | None) -> str:
    """Validate a device name (``cpu``, ``cuda``, ``cuda:N``; None means ``cpu``)."""
    wp = warp()
    name = name or "cpu"
    if name != "cpu" and not name.startswith("cuda"):
        raise TpsvError(f"unknown device {name!r}; use cpu or cuda")
    try:
        wp.get_device(name)
    except Exception:
        raise TpsvError(f"device {name!r} is not available here (no CUDA GPU?)") from None
    return name
