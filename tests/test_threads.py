"""tpsv.threads: host thread pools kept for the process."""

from __future__ import annotations

import os

import pytest

from tpsv import threads


def test_one_pool_per_purpose_and_size():
    a = threads.pool("test", 2)
    assert threads.pool("test", 2) is a
    assert threads.pool("test", 3) is not a
    assert threads.pool("other", 2) is not a
    assert list(a.map(lambda x: x * x, range(5))) == [0, 1, 4, 9, 16]


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
