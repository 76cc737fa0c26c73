"""Rate control: one quality knob, a PSNR target or a byte budget.

``tpsv vectorize --quality Q`` (1-100, like JPEG). With the detail layer (the
default) the picture is a cheap vector base plus the texture residual:

* the base is the regions (fitted outlines, edge widths) and a coarse lattice
  of gradation features with fitted colours (:data:`BASE_T_SUPER`, no
  curvilinear pairs, coarse colour steps), the same for every ``Q``;
* ``Q`` sets the detail texture's AVIF quality (``tpsv.codec.detail.avif_quality``).

Why the split is fixed rather than searched per image: on the four samples
a richer vector base never paid for its bytes once the residual is coded by
AVIF (docs/DESIGN.md, "Detail layer and rate control", for the measurements), while a fixed
base makes bytes and PSNR rise with ``Q`` (the texture's quality alone
changes) and makes ``--target-psnr`` / ``--max-bytes`` cheap: the base is
built once and only the texture is coded again while ``Q`` is searched.

Without the detail layer (``--no-detail``) ``Q`` sets the vector model
itself: lattice fineness (``T_super``, down to 2 px lattices), colour steps
and, at the top, curvilinear pairs, from :func:`vector_params`.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import cv2
import numpy as np
from scipy import ndimage

from .. import codec, metrics
from ..errors import TpsvError
from ..geometry import segment
from ..model import DETAIL_ZERO, Params
from ..rendering.raster import render
from ..threads import host_cores, pool as host_pool
from . import detail as detail_layer
from .features import FINE_LATTICE_PX, LATTICE_PX, FeatureExtractor
from .memory import give_back
from .vectorize import (Candidates, Evaluation, VectorizeResult, alpha_geometry, fit_model, image_geometry, label_map,
                        make_model, scheme_params, soften_false_steps)

#: The default quality: at least 32 dB on every bundled sample (README, "Quality").
DEFAULT_QUALITY = 75
MIN_QUALITY, MAX_QUALITY = 1, 100
#: A ``T_canny`` above every gradient: no curvilinear pairs.
NO_PAIRS = 1e9
#: The vector base under the detail layer: the coarsest lattice, no pairs.
BASE_T_CANNY = NO_PAIRS
BASE_T_SUPER = 1e9
#: The base's colour steps. Its few features cost little at any step, while steps of 16
#: (6 L units) left bumps in smooth fills that the texture, magnified, cannot hide: the
#: synthetic shapes at 8x went from 39.99 to 41.93 dB at 7-12 % fewer bytes with steps 4
#: (and 30 fit iterations); the samples moved by -0.07..+0.02 dB and -1..+2 % bytes.
BASE_STEPS = (4, 4)
#: Iterations of the base's colour fit (4 left the shapes' fills 1 dB short of converged).
BASE_FIT_ITERATIONS = 30
#: Smooth fills (:func:`smooth_fills`): the blur (px), the least RMS of the smooth residual
#: and the most of the rest (sRGB, 0-1), the lattice spacing (px) such a region gets and the
#: colour steps of a base that has one. On the synthetic shapes at 8x (``tpsv bench``, edge
#: table, default column): the coarsest lattice 42.47 dB / 1761 B; fills on a 16 px lattice
#: 43.91 dB / 1755 B, on 8 px 43.99 dB / 1860 B. Steps 4 were then the limit:
#: quantised Lab colours (4 a/b units a step) put bumps into the fill that the texture
#: carried at 1x and AVIF coded with its own error. Steps 1 on the 16 px lattice: 45.14 dB /
#: 1727 B, on 12 px 45.55 dB / 1751 B (steps 2: 45.03 dB / 1759 B), as the texture then
#: holds almost nothing in the fills and costs less than the finer colours.
SMOOTH_SIGMA = 4.0
SMOOTH_FILL_MIN = 3.0 / 255.0
SMOOTH_FILL_TEXTURE = 4.0 / 255.0
SMOOTH_FILL_PX = 12.0
SMOOTH_FILL_STEPS = (1, 1)
#: Regions of more pixels are never smooth fills: the 12 px lattice at colour steps 1 costs in
#: proportion to the area, and a photo's large smooth region is a low-frequency residual the
#: texture codes for less. retina at 1411 x 1411 (its fundus a smooth fill): 71040 -> 57885 B at
#: quality 75, 44.34 -> 44.32 dB, BD-PSNR +0.99 dB over qualities 20-95; rendered at 4x its
#: fundus no blurrier (docs/DESIGN.md, "Weak borders joined"). The edge table's fills are 0.3-7
#: thousand pixels, the colorwheel's at 240 px 57 thousand.
SMOOTH_FILL_MAX_PX = 1 << 17


def base_fit_sub(width: int, height: int) -> int:
    """Every how many pixels (per axis) the base's colours are fitted: 2 up to 1 Mpx, then
    so that about 2^18 pixels take part (memory and time stay bounded for large photos)."""
    return max(2, int(np.ceil(np.sqrt(width * height / 2**18))))


#: The pure vector ladder (:func:`vector_params`): ``T_super`` at some qualities (geometric in
#: between), the colour steps (l_step, ab_step) from each quality up, and the finest lattice
#: spacing (px) at some qualities (linear in between).
VECTOR_T_SUPER = ((1, 70.0), (60, 12.7), (90, 3.0), (100, 2.0))
VECTOR_STEPS = ((1, (16, 8)), (61, (8, 4)), (91, (4, 4)), (98, (4, 2)))
#: ``T_canny`` of the curvilinear pairs from each quality up (none below the first).
VECTOR_T_CANNY = ((1, NO_PAIRS), (96, 300.0), (98, 200.0), (100, 150.0))
VECTOR_MIN_SPACING = ((60, LATTICE_PX[0]), (85, FINE_LATTICE_PX[0]))


#: Features a file holds at most (``tpsv.codec.MAX_FEATURES``): the ladder's lattices stay within it.
FEATURE_LIMIT = codec.MAX_FEATURES


def finest_lattice(width: int, height: int) -> float:
    """The finest lattice spacing (px) whose features fit in a file of a ``width`` x ``height``
    image: a feature per ``d^2`` pixels, with a quarter more for the cells along the borders
    (:data:`FEATURE_LIMIT`; a 12-megapixel photo's pure vector ladder stops at 3.8 px)."""
    return float(np.sqrt(1.25 * width * height / FEATURE_LIMIT))


def vector_params(quality: int) -> dict:
    """Vector-only settings for ``quality``: ``t_canny``, ``t_super``, ``l_step``, ``ab_step``
    and ``min_spacing`` (the finest lattice a region may take, pixels).

    ``T_super`` falls geometrically from 70 (Q 1) to 12.7 (Q 60), 3 (Q 90)
    and 2 (Q 100) (:data:`VECTOR_T_SUPER`) and the finest spacing from 4 px
    (Q 60) to 2 px (Q 85, :data:`VECTOR_MIN_SPACING`): over the samples'
    regions the lattices' RMS colour deviation runs from 4-18 (4 px cells)
    to 26-70 (64 px), so the lattice goes from the coarsest to the finest.
    Colour steps (:data:`VECTOR_STEPS`) are L 16 / a,b 8 up to Q 60, then
    8/4, 4/4 and 4/2. a,b steps of 16 (the ladder's up to Q 60 before) made
    pink and yellow blotches in astronaut's face at 4x, a,b steps of 8 on
    lattices below 4 px pink and green ones in chelsea's fur at 8x. Finer
    a,b steps cost bytes: astronaut at Q 60, steps 16/16 0.370 bpp / 24.20
    dB, 16/8 0.425 bpp / 24.54 dB. On the fine lattices they also pay more
    than a finer lattice: 3.2 dB per doubling of the bytes against 2
    (chelsea, ``T_super`` 6.5: steps 8/8 1.27 bpp, 32.69 dB; 8/4 1.49 bpp,
    33.44 dB). Steps 1/2 (the old top) on the 2 px lattice gained 0.25 dB
    for 32 % more bytes than 2/4. Curvilinear pairs only from Q 96 up
    (:data:`VECTOR_T_CANNY`), on top of the 2 px lattices: there they gain
    1.5-3.8 dB per doubling of the bytes (astronaut, ``T_canny`` 300: 2.45
    -> 4.44 bpp, 30.87 -> 34.13 dB). Switched on from Q 60 up (``T_canny``
    160 -> 40) they made chelsea's curve jump from 0.1 to 4.4 bpp (35.9 dB)
    with no point between.
    """
    knots, values = zip(*VECTOR_T_SUPER)
    t_super = float(np.exp(np.interp(int(quality), knots, np.log(values))))
    l_step, ab_step = [steps for start, steps in VECTOR_STEPS if quality >= start][-1]
    t_canny = [t for start, t in VECTOR_T_CANNY if quality >= start][-1]
    knots, values = zip(*VECTOR_MIN_SPACING)
    min_spacing = float(np.interp(int(quality), knots, values))
    return dict(t_canny=t_canny, t_super=t_super, l_step=l_step, ab_step=ab_step, min_spacing=min_spacing)


def smooth_fills(rgb: np.ndarray, shown: np.ndarray, index: np.ndarray, transparent=()) -> np.ndarray:
    """Regions whose residual under the base is a smooth fill: the base should carry it.

    A region's residual ``rgb - shown`` is blurred within the region (a
    Gaussian of :data:`SMOOTH_SIGMA` px, normalised by the region's own
    mask, at half resolution). The region is a smooth fill when the blurred
    residual is at least :data:`SMOOTH_FILL_MIN` RMS while what the blur
    takes away is at most :data:`SMOOTH_FILL_TEXTURE` RMS (sRGB, 0-1): a
    gradient the coarsest lattice does not follow (a ramp that is straight
    in sRGB is curved in Lab) in a region with little texture, which the
    detail texture, coded by AVIF and magnified, would turn into blotches.
    The samples' regions (with their label maps) hold 4.7-42 levels of
    texture and noise and stay as they are; the synthetic shapes'
    backgrounds hold 0.7-1.4. A region of more than :data:`SMOOTH_FILL_MAX_PX`
    pixels is never one.

    Parameters
    ----------
    rgb, shown : ndarray (H, W, 3) float
        The image and the base's render.
    index : ndarray (H, W) int
        Region of every pixel (``-1``: none).
    transparent : sequence of bool
        Per region; transparent regions are never smooth fills.

    Returns
    -------
    ndarray (n_regions,) bool
    """
    n = len(transparent) if len(transparent) else int(index.max()) + 1
    out = np.zeros(n, bool)
    boxes = ndimage.find_objects(np.asarray(index, np.int32) + 1, max_label=n)
    for r, box in enumerate(boxes):
        if box is None or (len(transparent) and transparent[r]):
            continue
        mask = index[box] == r
        if int(mask.sum()) > SMOOTH_FILL_MAX_PX:
            continue
        inside = mask[..., None]
        res = np.asarray(rgb[box], np.float32) - np.asarray(shown[box], np.float32)
        res *= inside  # zero outside the region
        h, w = mask.shape
        half = ((w + 1) // 2, (h + 1) // 2)
        s = SMOOTH_SIGMA / 2.0
        num = cv2.GaussianBlur(cv2.resize(res, half, interpolation=cv2.INTER_AREA), (0, 0), s,
                               borderType=cv2.BORDER_CONSTANT)
        den = cv2.GaussianBlur(cv2.resize(mask.astype(np.float32), half, interpolation=cv2.INTER_AREA), (0, 0), s,
                               borderType=cv2.BORDER_CONSTANT)
        num /= np.maximum(den, 1e-6)[..., None]
        smooth = cv2.resize(num, (w, h), interpolation=cv2.INTER_LINEAR)
        smooth *= inside
        res -= smooth  # texture, noise, steps
        count = 3.0 * max(int(mask.sum()), 1)
        # sums over the region's values (the rest are zeros), in float64
        rms = float(np.sqrt(np.sum(np.square(smooth), dtype=np.float64) / count))
        rest = float(np.sqrt(np.sum(np.square(res), dtype=np.float64) / count))
        out[r] = rms >= SMOOTH_FILL_MIN and rest <= SMOOTH_FILL_TEXTURE
    return out


def check_quality(quality) -> int:
    q = int(quality)
    if not MIN_QUALITY <= q <= MAX_QUALITY:
        raise TpsvError(f"quality {quality} not in {MIN_QUALITY}..{MAX_QUALITY}")
    return q


class Trials:
    """Encodings at several qualities of one image, each made once (the search reuses them)."""

    def __init__(self, rgb, geometry, params: Params, detail: bool, device: str, tried=None):
        self.rgb = rgb
        self.tried = tried or (lambda n: None)  # called with the number of encodings made so far
        self.detail = detail
        self.device = device
        self.geometry = geometry
        self.params = params
        self.cands: dict = {}  # colour steps -> Candidates (their caches assume fixed steps)
        self.base = None
        #: Regions (and their pixels) whose texture is read in luma mode (set with the base).
        self.grey, self.grey_pixels = None, None
        self.done: dict = {}  # quality -> (data, model, mse)

    def vector_base(self):
        """``(evaluation, render at scale 1, residual texels)`` of the vector base (made once).

        Its colours are fitted on a subsampled lattice of pixels
        (:func:`base_fit_sub`): the texture corrects what the fit leaves, so a
        fit on every pixel bought 0.04 dB at the default quality on the
        samples, for 1.5 times the time and, on a 2048x2048 photo, 39 s and
        4.8 GB of peak memory. Regions whose residual under the coarsest
        lattice is a smooth fill (:func:`smooth_fills`) are made again on a
        lattice of :data:`SMOOTH_FILL_PX`, and that base gets the colour steps
        :data:`SMOOTH_FILL_STEPS` (steps are the file's, not a region's).
        """
        if self.base is None:
            ev, shown = self._base()
            clear = [r.transparent for r in ev.model.regions]
            fine = smooth_fills(self.rgb, shown, self.geometry.index, clear)
            if fine.any():
                ev = shown = None
                give_back()
                ev, shown = self._base(np.where(fine, SMOOTH_FILL_PX, np.inf), SMOOTH_FILL_STEPS)
            texels = detail_layer.residual_texels(self.rgb, shown)
            clear = np.array(clear + [False])
            texels[clear[self.geometry.index]] = DETAIL_ZERO  # nobody sees a transparent region's texture
            # a region without chroma in its residual reads the luma alone: what the codec would
            # make of its chroma is noise, and the chroma planes are coded flat there
            self.grey = detail_layer.grey_regions(texels, self.geometry.index, len(clear) - 1) & ~clear[:-1]
            if self.grey.any():
                self.grey_pixels = np.append(self.grey, False)[self.geometry.index]
                texels[self.grey_pixels, 1:] = DETAIL_ZERO
            self.base = (ev, shown, texels)
            give_back()  # before the AVIF encoder takes its own
        return self.base

    def _base(self, max_spacing=None, steps=BASE_STEPS):
        """``(evaluation, render at scale 1)`` of the base, each region's lattice spacing at most
        its ``max_spacing`` (px) where given, its colours quantised by ``steps`` (L, a/b)."""
        h, w = self.rgb.shape[:2]
        p = replace(self.params, t_canny=BASE_T_CANNY, t_super=BASE_T_SUPER, l_step=steps[0],
                    ab_step=steps[1])
        # per-pixel data is dropped as soon as its stage is done: the peak memory is the
        # largest stage's, not the sum of them (issue 12)
        model = make_model(self.rgb, self.geometry, FeatureExtractor(self.rgb, self.geometry.index), p,
                           fit=False, max_spacing=max_spacing)
        self.geometry.forget("lattice")
        give_back()
        model = fit_model(self.rgb, self.geometry, model, base_fit_sub(w, h), BASE_FIT_ITERATIONS)
        self.geometry.forget("lattice", "fit", "borders", "st")  # the render makes its own maps
        give_back()
        def drawn(model):
            data = codec.encode(model)
            decoded = codec.decode(data)
            return data, decoded, render(decoded, device=self.device)

        data, decoded, shown = drawn(model)
        # borders where the base steps as the photo does not are softened, and the base drawn again: the
        # texture holds the difference, and magnified its interpolation cannot follow a sharp step
        wide = soften_false_steps(self.rgb, self.geometry, shown)
        if wide is not None:
            data, decoded, shown = drawn(replace(model, blur_map=wide))
        return Evaluation(data, decoded, metrics.mse(self.rgb, shown)), shown

    def _candidates(self, l_step: int, ab_step: int) -> Candidates:
        key = (l_step, ab_step)
        if key not in self.cands:
            p = replace(self.params, l_step=l_step, ab_step=ab_step)
            # lattices that stand alone: a coarser one padded with anchors made a lower quality a
            # larger file (make_model)
            self.cands[key] = Candidates(self.rgb, self.geometry, p, device=self.device, standalone=True)
        return self.cands[key]

    def __call__(self, quality: int):
        if quality in self.done:
            return self.done[quality]
        if self.detail:
            ev, shown, texels = self.vector_base()
            coded = detail_layer.code_texels(texels, quality)
            base = _stamped(ev.model, quality)
            model = replace(base, detail=detail_layer.make_detail(ev.model, texels, quality, coded, self.grey))
            err = metrics.mse(self.rgb, detail_layer.with_texels(shown, coded[1], self.grey_pixels))
            data, base_data = codec.encode(model), codec.encode(base)
            if not detail_pays(ev.mse, err, len(base_data), len(data)):
                model, err, data = base, ev.mse, base_data
        else:
            v = vector_params(quality)
            h, w = self.rgb.shape[:2]
            finest = max(v["min_spacing"], finest_lattice(w, h))
            cands = self._candidates(v["l_step"], v["ab_step"])
            t_canny, made = v["t_canny"], None
            if t_canny < NO_PAIRS:
                made = cands.model(t_canny, v["t_super"], finest)
                if len(made.features) > FEATURE_LIMIT:
                    t_canny, made = NO_PAIRS, None  # the pairs do not fit in the file (a large photo): the lattice alone
            ev = cands.evaluate(t_canny, v["t_super"], final=True, min_spacing=finest, model=made)
            model, err = _stamped(ev.model, quality), ev.mse
            data = codec.encode(model)
        # quantize is decode(encode()) without decoding the texture's AVIF again
        out = (data, codec.quantize(model), err)
        self.done[quality] = out
        self.tried(len(self.done))
        return out


#: Least gain (dB of PSNR at scale 1) the detail layer must bring per doubling of the file for it
#: to be kept (:func:`detail_pays`). A texture costs bytes however little it holds: the bench's
#: drawings frames and grid at quality 75 carried 357 and 448 bytes of it (22-29 % of the file;
#: 196 and 270 as bare AV1 bitstreams, format version 9) for +0.00 and +0.02 dB, and frames at
#: quality 95 lost 0.10 dB by it. Where the texture holds anything (the logo +2.45 dB for 40 %
#: more bytes, 5 dB per doubling; photos 6-11 dB per doubling even at quality 1) it stays.
DETAIL_MIN_SLOPE = 1.0


def worth_its_bytes(ref_mse: float, ref_bytes: int, mse: float, nbytes: int, slope: float) -> bool:
    """Whether an encoding of ``nbytes`` bytes at ``mse`` (scale 1) is the better trade against one
    of ``ref_bytes`` at ``ref_mse``: its PSNR at least ``slope`` dB higher per doubling of the
    bytes (a smaller file: at most ``slope`` dB lower per halving). Against an exact reference
    (MSE 0) nothing is."""
    gain = metrics.psnr_of_mse(mse) - metrics.psnr_of_mse(ref_mse)
    return bool(gain >= slope * np.log2(max(nbytes, 1) / max(ref_bytes, 1)))


def detail_pays(base_mse: float, mse: float, base_bytes: int, nbytes: int) -> bool:
    """Whether a detail layer that takes the file from ``base_bytes`` to ``nbytes`` and the error
    from ``base_mse`` to ``mse`` (scale 1) is worth its bytes: at least :data:`DETAIL_MIN_SLOPE`
    dB per doubling of the file (:func:`worth_its_bytes`). A picture the base already draws
    exactly (MSE 0) needs none."""
    return worth_its_bytes(base_mse, base_bytes, mse, nbytes, DETAIL_MIN_SLOPE)


def _stamped(model, quality: int):
    """``model`` with the quality it was made at recorded in its params (``extra["quality"]``; ``tpsv info``)."""
    return replace(model, params=replace(model.params, extra={**model.params.extra, "quality": int(quality)}))


def encode_quality(
    rgb: np.ndarray,
    labels: np.ndarray | None = None,
    *,
    quality: int | None = None,
    target_psnr: float | None = None,
    max_bytes: int | None = None,
    detail: bool = True,
    seed: int = 0,
    params: Params | None = None,
    device: str = "cpu",
    outlines: str = "fitted",
    alpha: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> VectorizeResult:
    """Vectorise at a quality, or at the lowest quality that reaches a PSNR, or the highest within a size.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
        Label map; segmented automatically when absent.
    quality : int, optional
        1-100 (default :data:`DEFAULT_QUALITY` unless a target is given).
    target_psnr : float, optional
        The lowest quality whose PSNR (scale 1, as decoded) is at least this;
        the highest quality when none reaches it (``result.reached`` False).
    max_bytes : int, optional
        The highest quality whose file is at most this many bytes
        (:class:`TpsvError` when even quality 1 is larger).
    detail : bool
        With the texture detail layer (else the pure vector image).
    seed : int
        Seed of the automatic segmentation.
    params : Params, optional
        Kernel size and smoothing (default :func:`scheme_params`).
    device : str
        Warp device of the renders.
    outlines : {'fitted', 'traced'}
        As :func:`tpsv.encode.vectorize.vectorize`.
    alpha : ndarray (H, W) float in [0, 1], optional
        Opacity of an RGBA input, as :func:`tpsv.encode.vectorize.vectorize`
        (PSNR and the targets are then of the colours :func:`tpsv.encode.alpha.straight` encodes).
    progress : callable(done, total), optional
        Called after the geometry and after each encoding tried (a search for
        a target tries up to :data:`MAX_TRIALS`).

    Returns
    -------
    VectorizeResult
        With ``quality`` and ``reached`` set.
    """
    t0 = time.perf_counter()
    if sum(v is not None for v in (quality, target_psnr, max_bytes)) > 1:
        raise TpsvError("give one of quality, target PSNR and maximum bytes")
    if target_psnr is not None and not np.isfinite(target_psnr):
        raise TpsvError(f"target PSNR {target_psnr} is not a finite number")
    if max_bytes is not None and int(max_bytes) < 1:
        raise TpsvError(f"maximum bytes {max_bytes} is not positive")
    if quality is not None:
        quality = check_quality(quality)
    total = progress_steps(target_psnr, max_bytes)
    report = progress or (lambda done, total: None)
    rgb, geometry = alpha_geometry(rgb, alpha, labels, seed, outlines)
    report(1, total)

    def make_trials(geometry):
        return Trials(rgb, geometry, params or scheme_params(), detail, device,
                      tried=lambda n: report(min(1 + n, total - 1), total))

    trials = make_trials(geometry)
    if detail and labels is None and alpha is None:
        trials = fewer_regions(trials, make_trials, seed, outlines)
    reached = True
    workers = 1
    if detail and (target_psnr is not None or max_bytes is not None):
        # only the texture is coded again for each quality: several at once, the base made first
        workers = search_workers(rgb.shape[0] * rgb.shape[1])
        trials.vector_base()
    if target_psnr is not None:
        q = _lowest(lambda k: metrics.psnr_of_mse(trials(k)[2]) >= target_psnr, workers)
        reached = q is not None
        q = MAX_QUALITY if q is None else q
    elif max_bytes is not None:
        q = _highest(lambda k: len(trials(k)[0]) <= int(max_bytes), workers)
        if q is None:
            raise TpsvError(f"no quality fits in {int(max_bytes)} bytes: the smallest file is "
                            f"{len(trials(MIN_QUALITY)[0])} bytes (quality 1)")
    else:
        q = DEFAULT_QUALITY if quality is None else quality
    data, model, mse = trials(q)
    report(total, total)
    return VectorizeResult(model=model, data=data, psnr=metrics.psnr_of_mse(mse), mse=mse, seconds=time.perf_counter() - t0,
                           history=[(k, len(v[0]), metrics.psnr_of_mse(v[2])) for k, v in sorted(trials.done.items())],
                           quality=q, reached=reached)


#: Pictures of at most this many pixels (about 724 x 724), segmented automatically, are also tried
#: with fewer regions (:func:`fewer_regions`): there the outlines and the false borders of a
#: segmentation can weigh more than they buy. Until 2026-11-27 only pictures of at most 2^17
#: pixels in regions of fewer than 4096 pixels on average were tried (small photos, where outlines
#: weigh most); photos of 400-512 px gained as much: BD-PSNR over qualities 20-95 of the coarser
#: regions against their own, rocket +1.07 dB (9 -> 3 regions: the sky's gradient cut by borders
#: no edge explains), coffee +0.19, astronaut +0.16, chelsea 0.00 (the same 5), and photos the
#: encoder never saw (scikit-image's, at 400 px unless named) retina +1.41, immunohistochemistry
#: +1.40, coins (384 x 303) +1.19, camera (512 x 512) +0.36, hubble +0.26, astronaut +0.23,
#: cat 0.00 (docs/DESIGN.md, "Automatic regions"). The try costs a second geometry and encoding
#: (a 512 x 512 photo's ``vectorize`` 2.7-2.9 -> 4.8-4.9 s on 2 cores) where the coarser
#: segmentation has fewer regions, a second segmentation (0.2-0.3 s) where it has not. At a
#: megapixel (retina at 1024 x 1024, hubble at 1000 x 872) the coarser counts found the same
#: regions: larger photos are not tried.
FEW_REGIONS_PIXELS = 1 << 19
#: How much lower (dB, at scale 1 and the default quality) the smaller file with fewer regions may
#: read, per halving of the file: a quarter of what the detail layer buys per doubling on photos
#: (6-11 dB at quality 75), so that the fewer regions are taken only where they are clearly the
#: better trade. A fixed 0.1 dB (before 2026-11-27, night) turned on noise: coffee at 160 px, its
#: own borders smoothed, read 0.21 dB higher with 7 regions than with 4 for an 11 % larger file.
FEW_REGIONS_SLOPE = 2.0


def fewer_regions(trials: Trials, make_trials: Callable, seed: int = 0, outlines: str = "fitted") -> Trials:
    """``trials``, or, for a picture of at most :data:`FEW_REGIONS_PIXELS` pixels, those of the same
    picture segmented into fewer regions (:data:`tpsv.geometry.segment.FEW_COUNTS`) when at the
    default quality these make the better trade (:func:`fewer_pays`).

    A small photo gets about as many regions as a large one, and its outlines then hold much of its
    file: chelsea area-downscaled 4x (112 x 75) took 9 regions, whose outline vertices were 1011
    of the 2640 bytes at quality 20. With 3-4 regions, BD-PSNR over qualities 20-95 rose by 3.3 dB
    (chelsea at a quarter), 4.6 dB (rocket at a quarter) and 2.6 dB (rocket at half size: 7159 ->
    5358 bytes at quality 75, +0.09 dB; docs/DESIGN.md, "Automatic regions"). At full size a
    segmentation that cuts a gradient along borders no edge explains (rocket's sky: 9 regions, 3
    with the fewer counts) pays for outlines and soft borders the texture then corrects: rocket
    17392 -> 15561 bytes at quality 75, +0.08 dB. Where the regions hold edges the texture cannot
    (coins' coins at a quarter, drawn shapes) the coarser file reads lower and the regions stay.
    One quality decides, so bytes and PSNR still rise with the quality.

    Parameters
    ----------
    trials : Trials
        The encodings of the picture's own segmentation.
    make_trials : callable(Geometry) -> Trials
        Trials of the same picture and settings on another geometry.
    seed, outlines
        As :func:`tpsv.encode.vectorize.image_geometry`.
    """
    rgb = trials.rgb
    pixels = rgb.shape[0] * rgb.shape[1]
    if pixels > FEW_REGIONS_PIXELS:
        return trials
    few = label_map(rgb, None, seed, counts=segment.FEW_COUNTS)
    if int(few.max()) + 1 >= len(trials.geometry.regions):
        return trials
    # the picture's own encoding at the default quality is made on a host thread beside the coarser
    # geometry and its encoding (the same files: each is made as it would be alone)
    own = host_pool("fewer", 1).submit(trials, DEFAULT_QUALITY) if host_cores() > 1 else None
    try:
        coarse = make_trials(image_geometry(rgb, few, seed, outlines))
        fewer = len(coarse.geometry.regions) < len(trials.geometry.regions)
        if fewer:
            data_b, _, mse_b = coarse(DEFAULT_QUALITY)
    finally:
        if own is not None:
            own.result()  # (kept by trials; an error there is raised here)
    if not fewer:
        return trials
    data_a, _, mse_a = trials(DEFAULT_QUALITY)
    return coarse if fewer_pays(len(data_a), mse_a, len(data_b), mse_b) else trials


def fewer_pays(own_bytes: int, own_mse: float, fewer_bytes: int, fewer_mse: float) -> bool:
    """Whether the encoding with fewer regions is the better one: a smaller file that reads at most
    :data:`FEW_REGIONS_SLOPE` dB lower per halving of the file (scale 1, the default quality;
    :func:`worth_its_bytes`)."""
    return fewer_bytes < own_bytes and worth_its_bytes(own_mse, own_bytes, fewer_mse, fewer_bytes, FEW_REGIONS_SLOPE)


#: Most encodings a search for a target PSNR or size tries (bisection of 1..100, after the ends).
MAX_TRIALS = 9
#: Most textures a search codes at once (each on its own thread: OpenCV's AVIF writer codes one
#: image on one thread), and the memory the ones beyond the first may add (bytes), each about
#: :data:`SEARCH_BYTES_PER_PIXEL` (libaom's encoder, the coded texels and the picture: measured
#: 190 B a pixel on the 512x512 astronaut and 167 on it resized to 1448x1448).
SEARCH_WORKERS = 8
SEARCH_MEMORY = 1 << 29
SEARCH_BYTES_PER_PIXEL = 192


def search_workers(pixels: int) -> int:
    """Qualities a search for a target tries at once for a picture of ``pixels``: the cores this
    process may use (:func:`tpsv.threads.host_cores`), at most :data:`SEARCH_WORKERS`, and no
    more than the first and as many again as :data:`SEARCH_MEMORY` holds (one for photos of
    more than about 2.8 megapixels)."""
    by_memory = 1 + SEARCH_MEMORY // max(1, SEARCH_BYTES_PER_PIXEL * int(pixels))
    return int(max(1, min(host_cores(), SEARCH_WORKERS, by_memory)))


def progress_steps(target_psnr=None, max_bytes=None) -> int:
    """Steps :func:`encode_quality` reports to ``progress``: the geometry, then one encoding, or up to
    :data:`MAX_TRIALS` when searching for a PSNR or a size (a search on several workers may try
    more, in fewer rounds: the count stops one short of the end until it is done)."""
    return 1 + (MAX_TRIALS if target_psnr is not None or max_bytes is not None else 1)


def _lowest(ok, workers: int = 1) -> int | None:
    """The lowest quality for which ``ok`` holds (assumed monotonic), or None.

    Each round tries up to ``workers`` qualities at once, evenly spaced in the
    interval still open (``ok`` is then called from that many threads); one
    worker is a bisection. The top quality, the slowest to code (astronaut's
    texture: 5.8 s at quality 100 against 1.7 s at 75), is tried only when no
    lower one holds: the same answer as trying it first.
    """
    lo, hi = MIN_QUALITY - 1, MAX_QUALITY  # ok(hi) taken as true until tried; ok(lo) as false
    while hi - lo > 1:
        k = min(max(1, int(workers)), hi - lo - 1)
        points = sorted({lo + (j + 1) * (hi - lo) // (k + 1) for j in range(k)})
        if k > 1:
            results = list(host_pool("search", int(workers)).map(ok, points))
        else:
            results = [ok(q) for q in points]
        good = [q for q, r in zip(points, results) if r]
        hi = min(good, default=hi)
        lo = max([q for q, r in zip(points, results) if not r and q < hi], default=lo)
    if hi == MAX_QUALITY and not ok(MAX_QUALITY):
        return None
    return hi


def _highest(ok, workers: int = 1) -> int | None:
    """The highest quality for which ``ok`` holds (assumed monotonic: true up to a point), or None
    (``workers`` as :func:`_lowest`)."""
    if not ok(MIN_QUALITY):
        return None
    first_bad = _lowest(lambda k: not ok(k), workers)
    return MAX_QUALITY if first_bad is None else first_bad - 1
