"""Host thread pools kept for the process: one per purpose and size.

Starting threads for every call cost about 8 ms of a 512x512 CPU render
(26 launches). A pool's threads idle between calls. Each purpose has its
own pool, so work on one pool may wait on another's without starving it;
a task must not submit to its own purpose's pool and wait for the result.
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor


@functools.cache
def pool(purpose: str, threads: int) -> ThreadPoolExecutor:
    """The pool of ``threads`` host threads for ``purpose`` (made at first use).

    Parameters
    ----------
    purpose : str
        ``"launch"`` (banded Warp launches on the CPU device), ``"fit"``
        (the colour fit's batched numpy work), ...; names the threads.
    threads : int
        Worker threads, at least 1.

    Returns
    -------
    ThreadPoolExecutor
    """
    return ThreadPoolExecutor(max_workers=max(1, int(threads)), thread_name_prefix=f"tpsv-{purpose}")


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the system tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def host_cores() -> int:
    """:func:`usable_cores`, no more than ``OMP_NUM_THREADS`` when that is set (a ``tpsv batch``
    worker's share of the machine)."""
    n = usable_cores()
    limit = os.environ.get("OMP_NUM_THREADS", "").strip()
    if limit.isdigit() and int(limit) > 0:
        n = min(n, int(limit))
    return max(1, n)


def map_ordered(purpose: str, fn, items, limit: int = 8) -> list:
    """``[fn(x) for x in items]``, the calls made on up to ``limit`` host threads of ``purpose``'s pool.

    For independent pieces of numpy work (numpy releases the interpreter in its
    heavy calls): each result is what one thread computes, in the order of
    ``items``, so the values do not depend on the number of cores. ``fn``
    must not submit to ``purpose``'s pool itself.
    """
    items = list(items)
    workers = min(int(limit), host_cores(), len(items))
    if workers > 1:
        return list(pool(purpose, workers).map(fn, items))
    return [fn(x) for x in items]


# a forked child has the parent's pool objects but none of their threads: it makes its own
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=pool.cache_clear)
