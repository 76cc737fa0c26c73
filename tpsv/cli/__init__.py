"""The ``tpsv`` command line: a click group of file-to-file subcommands.

Exit status: 0 success, 1 bad data or failed work (one line on stderr, no
traceback), 2 usage error.

Each subcommand module (``segment``, ``vectorize``, ``render``, ``edit``,
``info``, ``bench``) parses with the value types and shared options of
``options`` and writes through ``outputs``; command bodies check option
combinations and call library functions once.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
import threading
import time
import warnings
from dataclasses import dataclass

import click
import numpy as np

from .. import __version__
from ..errors import TpsvError
from ..fileio import display, remove_temporaries


@dataclass
class Settings:
    """Global options, passed to every subcommand through the click context."""

    device: str = "cpu"
    quiet: bool = False


class TpsvFailure(click.ClickException):
    """A TpsvError (or any failure) shown as one line and exit status 1."""

    exit_code = 1

    def show(self, file=None) -> None:
        # display(): one line whatever the message holds (paths, strings read from a file)
        click.echo(f"tpsv: error: {display(self.format_message())}", err=True)


class Stopped(click.ClickException):
    """SIGINT or SIGTERM: outputs discarded, one line, exit 130 or 143 (128 + the signal)."""

    def __init__(self, signum: int) -> None:
        super().__init__("interrupted" if signum == signal.SIGINT else "terminated")
        self.exit_code = 128 + signum

    def show(self, file=None) -> None:
        global _stop_reported
        # A watchdog that got there first holds the lock until it exits: one line either way.
        with _STOP_LINE:
            _stop_reported = True
            click.echo(f"tpsv: {self.message}", err=True)


class Terminated(BaseException):
    """Raised in the main thread by :func:`run`'s SIGTERM handler (as SIGINT raises KeyboardInterrupt).

    A BaseException, so that no ``except Exception`` on the way swallows it and
    every ``with`` block (staged outputs) unwinds.
    """


def _one_line(exc: BaseException) -> click.ClickException | None:
    """The one-line failure of an exception a user can cause, or None for a bug."""
    if isinstance(exc, TpsvError):
        return TpsvFailure(str(exc))
    if isinstance(exc, click.FileError):  # click's own "Error: Could not open file"
        return TpsvFailure(f"{exc.ui_filename}: cannot read ({exc.message})")
    if isinstance(exc, MemoryError):
        return TpsvFailure("out of memory")
    if isinstance(exc, RecursionError):
        return TpsvFailure("input nested too deeply")
    if isinstance(exc, KeyboardInterrupt):
        return Stopped(signal.SIGINT)
    if isinstance(exc, Terminated):
        return Stopped(signal.SIGTERM)
    if isinstance(exc, OSError) and exc.strerror:  # a file a library opened itself
        where = f"{exc.filename}: " if exc.filename else ""
        return TpsvFailure(f"{where}{exc.strerror}")
    return None


#: Subcommand -> the module of ``tpsv.cli`` that defines it, imported when the command is first looked
#: up: ``tpsv info`` or ``tpsv --version`` does not import what rendering, editing or benchmarking needs
#: (SciPy's spatial package alone took a third of a second).
COMMAND_MODULES = {
    "batch": "batch", "bench": "bench", "crossmap": "edit", "deform": "edit", "export": "export", "info": "info",
    "magnify": "render", "recolor": "edit", "render": "render", "segment": "segment", "stylize": "edit",
    "vectorize": "vectorize",
}


def command(name: str) -> click.Command | None:
    """The subcommand ``name`` of :data:`main` (its module imported on first use), or None."""
    module = COMMAND_MODULES.get(name)
    if module is not None and name not in main.commands:
        importlib.import_module(f"{__name__}.{module}")
    return main.commands.get(name)


class TpsvGroup(click.Group):
    """The group: subcommands run quietly, and every failure ends as one line. Subcommands are
    imported when looked up (:data:`COMMAND_MODULES`)."""

    def list_commands(self, ctx):
        return sorted(set(COMMAND_MODULES) | set(self.commands))

    def get_command(self, ctx, cmd_name):
        return command(cmd_name) if self is main else super().get_command(ctx, cmd_name)

    def invoke(self, ctx):
        try:
            # Overflow and invalid-value warnings of numpy (a huge --affine, a
            # model's extreme smoothing) are not news for the user: the result
            # is checked, and a value that does not fit is an error line.
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, BrokenPipeError):
            raise  # click ends a closed pipe quietly (exit 1), as `tpsv render ... -o - | head` expects
        except click.ClickException as exc:
            failure = _one_line(exc)
            if failure is None:
                raise
            raise failure from None
        except BaseException as exc:
            failure = _one_line(exc)
            if failure is not None:
                raise failure from None
            if not isinstance(exc, Exception) or os.environ.get("TPSV_DEBUG"):
                raise  # SystemExit and the like; or a traceback on request
            raise TpsvFailure(
                f"internal error: {type(exc).__name__}: {exc} (set TPSV_DEBUG=1 for a traceback)"
            ) from None


@click.group(cls=TpsvGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="tpsv")
@click.option(
    "--device",
    default="cpu",
    show_default=True,
    envvar="TPSV_DEVICE",
    help="Warp device for TPS kernels: cpu, cuda or cuda:N (env TPSV_DEVICE).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress or summaries on stderr.")
@click.pass_context
def main(ctx: click.Context, device: str, quiet: bool) -> None:
    """tpsv: photos to editable, resolution-free vector images (Hermite patches + TPS).

    Each subcommand reads files and writes files; '-' means stdin/stdout where it
    makes sense. Outputs are written together at the end, only when everything
    succeeded: a failed or interrupted run changes no file.
    """
    ctx.obj = Settings(device=device, quiet=quiet)


def settings(ctx: click.Context) -> Settings:
    """The group's settings (defaults when a command is invoked on its own)."""
    root = ctx.find_root()
    return root.obj if isinstance(root.obj, Settings) else Settings()


