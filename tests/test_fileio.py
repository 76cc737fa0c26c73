"""Output safety: staged outputs, inputs never clobbered, modes, links, stale temporaries."""

import os
import stat
import subprocess
import sys

import pytest

from tpsv.errors import TpsvError
from tpsv.fileio import Outputs, read_bytes, write_bytes_atomic


def _umask() -> int:
    old = os.umask(0)
    os.umask(old)
    return old


def _leftovers(directory) -> list[str]:
    return sorted(n for n in os.listdir(directory) if n.endswith(".tmp"))


def test_new_file_gets_umask_permissions(tmp_path):
    out = tmp_path / "a.bin"
    write_bytes_atomic(out, b"x")
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~_umask()
    # the same as a file made by open()
    ref = tmp_path / "ref"
    ref.write_bytes(b"")
    assert stat.S_IMODE(out.stat().st_mode) == stat.S_IMODE(ref.stat().st_mode)


def test_replaced_file_keeps_its_mode(tmp_path):
    out = tmp_path / "a.bin"
    out.write_bytes(b"old")
    os.chmod(out, 0o640)
    write_bytes_atomic(out, b"new")
    assert out.read_bytes() == b"new"
    assert stat.S_IMODE(out.stat().st_mode) == 0o640


def test_symlinked_output_is_written_through(tmp_path):
    real = tmp_path / "real.bin"
    real.write_bytes(b"old")
    link = tmp_path / "link.bin"
    link.symlink_to(real)
    write_bytes_atomic(link, b"new")
    assert link.is_symlink()
    assert real.read_bytes() == b"new"


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink", "relative"])
def test_output_equal_to_input_is_refused_before_work(tmp_path, how, monkeypatch):
    src = tmp_path / "in.png"
    src.write_bytes(b"photo")
    if how == "same":
        out = src
    elif how == "symlink":
        out = tmp_path / "ln.png"
        out.symlink_to(src)
    elif how == "hardlink":
        out = tmp_path / "hard.png"
        os.link(src, out)
    else:
        monkeypatch.chdir(tmp_path)
        out = "./sub/../in.png"
        (tmp_path / "sub").mkdir()
    with pytest.raises(TpsvError, match="is the input file"):
        Outputs(inputs=[src]).claim(out)
    assert src.read_bytes() == b"photo"


def test_two_outputs_naming_one_file_are_refused(tmp_path):
    outs = Outputs()
    outs.claim(tmp_path / "a.png", "output")
    with pytest.raises(TpsvError, match="same file as output"):
        outs.claim(tmp_path / "a.png", "--preview")


def test_failure_after_staging_writes_nothing(tmp_path):
    good = tmp_path / "out.tpsv"
    good.write_bytes(b"good")
    with pytest.raises(RuntimeError):
        with Outputs() as outs:
            outs.write(good, b"new")
            outs.write(tmp_path / "p.png", b"preview")
            raise RuntimeError("later step failed")
    assert good.read_bytes() == b"good"
    assert not (tmp_path / "p.png").exists()
    assert _leftovers(tmp_path) == []


