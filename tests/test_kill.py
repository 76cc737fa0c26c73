"""Signals against a real ``tpsv`` process (issue 14, "Why" 8).

SIGTERM and SIGINT stop a command cleanly: no output, no temporary, one line,
exit 143 / 130. SIGKILL cannot be handled, but still never leaves a partial
output or clobbers a good one, and the temporary it may leave is removed by the
next run. ``tests/kill_campaign.py`` runs the long version (50 kills, 10
rounds of 8 concurrent runs).
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import small_sample
from tpsv import cli
from tpsv.fileio import Outputs

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals and /proc/PID/status")

#: The console script beside this Python, as a user runs it; else the module.
_SCRIPT = Path(sys.executable).with_name("tpsv")
TPSV = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "tpsv"]


def leftovers(directory) -> list[str]:
    return sorted(n for n in os.listdir(directory) if n.endswith(".tmp"))


def handlers_installed(pid: int) -> bool:
    """Whether ``tpsv.cli.run`` has installed its SIGTERM handler (the process is past its imports)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught & (1 << (signal.SIGTERM - 1)))


def start(args, cwd) -> subprocess.Popen:
    return subprocess.Popen(TPSV + ["--quiet", *map(str, args)], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def photo(tmp_path_factory) -> Path:
    """A photo whose searched vectorisation takes a few seconds."""
    path = tmp_path_factory.mktemp("kill") / "photo.png"
    rgb = small_sample(width=200)
    cv2.imwrite(str(path), np.rint(rgb[:, :, ::-1] * 255).astype(np.uint8))
    return path


@pytest.mark.parametrize("sig, code, line", [(signal.SIGTERM, 143, "tpsv: terminated"),
                                             (signal.SIGINT, 130, "tpsv: interrupted")])
def test_signal_during_vectorize_stops_cleanly(tmp_path, photo, sig, code, line):
    (tmp_path / "kept.png").write_bytes(b"earlier output")
    proc = start(["vectorize", photo, "-o", "new.tpsv", "--preview", "kept.png"], tmp_path)
    deadline = time.monotonic() + 60
    while not handlers_installed(proc.pid):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "tpsv never installed its handlers"
        time.sleep(0.02)
    time.sleep(0.5)  # inside the work
    assert proc.poll() is None, "vectorize ended before the signal; use a larger photo"
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == code, err
    assert err.splitlines() == [line]
    assert out == ""
    assert not (tmp_path / "new.tpsv").exists()
    assert (tmp_path / "kept.png").read_bytes() == b"earlier output"
    assert leftovers(tmp_path) == []


def test_a_stop_is_prompt_inside_a_long_native_call(tmp_path, monkeypatch, capfd):
    """The watchdog: the main thread does not come back, the process still stops within the grace."""
    (tmp_path / "x.png").write_bytes(b"")
    outs = Outputs()
    outs.write(tmp_path / "out.png", b"staged")  # a temporary exists
    assert leftovers(tmp_path) != []
    exited = []
    monkeypatch.setattr(cli, "STOP_GRACE", 0.0)
    monkeypatch.setattr(cli, "_stop_reported", False)
    monkeypatch.setattr(os, "_exit", lambda code: exited.append(code))
    rfd, wfd = os.pipe()
    os.write(wfd, bytes([signal.SIGTERM]))
    watcher = threading.Thread(target=cli._watchdog, args=(rfd,))
    watcher.start()
    watcher.join(10)
    os.close(wfd)
    os.close(rfd)
    from tpsv import fileio

    fileio._CRITICAL.release()  # remove_temporaries keeps it (the process exits next)
    assert exited == [143]
    assert capfd.readouterr().err == "tpsv: terminated\n"
    assert leftovers(tmp_path) == []


def test_sigkill_never_leaves_a_partial_or_clobbered_output(tmp_path, photo):
    """A few SIGKILLs at random moments: the output is the old file or the whole new one."""
    model = tmp_path / "m.tpsv"
    subprocess.run(TPSV + ["-q", "vectorize", photo, "-o", model, "--no-search"], check=True)
    args = ["render", model, "-o", "out.png", "--size", "600x400"]
    t0 = time.monotonic()
    subprocess.run(TPSV + ["-q", *map(str, args)], cwd=tmp_path, check=True)
    duration = time.monotonic() - t0
    new = (tmp_path / "out.png").read_bytes()
    old = cv2.imencode(".png", np.full((4, 4, 3), 7, np.uint8))[1].tobytes()
    rng = random.Random(14)
    for _ in range(3):
        (tmp_path / "out.png").write_bytes(old)
        proc = start(args, tmp_path)
        time.sleep(rng.uniform(0.3, 1.05) * duration)
        proc.kill()
        proc.communicate()
        assert (tmp_path / "out.png").read_bytes() in (old, new)
    # a temporary a SIGKILL left is removed by the next run on the same output
    Outputs().claim(tmp_path / "out.png")
    assert leftovers(tmp_path) == []


def test_no_handler_is_installed_on_import():
    code = ("import signal, tpsv.cli; "
            "assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL; "
            "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler")
    subprocess.run([sys.executable, "-c", code], check=True)
