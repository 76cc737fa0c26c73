"""Caches keyed by content: derived values kept from one call to the next, made again only for
what changed (an editor that moves one region redraws and re-flattens only that region)."""

from __future__ import annotations

from typing import Callable, Hashable, Sequence


def refresh(cache: dict, keys: Sequence[Hashable], make: Callable[[list[int]], list]) -> list:
    """The value of each of ``keys``, from ``cache`` where it is there, else made.

    Parameters
    ----------
    cache : dict
        Values by key from an earlier call; left holding the values of
        ``keys`` only (a cache never outgrows one call's worth).
    keys : sequence of hashable
        One per item (equal items, equal keys).
    make : callable(list of int) -> list
        The values of the items at these indices (one item per missing key),
        in that order: all missing items at once, so a batch can be vectorised.

    Returns
    -------
    list
        One value per key.
    """
    missing = {k: i for i, k in enumerate(keys) if k not in cache}
    made = make(list(missing.values())) if missing else []
    kept = {k: cache[k] for k in keys if k not in missing}
    cache.clear()
    cache.update(kept)
    cache.update(zip(missing, made))
    return [cache[k] for k in keys]


__all__ = ["refresh"]
