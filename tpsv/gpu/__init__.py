"""NVIDIA Warp kernels: inverse patch map, TPS solve, rasterisation (one code path for ``cpu`` and ``cuda``).

* ``patchmap``: pixel -> ``(S, T)`` in its region's patch (the twin of ``tpsv.geometry.patch.inverse``);
* ``device``: a kernel set's device arrays, bundled in ``@wp.struct`` types;
* ``solve``: Eq. (4) for every sub-patch kernel, float64;
* ``rasterise``: the per-pixel blend of the solved kernels, float32;
* ``color``: Lab -> sRGB, the twin of ``tpsv.color``;
* ``tps``: one namespace for the callers of the TPS stage (upload, solve, rasterise).

The modules of this package import ``warp`` at their top; everything outside
it imports them lazily, inside the functions that render, because importing
Warp costs start-up time that commands which never render should not pay.
Nothing initialises Warp at import: :func:`warp` does, quietly, on first use.
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
    # lazy: tpsv.gpu is imported (for device names) by commands that never render
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
        # Warp prints CUDA driver errors on stderr before it raises; the raise is our one line
        with contextlib.nullcontext() if os.environ.get("TPSV_WARP_VERBOSE") else _stderr_silenced():
            wp.get_device(name)
    except Exception:
        raise TpsvError(f"device {name!r} is not available here (no CUDA GPU?)") from None
    return name
