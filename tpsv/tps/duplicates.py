"""Coincident features: found once, merged for the TPS, spread back to every member.

A TPS through two colours at one point does not exist, so features of one
region at exactly the same ``(S, T)`` (or, with a coarser key, in the same
small square) form a group: the group's *representative* is its first
feature in index order, and only the representative enters a kernel, with the
group's mean colour. Everything that needs these groups (grouping, replacing
the colours of an existing kernel set, the colour fit handing its result back
to every feature) uses :class:`Duplicates`, so they agree bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Lab colour of a model without features (mid grey).
EMPTY_FILL = (50.0, 0.0, 0.0)


@dataclass
class Duplicates:
    """Groups of features with the same region and the same position key.

    Attributes
    ----------
    n : int
        Number of features.
    keep : (n,) bool
        Representatives (the first feature of each group; every feature
        without a duplicate is its own representative).
    order : (n,) int64 or None
        Features sorted by region, then key (stable, so a group's first
        feature comes first); None when no feature has a duplicate.
    gid : (n,) int64 or None
        Group of ``order[i]``.
    first : (G,) int64 or None
        Representative of each group.
    count : (G, 1) int64 or None
        Members per group.
    """

    n: int
    keep: np.ndarray
    order: np.ndarray | None = None
    gid: np.ndarray | None = None
    first: np.ndarray | None = None
    count: np.ndarray | None = None

    @classmethod
    def find(cls, region, key) -> "Duplicates":
        """Group features whose ``region`` (n,) and ``key`` (n, 2) are equal.

        Parameters
        ----------
        region : (n,) int
            Region of each feature.
        key : (n, 2) float
            Position key: ``(S, T)`` itself, or a pixel-square index for a
            coarser merge.

        Returns
        -------
        Duplicates
        """
        region = np.asarray(region, np.int64).reshape(-1)
        key = np.asarray(key, np.float64).reshape(-1, 2)
        n = region.shape[0]
        keep = np.ones(n, bool)
        if n < 2:
            return cls(n, keep)
        o = np.lexsort((key[:, 1], key[:, 0], region))  # stable: first occurrence first
        a, b = o[1:], o[:-1]
        same = (region[a] == region[b]) & (key[a, 0] == key[b, 0]) & (key[a, 1] == key[b, 1])
        if not same.any():
            return cls(n, keep)
        gid = np.concatenate([[0], np.cumsum(~same)])
        first = o[np.concatenate([[True], ~same])]
        keep[:] = False
        keep[first] = True
        return cls(n, keep, o, gid, first, np.bincount(gid)[:, None])

    @classmethod
    def of_features(cls, features) -> "Duplicates":
        """Features at exactly the same ``(S, T)`` of one region (``model.features``)."""
        F = len(features)
        return cls.find(np.asarray(features.region, np.int64).reshape(F), np.asarray(features.st, np.float64).reshape(F, 2))

    @property
    def any(self) -> bool:
        """Whether some feature has a duplicate."""
        return self.order is not None

    def _mean_into(self, values: np.ndarray, dtype) -> np.ndarray:
        out = np.array(values, dtype, copy=True)
        if self.any:
            acc = np.zeros((self.first.size, out.shape[1]))
            np.add.at(acc, self.gid, out[self.order].astype(np.float64))
            out[self.first] = (acc / self.count).astype(dtype)
        return out

    def merge_lab(self, lab) -> np.ndarray:
        """Lab (n, 3) float32 where each representative carries its group's mean colour.

        The mean is summed in float64 in sorted order, then rounded to float32.
        Other members keep their own colour (they enter no kernel).
        """
        return self._mean_into(np.asarray(lab, np.float32).reshape(self.n, 3), np.float32)

    def merge_st(self, st) -> np.ndarray:
        """``(S, T)`` (n, 2) float64 where each representative sits at its group's mean position."""
        return self._mean_into(np.asarray(st, np.float64).reshape(self.n, 2), np.float64)

    def fill(self, merged_lab: np.ndarray) -> np.ndarray:
        """Mean colour of the representatives (float64 (3,)); :data:`EMPTY_FILL` without features.

        Parameters
        ----------
        merged_lab : (n, 3) float32
            Colours from :meth:`merge_lab`.
        """
        if self.n == 0:
            return np.array(EMPTY_FILL)
        return merged_lab[self.keep].astype(np.float64).mean(0)

    def spread(self, values: np.ndarray) -> np.ndarray:
        """Every member takes its representative's value (a copy; ``values`` is (n, c))."""
        values = np.array(values, copy=True)
        if self.any:
            values[self.order] = values[self.first[self.gid]]
        return values


__all__ = ["Duplicates", "EMPTY_FILL"]
