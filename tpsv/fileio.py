"""Safe output: every output of a command is staged, then renamed into place together.

A command may write several files (``vectorize -o OUT.tpsv --preview P.png``).
:class:`Outputs` stages each one in a temporary file beside its target and
renames them all only once the whole command has succeeded, so a failed or
interrupted run leaves no partial file and never replaces a good one.

Rules (the README's "Files" section says the same to users):

- An output that is, or resolves to, one of the command's inputs is refused
  before any work, as are two outputs naming the same file.
- A new file gets the permissions ``open()`` would give it under the umask; a
  replaced file keeps its mode.
- An output that is a symbolic link is written through: the link stays and its
  target gets the new content (as ``cat > link`` would do).
- Temporary files are named ``.NAME.tpsv-PID-XXXX.tmp``; temporaries left by a
  process that no longer exists (killed by SIGKILL) are removed the next time
  the same output is written.
- An output that exists and is not a regular file (``/dev/null``, a named
  pipe) is written in place at commit, never replaced by a rename.
- ``-`` is stdout: its bytes are held in memory and written at commit, after
  every file output was renamed.
- SIGINT and SIGTERM are held back while a temporary is created and recorded
  and while the renames of a commit run, so an interrupt leaves either every
  output or none, and no temporary (SIGKILL can leave one; see above).
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import signal
import stat
import sys
import threading
from pathlib import Path
from typing import NamedTuple

from .errors import TpsvError

#: Largest input file read whole (bytes); bigger inputs are refused before reading.
MAX_INPUT_BYTES = 512 * 2**20

_TMP_RE = re.compile(r"^\.(?P<name>.+)\.tpsv-(?P<pid>\d+)-[0-9a-f]+\.tmp$")
_DEFERRED = (signal.SIGINT, signal.SIGTERM)
#: Held while a temporary is created and recorded, and during a commit's renames.
_CRITICAL = threading.Lock()
#: Every temporary of this process not yet renamed or removed.
_LIVE: set[Path] = set()


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist yet: compare where they would resolve
        return os.path.realpath(a) == os.path.realpath(b)


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (this one does; another user's does too)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _remove_stale_temporaries(target: Path) -> None:
    """Delete ``.NAME.tpsv-PID-*.tmp`` beside ``target`` whose writer process is gone."""
    remove_stale_temporaries(target.parent, {target.name})


def remove_stale_temporaries(directory: str | os.PathLike, names) -> int:
    """Delete the temporaries of outputs ``names`` in ``directory`` whose writer process is gone.

    One listing of the directory for any number of outputs (``tpsv batch``
    cleans up after workers stopped in the middle of a file).

    Parameters
    ----------
    directory : path-like
    names : collection of str
        Output file names (``NAME`` of ``.NAME.tpsv-PID-XXXX.tmp``).

    Returns
    -------
    int
        Files removed.
    """
    try:
        entries = os.listdir(directory)
    except OSError:
        return 0
    removed = 0
    for entry in entries:
        m = _TMP_RE.match(entry)
        if m and m.group("name") in names and not _pid_alive(int(m.group("pid"))):
            try:
                os.unlink(os.path.join(directory, entry))
                removed += 1
            except OSError:
                pass
    return removed


@contextlib.contextmanager
def signals_deferred():
    """SIGINT and SIGTERM wait until the block has run (a no-op outside the main thread).

    Creating a temporary and recording it, and the renames of a commit, must
    not be cut in half by an interrupt: a signal arriving meanwhile is
    delivered to the handler in place once the block ends.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _CRITICAL, _held_signals():
        yield


@contextlib.contextmanager
def _held_signals():
    caught: list[int] = []
    saved = {}
    for sig in _DEFERRED:
        try:
            saved[sig] = signal.signal(sig, lambda signum, frame: caught.append(signum))
        except (OSError, ValueError):  # not settable here: leave it as it is
            pass
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        if caught:
            signal.raise_signal(caught[0])


def remove_temporaries(timeout: float = 10.0) -> None:
    """Remove every temporary this process made and did not rename.

    For a stop decided outside the main thread (:func:`tpsv.cli.run`'s
    watchdog, when the main thread is stuck in a long native call): waits up
    to ``timeout`` seconds for a creation or a commit under way to finish,
    and keeps them from starting again (the caller is about to exit).
    """
    _CRITICAL.acquire(timeout=timeout)
    for tmp in list(_LIVE):
        _unlink(tmp)
        _LIVE.discard(tmp)


