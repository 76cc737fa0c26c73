"""The pixel map: the region and the ``(S, T)`` of every output pixel (render steps 1-2).

1. ``outline.rasterize_regions``: the region of every output pixel, from the
   vector outlines (no staircase when magnifying), in drawing order
   (:func:`region_index`).
2. ``gpu.patchmap.inverse_map``: ``(S, T)`` of every output pixel in its
   region's patch.

Everything that needs to know which feature colours reach which pixel builds
this map here: the renderer (:mod:`tpsv.rendering.raster`), the incremental
renderer (:mod:`tpsv.rendering.live`) and the encoder's colour fit and feature
lattices at scale 1 (``tpsv.encode.fit.pixel_maps``,
``tpsv.encode.vectorize.Geometry.pixel_st``), so the fit sees what the
renderer draws.

Output pixel ``(X, Y)`` of a ``W x H`` map samples
``((X + 0.5) * Ws / W, (Y + 0.5) * Hs / H)`` of the model's pixel space
(``tpsv.model``), ``(Ws, Hs)`` the model's size.

:class:`BandMaps` gives the same maps band of rows by band of rows, for
outputs too large to map whole (``tpsv.rendering.raster.render_bands``).

Draw order: where region outlines overlap (only after an edit such as
``deform`` moves a region), the region drawn first keeps the pixel. Regions are
drawn in index order, except that the regions listed in
``model.params.extra["front"]`` (:data:`FRONT_KEY`, a comma-separated list of
region indices, written by ``tpsv.edit.deform``) are drawn before all others, in
the order listed: they are on top. See :func:`region_index`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import TpsvError
from ..geometry import curves, outline
from ..gpu import warp

#: ``Params.extra`` key: regions drawn on top (comma-separated indices, first on top).
FRONT_KEY = "front"


def draw_order(model) -> list[int]:
    """Region indices in drawing order (first drawn is on top where outlines overlap).

    Index order, except that the regions named in ``model.params.extra["front"]``
    come first, in the order listed.

    Parameters
    ----------
    model : Model

    Returns
    -------
    list of int

    Raises
    ------
    TpsvError
        When that entry is not a comma-separated list of distinct region indices.
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
    """Region of every output pixel, honouring :func:`draw_order` (render step 1).

    ``outline.rasterize_regions`` on the regions in drawing order, mapped back
    to region indices (identical to it when nothing is in front).

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.

    Returns
    -------
    ndarray (height, width) int32
        Region index, ``-1`` outside every region.
    """
    model = curves.as_drawn(model, width, height)
    order = draw_order(model)
    if order == list(range(len(model.regions))):
        return outline.rasterize_regions(model.regions, width, height, src_size=(model.width, model.height))
    idx = outline.rasterize_regions([model.regions[r] for r in order], width, height, src_size=(model.width, model.height))
    lut = np.asarray(order + [-1], np.int32)
    return lut[idx]


def no_tick(name: str) -> None:
    """A stage callback that does nothing (the default ``tick``)."""


@dataclass
class PixelMap:
    """Region index and ``(S, T)`` of every output pixel, on the host and on a Warp device.

    Attributes
    ----------
    index_d : wp.array2d(int32)
        Region of every pixel on the device (``-1``: outside every region).
    st_d : wp.array2d(vec2)
        Normalised ``(S, T)`` of every pixel in its region's patch, on the
        device (``(-1, -1)`` outside every region).
    index : ndarray (H, W) int32
        ``index_d`` on the host (copied on first use when the map was made
        on the device).
    """

    index_d: object
    st_d: object
    _index: np.ndarray | None = field(default=None, repr=False)
    _st: np.ndarray | None = field(default=None, repr=False)

    @property
    def index(self) -> np.ndarray:
        if self._index is None:
            self._index = self.index_d.numpy()
        return self._index

    @property
    def st(self) -> np.ndarray:
        """``(S, T)`` copied to the host: ndarray (H, W, 2) float32 (copied once, then cached)."""
        if self._st is None:
            self._st = self.st_d.numpy().reshape(self.index.shape + (2,))
        return self._st

    @classmethod
    def build(cls, regions, index: np.ndarray, src_size: tuple[int, int], device: str = "cpu",
              tick: Callable[[str], None] = no_tick) -> "PixelMap":
        """Render step 2 for a given region map: upload it and invert every pixel's patch.

        Parameters
        ----------
        regions : list of Region
        index : ndarray (H, W) int
            Region of every output pixel (:func:`region_index`).
        src_size : (Ws, Hs)
            Model size in pixels.
        device : str
            Warp device.
        tick : callable(str), optional
            Called with ``"upload_regions"`` and ``"patchmap"`` after each
            stage (the renderer's timings).

        Returns
        -------
        PixelMap
        """
        # gpu.patchmap imports Warp and defines its kernels: only commands that render pay for it
        from ..gpu.patchmap import inverse_map

        wp = warp()
        index = np.ascontiguousarray(index, np.int32)
        index_d = wp.array(index, dtype=wp.int32, device=device)
        tick("upload_regions")
        st_d = inverse_map([r.patch for r in regions], index_d, src_size, device=device)
        tick("patchmap")
        return cls(index_d=index_d, st_d=st_d, _index=index)


