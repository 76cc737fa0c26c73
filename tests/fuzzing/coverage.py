"""Coverage-guided mode: atheris (libFuzzer) drives the decoder with our mutators.

Needs the optional extra: ``pip install -e '.[fuzz]'`` (``atheris>=2.3``).
Each input runs in-process through ``decode`` and ``info``, and, when it
decodes, ``render`` at a small size; libFuzzer's own ``-timeout`` and
``-rss_limit_mb`` catch hangs and memory. The custom mutator applies one of the
structure-aware families of :mod:`.mutate` to the input when it is a valid
file (else to a seed), or libFuzzer's byte mutation, so that coverage feedback
and structure both steer the search. Crashing inputs are written by libFuzzer
under ``--out`` (``crash-*``).
"""

from __future__ import annotations

import inspect
import random
import sys

from tpsv import codec
from tpsv.cli.info import summary
from tpsv.errors import TpsvFormatError
from tpsv.rendering.raster import render

from .mutate import MUTATORS, Case
from .runner import warm_up
from .seeds import seed_files
from .targets import RENDER_SIZE

#: Families the custom mutator draws from (the model family needs a valid model and is the campaign's).
STRUCTURED = ("bytes", "header", "section", "quantized")


def test_one_input(data: bytes) -> None:
    """Decode, summarise and (when valid) render one input; only a clean refusal may escape quietly."""
    try:
        model = codec.decode(data)
    except TpsvFormatError as exc:
        if "\n" in str(exc) or not str(exc):
            raise AssertionError(f"TpsvFormatError message is not one line: {exc!r}") from None
        return
    summary(data)
    if model.regions:
        render(model, width=RENDER_SIZE[0], height=RENDER_SIZE[1])


def custom_mutator(data: bytes, max_size: int, seed: int) -> bytes:
    """One structure-aware mutation of ``data`` (or of a seed when ``data`` does not decode)."""
    import atheris

    rng = random.Random(seed)
    if rng.random() < 0.2:
        return atheris.Mutate(data, max_size)
    base = data
    try:
        codec.decode(data)
    except Exception:  # not a valid file: mutate a seed instead
        base = rng.choice(seed_files())[1]
    family = rng.choice(STRUCTURED)
    case = Case(index=seed, family=family, seed="atheris")
    try:
        MUTATORS[family](case, base, rng)
    except Exception:  # a mutator that cannot apply to this base (e.g. quantized on an odd file)
        return atheris.Mutate(data, max_size)
    return (case.data or base)[:max_size]


def _instrument(package: str) -> int:
    """Instrument, in place, every function and method of the loaded modules of ``package``.

    ``atheris.instrument_all()`` would also instrument numpy, scipy and Warp's
    Python, which takes minutes and steers the search towards them.
    """
    import atheris

    count = 0
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name == package or name.startswith(package + ".")):
            continue
        for obj in list(vars(mod).values()):
            funcs = [obj] if inspect.isfunction(obj) else (
                [f for f in vars(obj).values() if inspect.isfunction(f)] if inspect.isclass(obj) else [])
            for f in funcs:
                if f.__module__ == name:
                    atheris.instrument_func(f)
                    count += 1
    return count


def run_atheris(args) -> int:
    """Run libFuzzer with the settings of ``python -m tests.fuzzing --atheris`` (never returns on success)."""
    try:
        import atheris
    except ImportError:
        sys.exit("atheris is not installed: pip install -e '.[fuzz]' (or run without --atheris)")
    argv = [sys.argv[0], f"-runs={args.n}", f"-seed={args.seed}", f"-timeout={int(args.timeout)}",
            f"-rss_limit_mb={args.rss_limit_mb}"]
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        argv.append(f"-artifact_prefix={args.out}/")
        corpus = args.out / "corpus"
        corpus.mkdir(exist_ok=True)
        for name, data in seed_files():
            (corpus / f"{name}.tpsv").write_bytes(data)
        argv.append(str(corpus))
    warm_up()  # imports and Warp kernels first, then instrument what was loaded
    _instrument("tpsv")
    atheris.Setup(argv, test_one_input, custom_mutator=custom_mutator)
    atheris.Fuzz()
    return 0
