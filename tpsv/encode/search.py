"""Choice of the feature thresholds (paper IV-C3 and VI-A).

Gradient histogram
------------------
``mu`` and ``sigma`` are the mean and standard deviation of the gradient
magnitude that the Canny detector of :mod:`tpsv.encode.features` thresholds: the 3x3
Sobel of the strongest channel of ``2.55 * Lab`` (L spans 0-255), on the scale
of ``cv2.Canny`` thresholds for 8-bit images (a step of height ``h`` gives
``4 h``). With this scale ``mu`` of ordinary photos falls between the paper's
constants ``C_canny = 30`` and ``C_super = 60`` (45-80 on the scikit-image
samples), so the paper's ``t`` interpolation is actually exercised; with a
normalised (``/ 4`` or ``/ 8``) Sobel every photo would sit at ``t = 1``.

Pixels left out of the histogram: exactly flat ones (magnitude < 0.5: a
synthetic or padded flat area would otherwise drag ``mu`` and ``sigma`` to 0
and the thresholds with them). Region borders are kept by default: Canny runs
on the whole image and places pairs across region borders too, so the
histogram describes the quantity that is thresholded. Leaving out pixels next
to region borders (``exclude_borders=True``, a per-patch reading of VI-A) was
measured and rejected as the default: automatic segment borders sit on the
strongest edges, so removing them cuts the histogram's upper tail and drives
``T0_canny`` far down (felzenszwalb, ~100-350 regions: astronaut 190 -> 34,
rocket 72 -> the 8 clamp), i.e. edges almost everywhere.

Initial thresholds (VI-A)
-------------------------
``t = clip((mu - C_super) / (C_canny - C_super), 0, 1)``,
``T0_canny = t (mu - 0.5 sigma) + (1 - t)(mu + sigma)`` and
``T0_super = t (0.8 sigma) + (1 - t)(0.25 sigma)``. The prose of VI-A says the
low-variance super-pixel threshold is ``mu + 0.25 sigma`` while the formula says
``0.25 sigma``; we follow the formula: it is the only unambiguous statement, it
keeps ``T_super`` proportional to the image contrast like the cell deviations
it is compared with, and on the samples it lands inside the range of level-0
cell deviations (so the adaptive splitting is active), whereas ``mu + 0.25
sigma`` (e.g. ~100 on astronaut) would stop every split. Both thresholds are
clamped to :data:`CANNY_RANGE` and :data:`SUPER_RANGE`.

Search (IV-C3)
--------------
Seeded Monte Carlo: evaluate the start, then repeatedly mutate the best so far,
``T' = T_best + Delta`` with ``Delta ~ U(-|T_best|, +|T_best|)`` per coordinate
(clamped to the ranges), keeping the best efficiency ``w = 1 / (E C)``.

With ``min_width`` the half-width of ``Delta`` is ``max(|T_best|, min_width)``
per coordinate. The paper's rule (``min_width = 0``) only ever moves by the
size of the current best: once a threshold has been improved near the bottom
of its range (``T_super = 1``, say) every later draw stays within ``2
T_best`` of it, and the search cannot come back up however much better that
would be. ``tpsv.encode.vectorize`` passes the start point as ``min_width`` for its
default scheme (measured: the search otherwise sticks at ``T_super`` near 1 on
all four samples while the best ``w`` is at 15-30).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
from scipy.ndimage import binary_dilation

from .. import metrics
from ..geometry.bands import lab_image
from ..geometry.regions import region_borders
from .features import LAB_SCALE, as_index, as_rgb, lab_gradient

#: Paper constants of VI-A.
C_CANNY = 30.0
C_SUPER = 60.0
#: Valid ranges of the thresholds (Sobel magnitude scale; RMS of 2.55 * Lab).
CANNY_RANGE = (8.0, 1500.0)
SUPER_RANGE = (1.0, 400.0)
#: Magnitudes below this count as flat and stay out of the histogram.
FLAT = 0.5


def gradient_magnitude(rgb: np.ndarray, blur_sigma: float = 0.0) -> np.ndarray:
    """Gradient magnitude (HxW float32) as thresholded by the Canny detector."""
    return lab_gradient(lab_image(as_rgb(rgb)), blur_sigma, scale=LAB_SCALE)[2]


def gradient_stats(
    rgb: np.ndarray, index: np.ndarray | None = None, exclude_borders: bool = False
) -> tuple[float, float]:
    """Mean and standard deviation of the gradient-magnitude histogram.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float in [0, 1] (uint8 accepted)
    index : ndarray (H, W) int, optional
        Region index (checked against the image; used only with
        ``exclude_borders``).
    exclude_borders : bool
        Leave out pixels whose 3x3 neighbourhood crosses a region border
        (unless that leaves nothing). Off by default (see module doc).

    Returns
    -------
    mu, sigma : float
        On the ``cv2.Canny`` threshold scale (see module doc); ``(0, 0)`` when
        the image has no non-flat pixel.
    """
    rgb = as_rgb(rgb)
    mag = gradient_magnitude(rgb)
    keep = mag >= FLAT
    if index is not None:
        ix = as_index(index, rgb.shape[:2])
    if index is not None and exclude_borders:
        # 3x3 neighbourhood crosses a border <=> within one pixel (8-connected) of one.
        border = binary_dilation(region_borders(ix), structure=np.ones((3, 3), bool))
        if (keep & ~border).any():
            keep &= ~border
    vals = mag[keep].astype(np.float64)
    if vals.size == 0:
        return 0.0, 0.0
    return float(vals.mean()), float(vals.std())


def thresholds_from_stats(mu: float, sigma: float) -> tuple[float, float]:
    """The VI-A interpolation for given histogram statistics (clamped)."""
    t = float(np.clip((mu - C_SUPER) / (C_CANNY - C_SUPER), 0.0, 1.0))
    tc = t * (mu - 0.5 * sigma) + (1.0 - t) * (mu + sigma)
    ts = t * (0.8 * sigma) + (1.0 - t) * (0.25 * sigma)
    return (
        float(np.clip(tc, *CANNY_RANGE)),
        float(np.clip(ts, *SUPER_RANGE)),
    )


def initial_thresholds(
    rgb: np.ndarray, index: np.ndarray | None = None, exclude_borders: bool = False
) -> tuple[float, float]:
    """``(T0_canny, T0_super)`` from the gradient histogram (paper VI-A).

    Parameters as :func:`gradient_stats`.
    """
    mu, sigma = gradient_stats(rgb, index, exclude_borders)
    return thresholds_from_stats(mu, sigma)


def efficiency(mse: float, file_bytes: int, width: int, height: int) -> float:
    """The paper's ``w = 1 / (E C)`` (:func:`tpsv.metrics.efficiency`), arguments checked.

    ``E`` is the MSE of RGB in [0, 1] over the whole image and ``C = file_bytes
    / (W H 3)``. ``inf`` when ``E`` or ``C`` is 0.

    Raises
    ------
    ValueError
        A size that is not positive, or a negative error or file size.
    """
    if width <= 0 or height <= 0:
        raise ValueError("image size must be positive")
    if mse < 0 or file_bytes < 0:
        raise ValueError("mse and file size must be non-negative")
    if file_bytes == 0:
        return float("inf")
    return metrics.efficiency(float(mse), file_bytes, width, height)


class Trial(NamedTuple):
    """One evaluated pair of thresholds."""

    t_canny: float
    t_super: float
    E: float
    C: float
    w: float


@dataclass
class SearchResult:
    """Outcome of :func:`monte_carlo_search`.

    Attributes
    ----------
    t_canny, t_super : float
        Best thresholds (exactly the values passed to ``evaluate``).
    w : float
        Best efficiency.
    history : list of Trial
        Every evaluation in order (the start first); no pair appears twice.
    iterations : int
        Trials drawn (evaluations plus draws that only hit the cache).
    """

    t_canny: float
    t_super: float
    w: float
    history: list[Trial] = field(default_factory=list)
    iterations: int = 0

    @property
    def best(self) -> Trial:
        return next(h for h in self.history if (h.t_canny, h.t_super) == (self.t_canny, self.t_super))


def _as_w(out) -> tuple[float, float, float]:
    """``evaluate``'s return value -> (E, C, w)."""
    if isinstance(out, tuple | list) and len(out) == 2:
        e, c = float(out[0]), float(out[1])
        ec = e * c
        return e, c, (float("inf") if ec == 0 else 1.0 / ec)
    w = float(out)
    return float("nan"), float("nan"), w