def resolve_output(path: str | os.PathLike) -> Path:
    """The file an output path really writes: symbolic links followed to their target.

    Parameters
    ----------
    path : str or path-like
        The path the user gave (not ``-``).

    Returns
    -------
    target : Path
        Absolute path of the file that will be replaced.

    Raises
    ------
    TpsvError
        Empty path, a directory, or a directory part that does not exist or is
        not a directory.
    """
    text = os.fspath(path)
    if text == "":
        raise TpsvError("output path is empty")
    shown = display(text)
    if _is_special(text):  # /dev/stdout's real path is no path at all: keep the user's
        if not os.access(text, os.W_OK):
            raise TpsvError(f"cannot write {shown}: permission denied")
        return Path(os.path.abspath(text))
    target = Path(os.path.realpath(text))
    if target.is_dir():
        raise TpsvError(f"cannot write {shown}: it is a directory")
    parent = target.parent
    if not parent.exists():
        raise TpsvError(f"cannot write {shown}: directory {display(os.path.dirname(text) or '.')} does not exist")
    if not parent.is_dir():
        raise TpsvError(f"cannot write {shown}: {display(os.path.dirname(text))} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise TpsvError(f"cannot write {shown}: permission denied")
    return target


def _is_special(path: str | Path) -> bool:
    """An existing file, links followed, that is neither a regular file nor a directory (a device, a pipe).

    Such an output is written in place, never replaced by a rename.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


class _Claim(NamedTuple):
    """One claimed output: how it is written, and where."""

    kind: str  # "file" (staged, renamed), "special" (written in place at commit), "stdout"
    target: Path | None


class Outputs:
    """The outputs of one command: claimed up front, staged, then committed together.

    Parameters
    ----------
    inputs : iterable of str or path-like
        The command's input files; an output resolving to one of them is refused.
        ``-`` and ``None`` entries are ignored.

    Examples
    --------
    >>> with Outputs(inputs=[src]) as out:          # doctest: +SKIP
    ...     out.claim(args.output); out.claim(args.preview)
    ...     model = work()                          # nothing written yet
    ...     out.write(args.output, encode(model))   # staged beside the target
    ...     out.write(args.preview, png)
    ... # leaving the block renames both; an exception removes both temporaries
    """

    def __init__(self, inputs=()):
        self._inputs = [Path(os.fspath(p)) for p in inputs if p is not None and os.fspath(p) != "-"]
        self._claimed: dict[str, _Claim] = {}
        self._temps: list[Path] = []  # every temporary made and not yet renamed
        self._staged: list[tuple[str, _Claim, Path | bytes]] = []

    def claim(self, path: str | os.PathLike | None, what: str = "output") -> None:
        """Reserve an output path before any work; refuse inputs, duplicates and unwritable places.

        Parameters
        ----------
        path : str, path-like or None
            ``None`` (an optional output not asked for) is ignored; ``-`` is stdout.
        what : str
            How the message names this output (``"output"``, ``"--preview"``...).

        Raises
        ------
        TpsvError
            The path cannot be written, is an input, or is claimed already.
        """
        if path is None:
            return
        text = os.fspath(path)
        if text == "-":
            if any(c.kind == "stdout" for c in self._claimed.values()):
                raise TpsvError(f"{what}: only one output can go to stdout ('-')")
            self._claimed[text] = _Claim("stdout", None)
            return
        target = resolve_output(text)
        for src in self._inputs:
            if _same_file(target, src):
                raise TpsvError(f"{what} {display(text)} is the input file {display(os.fspath(src))}; "
                                "choose another output path")
        for other, c in self._claimed.items():
            if c.target is not None and c.target == target:
                raise TpsvError(f"{what} {display(text)} names the same file as output {display(other)}")
        if _is_special(text):
            self._claimed[text] = _Claim("special", target)
            return
        _remove_stale_temporaries(target)
        self._claimed[text] = _Claim("file", target)

    def write(self, path: str | os.PathLike, data) -> None:
        """Stage ``data`` for ``path`` (claimed first if it was not).

        ``data`` is bytes, or an iterable of bytes pieces written as they come
        (a streamed render never holds its whole file in memory).

        Raises
        ------
        TpsvError
            The temporary cannot be made or written (disk full...); it is removed.
        """
        text = os.fspath(path)
        if text not in self._claimed:
            self.claim(text)
        claim = self._claimed[text]
        pieces = [data] if isinstance(data, (bytes, bytearray, memoryview)) else data
        if claim.kind != "file":
            self._staged.append((text, claim, b"".join(pieces)))
            return
        target = claim.target
        with signals_deferred():  # a temporary made is a temporary recorded
            tmp = target.parent / f".{target.name}.tpsv-{os.getpid()}-{secrets.token_hex(4)}.tmp"
            try:
                # 0o666 lets the umask decide, as for any new file; a replaced file keeps its mode
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
            except OSError as exc:
                raise TpsvError(f"cannot write {display(text)}: {_reason(exc)}") from None
            self._temps.append(tmp)
            _LIVE.add(tmp)
        try:
            try:
                for piece in pieces:
                    _write_fd(fd, piece)
                os.fsync(fd)
            finally:
                os.close(fd)
            if target.exists():
                os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
        except OSError as exc:
            self._forget(tmp)
            raise TpsvError(f"cannot write {display(text)}: {_reason(exc)}") from None
        except BaseException:
            self._forget(tmp)
            raise
        self._staged.append((text, claim, tmp))

    def _forget(self, tmp: Path) -> None:
        _unlink(tmp)
        _LIVE.discard(tmp)
        if tmp in self._temps:
            self._temps.remove(tmp)

    def commit(self) -> None:
        """Rename every staged file into place, then write special files and stdout.

        Raises
        ------
        TpsvError
            A rename or a write failed (the temporaries not renamed are removed).
        """
        staged, self._staged = self._staged, []
        with signals_deferred():  # all renames or, on a failure, none of the rest
            try:
                for text, claim, tmp in staged:
                    if claim.kind == "file":
                        try:
                            os.replace(tmp, claim.target)
                        except OSError as exc:
                            raise TpsvError(f"cannot write {display(text)}: {_reason(exc)}") from None
                        self._temps.remove(tmp)
                        _LIVE.discard(tmp)
            finally:
                self.discard()
        for text, claim, data in staged:
            if claim.kind == "special":
                try:
                    with open(claim.target, "wb") as fh:
                        fh.write(data)
                except OSError as exc:
                    raise TpsvError(f"cannot write {display(text)}: {_reason(exc)}") from None
        for _, claim, data in staged:
            if claim.kind == "stdout":
                sys.stdout.buffer.write(data)
                sys.stdout.buffer.flush()

    def discard(self) -> None:
        """Remove every temporary not yet renamed; nothing (more) is written."""
        self._staged = []
        temps, self._temps = self._temps, []
        for tmp in temps:
            _unlink(tmp)
            _LIVE.discard(tmp)

    def __enter__(self) -> "Outputs":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def _write_fd(fd: int, data: bytes) -> None:
    """Write all of ``data`` to ``fd`` (``os.write`` may write less than asked)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view[: 1 << 24])
        view = view[n:]


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def write_bytes_atomic(path: str | os.PathLike, data: bytes, inputs=()) -> None:
    """Write one output safely (see the module doc); ``-`` writes to stdout.

    Parameters
    ----------
    path : str or path-like
        Destination. Its directory must exist.
    data : bytes
        The whole content.
    inputs : iterable of path-like, optional
        Files ``path`` must not be.
    """
    with Outputs(inputs) as out:
        out.write(path, data)