def test_all_outputs_appear_together(tmp_path):
    with Outputs() as outs:
        outs.write(tmp_path / "a", b"1")
        outs.write(tmp_path / "b", b"2")
        assert not (tmp_path / "a").exists()  # staged, not yet renamed
    assert (tmp_path / "a").read_bytes() == b"1"
    assert (tmp_path / "b").read_bytes() == b"2"
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize(
    "path, message",
    [
        ("", "output path is empty"),
        ("nodir/x.png", "directory nodir does not exist"),
        ("file.txt/x.png", "is not a directory"),
        (".", "is a directory"),
    ],
)
def test_bad_output_paths_are_plain_sentences(tmp_path, monkeypatch, path, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(TpsvError, match=message) as info:
        Outputs().claim(path)
    assert ".tmp" not in str(info.value)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_unwritable_directory(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    os.chmod(locked, 0o500)
    try:
        with pytest.raises(TpsvError, match="permission denied"):
            Outputs().claim(locked / "x.png")
    finally:
        os.chmod(locked, 0o700)


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f".out.png.tpsv-{dead_pid}-0badcafe.tmp"
    stale.write_bytes(b"partial")
    alive = tmp_path / f".out.png.tpsv-{os.getppid()}-00c0ffee.tmp"  # a running process's
    alive.write_bytes(b"in progress")
    foreign = tmp_path / ".out.png.other.tmp"
    foreign.write_bytes(b"not ours")
    write_bytes_atomic(tmp_path / "out.png", b"done")
    assert not stale.exists()
    assert alive.exists() and foreign.exists()


def test_stdout_is_written_at_commit(tmp_path, capfdbinary):
    with pytest.raises(RuntimeError):
        with Outputs() as outs:
            outs.write("-", b"payload")
            raise RuntimeError
    assert capfdbinary.readouterr().out == b""
    with Outputs() as outs:
        outs.write("-", b"payload")
    assert capfdbinary.readouterr().out == b"payload"


def test_only_one_output_on_stdout():
    outs = Outputs()
    outs.claim("-")
    with pytest.raises(TpsvError, match="stdout"):
        outs.claim("-", "--preview")


def test_read_bytes_errors(tmp_path):
    with pytest.raises(TpsvError, match="missing.bin: cannot read"):
        read_bytes(tmp_path / "missing.bin")
    with pytest.raises(TpsvError, match="is a directory"):
        read_bytes(tmp_path)
    big = tmp_path / "big.bin"
    big.write_bytes(b"x" * 100)
    with pytest.raises(TpsvError, match="larger than 10 bytes"):
        read_bytes(big, limit=10)
    assert read_bytes(big, limit=100) == b"x" * 100


def test_interrupt_while_staging_removes_the_temporary(tmp_path, monkeypatch):
    import tpsv.fileio as fileio

    def interrupted(fd, data):
        raise KeyboardInterrupt

    monkeypatch.setattr(fileio, "_write_fd", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with Outputs() as outs:
            outs.write(tmp_path / "a.png", b"x")
    assert _leftovers(tmp_path) == [] and not (tmp_path / "a.png").exists()
    assert fileio._LIVE == set()


def test_a_signal_during_the_commit_waits_for_all_renames(tmp_path, monkeypatch):
    """SIGTERM arriving between two renames is delivered after the last one: all outputs, or none."""
    import signal

    class Stop(Exception):
        pass

    def handler(signum, frame):
        raise Stop

    old = signal.signal(signal.SIGTERM, handler)
    real_replace = os.replace

    def replace_then_signal(a, b):
        real_replace(a, b)
        os.kill(os.getpid(), signal.SIGTERM)

    try:
        outs = Outputs()
        outs.write(tmp_path / "a", b"1")
        outs.write(tmp_path / "b", b"2")
        monkeypatch.setattr(os, "replace", replace_then_signal)
        with pytest.raises(Stop):
            outs.commit()
    finally:
        signal.signal(signal.SIGTERM, old)
    assert (tmp_path / "a").read_bytes() == b"1" and (tmp_path / "b").read_bytes() == b"2"
    assert _leftovers(tmp_path) == []


def test_remove_temporaries_clears_what_this_process_staged(tmp_path):
    import tpsv.fileio as fileio

    outs = Outputs()
    outs.write(tmp_path / "a", b"1")
    assert _leftovers(tmp_path) != []
    fileio.remove_temporaries()
    fileio._CRITICAL.release()  # kept by remove_temporaries: its caller exits next
    assert _leftovers(tmp_path) == []


def test_a_fifo_output_is_written_in_place(tmp_path):
    import threading

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()))
    reader.start()
    write_bytes_atomic(fifo, b"through the pipe")
    reader.join(10)
    assert got == [b"through the pipe"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and _leftovers(tmp_path) == []


def test_a_symlink_to_a_device_is_written_through(tmp_path):
    link = tmp_path / "null"
    link.symlink_to(os.devnull)
    write_bytes_atomic(link, b"gone")
    assert link.is_symlink() and stat.S_ISCHR(os.stat(os.devnull).st_mode)


@pytest.mark.parametrize("text, shown", [
    ("plain name.png", "plain name.png"),
    ("a\x1b[2Jb", "a\\x1b[2Jb"),
    ("bell\x07 cr\r nl\n", "bell\\x07 cr\\x0d nl\\x0a"),
    ("c1\x9b del\x7f", "c1\\x9b del\\x7f"),
    ("bidi\u202eevil", "bidi\\u202eevil"),
    ("back\\slash", "back\\\\slash"),
    ("caf\u00e9 \u6f22", "caf\u00e9 \u6f22"),
])
def test_display_escapes_terminal_controls(text, shown):
    from tpsv.fileio import display

    assert display(text) == shown
