"""Many files through one subcommand, in parallel on Dask (``tpsv batch``).

Each input goes through the very code path of the single-file command: a
worker invokes the subcommand's click command in-process
(:func:`run_one`), so options, checks, messages and the staged, atomic
outputs are exactly those of ``tpsv vectorize IN -o OUT ...``. A worker
process is reused across files, so Python, Warp and the compiled kernels
load once per worker rather than once per file.

Rules
-----
Naming
    ``DIR/STEM.EXT``, ``EXT`` by command (:data:`EXTENSIONS`). Two different
    inputs with the same stem are refused before any work; the same path given
    twice is run once.
Resume
    An output whose modification time is newer than its input's is skipped
    (``force=True`` redoes it). Options are not recorded: after changing them,
    force.
Failures
    One bad file does not stop the others; its result holds the one-line error
    the single-file command would print.
Engine
    By default an embedded ``LocalCluster`` of ``jobs`` single-threaded worker
    processes, without dashboard and with its logs silenced, shut down at the
    end (also when interrupted); or an existing cluster by the address of its
    scheduler, whose workers must reach the inputs and outputs at the same
    absolute paths.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import multiprocessing
import os
import signal
import threading
import time
import uuid
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Sequence

from .errors import TpsvError
from .fileio import display, remove_stale_temporaries
from .threads import usable_cores

#: Output extension of each command ``batch`` runs.
EXTENSIONS = {"vectorize": ".tpsv", "render": ".png", "magnify": ".png", "export": ".pdf"}
#: Seconds to wait for the workers of the embedded cluster, or a first one of an existing cluster.
WORKER_WAIT = 30.0
#: Seconds to wait for a connection to an existing scheduler.
CONNECT_TIMEOUT = 10.0

DONE, SKIPPED, FAILED = "done", "skipped", "failed"

# One file at a time per worker process, whatever its thread count: a command
# redirects the process's stdout and file descriptor 2 while it runs.
_ONE_AT_A_TIME = threading.Lock()


@dataclass(frozen=True)
class Task:
    """One input and the output ``batch`` writes for it.

    Attributes
    ----------
    input, output : str
        As the user gave the input, and ``DIR/STEM.EXT`` under the given ``DIR``.
    """

    input: str
    output: str


@dataclass
class Result:
    """What became of one file.

    Attributes
    ----------
    input, output : str
    status : str
        ``"done"``, ``"skipped"`` (output newer than input) or ``"failed"``.
    seconds : float
        Wall time of the command on its worker (0 when skipped).
    error : str or None
        The one-line error of a failed file.
    worker : str or None
        Address of the worker that ran it.
    summary : dict or None
        The command's own ``--json`` summary, where it has one.
    """

    input: str
    output: str
    status: str
    seconds: float = 0.0
    error: str | None = None
    worker: str | None = None
    summary: dict | None = field(default=None, repr=False)

    def to_json(self) -> str:
        """One JSON line (sorted keys)."""
        return json.dumps(asdict(self), sort_keys=True, default=float)


#: The extension of each picture format ``--format`` names (``render``, ``magnify``).
FORMAT_EXTENSIONS = {"PNG": ".png", "JPEG": ".jpg", "WebP": ".webp", "TIFF": ".tif"}


def extension(command: str, options: Sequence[str] = ()) -> str:
    """``EXT`` of the outputs: by command, or the picture format that ``--format`` names in ``options``."""
    from .image import OUTPUT_NAMES

    ext = EXTENSIONS.get(command, "")
    for flag, value in zip(options, list(options)[1:]):
        if flag == "--format" and str(value).lower() in OUTPUT_NAMES:
            ext = FORMAT_EXTENSIONS[OUTPUT_NAMES[str(value).lower()]]
    return ext


def plan(command: str, inputs: Sequence[str], out_dir: str, options: Sequence[str] = ()) -> list[Task]:
    """The task list: one output ``DIR/STEM.EXT`` per distinct input.

    Parameters
    ----------
    command : str
        A key of :data:`EXTENSIONS`.
    inputs : sequence of str
        Input paths; a path given twice (``a.png ./a.png``) counts once.
    out_dir : str
        Output directory.
    options : sequence of str
        The command's options (``--format jpeg`` gives ``.jpg`` outputs: :func:`extension`).

    Returns
    -------
    list of Task
        In the order of ``inputs``.

    Raises
    ------
    TpsvError
        An unknown command, ``-`` as an input, or two inputs that would write
        the same output.
    """
    if command not in EXTENSIONS:
        raise TpsvError(f"batch runs {', '.join(EXTENSIONS)}, not {display(command)}")
    ext = extension(command, options)
    tasks: list[Task] = []
    seen: set[str] = set()
    owner: dict[str, str] = {}
    for path in inputs:
        path = os.fspath(path)
        if path == "-":
            raise TpsvError("batch reads files; '-' (stdin) cannot be one of its inputs")
        same = os.path.abspath(path)
        if same in seen:
            continue
        seen.add(same)
        output = os.path.join(out_dir, Path(path).stem + ext)
        if output in owner:
            raise TpsvError(f"{display(owner[output])} and {display(path)} would both write {display(output)}; "
                            "rename one, or batch them into different --out directories")
        owner[output] = path
        tasks.append(Task(path, output))
    return tasks


def is_fresh(task: Task) -> bool:
    """The resume rule: the output exists and is newer than its input (modification times).

    Returns
    -------
    bool
        False also when either file cannot be read (the command will say why).
    """
    try:
        return os.stat(task.output).st_mtime_ns > os.stat(task.input).st_mtime_ns
    except OSError:
        return False


def run_one(command: str, input_path: str, output_path: str, options: Sequence[str] = (),
            device: str | None = None) -> dict:
    """Run ``tpsv [--device D] --quiet COMMAND INPUT -o OUTPUT OPTIONS...`` in this process.

    This is the function a worker runs. The command's stdout (its ``--json``
    summary, when it has one) is captured; its failure comes back as the
    one line ``tpsv`` would print.

    Parameters
    ----------
    command : str
    input_path, output_path : str
    options : sequence of str
        The command's other options, as command-line tokens.
    device : str, optional
        The global ``--device``.

    Returns
    -------
    dict
        ``ok`` (bool), ``error`` (str or None), ``seconds``, ``summary``
        (dict or None), ``worker`` (address, or ``pid N`` outside Dask).
    """
    import click

    from .cli import command as cli_command, main

    target = cli_command(command)
    if target is None:
        return _outcome(False, f"this tpsv has no {command!r} command", 0.0, None)
    wants_json = any(p.name == "as_json" for p in target.params)
    argv = (["--device", device] if device else []) + ["--quiet", command, input_path, "-o", output_path,
                                                       *options] + (["--json"] if wants_json else [])
    captured = io.StringIO()
    error = None
    with _ONE_AT_A_TIME:
        t0 = time.perf_counter()
        try:
            with contextlib.redirect_stdout(captured):
                code = main.main(args=argv, prog_name="tpsv", standalone_mode=False)
            if code not in (None, 0):
                error = f"exit status {code}"
        except click.ClickException as exc:
            error = exc.format_message()
        except click.exceptions.Abort:
            error = "aborted"
        except Exception as exc:  # TpsvGroup turns failures into ClickException: a bug in the group itself
            error = f"internal error: {type(exc).__name__}: {exc}"
        seconds = time.perf_counter() - t0
    summary = None
    if error is None and wants_json:
        try:
            summary = json.loads(captured.getvalue())
        except ValueError:
            summary = None
    return _outcome(error is None, None if error is None else display(error), seconds, summary)


def _outcome(ok: bool, error: str | None, seconds: float, summary: dict | None) -> dict:
    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = f"pid {os.getpid()}"
    return {"ok": ok, "error": error, "seconds": seconds, "summary": summary, "worker": worker}


@contextlib.contextmanager
def _quiet_distributed(level: int = logging.CRITICAL) -> Iterator[None]:
    """Dask's loggers at ``level`` in this process while the block runs (its news is not the user's)."""
    loggers = [logging.getLogger(n) for n in ("distributed", "dask", "tornado", "asyncio", "bokeh")]
    saved = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(level)
    try:
        yield
    finally:
        for lg, lv in zip(loggers, saved):
            lg.setLevel(lv)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored by this process, and by the processes it starts, while the block runs.

    SIG_IGN is inherited across fork and exec, Python keeps it, and asyncio
    then leaves SIGINT alone: a worker process started here ignores Ctrl-C for
    good. A Ctrl-C meanwhile is lost, so the block must be short.
    """
    try:
        saved = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


