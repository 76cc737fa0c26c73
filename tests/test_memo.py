"""Caches keyed by content (tpsv.memo)."""

from tpsv import memo


def test_refresh_makes_only_missing_values_at_once_and_keeps_only_this_calls_keys():
    cache = {}
    asked = []

    def maker(keys):
        def make(idx):
            asked.append([keys[i] for i in idx])
            return [keys[i].upper() for i in idx]
        return make

    keys = ["a", "b", "a", "c"]
    assert memo.refresh(cache, keys, maker(keys)) == ["A", "B", "A", "C"]
    assert len(asked) == 1 and sorted(asked[0]) == ["a", "b", "c"]  # one batch, each key once
    assert set(cache) == {"a", "b", "c"}
    keys = ["c", "d"]
    assert memo.refresh(cache, keys, maker(keys)) == ["C", "D"]
    assert asked[-1] == ["d"]  # "c" came from the cache
    assert set(cache) == {"c", "d"}  # "a" and "b" were dropped
    assert memo.refresh(cache, keys, maker(keys)) == ["C", "D"] and len(asked) == 2  # nothing to make
