"""Image (+ label map) -> hybrid vector image.

image -> labels -> regions (outline + Hermite patch) -> features -> Model.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from . import codec, metrics, outline, patch, segment
from .errors import TpsvError
from .features import FeatureExtractor
from .model import Features, Model, Params, Region


@dataclass
class Geometry:
    """The threshold-independent part of a vectorisation, computed once.

    Attributes
    ----------
    regions : list of Region
    index : ndarray (H, W) int32
        Region index of every pixel, as the renderer sees it at scale 1 (from the
        outlines), so each feature takes its colour from the region it belongs to.
    """

    regions: list[Region]
    index: np.ndarray


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


def make_model(
    rgb: np.ndarray,
    geometry: Geometry,
    extractor: FeatureExtractor,
    params: Params,
) -> Model:
    """The model for one pair of thresholds (``params.t_canny``, ``params.t_super``)."""
    fs = extractor.extract(params.t_canny, params.t_super)
    st = to_patch_space(geometry, fs.xy, fs.region)
    feats = Features(
        region=fs.region.astype(np.int32),
        st=st,
        lab=fs.lab.astype(np.float32),
        kind=fs.kind.astype(np.uint8),
        pair=fs.pair.astype(np.int32),
    )
    h, w = rgb.shape[:2]
    return Model(width=w, height=h, regions=geometry.regions, features=feats, params=params)


def evaluate(rgb: np.ndarray, model: Model, device: str = "cpu") -> tuple[bytes, Model, float]:
    """Encode, decode and render a model at scale 1; return (bytes, decoded model, MSE).

    The render is of the decoded (quantised) model, so the error is the one a
    user of the file sees.
    """
    from .render import render

    data = codec.encode(model)
    decoded = codec.decode(data)
    out = render(decoded, device=device)
    return data, decoded, metrics.mse(rgb, out)


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
        Other parameters (kernel size, overlap, smoothing).
    device : str
        Warp device for rendering during the search.
    progress : callable(done, total), optional

    Returns
    -------
    VectorizeResult
    """
    from . import selection

    t0 = time.perf_counter()
    h, w = rgb.shape[:2]
    if labels is None:
        labels = segment.segment_auto(rgb, seed=seed)
    elif labels.shape != (h, w):
        raise TpsvError(f"label map is {labels.shape[1]}x{labels.shape[0]} but the image is {w}x{h}")
    geometry = build_geometry(labels)
    extractor = FeatureExtractor(rgb, geometry.index)
    base = params or Params()
    c0, s0 = selection.initial_thresholds(rgb, geometry.index)
    c0 = float(t_canny) if t_canny is not None else c0
    s0 = float(t_super) if t_super is not None else s0

    def run(tc: float, ts: float):
        model = make_model(rgb, geometry, extractor, replace(base, t_canny=float(tc), t_super=float(ts)))
        return evaluate(rgb, model, device)

    history: list = []
    if search and iterations > 0 and (t_canny is None or t_super is None):
        cache: dict = {}

        def objective(tc: float, ts: float) -> tuple[float, float]:
            tc = c0 if t_canny is not None else tc
            ts = s0 if t_super is not None else ts
            data, decoded, err = run(tc, ts)
            cache[(tc, ts)] = (data, decoded, err)
            if progress:
                progress(len(cache), iterations)
            return err, len(data) / (w * h * 3.0)

        res = selection.monte_carlo_search(objective, (c0, s0), iterations=iterations, seed=seed)
        best = (c0 if t_canny is not None else res.t_canny, s0 if t_super is not None else res.t_super)
        data, decoded, err = cache.get(best) or run(*best)
        history = res.history
    else:
        data, decoded, err = run(c0, s0)
    return VectorizeResult(
        model=decoded,
        data=data,
        psnr=float("inf") if err == 0 else float(10 * np.log10(1.0 / err)),
        mse=err,
        seconds=time.perf_counter() - t0,
        history=history,
    )
