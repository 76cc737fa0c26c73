"""``tpsv batch COMMAND INPUTS... --out DIR``: many files through one subcommand, on Dask.

``tpsv batch vectorize`` takes the options of ``tpsv vectorize`` (all but
``-o`` and the extra per-file outputs such as ``--preview``), checks them
before any work exactly as ``vectorize`` would, and hands them on as
command-line tokens, so each file runs as ``tpsv vectorize IN -o DIR/STEM.tpsv
OPTIONS...`` would (:mod:`tpsv.batch`). Its subcommands are made from the
commands themselves when asked for, so a command added later (``export``)
is there without change here.
"""

from __future__ import annotations

import contextlib
import copy
import os
import signal

import click
from click.core import ParameterSource

from . import Stopped, Terminated, command, main, progress_bar, say, settings
from .. import batch as engine

#: Options of a command that ``batch`` sets itself or cannot pass on: the main
#: output (named by ``batch``), per-file extra outputs (one path for every file
#: would make them overwrite each other), and ``--json`` (``batch`` has its own).
NOT_PASSED = {"output", "as_json", "preview", "save_model", "render_path", "abstract_out"}


class _Raw(click.ParamType):
    """A command's value type, checked now but handed on as typed (the worker parses it again)."""

    def __init__(self, inner: click.ParamType) -> None:
        self.inner = inner
        self.name = inner.name

    def get_metavar(self, *args, **kwargs):
        return self.inner.get_metavar(*args, **kwargs)

    def convert(self, value, param, ctx):
        self.inner.convert(value, param, ctx)  # a bad value is a usage error before any work
        return value


def _passed_on(target: click.Command) -> list[click.Option]:
    """The target command's options that ``batch`` accepts, with their help, checks and defaults."""
    own = {o for p in _batch_options("") for o in (*p.opts, *p.secondary_opts)}
    params = []
    for p in target.params:
        if not isinstance(p, click.Option) or own & {*p.opts, *p.secondary_opts}:
            continue  # batch's own option of that name wins
        if p.name in NOT_PASSED:
            if not (p.is_flag or p.count):
                params.append(_refused(p))
            continue
        q = copy.copy(p)
        if not (p.is_flag or p.count):
            q.type = _Raw(p.type)
        params.append(q)
    return params


def _refused(p: click.Option) -> click.Option:
    """A hidden stand-in for an output option ``batch`` cannot pass on: a usage error saying why."""
    def refuse(ctx, param, value):
        if value is None:
            return
        if p.name == "output":
            raise click.UsageError(f"batch names each output itself (DIR/STEM); give the directory with --out "
                                   f"instead of {'/'.join(param.opts)}", ctx)
        raise click.UsageError(f"{param.opts[0]} writes one more file per input; batch does not take it "
                               "(run the command on that file alone)", ctx)

    return click.Option(p.opts, type=click.Path(allow_dash=True), default=None, expose_value=False, hidden=True,
                        callback=refuse, is_eager=True)


def _tokens(ctx: click.Context, options: list[click.Option], values: dict) -> list[str]:
    """The options given on the command line, as tokens for the target command.

    Paths become absolute: a worker elsewhere (``--scheduler``) has another
    working directory.
    """

    def name(opts):
        return max(opts, key=lambda o: (o.startswith("--"), len(o)))

    def value(p, v):
        if isinstance(p.type, _Raw) and isinstance(p.type.inner, click.Path) and v != "-":
            return os.path.abspath(v)
        return str(v)

    out: list[str] = []
    for p in options:
        if ctx.get_parameter_source(p.name) != ParameterSource.COMMANDLINE:
            continue
        v = values[p.name]
        if p.count:
            out += [name(p.opts)] * int(v)
        elif p.is_flag:
            if p.secondary_opts and not v:
                out.append(name(p.secondary_opts))
            else:
                out.append(name(p.opts))
        else:
            for item in (v if p.multiple else [v]):
                parts = item if p.nargs != 1 else [item]
                out += [name(p.opts), *(value(p, x) for x in parts)]
    return out


def _batch_options(ext: str) -> list[click.Option]:
    """``batch``'s own options (a target option of the same name gives way to them)."""
    return [
        click.Option(["--out", "out_dir"], required=True, type=click.Path(file_okay=False),
                     help=f"Output directory (made if missing): each INPUT gives DIR/STEM{ext}."),
        click.Option(["--jobs", "-j"], type=click.IntRange(1, None), default=None,
                     help="Worker processes of the embedded cluster [default: the CPU cores]."),
        click.Option(["--scheduler"], default=None, metavar="ADDRESS",
                     help="Run on an existing Dask cluster (tcp://host:8786) instead; its workers must reach "
                          "the inputs and DIR at the same absolute paths."),
        click.Option(["--force"], is_flag=True, help="Redo outputs newer than their inputs (skipped by default)."),
        click.Option(["--json", "as_json"], is_flag=True,
                     help="One JSON line per file on stdout: input, output, status, seconds, error."),
    ]