def _mutate(rng, best: Trial, min_width: tuple[float, float], clamp, seen, redraws: int) -> tuple[float, float] | None:
    """A candidate ``T_best + Delta``, ``Delta ~ U(-w, w)`` per coordinate with ``w = max(|T_best|, min_width)``.

    Clamped and rounded by ``clamp``; redrawn (at most ``redraws`` times)
    while it lands on a pair in ``seen``; None when every draw did.
    """
    for _try in range(redraws + 1):
        wc = max(abs(best.t_canny), float(min_width[0]))
        ws = max(abs(best.t_super), float(min_width[1]))
        dc = rng.uniform(-wc, wc)
        ds = rng.uniform(-ws, ws)
        key = clamp(best.t_canny + dc, best.t_super + ds)
        if key not in seen:
            return key
    return None


def monte_carlo_search(
    evaluate: Callable[[float, float], object],
    t0: tuple[float, float],
    iterations: int = 20,
    seed: int = 0,
    *,
    canny_range: tuple[float, float] = CANNY_RANGE,
    super_range: tuple[float, float] = SUPER_RANGE,
    decimals: int = 1,
    redraws: int = 20,
    min_width: tuple[float, float] = (0.0, 0.0),
) -> SearchResult:
    """Seeded Monte Carlo search maximising ``w = 1 / (E C)`` (paper IV-C3).

    Parameters
    ----------
    evaluate : callable ``(t_canny, t_super) -> (E, C)`` or ``-> w``
        Vectorise, encode, render and measure. A 2-tuple is read as ``(E, C)``
        (``w = 1 / (E C)``); anything else as ``w`` itself (``E``, ``C`` are
        then recorded as NaN).
    t0 : (float, float)
        Start (usually :func:`initial_thresholds`); evaluated first.
    iterations : int
        ``N_total``: trials including the start. A draw that rounds to an
        already evaluated pair is redrawn (up to ``redraws`` times, then the
        trial is spent without evaluation), so ``len(history) <= iterations``
        and ``evaluate`` never sees the same pair twice.
    seed : int
        Seed of the mutations (``numpy.random.default_rng``).
    canny_range, super_range : (float, float)
        Clamp of every candidate.
    decimals : int
        Candidates are rounded to this many decimals before evaluation (the
        cache key); the rounded values are the ones passed to ``evaluate``.
    min_width : (float, float)
        Least half-width of the mutation per coordinate (module doc; 0: the
        paper's ``U(-|T_best|, +|T_best|)``).

    Returns
    -------
    SearchResult
        Never worse than the start: the start is evaluated first and only a
        strictly better ``w`` replaces the best.
    """
    rng = np.random.default_rng(seed)

    def clamp(tc: float, ts: float) -> tuple[float, float]:
        tc = round(float(np.clip(tc, *canny_range)), decimals)
        ts = round(float(np.clip(ts, *super_range)), decimals)
        return tc, ts

    cache: dict[tuple[float, float], Trial] = {}
    history: list[Trial] = []

    def run(tc: float, ts: float) -> Trial:
        e, c, w = _as_w(evaluate(tc, ts))
        if np.isnan(w):
            w = -np.inf
        trial = Trial(tc, ts, e, c, w)
        cache[(tc, ts)] = trial
        history.append(trial)
        return trial

    best = run(*clamp(*t0)) if iterations > 0 else None
    if best is None:
        tc, ts = clamp(*t0)
        return SearchResult(tc, ts, float("nan"), [], 0)
    for _ in range(iterations - 1):
        cand = _mutate(rng, best, min_width, clamp, cache, redraws)
        if cand is None:
            continue
        trial = run(*cand)
        if trial.w > best.w:
            best = trial
    return SearchResult(best.t_canny, best.t_super, best.w, history, iterations)
