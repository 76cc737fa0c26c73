"""Seed inputs: the bundled corpus of real files plus small hand-built models.

The corpus (``corpus/*.tpsv``) holds files written by ``tpsv vectorize`` on the
bundled samples (``corpus/README.md``), and ``tests/data/v1`` the same samples
as format version 1 once wrote them (the decoder still reads those); the hand-built models reach corners a
vectorized photo never shows (no features, no regions, holes, a 1x1 canvas,
dense curvilinear pairs, every supported kernel size).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from tpsv import codec
from tpsv.model import CURVILINEAR, Features, Model, Params, Patch, Region

CORPUS = Path(__file__).resolve().parent / "corpus"
VERSION_1 = Path(__file__).resolve().parents[1] / "data" / "v1"
VERSION_2 = Path(__file__).resolve().parents[1] / "data" / "v2"


def grid_ctrl(m: int, n: int, x0: float, y0: float, w: float, h: float) -> np.ndarray:
    """An affine ``m x n`` Hermite grid covering the rectangle ``(x0, y0, w, h)``."""
    ii, jj = np.meshgrid(np.arange(m, dtype=float), np.arange(n, dtype=float), indexing="ij")
    a = np.array([w / (m - 1), 0.0])
    b = np.array([0.0, h / (n - 1)])
    ctrl = np.zeros((m, n, 4, 2))
    ctrl[..., 0, :] = np.array([x0, y0]) + ii[..., None] * a + jj[..., None] * b
    ctrl[..., 1, :] = a
    ctrl[..., 2, :] = b
    return ctrl


def rect(x0: float, y0: float, w: float, h: float) -> np.ndarray:
    """A rectangle as an outline polygon (positive shoelace area, as traced outlines)."""
    return np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]], float)


def features(region, st, lab, kind=None, pair=None) -> Features:
    """Features from plain lists (kind 0 and no pairs unless given)."""
    n = len(region)
    return Features(
        region=np.asarray(region, np.int32).reshape(n),
        st=np.asarray(st, np.float64).reshape(n, 2),
        lab=np.asarray(lab, np.float32).reshape(n, 3),
        kind=np.zeros(n, np.uint8) if kind is None else np.asarray(kind, np.uint8),
        pair=np.full(n, -1, np.int32) if pair is None else np.asarray(pair, np.int32),
    )


def two_regions(kernel_size: int = 32) -> Model:
    """Left and right halves of a 40x24 canvas, a hole in the right one, gradation
    features on a lattice and curvilinear pairs along the shared edge."""
    left = Region(0, [rect(0, 0, 20, 24)], Patch(grid_ctrl(3, 3, 0, 0, 20, 24)))
    hole = rect(26, 8, 6, 6)[::-1].copy()
    right = Region(1, [rect(20, 0, 20, 24), hole], Patch(grid_ctrl(4, 3, 20, 0, 20, 24)))
    s = np.linspace(0.05, 0.95, 6)
    lattice = np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
    reg, st, lab, kind, pair = [], [], [], [], []
    for r in (0, 1):
        for k, p in enumerate(lattice):
            reg.append(r), st.append(p), lab.append((30 + 40 * r + k, 20 - k, -10 + k)), kind.append(0), pair.append(-1)
    base = len(reg)
    for k, t in enumerate(np.linspace(0.1, 0.9, 5)):
        # region 0's edge is at S = 1, region 1's at S = 0; pair i <-> i + 5
        reg.append(0), st.append((1.0, t)), lab.append((60, 5, 5)), kind.append(CURVILINEAR), pair.append(base + 5 + k)
    for k, t in enumerate(np.linspace(0.1, 0.9, 5)):
        reg.append(1), st.append((0.0, t)), lab.append((20, -5, -5)), kind.append(CURVILINEAR), pair.append(base + k)
    order = np.argsort(np.asarray(reg), kind="stable")
    f = features(reg, st, lab, kind, pair).subset(order)
    return Model(40, 24, [left, right], f, Params(kernel_size=kernel_size, overlap=0.25))


def one_pixel() -> Model:
    """A 1x1 canvas with one diamond region and one feature."""
    diamond = np.array([[0.5, 0.0], [1.0, 0.5], [0.5, 1.0], [0.0, 0.5]])
    region = Region(7, [diamond], Patch(grid_ctrl(2, 2, 0, 0, 1, 1)))
    return Model(1, 1, [region], features([0], [(0.5, 0.5)], [(50, 0, 0)]), Params(kernel_size=8))


def no_features() -> Model:
    m = two_regions()
    return Model(m.width, m.height, m.regions, Features.empty(), m.params)


def transparent_hole() -> Model:
    """The two-region model with its right half transparent (format version 4, flag 2)."""
    m = two_regions()
    m.regions[1].transparent = True
    return m


def no_regions() -> Model:
    return Model(3, 2, [], Features.empty(), Params(kernel_size=16))


def fine_steps() -> Model:
    """The two-region model at the paper's settings with extras tpsv writes."""
    m = two_regions(kernel_size=64)
    m.params = Params(kernel_size=64, overlap=0.5, smoothing=1e-3, st_steps=64, l_step=1, ab_step=1,
                      extra={"scheme": "paper", "front": "1"})
    return m


HAND_MODELS = {
    "two-regions": two_regions,
    "two-regions-k128": lambda: two_regions(kernel_size=128),
    "one-pixel": one_pixel,
    "no-features": no_features,
    "no-regions": no_regions,
    "transparent": transparent_hole,
    "fine-steps": fine_steps,
}


@lru_cache(maxsize=None)
def seed_files() -> tuple[tuple[str, bytes], ...]:
    """Every seed as ``(name, file bytes)``: the corpus, then the hand-built models encoded."""
    out = [(p.stem, p.read_bytes()) for p in sorted(CORPUS.glob("*.tpsv"))]
    out += [(f"v1-{p.stem}", p.read_bytes()) for p in sorted(VERSION_1.glob("*.tpsv"))]
    out += [(f"v2-{p.stem}", p.read_bytes()) for p in sorted(VERSION_2.glob("*.tpsv"))]
    out += [(name, codec.encode(make())) for name, make in HAND_MODELS.items()]
    return tuple(out)
