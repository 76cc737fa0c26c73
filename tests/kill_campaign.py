"""Kill and concurrency campaign against the real ``tpsv`` command (issue 14, "Targets").

Not collected by pytest (``tests/test_kill.py`` is the short version). Run::

    .venv/bin/python tests/kill_campaign.py [--kills 50] [--rounds 10] [--concurrency 8] [--seed 0]

Kills: each of ``--kills`` runs of a command (vectorize with --preview, render,
stylize with --abstract-out, magnify with --save-model; in turn) gets SIGKILL
at a random moment: half of them anywhere in an uninterrupted run's duration,
half within 20 ms of the first temporary appearing (while the outputs are
written and renamed). Every output existed before with other
content; afterwards it must be that old content or the complete new output
(the bytes of an uninterrupted run), never partial, corrupt or missing. A
temporary a SIGKILL leaves must be removed by the next run on that output.

Concurrency: ``--rounds`` rounds of ``--concurrency`` runs started at once,
two of each command writing the *same* outputs; the first round starts with
an empty Warp kernel cache (every run compiles). Each run must exit 0 with
nothing on stderr, every output must equal the uninterrupted run's, and no
temporary may remain.

Prints one table for each part and exits 1 if any target is missed.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tpsv.fileio import Outputs  # noqa: E402

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
_SCRIPT = Path(sys.executable).with_name("tpsv")
TPSV = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "tpsv"]


@dataclass
class Command:
    """One command line and the outputs it writes (paths relative to the run's folder)."""

    name: str
    args: list[str]
    outputs: list[str]
    reference: dict[str, bytes] = field(default_factory=dict)
    seconds: float = 0.0


def commands(photo: Path, model: Path) -> list[Command]:
    return [
        Command("vectorize", ["vectorize", str(photo), "--no-search", "-o", "v.tpsv", "--preview", "v.png"],
                ["v.tpsv", "v.png"]),
        Command("render", ["render", str(model), "-o", "r.png", "--size", "600x400"], ["r.png"]),
        Command("stylize", ["stylize", str(model), "-o", "s.png", "--abstract-out", "s.tpsv"], ["s.png", "s.tpsv"]),
        Command("magnify", ["magnify", str(photo), "-o", "m.png", "--factor", "2", "--save-model", "m.tpsv"],
                ["m.png", "m.tpsv"]),
    ]


def run(cmd: Command, cwd: Path, env=None) -> subprocess.CompletedProcess:
    return subprocess.run(TPSV + ["--quiet", *cmd.args], cwd=cwd, env=env, capture_output=True)


def past_startup(pid: int) -> bool:
    """Whether the process has installed its signal handlers (imports done, the command under way)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True  # already gone: it finished
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught & (1 << (signal.SIGTERM - 1)))


def temporaries(folder: Path) -> list[str]:
    return sorted(n for n in os.listdir(folder) if n.endswith(".tmp"))


def prepare(work: Path) -> tuple[Path, Path]:
    """A 200 px photo and its .tpsv in ``work``."""
    img = cv2.imread(str(SAMPLES / "chelsea.png"))
    h, w = img.shape[:2]
    photo = work / "photo.png"
    cv2.imwrite(str(photo), cv2.resize(img, (200, round(h * 200 / w)), interpolation=cv2.INTER_AREA))
    model = work / "model.tpsv"
    subprocess.run(TPSV + ["-q", "vectorize", str(photo), "-o", str(model), "--no-search"], check=True)
    return photo, model


def references(cmds: list[Command], work: Path) -> bool:
    """Each command's outputs and duration from an uninterrupted run (twice: outputs are deterministic)."""
    deterministic = True
    for cmd in cmds:
        for attempt in range(2):
            folder = work / f"ref-{cmd.name}-{attempt}"
            folder.mkdir()
            t0 = time.monotonic()
            r = run(cmd, folder)
            if r.returncode != 0:
                raise SystemExit(f"{cmd.name} failed: {r.stderr.decode()}")
            seconds = time.monotonic() - t0  # the faster run: the first may compile kernels
            cmd.seconds = seconds if attempt == 0 else min(cmd.seconds, seconds)
            got = {o: (folder / o).read_bytes() for o in cmd.outputs}
            if attempt == 0:
                cmd.reference = got
            elif got != cmd.reference:
                deterministic = False
    return deterministic


# ------------------------------------------------------------------ kills


def kill_campaign(cmds: list[Command], work: Path, n: int, rng: random.Random) -> dict:
    """``n`` SIGKILLs at random moments; counts of what each output became."""
    rows = {c.name: dict(kills=0, startup=0, working=0, writing=0, finished=0, old=0, new=0, partial=0, missing=0,
                         mixed=0, tmp_left=0, tmp_after=0) for c in cmds}
    folder = work / "kills"
    folder.mkdir()
    for i in range(n):
        cmd = cmds[i % len(cmds)]
        row = rows[cmd.name]
        old = {o: f"old content of {o} #{i}".encode() for o in cmd.outputs}
        for o, data in old.items():
            (folder / o).write_bytes(data)
        proc = subprocess.Popen(TPSV + ["--quiet", *cmd.args], cwd=folder, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        writing = False
        if (i // len(cmds)) % 2 == 0:  # anywhere in the run
            time.sleep(rng.uniform(0.0, 1.0) * cmd.seconds)
        else:  # while the outputs are written: once the first temporary appears, within 20 ms
            deadline = time.monotonic() + 10 * cmd.seconds
            while proc.poll() is None and not temporaries(folder) and time.monotonic() < deadline:
                time.sleep(0.0005)
            writing = proc.poll() is None and bool(temporaries(folder))
            time.sleep(rng.uniform(0.0, 0.02))
        started = past_startup(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        row["kills"] += 1
        finished = all((folder / o).exists() and (folder / o).read_bytes() == cmd.reference[o] for o in cmd.outputs)
        row["finished" if finished else "writing" if writing else "working" if started else "startup"] += 1
        states = set()
        for o in cmd.outputs:
            path = folder / o
            if not path.exists():
                state = "missing"
            elif path.read_bytes() == old[o]:
                state = "old"
            elif path.read_bytes() == cmd.reference[o]:
                state = "new"
            else:
                state = "partial"
            states.add(state)
            row[state] += 1
        if {"old", "new"} <= states:
            row["mixed"] += 1  # SIGKILL between two renames: each file whole, not all of one run
        left = temporaries(folder)
        row["tmp_left"] += len(left)
        if left:  # what the next run does first: claim its outputs, which removes dead runs' temporaries
            out = Outputs()
            for o in cmd.outputs:
                out.claim(folder / o)
            row["tmp_after"] += len(temporaries(folder))
    return rows


# ------------------------------------------------------------------ concurrency


def concurrency_campaign(cmds: list[Command], work: Path, rounds: int, width: int) -> list[dict]:
    """``rounds`` rounds of ``width`` simultaneous runs, two of each command on the same outputs."""
    cache = work / "warp-cache"  # empty: the first round compiles every kernel, all runs at once
    env = dict(os.environ, WARP_CACHE_PATH=str(cache))
    results = []
    for k in range(rounds):
        folder = work / f"round-{k}"
        folder.mkdir()
        batch = [cmds[j % len(cmds)] for j in range(width)]
        t0 = time.monotonic()
        procs = [subprocess.Popen(TPSV + ["--quiet", *c.args], cwd=folder, env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE) for c in batch]
        done = [p.communicate() for p in procs]
        seconds = time.monotonic() - t0
        failed = sum(p.returncode != 0 for p in procs)
        noisy = sum(bool(err.strip()) for _, err in done)
        wrong = sum((folder / o).read_bytes() != c.reference[o] if (folder / o).exists() else 1
                    for c in cmds[:width] for o in c.outputs)
        results.append(dict(round=k, cold=k == 0, runs=width, failed=failed, stderr=noisy, wrong=wrong,
                            tmp=len(temporaries(folder)), seconds=seconds,
                            errors=[err.decode()[-300:] for p, (_, err) in zip(procs, done) if p.returncode]))
    return results


# ------------------------------------------------------------------ report


def print_kills(rows: dict) -> int:
    cols = ["kills", "startup", "working", "writing", "finished", "old", "new", "partial", "missing", "mixed",
            "tmp_left", "tmp_after"]
    print("SIGKILL at random moments. When: startup (imports), working (command under way), writing (a temporary"
          " exists),\nfinished (all outputs in place). Per output: old = untouched, new = the complete new output; partial/missing must be 0;"
          " mixed = runs\nwith one output old and another new; tmp_left = temporaries a kill left, tmp_after ="
          " after the next run.")
    print(f"{'command':<11}" + "".join(f"{c:>10}" for c in cols))
    total = {c: sum(r[c] for r in rows.values()) for c in cols}
    for name, r in [*rows.items(), ("total", total)]:
        print(f"{name:<11}" + "".join(f"{r[c]:>10}" for c in cols))
    return total["partial"] + total["missing"] + total["tmp_after"]


def print_rounds(results: list[dict]) -> int:
    print(f"Concurrent runs ({results[0]['runs'] if results else 0} at once, two per command on the same outputs)")
    cols = ["round", "cold", "runs", "failed", "stderr", "wrong", "tmp", "seconds"]
    print("".join(f"{c:>9}" for c in cols))
    bad = 0
    for r in results:
        print("".join(f"{(f'{r[c]:.1f}' if c == 'seconds' else str(r[c])):>9}" for c in cols))
        bad += r["failed"] + r["stderr"] + r["wrong"] + r["tmp"]
        for e in r["errors"]:
            print("   ", e.strip().replace("\n", " / "))
    return bad


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kills", type=int, default=50)
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--concurrency", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workdir", type=Path, default=None, help="Keep the files here (default: a temporary folder).")
    a = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="tpsv-kill-") as tmp:
        work = a.workdir or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        photo, model = prepare(work)
        cmds = commands(photo, model)
        t0 = time.monotonic()
        deterministic = references(cmds, work)
        print(f"commands: {TPSV[-1]} ... (uninterrupted: "
              + ", ".join(f"{c.name} {c.seconds:.1f} s" for c in cmds)
              + f"; outputs deterministic: {'yes' if deterministic else 'NO'})")
        bad = print_kills(kill_campaign(cmds, work, a.kills, random.Random(a.seed)))
        print()
        bad += print_rounds(concurrency_campaign(cmds, work, a.rounds, a.concurrency))
        print(f"\n{'PASS' if bad == 0 and deterministic else 'FAIL'} in {time.monotonic() - t0:.0f} s")
    return 0 if bad == 0 and deterministic else 1


if __name__ == "__main__":
    sys.exit(main())
