"""tpsv.threads: host thread pools kept for the process."""

from __future__ import annotations

import os

import numpy as np
import pytest

from tpsv import threads


def test_one_pool_per_purpose_and_size():
    a = threads.pool("test", 2)
    assert threads.pool("test", 2) is a
    assert threads.pool("test", 3) is not a
    assert threads.pool("other", 2) is not a
    assert list(a.map(lambda x: x * x, range(5))) == [0, 1, 4, 9, 16]


def test_map_ordered_keeps_the_order(monkeypatch):
    """Results come in the items' order, from the pool's threads when there are cores, else a loop."""
    import threading
    import time

    monkeypatch.setattr(threads, "host_cores", lambda: 4)
    names = set()

    def work(i):
        names.add(threading.current_thread().name)
        time.sleep(0.005 * (8 - i))  # the first items finish last
        return i * i

    assert threads.map_ordered("test-ordered", work, range(8)) == [i * i for i in range(8)]
    assert all(n.startswith("tpsv-test-ordered") for n in names)
    monkeypatch.setattr(threads, "host_cores", lambda: 1)
    names.clear()
    assert threads.map_ordered("test-ordered", work, [3, 1]) == [9, 1]
    assert names == {threading.current_thread().name}


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork only")
def test_a_forked_child_gets_pools_of_its_own():
    parent = threads.pool("test", 2)
    parent.submit(int).result()  # its threads exist in the parent
    pid = os.fork()
    if pid == 0:
        import signal

        signal.alarm(30)  # a pool without threads would wait forever
        child = threads.pool("test", 2)
        ok = child is not parent and child.submit(lambda: 7).result() == 7
        os._exit(0 if ok else 3)
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0


def test_launches_split_only_as_far_as_their_work_pays():
    """A CPU launch is cut into bands of at least BAND_SECONDS of work, at most 4 a thread; CUDA never."""
    from tpsv.gpu import device

    least = device.BAND_SECONDS
    assert device.bands("cpu", 1000, 2, 0.5 * least) == 1  # less than two bands' work: the calling thread
    assert device.bands("cpu", 1000, 2, 2.5 * least) == 2
    assert device.bands("cpu", 1000, 2, 100 * least) == 8
    assert device.bands("cpu", 1000, 2) == 8  # no estimate: 4 a thread
    assert device.bands("cpu", 3, 2, 100 * least) == 3  # a row a band at most
    assert device.bands("cpu", 1000, 1, 100 * least) == 1
    assert device.bands("cuda:0", 1000, 8, 100 * least) == 1


@pytest.mark.parametrize("seconds", [None, 1e-9, 0.05])
def test_split_launch_covers_each_row_once(seconds):
    from tpsv.gpu import device

    seen = []
    device.split_launch("cpu", 1001, 2, lambda a, b: seen.append((a, b)), seconds)
    covered = np.concatenate([np.arange(a, b) for a, b in sorted(seen)])
    assert np.array_equal(covered, np.arange(1001))
    assert len(seen) == device.bands("cpu", 1001, 2, seconds)


def test_every_banded_kernel_has_a_cost():
    """Each kernel launched through ``_launch_banded`` has its work per item in ``HOST_SECONDS``."""
    import re
    from pathlib import Path

    import tpsv.gpu
    from tpsv.gpu.rasterise import HOST_SECONDS

    launched = set()
    for path in Path(tpsv.gpu.__file__).parent.glob("*.py"):
        launched |= set(re.findall(r"_launch_banded\(\s*(\w+)\s*,", path.read_text()))
    launched.discard("kernel")  # the definition's parameter
    assert len(launched) >= 15
    assert launched <= set(HOST_SECONDS), launched - set(HOST_SECONDS)


def test_bands_on_threads_give_the_whole_image_once():
    """for_bands visits every band once from its threads, and lab_image's bands put together are
    srgb_to_lab of the whole image, bit for bit."""
    from tpsv.color import srgb_to_lab
    from tpsv.geometry.bands import for_bands, lab_image, row_bands

    seen = []

    def visit(rows):
        seen.append(rows)

    for_bands(visit, 300, 7, pixels=64)
    assert sorted(seen) == list(row_bands(300, 7, 64))
    rgb = np.random.default_rng(1).random((1500, 90, 3))
    assert np.array_equal(lab_image(rgb), srgb_to_lab(rgb))
    assert np.array_equal(lab_image(rgb * 1.2 - 0.1, clip=True), srgb_to_lab(np.clip(rgb * 1.2 - 0.1, 0, 1)))


def test_progress_moves_forward_only_from_any_thread():
    """A quality search reports from several threads: the bar never steps back."""
    from tpsv.cli import advance

    class Bar:
        pos = 0

        def update(self, n):
            assert n > 0
            self.pos += n

    bar = Bar()
    step = advance(bar)
    list(threads.pool("test-progress", 4).map(lambda d: step(d, 10), [3, 1, 5, 2, 5, 4]))
    assert bar.pos == 5
    advance(None)(3, 10)  # no bar: nothing
