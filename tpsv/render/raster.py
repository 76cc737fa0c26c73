"""Model -> pixels at any size (paper V and VII-A).

1. ``outline.rasterize_regions``: the region of every output pixel, from the
   vector outlines (no staircase when magnifying).
2. ``gpu.patchmap.inverse_map``: ``(S, T)`` of every output pixel in its
   region's patch.
3. ``tps.group_kernels``: sub-patch kernels (derived at load time).
4. ``gpu.tps``: build + solve every kernel, then rasterise with the blend;
   by default each kernel is clamped to its features' Lab range before
   blending (removes TPS overshoot; ``clamp=False`` for the plain TPS).

Output pixel ``(X, Y)`` at scale ``k`` samples ``((X + 0.5) / k, (Y + 0.5) / k)``
of the model's pixel space (``tpsv.model``); for a size ``W x H`` the scale is
per axis, ``W / model.width`` and ``H / model.height``.

Draw order: where region outlines overlap (only after an edit such as
``deform`` moves a region), the region drawn first keeps the pixel. Regions are
drawn in index order, except that the regions listed in
``model.params.extra["front"]`` (:data:`FRONT_KEY`, a comma-separated list of
region indices, written by ``tpsv.edit.deform``) are drawn before all others, in
the order listed: they are on top. See :func:`region_index`.

A region without features (``vectorize`` never makes one) renders flat in the
mean colour of all the model's features (mid grey, Lab (50, 0, 0), when the
model has none); a pixel outside every region (only when the model has no
regions) is mid grey.
"""

from __future__ import annotations

import time

import numpy as np

from ..geometry import outline
from ..tps import group as tps
from ..errors import TpsvError

#: ``Params.extra`` key: regions drawn on top (comma-separated indices, first on top).
FRONT_KEY = "front"

#: Largest output side, in pixels.
MAX_SIDE = 16384
#: Largest output, in pixels.
MAX_PIXELS = 1 << 28


def output_size(model, width=None, height=None, scale=None) -> tuple[int, int]:
    """``(W, H)`` of the output: from ``width``/``height`` or ``scale`` (default 1).

    With only one of ``width``/``height`` the other keeps the aspect ratio.
    Raises :class:`TpsvError` for non-positive, non-finite or too large sizes,
    or when both a size and a scale are given.
    """
    if model.width <= 0 or model.height <= 0:
        raise TpsvError(f"model size {model.width}x{model.height} is empty")
    if scale is not None and (width is not None or height is not None):
        raise TpsvError("give either a scale or an output size, not both")
    if width is None and height is None:
        k = 1.0 if scale is None else scale
        try:
            k = float(k)
        except (TypeError, ValueError):
            raise TpsvError(f"scale {scale!r} is not a number") from None
        if not np.isfinite(k) or k <= 0:
            raise TpsvError(f"scale {scale!r} must be a positive number")
        W = int(round(model.width * k))
        H = int(round(model.height * k))
    else:
        try:
            W = None if width is None else _as_int(width)
            H = None if height is None else _as_int(height)
        except (TypeError, ValueError):
            raise TpsvError(f"output size {width!r} x {height!r} is not a pair of whole numbers") from None
        if W is None:
            W = int(round(H * model.width / model.height)) if H > 0 else H
        if H is None:
            H = int(round(W * model.height / model.width)) if W > 0 else W
    if W <= 0 or H <= 0:
        raise TpsvError(f"output size {W}x{H} is empty")
    if W > MAX_SIDE or H > MAX_SIDE or W * H > MAX_PIXELS:
        raise TpsvError(f"output size {W}x{H} is too large (at most {MAX_SIDE} px per side)")
    return W, H


def _as_int(v) -> int:
    f = float(v)
    if not np.isfinite(f) or f != int(f):
        raise ValueError(v)
    return int(f)