def say(ctx: click.Context, message: str) -> None:
    """A human summary line on stderr (suppressed by --quiet)."""
    if not settings(ctx).quiet:
        click.echo(message, err=True)


def progress_enabled(ctx: click.Context) -> bool:
    """Progress bars go to stderr, only on a terminal and without --quiet."""
    return not settings(ctx).quiet and sys.stderr.isatty()


@contextlib.contextmanager
def progress_bar(ctx: click.Context, length: int, label: str, enabled: bool = True):
    """A click progress bar on stderr while the block runs, or None where progress is not shown.

    Parameters
    ----------
    ctx : click.Context
    length : int
        Steps of the bar.
    label : str
    enabled : bool
        False: no bar whatever the terminal.

    Yields
    ------
    click.termui.ProgressBar or None
    """
    if not (enabled and progress_enabled(ctx)):
        yield None
        return
    with click.progressbar(length=length, label=label, file=click.get_text_stream("stderr")) as bar:
        yield bar


def advance(bar):
    """A ``progress(done, total)`` callback moving ``bar`` (None, no bar shown: does nothing) forward to
    ``done``; it may be called from several threads (a quality search codes several textures at once)."""
    lock = threading.Lock()

    def progress(done, total):
        if bar is not None:
            with lock:
                if done > bar.pos:
                    bar.update(done - bar.pos)

    return progress


_STOP_LINE = threading.Lock()
_stop_reported = False
#: Seconds the main thread has to stop by itself before the watchdog stops the process.
STOP_GRACE = 1.0


def _watchdog(rfd: int) -> None:
    """Stop the process shortly after SIGINT/SIGTERM if the main thread cannot.

    Python runs signal handlers in the main thread between bytecodes, so a
    long native call (a large Warp render, an OpenCV decode) would hold off
    the stop for minutes. Python's C-level handler writes the signal number
    to the wakeup pipe at once; this thread reads it, gives the main thread
    :data:`STOP_GRACE` seconds, then removes the temporaries itself and exits.
    """
    global _stop_reported
    while True:
        try:
            data = os.read(rfd, 1)
        except OSError:
            return
        if not data:
            return
        if data[0] in (signal.SIGINT, signal.SIGTERM):
            break
    signum = data[0]
    time.sleep(STOP_GRACE)
    remove_temporaries()  # waits for a commit under way, and keeps others from starting
    with _STOP_LINE:
        if _stop_reported:  # the main thread is stopping by itself
            return
        _stop_reported = True
        os.write(2, f"tpsv: {Stopped(signum).message}\n".encode())
        os._exit(128 + signum)


def _start_watchdog() -> None:
    try:
        rfd, wfd = os.pipe()
        os.set_blocking(wfd, False)
        signal.set_wakeup_fd(wfd, warn_on_full_buffer=False)
    except (OSError, ValueError):  # no pipe, or not the main thread: signals still stop, later
        return
    threading.Thread(target=_watchdog, args=(rfd,), name="tpsv-stop", daemon=True).start()


def _on_signal(signum: int, frame) -> None:
    # Later signals wait: the first one is already unwinding and cleaning up.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated


def run(argv: list[str] | None = None) -> None:
    """The ``tpsv`` console entry point: :data:`main` with SIGINT and SIGTERM as clean stops.

    Either signal unwinds the command (staged outputs and their temporaries are
    removed), prints one line ("tpsv: interrupted" / "tpsv: terminated") and
    exits 130 / 143; within :data:`STOP_GRACE` seconds even when the main
    thread is inside a long native call (:func:`_watchdog`). The handlers are
    installed here, not on import, so that a program importing
    :mod:`tpsv.cli` keeps its own.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).
    """
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    _start_watchdog()
    try:
        main.main(args=argv, prog_name="tpsv")
    except (KeyboardInterrupt, Terminated) as exc:  # a signal outside a command (parsing, exit)
        stop = Stopped(signal.SIGINT if isinstance(exc, KeyboardInterrupt) else signal.SIGTERM)
        stop.show()
        sys.exit(stop.exit_code)

