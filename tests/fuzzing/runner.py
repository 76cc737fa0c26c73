"""The campaign: inputs run in forked workers with a time limit and a memory limit.

The parent imports everything and warms Warp up once, then forks a worker that
runs inputs ``i, i+1, ...`` through the targets and reports each step over a
pipe. The parent waits at most ``timeout`` seconds for a step and polls the
worker's RSS meanwhile; a step that overruns is a ``hang``, one that passes
the RSS limit a ``memory`` finding; the worker is killed and a fresh one
resumes at the next input. Inside the worker, ``RLIMIT_AS`` caps new
allocations at the RSS limit (so a hostile input fails with MemoryError
instead of taking the machine's memory), and the kernel's peak-RSS counter is
reset before each step to measure that step alone.

Each crash, hang and memory finding is saved under ``out`` as the input file
and a ``.txt`` with its mutations and traceback (the first few per distinct
signature); the input is also a pure function of ``(seed, index)``.
"""

from __future__ import annotations

import faulthandler
import os
import resource
import signal
import tempfile
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from multiprocessing.connection import Pipe, wait
from pathlib import Path

from .mutate import make_case, materialize
from .targets import LIBRARY_TARGETS, OUTCOMES, Result, State, run_cli, run_library

#: Findings saved per distinct (target, outcome, signature).
SAVE_PER_SIGNATURE = 3
#: A worker whose resident memory stays above this share of the limit after a
#: step is replaced, so that a leak or fragmentation is not blamed on later inputs.
RECYCLE_SHARE = 0.6
#: How often the parent samples a worker's RSS while it waits, in seconds.
POLL_S = 0.1


@dataclass
class Config:
    """Campaign settings (see ``python -m tests.fuzzing --help``)."""

    n: int = 1000
    seed: int = 0
    timeout: float = 10.0
    rss_limit_mb: int = 1024
    out: Path | None = None
    targets: tuple = tuple(LIBRARY_TARGETS)
    cli_every: int = 10
    start: int = 0
    progress: bool = False
    jobs: int = 1


@dataclass
class Summary:
    """Outcome counts per target, findings, and timing."""

    inputs: int = 0
    runs: int = 0
    seconds: float = 0.0
    counts: dict = field(default_factory=lambda: defaultdict(Counter))
    families: Counter = field(default_factory=Counter)
    findings: list = field(default_factory=list)  # (index, target, outcome, first line)
    peak_mb: float = 0.0
    slowest: tuple = (0.0, -1, "")  # seconds, index, target

    def add(self, index: int, target: str, res: Result, seconds: float = 0.0, peak_mb: float = 0.0) -> None:
        self.counts[target][res.outcome] += 1
        if res.outcome != "skip":
            self.runs += 1
        self.peak_mb = max(self.peak_mb, peak_mb)
        if seconds > self.slowest[0]:
            self.slowest = (seconds, index, target)
        if res.outcome in ("crash", "hang", "memory"):
            self.findings.append((index, target, res.outcome, signature(res)))

    def total(self, outcome: str) -> int:
        return sum(c[outcome] for c in self.counts.values())

    def table(self) -> str:
        """The summary table: one row per target, one column per outcome."""
        cols = [o for o in OUTCOMES]
        rows = [f"{'target':<16}" + "".join(f"{c:>9}" for c in cols)]
        for name in sorted(self.counts, key=_target_order):
            rows.append(f"{name:<16}" + "".join(f"{self.counts[name][c]:>9}" for c in cols))
        rows.append(f"{'total':<16}" + "".join(f"{self.total(c):>9}" for c in cols))
        rate = self.runs / self.seconds if self.seconds else 0.0
        rows.append(f"inputs {self.inputs} ({', '.join(f'{k} {v}' for k, v in sorted(self.families.items()))}); "
                    f"runs {self.runs} in {self.seconds:.1f} s = {rate:.1f} runs/s, "
                    f"{self.inputs / max(self.seconds, 1e-9):.1f} inputs/s; peak RSS {self.peak_mb:.0f} MB; "
                    f"slowest step {self.slowest[0]:.2f} s (#{self.slowest[1]} {self.slowest[2]})")
        return "\n".join(rows)


def _target_order(name: str):
    names = list(LIBRARY_TARGETS)
    return (names.index(name), name) if name in names else (len(names), name)


def signature(res: Result) -> str:
    """A short key that groups findings with the same cause: the exception line and the deepest tpsv frame."""
    lines = [ln.strip() for ln in res.detail.splitlines() if ln.strip()]
    if not lines:
        return res.outcome
    frames = [ln for ln in lines if ln.startswith('File "') and "/tpsv/" in ln]
    where = frames[-1].split("/tpsv/")[-1] if frames else ""
    return f"{lines[-1][:160]} @ {where}" if where else lines[-1][:200]


# ------------------------------------------------------------------ memory accounting (Linux /proc)


