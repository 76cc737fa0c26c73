"""Image (+ label map) -> hybrid vector image.

image -> labels -> regions (outline + Hermite patch) -> features -> Model.

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
  from :data:`STEP_CHOICES` by ``w`` after it (coarser colours cost little
  error next to the representation's own and save up to half the bytes);
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

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .. import codec, metrics
from ..geometry import outline, patch, segment
from ..errors import TpsvError
from .features import FeatureExtractor, FeatureSet, LatticeGradation
from ..model import Features, Model, Params, Region

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
#: times less efficient than its best (see ``vectorize``).
START_MARGIN = 1.5
#: Colour quantisation steps (l_step, ab_step) the "tpsv" scheme chooses from
#: after the search, by the same efficiency w.
STEP_CHOICES = ((2, 4), (4, 8), (8, 8), (8, 16), (12, 16), (16, 16))
#: Params of each scheme that differ from the Params defaults (the paper's).
SCHEME_PARAMS = {
    "tpsv": dict(kernel_size=32, overlap=0.25, st_steps=2, l_step=8, ab_step=8),
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
    """

    regions: list[Region]
    index: np.ndarray
    st: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def pixel_st(self, device: str = "cpu") -> np.ndarray:
        """``(S, T)`` of every pixel at scale 1 (cached)."""
        if self.st is None:
            from ..gpu.patchmap import inverse_map_numpy

            h, w = self.index.shape
            self.st = inverse_map_numpy([r.patch for r in self.regions], self.index, (w, h), device=device)
        return self.st

    def _cached(self, kind: str, image: np.ndarray, extra: tuple, make):
        key = (kind, id(image)) + extra
        hit = self._cache.get(key)
        if hit is None or hit[0] is not image:  # the image is kept so its id is not reused
            hit = (image, make())
            self._cache[key] = hit
        return hit[1]

    def fit_target(self, rgb: np.ndarray, sub: int = 1):
        """The :class:`tpsv.encode.fit.FitTarget` of ``rgb`` on every ``sub``-th pixel (cached per image and ``sub``)."""
        from .fit import fit_target

        return self._cached("fit", rgb, (int(sub),), lambda: fit_target(rgb, self.index, self.pixel_st(), sub))

    def lattice(self, lab: np.ndarray) -> LatticeGradation:
        """The gradation lattices of the image of Lab colours ``lab`` (cached per image)."""
        return self._cached(
            "lattice", lab, (),
            lambda: LatticeGradation(lab, self.index, self.pixel_st(), [r.patch for r in self.regions]),
        )


@dataclass
class VectorizeResult:
    """A model and the figures of how it was made."""

    model: Model
    data: bytes
    psnr: float
    mse: float
    seconds: float
    history: list = field(default_factory=list)


def build_geometry(labels: np.ndarray) -> Geometry:
    """Regions with outlines and patches from a label map.

    Disconnected labels become several regions (each keeps its label value);
    nothing is merged away, so a single-pixel region stays a region.

    Parameters
    ----------
    labels : ndarray (H, W) int
        Label map.

    Returns
    -------
    Geometry
    """
    from scipy import ndimage

    h, w = labels.shape
    comp = segment.split_connected(labels, min_size=1)
    n = int(comp.max()) + 1
    regions: list[Region] = []
    slices = ndimage.find_objects(comp + 1, max_label=n)
    for i in range(n):
        sl = slices[i]
        if sl is None:
            continue
        mask = comp == i
        label = int(np.bincount(labels[sl][mask[sl]].ravel()).argmax())
        polys = outline.trace_outline(mask)
        regions.append(Region(label=label, outline=polys, patch=patch.build_patch(mask, polys)))
    if not regions:
        raise TpsvError("label map has no regions")
    index = outline.rasterize_regions(regions, w, h, src_size=(w, h))
    return Geometry(regions=regions, index=index)


