"""Helpers shared by the vector-space edits (``recolor``, ``crossmap``, ``deform``, ``stylize``).

All functions are pure: they never mutate the models they are given.
"""

from __future__ import annotations

import copy

import numpy as np

from .. import tps
from ..errors import TpsvError
from ..geometry.regions import to_pixel_space
from ..model import Features, Model
from ..rendering.pixelmap import region_index


def copy_model(model: Model) -> Model:
    """A deep copy of ``model`` (arrays included)."""
    return copy.deepcopy(model)


def check_region(model: Model, region, what: str = "region") -> int:
    """``region`` as an index into ``model.regions``; :class:`TpsvError` when there is no such region."""
    try:
        r = int(region)
    except (TypeError, ValueError):
        raise TpsvError(f"{what} {region!r} is not a region index") from None
    if r != region or r < 0 or r >= len(model.regions):
        raise TpsvError(f"{what} {region} does not exist (the model has regions 0..{len(model.regions) - 1})")
    return r


def check_point(model: Model, xy, what: str = "point") -> np.ndarray:
    """``xy`` as a float64 pair inside the image ``[0, W) x [0, H)``; :class:`TpsvError` otherwise."""
    p = np.asarray(xy, np.float64).reshape(-1)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise TpsvError(f"{what} {xy!r} is not a pair of numbers")
    if not (0.0 <= p[0] < model.width and 0.0 <= p[1] < model.height):
        raise TpsvError(f"{what} ({p[0]:g}, {p[1]:g}) is outside the {model.width}x{model.height} image")
    return p


def region_at(model: Model, xy) -> int:
    """The region the renderer shows at pixel-space point ``xy`` (at scale 1).

    The pixel containing the point gets its region from the vector outlines
    (``tpsv.rendering.pixelmap.region_index``, draw order honoured), so this is the region
    a user sees under the cursor.
    """
    p = check_point(model, xy)
    if not model.regions:
        raise TpsvError("the model has no regions")
    index = region_index(model, model.width, model.height)
    return int(index[int(p[1]), int(p[0])])


def feature_xy(model: Model, features: Features | None = None) -> np.ndarray:
    """Pixel-space positions ``(F, 2)`` of features: ``M(S (M-1), T (N-1))`` in their region's patch.

    Parameters
    ----------
    model : Model
    features : Features, optional
        Features of ``model``'s regions (default: ``model.features``).

    Returns
    -------
    ndarray (F, 2) float64
    """
    f = model.features if features is None else features
    return to_pixel_space([r.patch for r in model.regions], f.region, f.st)


def sort_by_region(f: Features) -> Features:
    """Features stably sorted by region, pairs remapped (the order files require)."""
    order = np.argsort(np.asarray(f.region), kind="stable")
    if np.array_equal(order, np.arange(len(f))):
        return f.subset(np.arange(len(f)))
    return f.subset(order)


def concat_features(a: Features, b: Features) -> Features:
    """``a`` then ``b`` (``b``'s pair indices shifted), not sorted (:meth:`tpsv.model.Features.concat`)."""
    return Features.concat([a, b])


def clip_lab(lab: np.ndarray) -> np.ndarray:
    """Lab clipped to the stored ranges (L in [0, 100], a and b in [-128, 127]), float32."""
    lab = np.asarray(lab, np.float64).copy()
    lab[..., 0] = np.clip(lab[..., 0], 0.0, 100.0)
    lab[..., 1:] = np.clip(lab[..., 1:], -128.0, 127.0)
    return lab.astype(np.float32)


def solved_kernels(model: Model, device: str = "cpu"):
    """Grouped and solved kernels of ``model`` (for sampling its TPS colours at points)."""
    from ..gpu import tps as gtps  # lazy: importing Warp costs start-up time (tpsv.gpu)

    ks = tps.group_kernels(model)
    return gtps.solve(gtps.upload(ks, device))


def tps_lab(model: Model, region, st, device: str = "cpu", dk=None) -> np.ndarray:
    """The model's rendered Lab colour (blended TPS, range-clamped as ``render``) at ``(S, T)`` points of regions.

    ``region`` (n,) or a scalar; ``st`` (n, 2). Returns (n, 3) float64.
    """
    from ..gpu import tps as gtps  # lazy: importing Warp costs start-up time (tpsv.gpu)

    st = np.asarray(st, np.float64).reshape(-1, 2)
    if st.shape[0] == 0:
        return np.zeros((0, 3))
    if dk is None:
        # only the kernels of the regions asked for (a region's kernels depend on its features alone)
        regs = np.unique(np.asarray(region, np.int64))
        sub = copy.copy(model)
        sub.features = model.features.subset(np.isin(model.features.region, regs))
        dk = solved_kernels(sub, device)
    return gtps.eval_points(dk, region, st, clamp=True)
