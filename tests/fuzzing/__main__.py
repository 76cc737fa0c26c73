"""``python -m tests.fuzzing``: run a fuzz campaign and print its summary.

Exit status 0 when no input crashed, hung or overran memory, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .runner import Config, run_campaign
from .targets import LIBRARY_TARGETS


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m tests.fuzzing", description=__doc__)
    p.add_argument("-n", type=int, default=1000, help="inputs to run (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed: inputs are a function of (seed, index)")
    p.add_argument("--start", type=int, default=0, help="first input index (reproduce one: --start I -n 1)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds one target may take on one input")
    p.add_argument("--rss-limit-mb", type=int, default=1024, help="peak resident memory per target step")
    p.add_argument("--out", type=Path, default=None, help="folder for crashing inputs and their tracebacks")
    p.add_argument("--targets", default=",".join(LIBRARY_TARGETS),
                   help="comma-separated library targets (default: all)")
    p.add_argument("--cli-every", type=int, default=10,
                   help="also run one CLI command (in-process) on every Nth input; 0: never")
    p.add_argument("--atheris", action="store_true",
                   help="coverage-guided mode (needs the 'fuzz' extra: pip install -e '.[fuzz]')")
    p.add_argument("--jobs", "-j", type=int, default=1, help="workers run at once (default 1)")
    p.add_argument("--progress", action="store_true", help="a line every 100 inputs")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    targets = tuple(t for t in args.targets.split(",") if t)
    if "encode" not in targets:  # the model family's inputs exist only once encoded
        targets = ("encode",) + targets
    unknown = [t for t in targets if t not in LIBRARY_TARGETS]
    if unknown:
        sys.exit(f"unknown target {unknown[0]!r}; known: {', '.join(LIBRARY_TARGETS)}")
    if args.atheris:
        from .coverage import run_atheris
        return run_atheris(args)
    cfg = Config(n=args.n, seed=args.seed, timeout=args.timeout, rss_limit_mb=args.rss_limit_mb, out=args.out,
                 targets=targets, cli_every=args.cli_every, start=args.start, progress=args.progress,
                 jobs=max(1, args.jobs))
    summary = run_campaign(cfg, log=lambda line: print(line, file=sys.stderr, flush=True))
    print(summary.table())
    bad = sum(summary.total(k) for k in ("crash", "hang", "memory"))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
