"""The fuzzing harness (tests/fuzzing): a short seeded campaign, and the harness's own contracts.

The campaign is the one ``make fuzz`` runs, cut to a size that takes well
under 30 s on 2 cores: every mutator family and every target take part, and
no input may crash, hang or overrun memory.
"""

from __future__ import annotations

import os

import pytest

from tests.fuzzing import FAMILIES, LIBRARY_TARGETS, Config, make_case, materialize, run_campaign
from tests.fuzzing.mutate import MODEL_OPS, reseal
from tests.fuzzing.runner import Summary, signature
from tests.fuzzing.seeds import seed_files
from tests.fuzzing.targets import Result, judge_cli
from tpsv import codec

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the runner forks its workers")

#: Inputs of the seeded run (about 10-15 s here).
SHORT_RUN = 150


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> tuple[Summary, object]:
    out = tmp_path_factory.mktemp("fuzz")
    # A generous time limit: the suite shares 2 cores with whatever else runs.
    cfg = Config(n=SHORT_RUN, seed=0, timeout=30.0, rss_limit_mb=1024, out=out, cli_every=5)
    return run_campaign(cfg, log=lambda line: None), out


def test_short_campaign_finds_nothing(short_run):
    summary, out = short_run
    bad = {k: summary.total(k) for k in ("crash", "hang", "memory")}
    assert not any(bad.values()), (bad, summary.findings[:5], sorted(p.name for p in out.iterdir())[:10])
    assert summary.inputs == SHORT_RUN


def test_short_campaign_reaches_every_family_and_target(short_run):
    summary, _ = short_run
    assert set(summary.families) == set(FAMILIES)
    for name in LIBRARY_TARGETS:
        counts = summary.counts[name]
        assert counts["ok"] + counts["clean"] > 0, name
    # most mutants are refused by the decoder, and some decode to valid (hostile) models
    assert summary.counts["decode"]["clean"] > 0 and summary.counts["decode"]["ok"] > 0
    assert any(name.startswith("cli-") for name in summary.counts)


def test_mutants_are_deterministic():
    for i in range(40):
        a, b = make_case(7, i), make_case(7, i)
        assert (a.family, a.ops, materialize(a)) == (b.family, b.ops, materialize(b))


def test_seeds_are_valid_files():
    for name, data in seed_files():
        m = codec.decode(data)
        if name.startswith(("v1-", "v2-")):
            # old-version seeds are written back as version 3, the same model
            assert codec.decode(codec.encode(m)).regions[0].outline[0].tobytes() == m.regions[0].outline[0].tobytes()
        else:
            assert codec.encode(m) == data, name


def test_model_ops_keep_the_model_shape():
    """Each model-level mutator returns a description and leaves a Model the encoder can judge."""
    import random
    for k, op in enumerate(MODEL_OPS):
        for name, data in seed_files()[:6]:
            m = codec.decode(data)
            assert isinstance(op(m, random.Random(k)), str)
            try:
                codec.encode(m)
            except ValueError:
                pass


def test_reseal_fixes_both_checksums():
    data = bytearray(seed_files()[0][1])
    data[-1] ^= 0xFF
    data[20] = 0  # regions count: the decoder's checks, not a CRC, must now refuse it
    msg = ""
    try:
        codec.decode(reseal(data))
    except codec.layout.TpsvFormatError as exc:
        msg = str(exc)
    assert msg and "checksum" not in msg


def test_cli_judgement():
    class R:
        def __init__(self, code, err="", out="", exc=None):
            self.exit_code, self.stderr, self.stdout, self.exception = code, err, out, exc

    assert judge_cli(R(0), "render").outcome == "ok"
    assert judge_cli(R(1, "tpsv: error: x.tpsv: bad magic\n"), "render").outcome == "clean"
    assert judge_cli(R(2, "Error: bad option\n"), "render").outcome == "clean"
    assert judge_cli(R(1, "tpsv: error: internal error: KeyError\n"), "render").outcome == "crash"
    assert judge_cli(R(1, "a warning\ntpsv: error: x\n"), "render").outcome == "crash"
    assert judge_cli(R(0, "RuntimeWarning: overflow\n"), "render").outcome == "crash"
    assert judge_cli(R(0, out="\x1b[2J"), "info").outcome == "crash"
    assert judge_cli(R(1, "tpsv: error: out of memory\n"), "render").outcome == "memory"
    assert judge_cli(R(1, exc=KeyError("k")), "render").outcome == "crash"


def test_signatures_group_by_cause():
    tb = 'Traceback\n  File "/x/tpsv/edit/deform.py", line 3, in f\nKeyError: 4\n'
    assert signature(Result("crash", tb)) == "KeyError: 4 @ edit/deform.py\", line 3, in f"
    assert signature(Result("hang", "no result after 10 s")) == "no result after 10 s"


def _misbehave(state):
    """A target that hangs, overruns memory, dies or raises, by input index."""
    import signal
    import time

    import numpy as np

    i = state.case.index
    if i == 0:
        time.sleep(60)
    elif i == 1:
        np.ones(2**31, np.uint8)  # 2 GiB: over the address-space cap
    elif i == 2:
        os.kill(os.getpid(), signal.SIGSEGV)
    elif i == 3:
        raise KeyError("a bug")
    elif i == 4:
        from tpsv.errors import TpsvError
        raise TpsvError("a clean refusal")


def test_runner_classifies_hangs_memory_deaths_and_crashes(monkeypatch, tmp_path):
    from tests.fuzzing import targets

    monkeypatch.setitem(targets.LIBRARY_TARGETS, "misbehave", _misbehave)
    cfg = Config(n=6, seed=0, timeout=2.0, rss_limit_mb=1024, out=tmp_path, targets=("misbehave",), cli_every=0)
    summary = run_campaign(cfg, log=lambda line: None)
    outcomes = {i: o for i, _, o, _ in summary.findings}
    assert outcomes == {0: "hang", 1: "memory", 2: "crash", 3: "crash"}
    assert summary.counts["misbehave"]["clean"] == 1 and summary.counts["misbehave"]["ok"] == 1
    assert summary.inputs == 6
    saved = sorted(p.name for p in tmp_path.iterdir())
    assert "hang-misbehave-0-0000000.txt" in saved and "crash-misbehave-0-0000003.txt" in saved
    assert "KeyError" in (tmp_path / "crash-misbehave-0-0000003.txt").read_text()