def _status_kb(pid: int | str, key: str) -> int:
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def _reset_peak() -> None:
    """Reset this process's VmHWM to its current RSS (Linux >= 4.0), so a step's peak is its own."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _limit_address_space(rss_limit_mb: int) -> None:
    """Cap the address space at what is mapped now plus the RSS limit: a hostile
    allocation then fails with MemoryError instead of taking the machine's memory."""
    now = _status_kb("self", "VmSize") * 1024
    cap = now + rss_limit_mb * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))


# ------------------------------------------------------------------ worker (child process)


def _steps(cfg: Config, index: int) -> list:
    """The target steps for input ``index``: the library targets, plus one CLI command now and then."""
    steps = list(cfg.targets)
    if cfg.cli_every and index % cfg.cli_every == 0:
        steps.append(("cli", index // cfg.cli_every))
    return steps


def _worker(cfg: Config, first: int, end: int, conn, workdir: Path) -> None:
    """Run inputs ``first .. end - 1``, reporting each step; never returns."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles ^C and kills us
    faulthandler.disable()  # a native crash is reported by the parent, not dumped over its output
    if cfg.rss_limit_mb:
        _limit_address_space(cfg.rss_limit_mb)
    limit_kb = cfg.rss_limit_mb * 1024
    for i in range(first, end):
        try:
            case = make_case(cfg.seed, i)
        except Exception as exc:  # a harness bug; report it rather than die
            conn.send(("end", i, "mutate", Result.from_exception(exc, ()), 0.0, 0.0))
            conn.send(("done", i, "none"))
            continue
        state = State(case, workdir)
        for step in _steps(cfg, i):
            label = step if isinstance(step, str) else "cli"
            conn.send(("begin", i, label))
            _reset_peak()
            t0 = time.perf_counter()
            if isinstance(step, str):
                name, res = step, run_library(step, state)
            else:
                name, res = run_cli(state, step[1])
            seconds = time.perf_counter() - t0
            peak = _status_kb("self", "VmHWM")
            if limit_kb and peak > limit_kb and res.outcome in ("ok", "clean"):
                res = Result("memory", f"peak RSS {peak / 1024:.0f} MB over {cfg.rss_limit_mb} MB")
            conn.send(("end", i, name, res, seconds, peak / 1024))
        conn.send(("done", i, case.family))
        if limit_kb and _status_kb("self", "VmRSS") > RECYCLE_SHARE * limit_kb:
            conn.send(("recycle", i))
            break
    conn.close()
    os._exit(0)


def _spawn(cfg: Config, first: int, end: int, workdir: Path, others=()):
    recv, send = Pipe(duplex=False)
    pid = os.fork()
    if pid == 0:  # child
        recv.close()
        for conn in others:  # the other workers' pipes are the parent's business
            conn.close()
        try:
            _worker(cfg, first, end, send, workdir)
        finally:
            os._exit(70)
    send.close()
    return pid, recv


def _kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


# ------------------------------------------------------------------ parent


class _Saver:
    """Writes the first few findings of each signature under ``out``."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.seen = Counter()
        if cfg.out:
            Path(cfg.out).mkdir(parents=True, exist_ok=True)

    def save(self, index: int, target: str, res: Result) -> None:
        key = (target, res.outcome, signature(res))
        self.seen[key] += 1
        if not self.cfg.out:
            return
        with open(Path(self.cfg.out) / "findings.tsv", "a") as fh:  # every finding, saved or not
            fh.write(f"{self.cfg.seed}\t{index}\t{target}\t{res.outcome}\t{key[2]}\n")
        if self.seen[key] > SAVE_PER_SIGNATURE:
            return
        try:
            case = make_case(self.cfg.seed, index)
            data, what = materialize(case), case.describe()
        except Exception as exc:  # a harness bug, reported as the "mutate" target's crash
            data, what = None, f"#{index}: the mutator failed ({type(exc).__name__}: {exc})"
        stem = Path(self.cfg.out) / f"{res.outcome}-{target}-{self.cfg.seed}-{index:07d}"
        if data is not None:
            stem.with_suffix(".tpsv").write_bytes(data)
        note = (f"seed {self.cfg.seed} index {index} target {target} outcome {res.outcome}\n"
                f"{what}\n"
                f"reproduce: python -m tests.fuzzing --seed {self.cfg.seed} --start {index} -n 1\n\n{res.detail}\n")
        stem.with_suffix(".txt").write_text(note)


def run_campaign(cfg: Config, log=print) -> Summary:
    """Run ``cfg.n`` inputs from ``cfg.start``; returns the summary (findings saved under ``cfg.out``).

    With ``cfg.jobs`` above 1 the range is cut into that many consecutive
    chunks, each followed by its own worker; the inputs, and so the findings,
    do not depend on the number of jobs.
    """
    warm_up()
    summary, saver = Summary(), _Saver(cfg)
    t_start = time.perf_counter()
    bounds = [cfg.start + cfg.n * k // cfg.jobs for k in range(cfg.jobs + 1)]
    with tempfile.TemporaryDirectory(prefix="tpsv-fuzz-") as tmp:
        slots = [_Slot(lo, hi) for lo, hi in zip(bounds, bounds[1:]) if hi > lo]
        try:
            while slots:
                for slot in slots:
                    if slot.pid is None:
                        slot.start(cfg, Path(tmp), [o.conn for o in slots if o.conn is not None])
                ready = wait([slot.conn for slot in slots], timeout=POLL_S)
                for slot in slots:
                    slot.step(cfg, slot.conn in ready, summary, saver, log)
                slots = [slot for slot in slots if not slot.finished]
        finally:
            for slot in slots:
                slot.stop()
    summary.seconds = time.perf_counter() - t_start
    return summary


class _Slot:
    """One chunk of inputs and the worker following it (replaced after a hang, death or overrun)."""

    def __init__(self, first: int, end: int):
        self.next, self.end = first, end
        self.pid = self.conn = None
        self.current = (first, "mutate")
        self.since = 0.0

    @property
    def finished(self) -> bool:
        return self.pid is None and self.next >= self.end

    def start(self, cfg: Config, workdir: Path, others) -> None:
        if self.next < self.end:
            self.pid, self.conn = _spawn(cfg, self.next, self.end, workdir, others)
            self.current, self.since = (self.next, "mutate"), time.monotonic()

    def stop(self) -> None:
        if self.pid is not None:
            _kill(self.pid)
            self.conn.close()
            self.pid = self.conn = None

    def step(self, cfg: Config, readable: bool, summary: Summary, saver: "_Saver", log) -> None:
        """Handle what the worker sent, or check it for a hang or an overrun."""
        if self.pid is None:
            return
        if readable:
            while self.pid is not None and self.conn.poll():
                try:
                    msg = self.conn.recv()
                except EOFError:
                    self._died(summary, saver, log)
                    return
                self._handle(msg, cfg, summary, saver, log)
            return
        rss = _status_kb(self.pid, "VmRSS")
        if cfg.rss_limit_mb and rss > cfg.rss_limit_mb * 1024:
            self._abort(Result("memory", f"RSS {rss / 1024:.0f} MB"), summary, saver, log)
        elif time.monotonic() - self.since >= cfg.timeout:
            self._abort(Result("hang", f"no result after {cfg.timeout:g} s"), summary, saver, log)

    def _handle(self, msg: tuple, cfg: Config, summary: Summary, saver: "_Saver", log) -> None:
        self.since = time.monotonic()
        kind = msg[0]
        if kind == "begin":
            self.current = (msg[1], msg[2])
        elif kind == "end":
            _, index, target, res, seconds, peak = msg
            summary.add(index, target, res, seconds, peak)
            if res.outcome in ("crash", "hang", "memory"):
                saver.save(index, target, res)
                log(f"#{index} {target}: {res.outcome}: {signature(res)}")
        elif kind == "done":
            summary.inputs += 1
            summary.families[msg[2]] += 1
            self.next = msg[1] + 1
            self.current = (self.next, "mutate")
            if cfg.progress and summary.inputs % 100 == 0:
                log(f"{summary.inputs} inputs, {summary.total('crash')} crashes, "
                    f"{summary.total('hang')} hangs, {summary.total('memory')} over memory")
        elif kind == "recycle":
            self.stop()

    def _abort(self, res: Result, summary: Summary, saver: "_Saver", log) -> None:
        """Kill a worker stuck on its current step; count and save the finding; resume after that input."""
        self.stop()
        self._finding(res, summary, saver, log)

    def _died(self, summary: Summary, saver: "_Saver", log) -> None:
        """The worker ended without saying so: the end of its chunk, or a crash in native code."""
        _, status = os.waitpid(self.pid, 0)
        self.conn.close()
        self.pid = self.conn = None
        if os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0 and self.next >= self.end:
            return
        how = f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit {os.WEXITSTATUS(status)}"
        self._finding(Result("crash", f"worker died ({how})"), summary, saver, log)

    def _finding(self, res: Result, summary: Summary, saver: "_Saver", log) -> None:
        index, target = self.current
        summary.add(index, target, res)
        summary.inputs += 1
        saver.save(index, target, res)
        log(f"#{index} {target}: {res.outcome}: {signature(res)}")
        self.next = index + 1


def warm_up() -> None:
    """Import every target's modules and load Warp's kernels in the parent, once, so workers fork
    ready (a first compilation inside a worker would count against its time limit)."""
    import tpsv.cli  # noqa: F401
    import tpsv.cli.info  # noqa: F401
    import tpsv.cli.outputs  # noqa: F401
    from tpsv import codec
    from tpsv.edit import crossmap, deform, recolor, stylize  # noqa: F401
    from tpsv.rendering.raster import render

    from .seeds import two_regions
    for k in codec.SUPPORTED_KERNEL_SIZES:
        render(two_regions(kernel_size=k), width=8, height=8)
