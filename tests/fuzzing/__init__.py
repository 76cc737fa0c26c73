"""A structure-aware fuzzer for .tpsv files (issue 14).

``python -m tests.fuzzing -n N --seed S`` makes N hostile inputs from the
seeds (:mod:`.seeds`) with the mutators of :mod:`.mutate`, runs each through
the targets of :mod:`.targets` (decode, info, render, the edits, the CLI) in
forked workers with a time and a memory limit (:mod:`.runner`), saves what
crashes, hangs or overruns, and prints a table of outcomes. ``--atheris``
runs the coverage-guided mode instead (the optional ``fuzz`` extra).

``make fuzz N=100000`` runs a campaign; ``tests/test_fuzz.py`` a short seeded
one inside ``make test``.
"""

from .mutate import FAMILIES, Case, make_case, materialize
from .runner import Config, Summary, run_campaign
from .targets import LIBRARY_TARGETS, OUTCOMES

__all__ = ["FAMILIES", "Case", "make_case", "materialize", "Config", "Summary", "run_campaign",
           "LIBRARY_TARGETS", "OUTCOMES"]