def _batch_command(name: str, target: click.Command) -> click.Command:
    options = _passed_on(target)
    ext = engine.EXTENSIONS[name]

    @click.pass_context
    def callback(ctx, inputs, out_dir, jobs, scheduler, force, as_json, **values):
        if jobs is not None and scheduler is not None:
            raise click.UsageError("--jobs sizes the embedded cluster; with --scheduler the cluster's workers "
                                   "run the files")
        run(ctx, name, inputs, out_dir, _tokens(ctx, options, values), jobs=jobs, scheduler=scheduler,
            force=force, as_json=as_json)

    return click.Command(
        name,
        callback=callback,
        params=[click.Argument(["inputs"], nargs=-1, required=True, type=click.Path(dir_okay=False)),
                *options, *_batch_options(ext)],
        short_help=f"'tpsv {name}' on every INPUT -> DIR/STEM{ext}",
        help=f"Run 'tpsv {name}' on every INPUT, writing DIR/STEM{ext}.\n\n"
             f"The options are those of 'tpsv {name}' (see 'tpsv {name} --help'), for every file. An output "
             "newer than its input is skipped (--force redoes it); a failed file does not stop the others. "
             "At the end: a summary line and one line per failure on stderr, exit status 1 if any failed.",
        context_settings={"help_option_names": ["-h", "--help"]},
    )


class BatchGroup(click.Group):
    """The subcommands of ``batch``, made from the commands of the same name when asked for."""

    def list_commands(self, ctx):
        return [n for n in engine.EXTENSIONS if command(n) is not None]

    def get_command(self, ctx, cmd_name):
        target = command(cmd_name)
        if cmd_name not in engine.EXTENSIONS or target is None:
            return None
        return _batch_command(cmd_name, target)


@main.group(cls=BatchGroup)
def batch():
    """Run vectorize, render, magnify or export on many files, in parallel (Dask).

    Outputs go to --out DIR as STEM.tpsv (vectorize), STEM.png (render,
    magnify) or STEM.pdf (export). Work runs on an embedded cluster of --jobs
    worker processes, or on an existing one (--scheduler tcp://host:8786).
    See docs/BATCH.md.
    """


@contextlib.contextmanager
def _stop_line_at_once(before_line):
    """The one stop line as soon as SIGINT or SIGTERM arrives, then the handler in place raises.

    Shutting the cluster down takes a second or two, and ``tpsv.cli.run``'s
    watchdog ends a process that has not printed its stop line within
    :data:`tpsv.cli.STOP_GRACE`, cleanup or not: the line goes first.

    Yields
    ------
    list
        Holds True once the line is out.
    """
    shown = []
    saved = {}

    def notice(signum, frame):
        if not shown:
            before_line()
            Stopped(signum).show()
            shown.append(True)
        saved[signum](signum, frame)

    for sig in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(sig)
        if callable(handler):  # a handler that raises (not SIG_DFL, which ends the process)
            try:
                signal.signal(sig, notice)
            except ValueError:  # not the main thread
                break
            saved[sig] = handler
    try:
        yield shown
    finally:
        for sig, handler in saved.items():
            # once stopping, the handler in place ignores further signals (tpsv.cli._on_signal): keep it
            if not shown and signal.getsignal(sig) is notice:
                signal.signal(sig, handler)


def run(ctx, name, inputs, out_dir, options, *, jobs, scheduler, force, as_json) -> None:
    """Run the batch, report each file and the summary, and exit 1 if any failed."""
    bars = contextlib.ExitStack()  # the progress bar, once the cluster is up
    bar = None

    def on_start(n: int) -> None:
        nonlocal bar
        bar = bars.enter_context(progress_bar(ctx, n, name))

    def on_result(r: engine.Result) -> None:
        if as_json:
            click.echo(r.to_json())
        if bar is not None and r.status != engine.SKIPPED:
            bar.update(1)

    stopping: list = []
    try:
        with _stop_line_at_once(bars.close) as stopping, bars:
            results = engine.run_batch(name, inputs, out_dir, options, jobs=jobs, scheduler=scheduler, force=force,
                                       device=settings(ctx).device, on_start=on_start, on_result=on_result)
    except (KeyboardInterrupt, Terminated) as exc:
        stop = Stopped(signal.SIGINT if isinstance(exc, KeyboardInterrupt) else signal.SIGTERM)
        if not stopping:
            stop.show()
        # the cluster is down: exit 130 / 143 with that one line
        raise click.exceptions.Exit(stop.exit_code) from None
    n = {s: sum(r.status == s for r in results) for s in (engine.DONE, engine.SKIPPED, engine.FAILED)}
    if not as_json:
        say(ctx, f"{len(results)} file{'' if len(results) == 1 else 's'}: {n[engine.DONE]} done, "
                 f"{n[engine.SKIPPED]} skipped, {n[engine.FAILED]} failed")
    for r in results:
        if r.status == engine.FAILED:  # r.error is made safe to show already (tpsv.fileio.display)
            click.echo(f"tpsv: error: {r.error}", err=True)
    if n[engine.FAILED]:
        ctx.exit(1)
