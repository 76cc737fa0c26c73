"""NVIDIA Warp kernels: TPS kernel construction, solve, inverse patch map, rasterisation.

The same kernels run on Warp's ``cpu`` device (CI) and on ``cuda``.
"""

from __future__ import annotations

import os

from ..errors import TpsvError

_initialised = False


def warp():
    """Import and initialise Warp once, quietly; return the module."""
    global _initialised
    import warp as wp

    if not _initialised:
        wp.config.quiet = True
        if os.environ.get("TPSV_WARP_VERBOSE"):
            wp.config.quiet = False
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
