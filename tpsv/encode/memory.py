"""Memory a stage of the encoder freed, given back to the system before the next one.

numpy takes arrays below glibc's mmap threshold (which rises to the size of
the largest array freed, up to 32 MB) from the C heap. When a stage frees
them, glibc keeps their pages for later allocations of the heap, interleaved
with arrays that live on, and gives nothing back; the native memory of the
next stage (Warp's kernels and arrays, the AVIF encoder's frames) then comes
on top, and the peak of the process is near the sum of the stages' peaks
instead of the largest. :func:`give_back` returns those free pages
(glibc's ``malloc_trim``; where there is none it does nothing). Measured on
a 2048 x 2048 photo (``tpsv vectorize``): peak RSS 763 MB without, 700 MB
with it called between the stages.
"""

from __future__ import annotations

import ctypes
import sys


def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return getattr(ctypes.CDLL(None), "malloc_trim", None)  # glibc; musl has none
    except OSError:
        return None


_TRIM = _malloc_trim()


def give_back() -> None:
    """Return the C heap's free pages to the system (a few milliseconds; nothing outside glibc)."""
    if _TRIM is not None:
        _TRIM(0)


__all__ = ["give_back"]