def display(text: str) -> str:
    """``text`` (a path, a string read from a file) safe to print on a terminal, on one line.

    Control characters (C0, DEL, C1), Unicode format characters (bidi
    overrides...) and line separators become visible escapes (``\\x1b``,
    ``\\u202e``), and a backslash is doubled so that an escape cannot be faked.

    Parameters
    ----------
    text : str

    Returns
    -------
    str
    """
    text = str(text)
    if text.isprintable() and "\\" not in text:
        return text
    out = []
    for ch in text:
        if ch == "\\":
            out.append("\\\\")
        elif ch.isprintable() or ch == " ":
            out.append(ch)
        elif ord(ch) < 0x100:
            out.append(f"\\x{ord(ch):02x}")
        elif ord(ch) < 0x10000:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(f"\\U{ord(ch):08x}")
    return "".join(out)


def read_bytes(path: str | os.PathLike, limit: int | None = MAX_INPUT_BYTES) -> bytes:
    """Read a whole file (``-`` reads stdin), refusing more than ``limit`` bytes.

    Raises
    ------
    TpsvError
        The file cannot be read, or is larger than ``limit``.
    """
    text = os.fspath(path)
    shown = display(text)
    try:
        if text == "-":
            data = _read_stream(sys.stdin.buffer, limit)
        else:
            with open(text, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                if limit is not None and size > limit:
                    raise TpsvError(f"{shown}: input larger than {limit} bytes")
                # read(n) allocates n bytes up front: ask for the known size
                # (+1 sees growth), the whole limit only when the size is unknown.
                data = fh.read(-1 if limit is None else (size or limit) + 1)
                if limit is not None and size and len(data) > size:  # grew while read
                    data += fh.read(limit + 1 - len(data))
    except IsADirectoryError:
        raise TpsvError(f"{shown}: is a directory, not a file") from None
    except OSError as exc:
        raise TpsvError(f"{shown}: cannot read ({_reason(exc)})") from None
    if limit is not None and len(data) > limit:
        raise TpsvError(f"{shown}: input larger than {limit} bytes")
    return data


def _read_stream(stream, limit: int | None) -> bytes:
    """Read a pipe to its end in chunks, stopping one byte past ``limit``.

    ``read(limit + 1)`` would allocate the whole limit up front.
    """
    chunks, total = [], 0
    while limit is None or total <= limit:
        chunk = stream.read(1 << 20)
        if not chunk:
            break
        chunks.append(chunk)
        total += len(chunk)
    return b"".join(chunks)