def _start_workers(cluster, jobs: int) -> None:
    """Start ``jobs`` worker processes that ignore SIGINT, then wait for them with signals on.

    Ctrl-C on a terminal signals the whole foreground process group; the
    client stops the batch and shuts the cluster down, so the workers must not
    die of it on their own (each would print a traceback and drop its file).
    SIGINT is ignored only until the processes exist (milliseconds), not
    while they load (seconds), so a Ctrl-C during the start still stops.
    """
    before = set(multiprocessing.active_children())
    deadline = time.monotonic() + 5.0
    with _sigint_ignored():
        cluster.scale(jobs)
        while len(set(multiprocessing.active_children()) - before) < jobs and time.monotonic() < deadline:
            time.sleep(0.005)
    try:
        cluster.wait_for_workers(jobs, timeout=WORKER_WAIT)
    except TimeoutError:
        raise TpsvError(f"the {jobs} worker processes of the local cluster did not start "
                        f"within {WORKER_WAIT:.0f} s") from None


def default_jobs() -> int:
    """The CPU cores this process may use."""
    return usable_cores()


@contextlib.contextmanager
def connect(jobs: int | None = None, scheduler: str | None = None) -> Iterator:
    """A Dask client: on an embedded ``LocalCluster``, or on an existing cluster.

    Parameters
    ----------
    jobs : int, optional
        Worker processes of the embedded cluster, one thread each (default:
        :func:`default_jobs`). Ignored with ``scheduler``.
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``).

    Yields
    ------
    distributed.Client
        Closed (and the embedded cluster shut down) when the block ends.

    Raises
    ------
    TpsvError
        The scheduler cannot be reached, no worker joined it, or the embedded
        cluster's workers did not start, within :data:`WORKER_WAIT` seconds.
    """
    import dask
    from distributed import Client, LocalCluster
    from distributed.comm import resolve_address

    with _quiet_distributed():
        if scheduler:
            try:
                # a malformed address or unknown host fails here at once; a Client
                # half made from one would hang the interpreter's exit
                address = resolve_address(scheduler)
                client = Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise TpsvError(f"cannot connect to the scheduler at {display(scheduler)}: "
                                f"{display(str(exc) or type(exc).__name__)}") from None
            try:
                try:
                    client.wait_for_workers(1, timeout=WORKER_WAIT)
                except TimeoutError:
                    raise TpsvError(f"no worker joined the scheduler at {display(scheduler)} "
                                    f"within {WORKER_WAIT:.0f} s") from None
                yield client
            finally:
                client.close()
            return
        jobs = jobs or default_jobs()
        # allowed-failures 0: a file that kills its worker (a crash, memory) fails once
        # instead of taking three more workers with it. memory_limit 0: no per-worker
        # cap, as for the same commands in a shell loop. Environment: the cores shared
        # among the workers' BLAS/OpenMP pools, and without Dask's MALLOC_TRIM_THRESHOLD_
        # of 64 KiB, which returns every freed array to the kernel (4 s of system time
        # in 27 s of CPU, 20 vectorized 256x256 photos on 2 workers).
        threads = max(1, default_jobs() // jobs)
        environ = {"OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads, "OPENBLAS_NUM_THREADS": threads}
        config = {"distributed.scheduler.allowed-failures": 0, "distributed.nanny.pre-spawn-environ": environ}
        with dask.config.set(config), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "port 8787 is in use" of its (dashboard-less) health server
            cluster = LocalCluster(n_workers=0, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.CRITICAL, memory_limit=0)
        try:
            with dask.config.set(config):  # read as the workers' nannies are made
                _start_workers(cluster, jobs)
            client = Client(cluster, set_as_default=False)
            try:
                yield client
            finally:
                client.close()
        finally:
            cluster.close()


def remove_orphan_temporaries(tasks: Sequence[Task]) -> int:
    """Remove the temporaries of ``tasks``' outputs whose writer process is gone.

    A worker stopped in the middle of a file (the batch interrupted, the
    worker killed) leaves the hidden temporary of its staged output; this
    runs once the embedded cluster is down.

    Returns
    -------
    int
        Files removed.
    """
    wanted: dict[str, set[str]] = {}
    for t in tasks:
        d, name = os.path.split(os.path.abspath(t.output))
        wanted.setdefault(d, set()).add(name)
    return sum(remove_stale_temporaries(d, names) for d, names in wanted.items())


def run_batch(command: str, inputs: Sequence[str], out_dir: str, options: Sequence[str] = (), *,
              client=None, jobs: int | None = None, scheduler: str | None = None, force: bool = False,
              device: str | None = None, on_start: Callable[[int], None] | None = None,
              on_result: Callable[[Result], None] | None = None) -> list[Result]:
    """Run ``tpsv COMMAND INPUT -o DIR/STEM.EXT OPTIONS...`` for every input, in parallel.

    Parameters
    ----------
    command : str
        ``vectorize``, ``render``, ``magnify`` or ``export``.
    inputs : sequence of str
    out_dir : str
        Created if missing.
    options : sequence of str
        The command's options as command-line tokens (``["--quality", "20"]``);
        a relative path in them is resolved in each worker's working
        directory (the command line makes them absolute).
    client : distributed.Client, optional
        Run on this client's cluster (left open). Default: :func:`connect`
        with ``jobs`` and ``scheduler``.
    jobs : int, optional
    scheduler : str, optional
    force : bool
        Redo outputs that are newer than their inputs.
    device : str, optional
        The global ``--device`` of each command.
    on_start : callable, optional
        Called with the number of files to run, once the cluster is up.
    on_result : callable, optional
        Called with each :class:`Result` as it comes (skipped files first,
        then in order of completion).

    Returns
    -------
    list of Result
        In the order of the tasks (:func:`plan`).

    Raises
    ------
    TpsvError
        Bad task list (:func:`plan`), an output directory that cannot be
        made, or a cluster that cannot be reached.
    """
    tasks = plan(command, inputs, out_dir, options)
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise TpsvError(f"cannot make the output directory {display(out_dir)}: {exc.strerror or exc}") from None
    if not os.path.isdir(out_dir):
        raise TpsvError(f"--out {display(out_dir)} is not a directory")
    results: dict[int, Result] = {}
    todo = []
    for i, task in enumerate(tasks):
        if not force and is_fresh(task):
            results[i] = Result(task.input, task.output, SKIPPED)
            if on_result:
                on_result(results[i])
        else:
            todo.append(i)
    if not todo:
        return [results[i] for i in range(len(tasks))]
    owned = client is None
    try:
        with contextlib.ExitStack() as stack:
            if owned:
                client = stack.enter_context(connect(jobs, scheduler))
            stack.enter_context(_quiet_distributed())
            if on_start:
                on_start(len(todo))
            _run_tasks(client, command, tasks, todo, options, device, results, on_result)
    finally:
        if owned and scheduler is None:  # the embedded workers are gone: their pids say so
            remove_orphan_temporaries([tasks[i] for i in todo])
    return [results[i] for i in range(len(tasks))]


def _run_tasks(client, command, tasks, todo, options, device, results, on_result) -> None:
    """Submit the tasks ``todo`` and collect their results; pending work is cancelled on the way out."""
    from distributed import as_completed

    # Workers may run elsewhere (--scheduler): they get absolute paths, and
    # messages show the paths as the user gave them.
    token = uuid.uuid4().hex[:8]
    futures = {}
    for i in todo:
        t = tasks[i]
        fut = client.submit(run_one, command, os.path.abspath(t.input), os.path.abspath(t.output),
                            list(options), device, key=f"tpsv-{command}-{token}-{i}", pure=False)
        futures[fut] = i
    try:
        for fut in as_completed(futures, loop=client.loop):
            i = futures[fut]
            results[i] = _result(tasks[i], fut)
            if on_result:
                on_result(results[i])
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)


def _result(task: Task, fut) -> Result:
    """The Result of one finished future: the command's outcome, or the worker's failure."""
    try:
        out = fut.result()
    except Exception as exc:  # the worker died (KilledWorker), the task was cancelled, ...
        name = type(exc).__name__
        why = "its worker died (a crash, or out of memory)" if name == "KilledWorker" else f"{name}: {exc}"
        return Result(task.input, task.output, FAILED, error=display(f"{task.input}: {why}"))
    error = out["error"]
    if error is not None:
        # the worker saw absolute paths; show the user's
        for given in (task.input, task.output):
            error = error.replace(display(os.path.abspath(given)), display(given))
        if display(task.input) not in error:
            error = f"{display(task.input)}: {error}"
    return Result(task.input, task.output, DONE if out["ok"] else FAILED, seconds=out["seconds"], error=error,
                  worker=out["worker"], summary=out["summary"])