def draw_order(model) -> list[int]:
    """Region indices in drawing order (first drawn is on top where outlines overlap).

    Index order, except that the regions named in ``model.params.extra["front"]``
    come first, in the order listed. Raises :class:`TpsvError` when that entry
    is not a comma-separated list of distinct region indices.
    """
    R = len(model.regions)
    text = (model.params.extra or {}).get(FRONT_KEY, "")
    if text in ("", None):
        return list(range(R))
    front = []
    try:
        for tok in str(text).split(","):
            front.append(int(tok))
    except ValueError:
        raise TpsvError(f"params.extra[{FRONT_KEY!r}] = {text!r} is not a list of region indices") from None
    if len(set(front)) != len(front) or any(r < 0 or r >= R for r in front):
        raise TpsvError(f"params.extra[{FRONT_KEY!r}] = {text!r} names a region twice or one that does not exist")
    rest = [r for r in range(R) if r not in set(front)]
    return front + rest


def region_index(model, width: int, height: int) -> np.ndarray:
    """Region of every output pixel ``(height, width)`` int32, honouring :func:`draw_order`.

    ``outline.rasterize_regions`` on the regions in drawing order, mapped back
    to region indices (identical to it when nothing is in front).
    """
    order = draw_order(model)
    if order == list(range(len(model.regions))):
        return outline.rasterize_regions(model.regions, width, height, src_size=(model.width, model.height))
    idx = outline.rasterize_regions([model.regions[r] for r in order], width, height, src_size=(model.width, model.height))
    lut = np.asarray(order + [-1], np.int32)
    return lut[idx]


def render(model, width=None, height=None, scale=None, device: str = "cpu", kernels=None, threads=None, clamp: bool = True) -> np.ndarray:
    """Render ``model``; returns float32 sRGB ``(H, W, 3)`` in ``[0, 1]``.

    ``kernels``: a :class:`tpsv.tps.group.KernelSet` from an earlier
    ``tps.group_kernels(model)`` to reuse (it must belong to this model).
    ``threads``: host threads for CPU launches (default: all cores).
    ``clamp``: clamp each kernel to its features' Lab range before blending
    (``tpsv.gpu.tps``; False gives the plain localised TPS).
    """
    img, _ = _render(model, width, height, scale, device, kernels, threads, clamp, timed=False)
    return img


def render_timed(model, width=None, height=None, scale=None, device: str = "cpu", repeat: int = 1, threads=None, clamp: bool = True):
    """Render and time each stage (seconds, best of ``repeat``): returns ``(image, timings)``.

    Stages: ``regions`` (outline rasterisation, host), ``upload_regions``
    (the region map to the device), ``patchmap``,
    ``group`` (host), ``upload``, ``solve`` (build + solve),
    ``rasterise``, ``download``, and ``total`` (their sum). Device stages end
    with a device synchronisation. The first call on a device also compiles
    or loads Warp modules: call once before timing (``repeat >= 2``).
    """
    best: dict = {}
    img = None
    for _ in range(max(1, int(repeat))):
        img, t = _render(model, width, height, scale, device, None, threads, clamp, timed=True)
        for k, v in t.items():
            best[k] = min(best.get(k, np.inf), v)
    best["total"] = sum(v for k, v in best.items() if k != "total")
    return img, best


def _render(model, width, height, scale, device, kernels, threads, clamp, timed: bool):
    from ..gpu import resolve_device
    from ..gpu import tps as gtps
    from ..gpu.patchmap import inverse_map

    W, H = output_size(model, width, height, scale)
    device = resolve_device(device)
    import warp as wp

    times: dict = {}
    t0 = time.perf_counter()

    def tick(name):
        nonlocal t0
        if timed:
            wp.synchronize_device(device)
            now = time.perf_counter()
            times[name] = now - t0
            t0 = now

    index = region_index(model, W, H)
    tick("regions")
    index_d = wp.array(np.ascontiguousarray(index, np.int32), dtype=wp.int32, device=device)
    tick("upload_regions")
    st_d = inverse_map([r.patch for r in model.regions], index_d, (model.width, model.height), device=device)
    tick("patchmap")
    ks = kernels if kernels is not None else tps.group_kernels(model)
    if ks.grid.shape[0] != len(model.regions):
        raise TpsvError("the kernel set does not belong to this model")
    tick("group")
    dk = gtps.upload(ks, device)
    tick("upload")
    gtps.solve(dk, threads=threads)
    tick("solve")
    out = gtps.rasterise(dk, index_d, st_d, threads=threads, clamp=clamp)
    tick("rasterise")
    img = out.numpy().reshape(H, W, 3)
    tick("download")
    return img, times