def pixel_map(model, width: int | None = None, height: int | None = None, device: str = "cpu",
              tick: Callable[[str], None] = no_tick, outlines=None, patch_set=None) -> PixelMap:
    """The pixel map of ``model`` at ``width x height`` (default: the model's size, scale 1).

    Parameters
    ----------
    model : Model
    width, height : int, optional
        Output size.
    device : str
        Warp device.
    tick : callable(str), optional
        Called with ``"regions"`` and ``"patchmap"`` after each stage.
    outlines : tpsv.gpu.regions.DeviceOutlines, optional
        The model's outlines already prepared on ``device`` for this size.
    patch_set : tpsv.gpu.patchmap.PatchSet, optional
        The model's patches already on ``device``.

    Returns
    -------
    PixelMap
    """
    from ..gpu.patchmap import inverse_map
    from ..gpu.regions import DeviceOutlines

    W = model.width if width is None else int(width)
    H = model.height if height is None else int(height)
    # the region map made on the device (the pixels of region_index), never uploaded
    if outlines is None:
        outlines = DeviceOutlines(model, W, H, device)
    index_d = outlines.index_device()
    tick("regions")
    st_d = inverse_map([r.patch for r in model.regions], index_d, (model.width, model.height), device=device,
                       patch_set=patch_set)
    tick("patchmap")
    return PixelMap(index_d=index_d, st_d=st_d)


class BandMaps:
    """Pixel maps of bands of output rows, identical to the rows of :func:`pixel_map` (tiled rendering).

    Everything that does not depend on the band is prepared once: the
    outlines' edges on the device (:class:`tpsv.gpu.regions.DeviceOutlines`,
    whose bands are the rows of the whole frame's map) and the patches.
    :meth:`band` then costs memory in proportion to the band only, and its
    region map never leaves the device.

    Parameters
    ----------
    model : Model
    width, height : int
        Output size.
    device : str
        Warp device.
    max_gap_bytes : int, optional
        Refuse outputs whose pixels far from every outline need more host
        memory than this (``outline.GapFill``).
    threads : int, optional
        Host threads for the CPU device.
    """

    def __init__(self, model, width: int, height: int, device: str = "cpu", max_gap_bytes: int | None = None,
                 threads: int | None = None):
        from ..gpu.patchmap import PatchSet
        from ..gpu.regions import DeviceOutlines

        self.width, self.height = int(width), int(height)
        self.device = device
        model = curves.as_drawn(model, self.width, self.height)
        self.outlines = DeviceOutlines(model, self.width, self.height, device, threads, max_gap_bytes)
        self.patch_set = PatchSet.build([r.patch for r in model.regions], device)
        self._src = (model.width, model.height)

    def index(self, a: int, b: int) -> np.ndarray:
        """Rows ``a <= y < b`` of :func:`region_index`: ndarray (b - a, width) int32."""
        return self.outlines.index_device(a, b).numpy()

    def band(self, a: int, b: int) -> PixelMap:
        """The pixel map of rows ``a <= y < b``: equal to those rows of :func:`pixel_map`."""
        from ..gpu.patchmap import inverse_map

        index_d = self.outlines.index_device(a, b)
        # the whole frame's kernel with a row offset: the same sample points and code
        st = inverse_map(None, index_d, self._src, patch_set=self.patch_set,
                         out_size=(self.width, self.height), row0=a)
        return PixelMap(index_d=index_d, st_d=st)


__all__ = ["BandMaps", "FRONT_KEY", "PixelMap", "draw_order", "no_tick", "pixel_map", "region_index"]
