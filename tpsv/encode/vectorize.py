"""Image (+ label map) -> hybrid vector image.

Stages
------
:func:`vectorize` runs these in order; each is a function of its own:

1. :func:`label_map`: the label map (segmented automatically when absent);
2. :func:`build_geometry`: regions (outline + Hermite patch) and the pixel
   maps at scale 1, as a :class:`Geometry` (threshold-independent, computed once);
3. :func:`start_thresholds`: ``(T0_canny, T0_super)`` of paper VI-A;
4. :meth:`Candidates.model` (:func:`make_model`): the features of one pair of
   thresholds, in the patches' ``(S, T)``;
5. :meth:`Candidates.fitted_colours`: their colours fitted to the image;
6. :meth:`Candidates.evaluate`: encoded, decoded and rendered as a user of
   the file sees it (an :class:`Evaluation`);
7. :func:`search_thresholds`: the Monte Carlo search over stages 4-6;
8. :func:`finish`: the best thresholds fitted on every pixel, compared with
   the start, and the colour quantisation steps chosen.

Schemes
-------
Two feature schemes share the regions, the TPS and the file format. The
scheme is a switch of :class:`Params` (``extra["scheme"] = "paper"``; absent
means the default) and of the command line (``tpsv vectorize --plain``).

``"tpsv"`` (default), built for compression efficiency (the efficiency
``w = 1 / (E C)`` the search maximises, and PSNR against JPEG at the same
byte count). Every choice below was measured on the four samples:

- gradation features on a regular lattice of each region's ``(S, T)``
  square whose spacing adapts per region to ``T_super``
  (:class:`tpsv.encode.features.LatticeGradation`), one feature per cell with the
  cell's mean colour. It replaced the superpixel-boundary features, which
  cost about 3 bytes per feature (irregular positions) and, sampled on cell
  borders, leave cell interiors to extrapolation;
- curvilinear pairs on Canny edges, one per ``CURVE_STEP`` x ``CURVE_STEP``
  block (the strongest edge pixel), lattice cells holding one subdivided
  to ``EDGE_PX`` (:data:`tpsv.encode.features.EDGE_PX`). At the efficiency optimum
  the search mostly raises ``T_canny`` above every edge: a pair costs two
  features and the fitted lattice already follows most edges;
- feature colours fitted by least squares to the image (:mod:`tpsv.encode.fit`):
  at equal features +0.5 to +1 dB over the cells' mean colours on lattices,
  +1.5 to +3.5 dB with edge pairs, +2 to +8 dB over colours sampled at one
  pixel (the paper scheme's). During the search on every
  ``SEARCH_FIT_SUB``-th pixel per axis, for the result on every pixel;
- features of a region in scan order (``T``, then ``S``; the halves of a
  pair kept together) so that the delta coding of the file sees neighbours;
- positions stored at ``st_steps = 2`` steps per pixel (the fit absorbs the
  rounding: 3-10 % fewer bytes, PSNR within 0.05 dB of 16 steps), colours at
  ``l_step = ab_step = 8`` during the search, the steps of the result chosen
  from :data:`STEP_CHOICES` by ``w`` after it (on photos coarser colours
  cost little error next to the representation's own and save up to half
  the bytes; on smooth gradients the finest steps, 1 and 1, are worth their
  bytes: the synthetic shapes of the edge table gain 2.4 dB at 8x for 8-11 %
  more bytes, and without them exactly linear fills come back blotchy);
- ``K = 32`` features per kernel and ``overlap = 0.25`` (the same PSNR as
  64 / 0.5 within 0.1 dB, 3.5 times fewer products per pixel).

``"paper"``: the paper's plain scheme as first implemented (curvilinear pairs
on every Canny pixel, gradation features on the boundaries of adaptive SLIC
superpixels, colours sampled from the image, K = 64, ``overlap = 0.5``,
finest quantisation, the paper's search).

Search
------
The Monte Carlo search of :mod:`tpsv.encode.search` maximises ``w = 1 / (E C)``
over ``(T_canny, T_super)`` from the VI-A start. For the ``"tpsv"`` scheme its
mutations are at least as wide as the start (``min_width``; the paper's
``U(-|T_best|, +|T_best|)`` sticks once ``T_super`` reaches its floor) and
each candidate is fitted on every ``SEARCH_FIT_SUB``-th pixel with
``SEARCH_FIT_ITERATIONS`` iterations; candidates with identical features share
their fit and render. The best is then fitted on every pixel, compared with
the start fitted so too (unless the search found the start ``START_MARGIN``
times less efficient; the lattice fit's misjudgement measured at most 1.3
times), and its colour steps chosen by ``w``. So the result is at least as
efficient as ``--no-search`` (which keeps the default steps), unless the
lattice fit misjudged the start by more than ``START_MARGIN``.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field, replace
from typing import Callable, NamedTuple

import numpy as np

from .. import codec, metrics, tps
from ..errors import TpsvError
from ..geometry import curves, segment
from ..geometry.edgewidth import edge_width_map, soften_map
from ..geometry.regions import build_regions
from ..geometry.subpixel import own_side_colours
from ..model import BlurMap, Features, Model, Params, Region
from ..rendering.pixelmap import PixelMap
from ..rendering.raster import render, shade
from . import search as selection
from .alpha import flatten, straight, transparent_mask, with_transparent_label
from .features import DEDUP_PX, LATTICE_PX, FeatureExtractor, FeatureSet, LatticeGradation, drop_near
from .fit import fit_colors, target_for_fit
from .memory import give_back

#: Feature schemes (see the module doc).
SCHEMES = ("tpsv", "paper")
DEFAULT_SCHEME = "tpsv"
#: Curvilinear subsampling of the "tpsv" scheme (one pair per block of this side).
CURVE_STEP = 2
#: Colour fit during the search (every SEARCH_FIT_SUB-th pixel per axis, few
#: iterations) and for the final model (every pixel).
SEARCH_FIT_SUB = 2
SEARCH_FIT_ITERATIONS = 2
FINAL_FIT_ITERATIONS = 10
#: The start is fitted on every pixel too unless the search found it this many
#: times less efficient than its best (see :func:`finish`).
START_MARGIN = 1.5
#: Colour quantisation steps (l_step, ab_step) the "tpsv" scheme chooses from
#: after the search, by the same efficiency w (photos take the coarse ones,
#: smooth gradients the fine ones). No a,b step above 8: the search took 12/16
#: for astronaut (15029 B, 25.49 dB), whose face then showed pink and yellow
#: blotches at 4x; with 16/8 it is 16572 B, 25.73 dB, and no blotches.
STEP_CHOICES = ((1, 1), (1, 2), (2, 4), (4, 4), (4, 8), (8, 4), (8, 8), (16, 8))
#: Params of each scheme that differ from the Params defaults (the "tpsv" scheme's).
SCHEME_PARAMS = {
    "tpsv": {},
    "paper": dict(kernel_size=64, overlap=0.5, st_steps=16, l_step=1, ab_step=1),
}


def scheme_of(params: Params) -> str:
    """The feature scheme a Params asks for (``extra["scheme"]``, default ``"tpsv"``)."""
    scheme = params.extra.get("scheme", DEFAULT_SCHEME) if isinstance(params.extra, dict) else DEFAULT_SCHEME
    if scheme not in SCHEMES:
        raise TpsvError(f"unknown feature scheme {scheme!r} (known: {', '.join(SCHEMES)})")
    return scheme


def scheme_params(scheme: str = DEFAULT_SCHEME, **overrides) -> Params:
    """Params with a scheme's defaults; ``overrides`` are Params fields (None: the default).

    ``extra["scheme"]`` is set only for a non-default scheme (the default
    scheme's files carry no scheme entry).
    """
    if scheme not in SCHEMES:
        raise TpsvError(f"unknown feature scheme {scheme!r} (known: {', '.join(SCHEMES)})")
    extra = dict(overrides.pop("extra", None) or {})
    if scheme != DEFAULT_SCHEME:
        extra["scheme"] = scheme
    fields = {**SCHEME_PARAMS[scheme], **{k: v for k, v in overrides.items() if v is not None}}
    return Params(**fields, extra=extra)


#: Pixels whose own region covers less than this share are left out of the colour fit.
MIXED_ALPHA = 0.9


@dataclass
class Geometry:
    """The threshold-independent part of a vectorisation, computed once.

    Attributes
    ----------
    regions : list of Region
    index : ndarray (H, W) int32
        Region index of every pixel, as the renderer sees it at scale 1 (from the
        outlines), so each feature takes its colour from the region it belongs to.
    st : ndarray (H, W, 2) float32, optional
        ``(S, T)`` of every pixel in its region's patch, as the renderer computes
        it at scale 1 (:meth:`pixel_st` fills it on first use).
    blur : ndarray (n, 3) float64
        Edge widths of the borders (``Model.blur``).
    blur_map : BlurMap or None
        Their widths point by point (``Model.blur_map``).
    curves : bool
        The outlines are drawn as curves (``Model.curves``: fitted outlines are, traced ones not).
    """

    regions: list[Region]
    index: np.ndarray
    st: np.ndarray | None = None
    blur: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    curves: bool = False
    blur_map: BlurMap | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def pixel_st(self, device: str = "cpu") -> np.ndarray:
        """``(S, T)`` of every pixel at scale 1, as the renderer computes it (cached).

        Parameters
        ----------
        device : str
            Warp device for the inverse patch map (first call only).

        Returns
        -------
        ndarray (H, W, 2) float32
        """
        if self.st is None:
            h, w = self.index.shape
            self.st = PixelMap.build(self.regions, self.index, (w, h), device).st
        return self.st

    def _cached(self, kind: str, image: np.ndarray, extra: tuple, make):
        key = (kind, id(image)) + extra
        hit = self._cache.get(key)
        if hit is None or hit[0] is not image:  # the image is kept so its id is not reused
            hit = (image, make())
            self._cache[key] = hit
        return hit[1]

    def fit_target(self, rgb: np.ndarray, sub: int = 1):
        """The :class:`tpsv.encode.fit.FitTarget` of ``rgb`` on every ``sub``-th pixel, or past
        ``fit.GROUP_PIXELS`` pixels its :class:`~tpsv.encode.fit.TargetSource` (cached per image and ``sub``)."""
        def make():
            mixed = self.mixed_pixels()
            colours, ok = own_side_colours(rgb, self.index, mixed, near=self.border_mix().pixels)
            return target_for_fit(rgb, self.index, self.pixel_st(), sub, skip=mixed[~ok],
                                  replace=(mixed[ok], colours[ok]))

        return self._cached("fit", rgb, (int(sub),), make)

    def border_mix(self):
        """The anti-aliased border pixels at scale 1, as the renderer finds them (:mod:`tpsv.gpu.coverage`; cached)."""
        if "borders" not in self._cache:
            from types import SimpleNamespace

            from ..gpu.coverage import DeviceBorders

            h, w = self.index.shape
            shape = SimpleNamespace(regions=self.regions, width=w, height=h, blur=self.blur,
                                    blur_map=self.blur_map, curves=self.curves)  # all it reads
            self._cache["borders"] = DeviceBorders(shape, w, h).mix(self.index)
        return self._cache["borders"]

    def mixed_pixels(self) -> np.ndarray:
        """Flat indices of the pixels a border crosses at scale 1 (the renderer mixes them)."""
        mix = self.border_mix()
        return mix.pixels[mix.own < MIXED_ALPHA]

    def lattice(self, lab: np.ndarray) -> LatticeGradation:
        """The gradation lattices of the image of Lab colours ``lab`` (cached per image)."""
        return self._cached(
            "lattice", lab, (),
            lambda: LatticeGradation(lab, self.index, self.pixel_st(), [r.patch for r in self.regions]),
        )

    def forget(self, *kinds: str) -> None:
        """Drop cached per-pixel data nobody will ask for again (each is made again if asked).

        Parameters
        ----------
        *kinds : str
            ``"lattice"`` (:meth:`lattice`, and the Lab image it was keyed
            on), ``"fit"`` (:meth:`fit_target`), ``"borders"``
            (:meth:`border_mix`), ``"st"`` (:meth:`pixel_st`).
        """
        if "st" in kinds:
            self.st = None
        self._cache = {k: v for k, v in self._cache.items() if (k if isinstance(k, str) else k[0]) not in kinds}


@dataclass
class VectorizeResult:
    """A model and the figures of how it was made."""

    model: Model
    data: bytes
    psnr: float
    mse: float
    seconds: float
    history: list = field(default_factory=list)
    #: The quality (1-100) of a rate-controlled encoding (``tpsv.encode.rate``), else None.
    quality: int | None = None
    #: False when a PSNR target was not reached (the result is the closest).
    reached: bool = True


class Evaluation(NamedTuple):
    """A model as a user of its file sees it: the file, the decoded model, the MSE of its render at scale 1."""

    data: bytes
    model: Model
    mse: float

    def efficiency(self) -> float:
        """The paper's ``w = 1 / (E C)`` of this file and error."""
        return metrics.efficiency(self.mse, len(self.data), self.model.width, self.model.height)


# ----------------------------------------------------------------------------- stages


def label_map(rgb: np.ndarray, labels: np.ndarray | None, seed: int = 0,
              counts: tuple[int, int] = segment.AUTO_COUNTS) -> np.ndarray:
    """Stage 1: the label map, segmented automatically when absent.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
    seed : int
        Seed of the automatic segmentation.
    counts : (int, int)
        The region counts the automatic segmentation chooses from.

    Returns
    -------
    ndarray (H, W) int

    Raises
    ------
    TpsvError
        ``labels`` is not the image's size.
    """
    h, w = rgb.shape[:2]
    if labels is None:
        return segment.segment_auto(rgb, seed=seed, counts=counts)
    if labels.shape != (h, w):
        raise TpsvError(f"label map is {labels.shape[1]}x{labels.shape[0]} but the image is {w}x{h}")
    return labels


def build_geometry(labels: np.ndarray, rgb: np.ndarray | None = None) -> Geometry:
    """Stage 2: regions with outlines and patches from a label map (:func:`tpsv.geometry.regions.build_regions`).

    Parameters
    ----------
    labels : ndarray (H, W) int
        Label map.
    rgb : ndarray (H, W, 3) float32, optional
        The image: outlines fitted to its edges at sub-pixel precision, and
        the borders' edge widths read from it (without it: outlines along the
        label map's pixel edges, sharp).

    Returns
    -------
    Geometry

    Raises
    ------
    TpsvError
        More connected regions than a file holds (``tpsv.codec.MAX_REGIONS``).
    """
    regions, index = build_regions(labels, rgb, max_regions=codec.MAX_REGIONS)
    if rgb is None:
        return Geometry(regions=regions, index=index)
    h, w = index.shape
    blur, blur_map = edge_width_map(rgb, regions, index, drawn=curves.drawn_regions(regions, w, h, curves.DRAWN_TOL))
    return Geometry(regions=regions, index=index, blur=blur, blur_map=blur_map, curves=True)


def soften_false_steps(rgb: np.ndarray, geometry: Geometry, shown: np.ndarray) -> BlurMap | None:
    """The geometry's blur map with the borders where the vector image steps as the photo does not
    softened (:func:`tpsv.geometry.edgewidth.soften_map`), or None when that changes nothing (or the
    geometry has no map).

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
        The colours the model is fitted to.
    geometry : Geometry
    shown : ndarray (H, W, 3)
        The vector image (before its detail layer) rendered at scale 1.
    """
    if geometry.blur_map is None:
        return None
    h, w = geometry.index.shape
    return soften_map(geometry.blur_map, rgb, shown, geometry.regions, geometry.index,
                      drawn=curves.drawn_regions(geometry.regions, w, h, curves.DRAWN_TOL))


def image_geometry(rgb: np.ndarray, labels: np.ndarray | None, seed: int = 0, outlines: str = "fitted",
                   transparent: np.ndarray | None = None) -> Geometry:
    """Stages 1-2 for a photo: its label map (segmented when absent), then its regions.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
    seed : int
        Seed of the automatic segmentation.
    outlines : {'fitted', 'traced'}
        Outlines fitted to the photo's edges (with edge widths), or along the
        label map's pixel edges.
    transparent : ndarray (H, W) bool, optional
        The transparent part of an RGBA input (:mod:`tpsv.encode.alpha`;
        ``rgb`` is then the flattened picture): it gets a label of its own,
        and its regions are marked transparent.

    Returns
    -------
    Geometry
    """
    if outlines not in ("fitted", "traced"):
        raise TpsvError(f"outlines {outlines!r} is not fitted or traced")
    labels = label_map(rgb, labels, seed)
    give_back()  # the segmentation's temporaries (tpsv.encode.memory)
    if transparent is not None:
        labels, clear = with_transparent_label(labels, transparent)
    geometry = build_geometry(labels, rgb if outlines == "fitted" else None)
    give_back()
    if transparent is not None:
        for region in geometry.regions:
            region.transparent = region.label == clear
    return geometry


def alpha_geometry(rgb: np.ndarray, alpha: np.ndarray | None, labels: np.ndarray | None, seed: int = 0,
                   outlines: str = "fitted") -> tuple[np.ndarray, Geometry]:
    """:func:`image_geometry` of a photo that may have transparency; returns ``(colours to encode, geometry)``.

    With a transparent part (:mod:`tpsv.encode.alpha`), the geometry comes
    from the picture flattened onto a contrasting backdrop and the colours to
    encode are the straight ones; the label map, when segmented here, from
    the colours (the backdrop's ramp would make slivers along the edge).
    """
    transparent = transparent_mask(alpha)
    if transparent is None:
        return rgb, image_geometry(rgb, labels, seed, outlines)
    shape_rgb, rgb = flatten(rgb, alpha, transparent), straight(rgb, alpha, transparent)
    if labels is None:
        labels = label_map(rgb, None, seed)
    return rgb, image_geometry(shape_rgb, labels, seed, outlines, transparent)


def start_thresholds(
    rgb: np.ndarray, geometry: Geometry, t_canny: float | None = None, t_super: float | None = None
) -> tuple[float, float]:
    """Stage 3: the search's start ``(T0_canny, T0_super)`` (paper VI-A); a given threshold is kept.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    geometry : Geometry
    t_canny, t_super : float, optional
        Thresholds fixed by the caller.

    Returns
    -------
    (float, float)
    """
    c0, s0 = selection.initial_thresholds(rgb, geometry.index)
    return (float(t_canny) if t_canny is not None else c0, float(t_super) if t_super is not None else s0)


def scan_order(region: np.ndarray, st: np.ndarray, pair: np.ndarray) -> np.ndarray:
    """Order of features by region, then ``T``, then ``S``, the halves of a pair in one region adjacent.

    A pair whose halves lie in one region sorts at its first half's position,
    the second half right after it; a pair across a region border is two
    ordinary features.
    """
    n = region.shape[0]
    idx = np.arange(n)
    lead = idx.copy()
    same = (pair >= 0) & (region[np.maximum(pair, 0)] == region)
    lead[same] = np.minimum(idx[same], pair[same])
    second = (same & (idx != lead)).astype(np.int64)
    return np.lexsort((second, lead, st[lead, 0], st[lead, 1], region))


def make_model(
    rgb: np.ndarray,
    geometry: Geometry,
    extractor: FeatureExtractor,
    params: Params,
    *,
    fit: bool = True,
    fit_sub: int = 1,
    fit_iterations: int = 6,
    max_spacing: np.ndarray | None = None,
    standalone: bool = False,
    min_spacing: float = LATTICE_PX[0],
) -> Model:
    """Stage 4: the model for one pair of thresholds (``params.t_canny``, ``params.t_super``).

    The scheme comes from ``params`` (:func:`scheme_of`). With the ``"tpsv"``
    scheme features are in scan order (:func:`scan_order`) of their positions
    as the file stores them, and with ``fit`` their colours are fitted to
    ``rgb`` (:mod:`tpsv.encode.fit`) after the positions are quantised.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    geometry : Geometry
    extractor : FeatureExtractor
        Of ``rgb`` and ``geometry.index``.
    params : Params
    fit : bool
    fit_sub, fit_iterations : int
        Pixel lattice and iterations of the fit.
    max_spacing : ndarray (n_regions,), optional
        The coarsest lattice spacing (pixels) each region may get (``"tpsv"`` scheme).
    standalone : bool
        Only lattices that give a region 3 non-collinear features by themselves
        (``LatticeGradation.region_spacing``), as the pure vector quality ladder
        asks: a coarser lattice padded with anchors made a lower quality a larger
        file. The threshold modes and the detail layer's base keep the coarsest
        lattice with its anchors, which hold small shapes' colour up to their
        borders (docs/DESIGN.md, "Detail layer and rate control").
    min_spacing : float
        The finest lattice spacing (pixels) a region may get (``"tpsv"`` scheme):
        only the pure vector quality ladder goes below 4
        (:data:`tpsv.encode.features.FINE_LATTICE_PX`).

    Returns
    -------
    Model
    """
    h, w = rgb.shape[:2]
    patches = [r.patch for r in geometry.regions]
    if scheme_of(params) == "paper":
        feats = extractor.extract(params.t_canny, params.t_super).in_patch_space(patches)
    else:
        feats = tpsv_features(geometry, extractor, params.t_canny, params.t_super,
                              max_spacing, standalone, min_spacing).in_patch_space(patches)
        # scan order of the positions as stored (quant: round(S * (2^b - 1)))
        q = 2 ** codec.quant.st_bits_for(w, h, params.st_steps) - 1
        feats = feats.subset(scan_order(feats.region, np.rint(np.clip(feats.st, 0.0, 1.0) * q), feats.pair))
    model = Model(width=w, height=h, regions=geometry.regions, features=feats, params=params, blur=geometry.blur,
                  curves=geometry.curves, blur_map=geometry.blur_map)
    return fit_model(rgb, geometry, model, fit_sub, fit_iterations) if fit else model


def fit_model(rgb: np.ndarray, geometry: Geometry, model: Model, fit_sub: int = 1, fit_iterations: int = 6) -> Model:
    """The fit of :func:`make_model` (``fit=True``) on a model it made with ``fit=False``.

    With the ``"tpsv"`` scheme the positions are quantised as stored and the
    colours fitted to ``rgb`` (:mod:`tpsv.encode.fit`); a ``"paper"`` model,
    or one without features, is returned as is.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    geometry : Geometry
    model : Model
    fit_sub, fit_iterations : int
        Pixel lattice and iterations of the fit.

    Returns
    -------
    Model
    """
    if scheme_of(model.params) == "paper" or not len(model.features):
        return model
    model = codec.quantize(model)
    target = geometry.fit_target(rgb, fit_sub)
    give_back()  # the target's temporaries: the fit's threads take memory of their own
    model, _ = fit_colors(model, target=target, iterations=fit_iterations)
    return model


def tpsv_features(geometry: Geometry, extractor: FeatureExtractor, t_canny: float, t_super: float,
                  max_spacing: np.ndarray | None = None, standalone: bool = False,
                  min_spacing: float = LATTICE_PX[0]) -> FeatureSet:
    """Features of the ``"tpsv"`` scheme (module doc), in pixel space with ``(S, T)`` where known.

    Curvilinear pairs (one per ``CURVE_STEP`` block), the gradation lattice
    (cells holding an edge pixel subdivided; each region's spacing at most its
    ``max_spacing``, pixels, when given; ``standalone`` and ``min_spacing``: as
    ``LatticeGradation.region_spacing``) without its features next to a pair,
    and the anchors regions still need.
    """
    w, h = extractor.w, extractor.h
    lattice = geometry.lattice(extractor.lab)  # before the gradient of the curvilinear features is made
    cur = extractor.curvilinear(t_canny, step=CURVE_STEP)
    edge = None
    if len(cur):
        cx = np.clip(np.floor(cur.xy[:, 0]).astype(np.int64), 0, w - 1)
        cy = np.clip(np.floor(cur.xy[:, 1]).astype(np.int64), 0, h - 1)
        edge = np.unique(cy * w + cx)
    grad = drop_near(lattice.features(t_super, edge, max_spacing, standalone, min_spacing), cur, DEDUP_PX, (w, h))
    both = FeatureSet.concat([cur, grad])
    return FeatureSet.concat([both, extractor.anchors(both)])


def evaluate(
    rgb: np.ndarray, model: Model, device: str = "cpu", kernels=None, maps: tuple | None = None
) -> tuple[bytes, Model, float]:
    """Encode, decode and render a model at scale 1; return (bytes, decoded model, MSE).

    The render is of the decoded (quantised) model, so the error is the one a
    user of the file sees.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float in [0, 1]
        The image the error is measured against.
    model : Model
    device : str
        Warp device.
    kernels : KernelSet, optional
        Grouped from a model with the same feature positions (its colours are
        replaced by the decoded ones, :func:`tpsv.tps.recolor`), to save the
        grouping.
    maps : (index, st, borders), optional
        The region index and ``(S, T)`` maps and the border pixels at scale 1
        of the decoded model's regions (``Geometry.index``,
        ``Geometry.pixel_st()``, ``Geometry.border_mix()`` when quantisation
        leaves the regions unchanged), to save computing them; then only
        render steps 3-5 run (:func:`tpsv.rendering.raster.shade`).

    Returns
    -------
    (bytes, Model, float)
        The file, the decoded model and the mean squared error of its render.
    """
    data = codec.encode(model)
    decoded = codec.decode(data)
    if kernels is not None:
        kernels = tps.recolor(kernels, decoded.features)
    if maps is None:
        out = render(decoded, device=device, kernels=kernels)
    else:
        out = shade(decoded, maps[0], maps[1], device=device, kernels=kernels, borders=maps[2])
    return data, decoded, metrics.mse(rgb, out)


def _signature(model: Model) -> tuple:
    """What determines a fitted model's colours and error: feature positions, kinds, pairs, regions."""
    f = model.features
    hsh = hashlib.sha1()
    for a in (f.region, f.st, f.kind, f.pair):
        hsh.update(np.ascontiguousarray(a).tobytes())
    p = model.params
    return (len(f), hsh.hexdigest(), p.kernel_size, p.overlap, p.smoothing, p.l_step, p.ab_step)


def _same_region(a: Region, b: Region) -> bool:
    return np.array_equal(a.patch.ctrl, b.patch.ctrl) and len(a.outline) == len(b.outline) and all(
        np.array_equal(x, y) for x, y in zip(a.outline, b.outline))


def stored_maps(geometry: Geometry) -> tuple | None:
    """The pixel maps ``(index, (S, T), borders)`` at scale 1 of the regions as the file stores them.

    ``geometry``'s own maps when quantisation leaves every region unchanged
    (then a render of a decoded model can reuse them), else None.
    """
    h, w = geometry.index.shape
    same = codec.quantize(Model(width=w, height=h, regions=geometry.regions, features=Features.empty(),
                                curves=geometry.curves))
    if all(_same_region(a, b) for a, b in zip(geometry.regions, same.regions)):
        return geometry.index, geometry.pixel_st(), geometry.border_mix()
    return None


def _best_steps(rgb: np.ndarray, model: Model, first: Evaluation, device: str, kernels=None, maps=None) -> Evaluation:
    """``evaluate`` of ``model`` with the quantisation steps of ``STEP_CHOICES`` giving the best w.

    ``first`` is the evaluation with the model's own steps (kept on ties).
    """
    best = first
    own = (model.params.l_step, model.params.ab_step)
    for ls, ab in STEP_CHOICES:
        if (ls, ab) == own:
            continue
        out = Evaluation(*evaluate(rgb, replace(model, params=replace(model.params, l_step=ls, ab_step=ab)),
                                   device, kernels, maps))
        if out.efficiency() > best.efficiency():
            best = out
    return best


class Candidates:
    """Stages 4-6 for any pair of thresholds of one image: features, colour fit, evaluation.

    Candidates whose features come out identical (e.g. two ``T_canny`` above
    every edge) share their fit and render; only the file (its params differ)
    is rebuilt.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    geometry : Geometry
    params : Params
        Everything but the thresholds, and the scheme.
    device : str
        Warp device of the renders.
    fit : bool
        Fit the colours (``"tpsv"`` scheme only).
    standalone : bool
        As :func:`make_model` (the pure vector quality ladder sets it).
    """

    def __init__(self, rgb: np.ndarray, geometry: Geometry, params: Params, *, device: str = "cpu", fit: bool = True,
                 standalone: bool = False):
        self.rgb = rgb
        self.standalone = standalone
        self.geometry = geometry
        self.params = params
        self.device = device
        self.scheme = scheme_of(params)
        self.fitted = fit and self.scheme != "paper"
        self.extractor = FeatureExtractor(rgb, geometry.index)
        self.maps = stored_maps(geometry) if self.fitted else None
        self._fits: dict = {}  # (final, signature) -> (fitted lab, kernels)
        self._done: dict = {}  # (final, steps, signature) -> (decoded lab, decoded params, mse)
        self._plain: dict = {}  # (t_canny, t_super, min_spacing) -> Evaluation, without fit

    def params_for(self, t_canny: float, t_super: float) -> Params:
        """The params of the candidate ``(t_canny, t_super)``."""
        return replace(self.params, t_canny=float(t_canny), t_super=float(t_super))

    def model(self, t_canny: float, t_super: float, min_spacing: float = LATTICE_PX[0]) -> Model:
        """Stage 4: the candidate's features with their unfitted colours (quantised as stored when fitted);
        ``min_spacing`` as :func:`make_model`."""
        model = make_model(self.rgb, self.geometry, self.extractor, self.params_for(t_canny, t_super), fit=False,
                           standalone=self.standalone, min_spacing=min_spacing)
        return codec.quantize(model) if self.fitted else model

    def fitted_colours(self, model: Model, final: bool) -> tuple:
        """Stage 5: ``(lab, kernels)`` fitted to the image: on every pixel (``final``) or the search's lattice.

        ``kernels`` is the grouping the fit used (None without features).
        """
        key = (final, _signature(model))
        if key not in self._fits:
            sub, its = (1, FINAL_FIT_ITERATIONS) if final else (SEARCH_FIT_SUB, SEARCH_FIT_ITERATIONS)
            ks = None
            if len(model.features):
                model, report = fit_colors(model, target=self.geometry.fit_target(self.rgb, sub), iterations=its)
                ks = report.kernels
                if final:
                    give_back()  # the fit's design, before the render's own arrays (tpsv.encode.memory)
            self._fits[key] = (model.features.lab, ks)
        return self._fits[key]

    def evaluate(self, t_canny: float, t_super: float, final: bool = True, steps: bool = False,
                 min_spacing: float = LATTICE_PX[0], model: Model | None = None) -> Evaluation:
        """Stage 6: the candidate encoded, decoded and rendered at scale 1.

        Parameters
        ----------
        t_canny, t_super : float
        final : bool
            Colours fitted on every pixel (else on the search's lattice).
        steps : bool
            Colour steps chosen from ``STEP_CHOICES`` by ``w`` (fitted models only).
        min_spacing : float
            As :func:`make_model`.
        model : Model, optional
            ``self.model(t_canny, t_super, min_spacing)`` when the caller has
            made it already (its features are the candidate's largest stage).

        Returns
        -------
        Evaluation
        """
        if not self.fitted:
            key = (float(t_canny), float(t_super), float(min_spacing))
            if key not in self._plain:
                made = model if model is not None else self.model(t_canny, t_super, min_spacing)
                self._plain[key] = Evaluation(*evaluate(self.rgb, made, self.device))
            return self._plain[key]
        if model is None:
            model = self.model(t_canny, t_super, min_spacing)
        key = (final, steps, _signature(model))
        hit = self._done.get(key)
        if hit is not None:
            lab, qparams, err = hit
            model = replace(model, features=replace(model.features, lab=lab),
                            params=replace(self.params_for(t_canny, t_super), l_step=qparams.l_step, ab_step=qparams.ab_step))
            data = codec.encode(model)
            return Evaluation(data, codec.decode(data), err)
        lab, ks = self.fitted_colours(model, final)
        model = replace(model, features=replace(model.features, lab=lab))
        out = Evaluation(*evaluate(self.rgb, model, self.device, kernels=ks, maps=self.maps))
        if steps:
            out = _best_steps(self.rgb, model, out, self.device, ks, self.maps)
        self._done[key] = (out.model.features.lab, out.model.params, out.mse)
        return out


def search_thresholds(
    candidates: Candidates,
    start: tuple[float, float],
    fixed: tuple[bool, bool] = (False, False),
    *,
    iterations: int = 20,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[tuple[float, float], selection.SearchResult]:
    """Stage 7: the Monte Carlo search for the thresholds (:mod:`tpsv.encode.search`).

    Fitted candidates are compared fitted on the search's pixel lattice.

    Parameters
    ----------
    candidates : Candidates
    start : (float, float)
        ``(T0_canny, T0_super)``.
    fixed : (bool, bool)
        Thresholds kept at the start (the search varies only the other).
    iterations, seed : int
        ``N_total`` and the seed of the search.
    progress : callable(done, total), optional
        Called after each evaluation with the number of thresholds evaluated.

    Returns
    -------
    best : (float, float)
        The best thresholds (fixed ones at the start).
    result : SearchResult
    """
    seen: set = set()

    def keep_fixed(tc: float, ts: float) -> tuple[float, float]:
        return (start[0] if fixed[0] else tc, start[1] if fixed[1] else ts)

    def objective(tc: float, ts: float) -> tuple[float, float]:
        tc, ts = keep_fixed(tc, ts)
        out = candidates.evaluate(tc, ts, final=not candidates.fitted)
        seen.add((tc, ts))
        if progress:
            progress(len(seen), iterations)
        h, w = candidates.geometry.index.shape
        return out.mse, len(out.data) / (w * h * 3.0)

    # the paper's mutations for its scheme; at least as wide as the start for ours (module doc)
    min_width = (0.0, 0.0) if candidates.scheme == "paper" else start
    res = selection.monte_carlo_search(objective, start, iterations=iterations, seed=seed, min_width=min_width)
    return keep_fixed(res.t_canny, res.t_super), res


def finish(
    candidates: Candidates,
    best: tuple[float, float],
    start: tuple[float, float],
    result: selection.SearchResult,
    choose_steps: bool,
) -> Evaluation:
    """Stage 8: the searched thresholds' result, fitted on every pixel, its colour steps chosen.

    The search compared candidates fitted on a pixel lattice; the result is
    fitted on every pixel. So that it is never worse than the start (what
    ``--no-search`` gives), the start is finished the same way and the
    better of the two is kept -- unless the search found the start
    ``START_MARGIN`` times less efficient (far beyond the lattice fit's bias,
    measured at most 1.3x). With ``choose_steps`` the colour steps of the
    result are then chosen by ``w``. Unfitted candidates are taken as the
    search evaluated them.
    """
    out = candidates.evaluate(*best)
    if not candidates.fitted:
        return out
    first = result.history[0] if result.history else None
    if best != start and (first is None or first.w * START_MARGIN > result.w):
        other = candidates.evaluate(*start)
        if other.efficiency() > out.efficiency():
            best, out = start, other
    if choose_steps:
        out = candidates.evaluate(*best, steps=True)
    return out


def vectorize(
    rgb: np.ndarray,
    labels: np.ndarray | None = None,
    *,
    t_canny: float | None = None,
    t_super: float | None = None,
    search: bool = True,
    iterations: int = 20,
    seed: int = 0,
    params: Params | None = None,
    device: str = "cpu",
    progress: Callable[[int, int], None] | None = None,
    fit: bool = True,
    choose_steps: bool | None = None,
    outlines: str = "fitted",
    alpha: np.ndarray | None = None,
) -> VectorizeResult:
    """Vectorise a photo: the stages of the module doc, in order.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
        Label map; segmented automatically when absent.
    t_canny, t_super : float, optional
        Fix a threshold (the search then only varies the other one; both fixed:
        no search).
    search : bool
        Run the Monte Carlo search for the thresholds (else keep the initial
        guess from the gradient histogram).
    iterations : int
        N_total of the search.
    seed : int
        Seed of the segmentation and of the search.
    params : Params, optional
        Other parameters (kernel size, overlap, smoothing, quantisation) and
        the scheme (``extra["scheme"]``); default :func:`scheme_params` of
        the default scheme.
    device : str
        Warp device for rendering during the search.
    progress : callable(done, total), optional
    fit : bool
        Fit the colours (``"tpsv"`` scheme only). During the search each
        candidate is fitted on every ``SEARCH_FIT_SUB``-th pixel with
        ``SEARCH_FIT_ITERATIONS`` iterations; the chosen thresholds are then
        fitted on every pixel, so the result is at least as good as the
        search's best (the history records the search's figures).
    choose_steps : bool, optional
        After the search, pick the colour quantisation steps of
        ``STEP_CHOICES`` with the best efficiency (default: with ``search``
        for the ``"tpsv"`` scheme; otherwise ``params``' steps are kept).
    outlines : {'fitted', 'traced'}
        Region outlines fitted to the image's edges at sub-pixel precision
        (crisp at any scale, soft where the photo's edge is), or traced along
        the label map's pixel edges, sharp (staircase borders when magnified;
        README, "Edges", for the figures at equal bytes).
    alpha : ndarray (H, W) float in [0, 1], optional
        Opacity of an RGBA input: its transparent part becomes transparent
        regions (:mod:`tpsv.encode.alpha`; PSNR is then of the colours
        :func:`tpsv.encode.alpha.straight` encodes).

    Returns
    -------
    VectorizeResult
    """
    t0 = time.perf_counter()
    rgb, geometry = alpha_geometry(rgb, alpha, labels, seed, outlines)
    candidates = Candidates(rgb, geometry, params or scheme_params(), device=device, fit=fit)
    start = start_thresholds(rgb, geometry, t_canny, t_super)
    fixed = (t_canny is not None, t_super is not None)
    searching = search and iterations > 0 and not all(fixed)
    if choose_steps is None:
        choose_steps = searching and candidates.scheme != "paper"
    history: list = []
    if searching:
        best, result = search_thresholds(candidates, start, fixed, iterations=iterations, seed=seed, progress=progress)
        out = finish(candidates, best, start, result, choose_steps)
        history = result.history
    else:
        out = candidates.evaluate(*start, steps=choose_steps)
    return VectorizeResult(
        model=out.model,
        data=out.data,
        psnr=metrics.psnr_of_mse(out.mse),
        mse=out.mse,
        seconds=time.perf_counter() - t0,
        history=history,
    )