def to_patch_space(geometry: Geometry, xy: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Normalised (S, T) of pixel-space points, each in the patch of its region."""
    st = np.zeros((xy.shape[0], 2), np.float64)
    order = np.argsort(region, kind="stable")
    bounds = np.searchsorted(region[order], np.arange(len(geometry.regions) + 1))
    for r, reg in enumerate(geometry.regions):
        idx = order[bounds[r] : bounds[r + 1]]
        if idx.size:
            raw = patch.inverse(reg.patch, xy[idx])
            st[idx] = np.clip(patch.normalize(reg.patch, raw), 0.0, 1.0)
    return st


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
) -> Model:
    """The model for one pair of thresholds (``params.t_canny``, ``params.t_super``).

    The scheme comes from ``params`` (:func:`scheme_of`). With the ``"tpsv"``
    scheme and ``fit``, colours are fitted to ``rgb`` (:mod:`tpsv.encode.fit`) after
    the positions are quantised as the file stores them.
    """
    h, w = rgb.shape[:2]
    if scheme_of(params) == "paper":
        fs = extractor.extract(params.t_canny, params.t_super)
        st = to_patch_space(geometry, fs.xy, fs.region)
        order = np.arange(len(fs))
    else:
        fs = tpsv_features(geometry, extractor, params.t_canny, params.t_super)
        st = fs.st.copy()
        todo = np.isnan(st[:, 0])
        if todo.any():
            st[todo] = to_patch_space(geometry, fs.xy[todo], fs.region[todo])
        # scan order of the positions as stored (quant: round(S * (2^b - 1)))
        q = 2 ** codec.quant.st_bits_for(w, h, params.st_steps) - 1
        order = scan_order(fs.region, np.rint(np.clip(st, 0.0, 1.0) * q), fs.pair)
    feats = Features(
        region=fs.region.astype(np.int32),
        st=st,
        lab=fs.lab.astype(np.float32),
        kind=fs.kind.astype(np.uint8),
        pair=fs.pair.astype(np.int32),
    ).subset(order)
    model = Model(width=w, height=h, regions=geometry.regions, features=feats, params=params)
    if fit and scheme_of(params) != "paper" and len(feats):
        from .fit import fit_colors

        model = codec.quantize(model)
        model, _ = fit_colors(model, target=geometry.fit_target(rgb, fit_sub), iterations=fit_iterations)
    return model


def tpsv_features(geometry: Geometry, extractor: FeatureExtractor, t_canny: float, t_super: float) -> FeatureSet:
    """Features of the ``"tpsv"`` scheme (module doc), in pixel space with ``(S, T)`` where known."""
    cur = extractor.curvilinear(t_canny, step=CURVE_STEP)
    qt = geometry.lattice(extractor.lab)
    edge = None
    if len(cur):
        cx = np.clip(np.floor(cur.xy[:, 0]).astype(np.int64), 0, extractor.w - 1)
        cy = np.clip(np.floor(cur.xy[:, 1]).astype(np.int64), 0, extractor.h - 1)
        edge = np.unique(cy * extractor.w + cx)
    grad = qt.features(t_super, edge)
    if len(cur) and len(grad):
        from scipy.spatial import cKDTree

        span = float(extractor.w + extractor.h + 10)
        key_c = np.column_stack([cur.xy, cur.region * span])
        key_g = np.column_stack([grad.xy, grad.region * span])
        dist, _ = cKDTree(key_c).query(key_g, k=1, distance_upper_bound=0.5 + 1e-9)
        grad = grad.subset(~np.isfinite(dist) | (dist > 0.5))
    both = FeatureSet.concat([cur, grad])
    anchors = extractor._anchors(both)
    return FeatureSet.concat([both, anchors])


def evaluate(
    rgb: np.ndarray, model: Model, device: str = "cpu", kernels=None, maps: tuple | None = None
) -> tuple[bytes, Model, float]:
    """Encode, decode and render a model at scale 1; return (bytes, decoded model, MSE).

    The render is of the decoded (quantised) model, so the error is the one a
    user of the file sees. ``kernels``: a ``tps.KernelSet`` grouped from a model
    with the same feature positions (its colours are replaced by the decoded
    ones, :func:`tpsv.encode.fit.recolor_kernels`), to save the grouping. ``maps``:
    the region index and ``(S, T)`` maps at scale 1 of the decoded model's
    regions (``Geometry.index``, ``Geometry.pixel_st()`` when quantisation
    leaves the regions unchanged), to save computing them.
    """
    from ..render.raster import render

    data = codec.encode(model)
    decoded = codec.decode(data)
    if kernels is not None:
        from .fit import recolor_kernels

        kernels = recolor_kernels(kernels, decoded)
    if maps is None:
        out = render(decoded, device=device, kernels=kernels)
    else:
        from ..tps import group as tps
        from ..gpu import resolve_device
        from ..gpu import tps as gtps

        ks = kernels if kernels is not None else tps.group_kernels(decoded)
        dk = gtps.solve(gtps.upload(ks, resolve_device(device)))
        img = gtps.rasterise(dk, maps[0], maps[1])
        out = img.numpy().reshape(decoded.height, decoded.width, 3)
    return data, decoded, metrics.mse(rgb, out)


def _signature(model: Model) -> tuple:
    """What determines a fitted model's colours and error: feature positions, kinds, pairs, regions."""
    import hashlib

    f = model.features
    hsh = hashlib.sha1()
    for a in (f.region, f.st, f.kind, f.pair):
        hsh.update(np.ascontiguousarray(a).tobytes())
    p = model.params
    return (len(f), hsh.hexdigest(), p.kernel_size, p.overlap, p.smoothing, p.l_step, p.ab_step)


def _same_region(a: Region, b: Region) -> bool:
    return np.array_equal(a.patch.ctrl, b.patch.ctrl) and len(a.outline) == len(b.outline) and all(
        np.array_equal(x, y) for x, y in zip(a.outline, b.outline))


def _best_steps(rgb: np.ndarray, model: Model, first: tuple, device: str, kernels=None, maps=None) -> tuple:
    """``evaluate`` of ``model`` with the quantisation steps of ``STEP_CHOICES`` giving the best w.

    ``first`` is the evaluation with the model's own steps (kept on ties).
    """
    h, w = rgb.shape[:2]

    def eff(out):
        return metrics.efficiency(out[2], len(out[0]), w, h)

    best, best_w = first, eff(first)
    own = (model.params.l_step, model.params.ab_step)
    for ls, ab in STEP_CHOICES:
        if (ls, ab) == own:
            continue
        out = evaluate(rgb, replace(model, params=replace(model.params, l_step=ls, ab_step=ab)), device, kernels, maps)
        if eff(out) > best_w:
            best, best_w = out, eff(out)
    return best


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
) -> VectorizeResult:
    """Vectorise a photo.

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

    Returns
    -------
    VectorizeResult
    """
    from . import search as selection

    t0 = time.perf_counter()
    h, w = rgb.shape[:2]
    if labels is None:
        labels = segment.segment_auto(rgb, seed=seed)
    elif labels.shape != (h, w):
        raise TpsvError(f"label map is {labels.shape[1]}x{labels.shape[0]} but the image is {w}x{h}")
    geometry = build_geometry(labels)
    base = params or scheme_params()
    scheme = scheme_of(base)
    extractor = FeatureExtractor(rgb, geometry.index)
    c0, s0 = selection.initial_thresholds(rgb, geometry.index)
    c0 = float(t_canny) if t_canny is not None else c0
    s0 = float(t_super) if t_super is not None else s0

    fitted = scheme != "paper" and fit
    searching = search and iterations > 0 and (t_canny is None or t_super is None)
    if choose_steps is None:
        choose_steps = searching and scheme != "paper"

    # Candidates whose features come out identical (e.g. two T_canny above every
    # edge) share their fit and render: only the file (params differ) is rebuilt.
    # Candidates whose features come out identical (e.g. two T_canny above every
    # edge) share their fit and render: only the file (params differ) is rebuilt.
    seen: dict = {}
    fits: dict = {}
    maps = None
    if fitted:
        same = codec.quantize(Model(width=w, height=h, regions=geometry.regions, features=Features.empty()))
        if all(_same_region(a, b) for a, b in zip(geometry.regions, same.regions)):
            maps = (geometry.index, geometry.pixel_st())

    def run(tc: float, ts: float, final: bool = True, steps: bool = False):
        p = replace(base, t_canny=float(tc), t_super=float(ts))
        if not fitted:
            return evaluate(rgb, make_model(rgb, geometry, extractor, p, fit=False), device)
        from .fit import fit_colors

        model = codec.quantize(make_model(rgb, geometry, extractor, p, fit=False))
        sig = _signature(model)
        key = (final, steps, sig)
        hit = seen.get(key)
        if hit is None:
            fk = (final, sig)
            if fk not in fits:
                sub, its = (1, FINAL_FIT_ITERATIONS) if final else (SEARCH_FIT_SUB, SEARCH_FIT_ITERATIONS)
                ks = None
                if len(model.features):
                    fm, rep = fit_colors(model, target=geometry.fit_target(rgb, sub), iterations=its)
                    model, ks = fm, rep.kernels
                fits[fk] = (model.features.lab, ks)
            lab, ks = fits[fk]
            model = replace(model, features=replace(model.features, lab=lab))
            out = evaluate(rgb, model, device, kernels=ks, maps=maps)
            if steps:
                out = _best_steps(rgb, model, out, device, ks, maps)
            seen[key] = (out[1].features.lab, out[1].params, out[2])
            return out
        lab, qparams, err = hit
        model = replace(model, features=replace(model.features, lab=lab),
                        params=replace(p, l_step=qparams.l_step, ab_step=qparams.ab_step))
        data = codec.encode(model)
        return data, codec.decode(data), err

    def eff(out) -> float:
        return metrics.efficiency(out[2], len(out[0]), w, h)

    history: list = []
    if searching:
        cache: dict = {}

        def objective(tc: float, ts: float) -> tuple[float, float]:
            tc = c0 if t_canny is not None else tc
            ts = s0 if t_super is not None else ts
            data, decoded, err = run(tc, ts, final=not fitted)
            cache[(tc, ts)] = (data, decoded, err)
            if progress:
                progress(len(cache), iterations)
            return err, len(data) / (w * h * 3.0)

        res = selection.monte_carlo_search(
            objective, (c0, s0), iterations=iterations, seed=seed,
            min_width=(0.0, 0.0) if scheme == "paper" else (c0, s0),
        )
        best = (c0 if t_canny is not None else res.t_canny, s0 if t_super is not None else res.t_super)
        history = res.history
        if not fitted:
            data, decoded, err = cache.get(best) or run(*best)
        else:
            # The search compared candidates fitted on a pixel lattice; the result is
            # fitted on every pixel. So that it is never worse than the start (what
            # --no-search gives), the start is finished the same way and the better
            # of the two is kept -- unless the search found the start START_MARGIN
            # times less efficient (far beyond the lattice fit's bias, measured at
            # most 1.3x). The colour steps of the result are then chosen.
            out = run(*best)
            start = res.history[0] if res.history else None
            if best != (c0, s0) and (start is None or start.w * START_MARGIN > res.w):
                other = run(c0, s0)
                if eff(other) > eff(out):
                    best, out = (c0, s0), other
            if choose_steps:
                out = run(*best, steps=True)
            data, decoded, err = out
    else:
        data, decoded, err = run(c0, s0, steps=choose_steps)
    return VectorizeResult(
        model=decoded,
        data=data,
        psnr=float("inf") if err == 0 else float(10 * np.log10(1.0 / err)),
        mse=err,
        seconds=time.perf_counter() - t0,
        history=history,
    )
