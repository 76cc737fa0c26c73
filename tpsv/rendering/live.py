"""Incremental rebuild after an edit: re-solve only the kernels whose features changed.

The paper's real-time claim for editing (VII) rests on the locality of the
sub-patch TPS: a colour edit changes a few features, so only the kernels that
hold one of them need a new solve, and only the pixels those kernels cover
need new colours. :class:`LiveImage` keeps a model together with everything
derived from it (region map, ``(S, T)`` map, kernel set, solved device
kernels, the rendered image) and brings them up to date for a new model:

1. **Geometry.** When an outline, a patch, the draw order or the way
   outlines are drawn (``curves``) changed (``deform``), the region map and
   the ``(S, T)`` map are recomputed; pixels whose region or ``(S, T)``
   changed are dirty. Otherwise both are kept.
2. **Grouping.** When the features' regions and ``(S, T)``, the patches'
   pixel scales and the TPS parameters are unchanged (a colour edit:
   ``recolor``; a translation), the grouping is unchanged too: the kernel
   set is reused with the new colours
   (:func:`tpsv.tps.recolor`, duplicates merged as :func:`tpsv.tps.group_kernels`
   merges them). Otherwise the kernels are regrouped with :func:`tpsv.tps.group_kernels`.
3. **Solve.** A kernel whose system is identical to one already solved (same
   local points, colours, frame, count and smoothing: compared bit for bit)
   reuses that solution; the others are solved as a subset
   (:func:`tpsv.gpu.tps.solve_reusing`). A GPU solves them all: one pass
   costs it less than the subset's copies. When every kernel keeps its own
   solution (a translation; an edit of no feature), the solved kernels on
   the device serve as they are: nothing is uploaded or solved.
4. **Rasterise.** Only dirty pixels are rasterised again: pixels of a region
   whose sub-patch grid changed, and pixels whose cell is within one cell of
   a re-solved kernel's cell (a kernel's support reaches at most half a cell
   into its neighbours), plus the geometry changes of step 1. The host flags
   regions and kernels only (few); the device finds the dirty pixels from
   the maps it already holds and draws them in the same launch
   (:func:`tpsv.gpu.rasterise.rasterise_dirty`), so no per-pixel array
   crosses to or from the host after a colour edit.
5. **Borders.** The anti-aliased border pixels (:mod:`tpsv.rendering.borders`)
   are mixed into a copy of that frame after every update; where they are and
   their ``(S, T)`` across are found again, on the device, only when the
   geometry or the borders' edge widths changed.
6. **Detail.** The detail layer (:mod:`tpsv.gpu.detail`) is added to every
   pixel of that copy; its texture is uploaded again only when it changed.

The result is bit-identical to :func:`tpsv.rendering.raster.render` of the new model
(tests check it); :class:`UpdateStats` says how much was rebuilt.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import tps
from ..errors import TpsvError
from ..geometry import curves
from ..gpu import resolve_device
# Warp is imported with gpu.tps; this module exists only to render, so it pays for it on import
from ..gpu import tps as gtps
from ..gpu import warp
from ..gpu.coverage import DeviceBorders
from ..gpu.patchmap import PatchSet
from ..gpu.rasterise import changed_pixels, rasterise_dirty
from ..tps.grouping import pixel_scales
from .pixelmap import draw_order, no_tick, pixel_map
from .raster import ONE_PIECE_PIXELS, Stopwatch, border_st_device, output_size


@dataclass
class UpdateStats:
    """What an update rebuilt.

    Attributes
    ----------
    kernels : int
        Kernels of the new model.
    solved : int
        Kernels solved again (the others reused an identical solution).
    pixels : int
        Output pixels rasterised again.
    regrouped : bool
        Whether the features were grouped into kernels again (else only
        their colours were replaced).
    geometry : bool
        Whether the region and ``(S, T)`` maps were recomputed.
    seconds : dict
        Wall time of the update to a device synchronisation at its end
        (``total``) and, when the :class:`LiveImage` is ``timed``, of each
        stage (``geometry``, ``group``, ``match``, ``solve``, ``rasterise``,
        ``borders``, ``detail``), each ending with one.
    """

    kernels: int
    solved: int
    pixels: int
    regrouped: bool
    geometry: bool
    seconds: dict = field(default_factory=dict)

    @property
    def reused(self) -> int:
        return self.kernels - self.solved

    def as_dict(self) -> dict:
        return {"kernels": self.kernels, "solved": self.solved, "reused": self.reused, "pixels": self.pixels,
                "regrouped": self.regrouped, "geometry": self.geometry,
                "seconds": {k: float(v) for k, v in self.seconds.items()}}


# --------------------------------------------------------------------------- comparisons


def same_geometry(a, b) -> bool:
    """Whether two models have the same size, outlines, patches and draw order, their outlines drawn
    the same way (as curves or as polygons)."""
    if (a.width, a.height) != (b.width, b.height) or len(a.regions) != len(b.regions):
        return False
    if bool(getattr(a, "curves", False)) != bool(getattr(b, "curves", False)):
        return False
    if draw_order(a) != draw_order(b):
        return False
    for ra, rb in zip(a.regions, b.regions):
        if len(ra.outline) != len(rb.outline):
            return False
        if not np.array_equal(np.asarray(ra.patch.ctrl, np.float64), np.asarray(rb.patch.ctrl, np.float64)):
            return False
        for pa, pb in zip(ra.outline, rb.outline):
            if not np.array_equal(np.asarray(pa, np.float64), np.asarray(pb, np.float64)):
                return False
    return True


def same_edge_widths(a, b) -> bool:
    """Whether two models' borders have the same edge widths (``blur`` and ``blur_map``): what the
    anti-aliased border pixels read of a model besides its geometry."""
    return (np.array_equal(np.asarray(a.blur, np.float64), np.asarray(b.blur, np.float64))
            and a.blur_map == b.blur_map)


def _same_tps_params(a, b) -> bool:
    pa, pb = a.params, b.params
    return (int(pa.kernel_size), float(pa.overlap), float(pa.smoothing)) == (
        int(pb.kernel_size), float(pb.overlap), float(pb.smoothing))


def same_grouping(a, b) -> bool:
    """Whether ``group_kernels`` gives both models the same kernels up to colours.

    True when the TPS parameters, the features' regions and ``(S, T)`` and
    the patches' pixel scales (all that the grouping reads of the patches,
    :func:`tpsv.tps.grouping.pixel_scales`) are identical: only colours,
    kinds or pairs may differ, or the patches moved without changing size
    (a translation).
    """
    if len(a.regions) != len(b.regions) or not _same_tps_params(a, b):
        return False
    fa, fb = a.features, b.features
    if len(fa) != len(fb):
        return False
    if not (np.array_equal(np.asarray(fa.region), np.asarray(fb.region))
            and np.array_equal(np.asarray(fa.st, np.float64), np.asarray(fb.st, np.float64))):
        return False
    # only the patches that moved are measured (a few small numpy calls each)
    moved = [i for i, (ra, rb) in enumerate(zip(a.regions, b.regions))
             if not np.array_equal(np.asarray(ra.patch.ctrl, np.float64), np.asarray(rb.patch.ctrl, np.float64))]
    return not moved or np.array_equal(pixel_scales([a.regions[i].patch for i in moved]),
                                       pixel_scales([b.regions[i].patch for i in moved]))


def kernel_keys(ks) -> np.ndarray:
    """One byte string per kernel that determines its solution (frame, smoothing, count, slots' (S, T) and Lab)."""
    n, K = ks.n_kernels, ks.kernel_size
    idx = np.maximum(ks.index, 0)
    act = (ks.index >= 0)[..., None]
    st = np.where(act, ks.st[idx], 0.0).reshape(n, 2 * K)
    lab = np.where(act, ks.lab[idx].astype(np.float64), 0.0).reshape(n, 3 * K)
    head = np.column_stack([ks.frame, tps.kernel_lambda(ks), ks.count.astype(np.float64),
                            ks.degenerate.astype(np.float64)]) if n else np.zeros((0, 7))
    rows = np.ascontiguousarray(np.concatenate([head, st, lab], axis=1), np.float64)
    return rows.view(np.dtype((np.void, rows.shape[1] * 8))).reshape(n)


# --------------------------------------------------------------------------- the live image


class LiveImage:
    """A model, its derived TPS kernels and its rendered image, kept up to date across edits.

    Parameters
    ----------
    model : Model
    width, height, scale : optional
        Output size, as for :func:`tpsv.rendering.raster.render` (default scale 1).
    device : str
        Warp device.
    threads : int, optional
        Host threads for CPU launches.
    clamp : bool
        Clamp each kernel to its features' Lab range (as ``render``).
    timed : bool
        Time each stage of an update (:attr:`UpdateStats.seconds`): each then
        ends with a device synchronisation, so the host no longer queues the
        next stage's launches while the device works, and an update takes
        longer. Untimed, an update synchronises once, at its end.

    Attributes
    ----------
    model : Model
        The current model (not copied: do not mutate it).
    kernels : tpsv.tps.KernelSet
    stats : UpdateStats
        Figures of the last build or update.

    Examples
    --------
    >>> live = LiveImage(model)                                   # doctest: +SKIP
    >>> stats = live.update(recolor.recolor(model, region=2, hue=40))  # doctest: +SKIP
    >>> stats.solved, stats.kernels                               # doctest: +SKIP
    (31, 2533)
    >>> img = live.image                                          # doctest: +SKIP
    """

    def __init__(self, model, width=None, height=None, scale=None, device: str = "cpu", threads=None, clamp: bool = True,
                 timed: bool = False):
        self.device = resolve_device(device)
        self.timed = bool(timed)
        self._size_args = (width, height, scale)
        self.threads = threads
        self.clamp = bool(clamp)
        self.model = None
        self.kernels = None
        self._dk = None
        self._out = None
        self._pm = None  # PixelMap of the current geometry
        self._mix = None  # its anti-aliased border pixels and their (S, T) across, on the device
        self._patches = None  # the model's patches on the device (PatchSet), for both maps
        self._patch_cache = {}  # their flattened arrays by control points: a deform redoes one patch
        self._drawn = None  # the model as drawn at this size (curves as polygons), for the maps and borders
        self._drawn_cache = {}  # its polygons by outline: a deform draws only what moved
        self._shown = None  # _out with the borders mixed in
        self._duplicates = None  # duplicate groups of the current features' positions
        self._detail = (None, None)  # (Detail, DeviceDetail) last uploaded
        self.stats = self._rebuild(model, full=True)

    # ------------------------------------------------------------------ public

    @property
    def size(self) -> tuple[int, int]:
        """``(W, H)`` of the output."""
        return self.W, self.H

    @property
    def image(self) -> np.ndarray:
        """The current render: float32 sRGB ``(H, W, 3)`` in ``[0, 1]`` (a copy)."""
        return self._shown.numpy().reshape(self.H, self.W, 3)

    def update(self, model) -> UpdateStats:
        """Bring everything up to date for ``model`` (see the module docstring); returns the figures."""
        self.stats = self._rebuild(model, full=False)
        return self.stats

    # ------------------------------------------------------------------ internals

    def _rebuild(self, model, full: bool) -> UpdateStats:
        """Steps 1-4 of the module docstring for ``model`` (everything when ``full``)."""
        watch = Stopwatch(self.device) if self.timed else no_tick
        t_start = time.perf_counter()
        old = self.model
        if old is not None and (old.width, old.height) != (model.width, model.height):
            full = True
        W, H = output_size(model, *self._size_args)
        if W * H > ONE_PIECE_PIXELS:
            # the live image keeps full-frame maps and the image on the device
            raise TpsvError(f"output {W}x{H} px is too large for live editing (at most {ONE_PIECE_PIXELS:,} px)")
        geometry, dirty = self._update_geometry(model, W, H, full)
        watch("geometry")
        ks, regrouped = self._update_grouping(model, full)
        watch("group")
        reuse = self._match(ks, model, full, regrouped)
        watch("match")
        if self._unchanged(ks, regrouped, reuse):
            dk, solved = self._dk, 0  # every kernel as it was: nothing to upload or solve
        else:
            dk, solved = gtps.solve_reusing(ks, self._dk, reuse, device=self.device, threads=self.threads)
        watch("solve")
        pixels = self._rasterise(dk, ks, reuse, dirty)
        watch("rasterise")
        self._mix_borders(model, dk)
        watch("borders")
        self._add_detail(model)
        watch("detail")
        if not self.timed:
            warp().synchronize_device(self.device)
        times = dict(getattr(watch, "times", {}), total=time.perf_counter() - t_start)
        self.model, self.kernels, self._dk = model, ks, dk
        return UpdateStats(kernels=ks.n_kernels, solved=solved, pixels=pixels, regrouped=regrouped,
                           geometry=geometry, seconds=times)

    def _update_geometry(self, model, W: int, H: int, full: bool):
        """Step 1: a new pixel map when the geometry changed.

        Returns
        -------
        recomputed : bool
        dirty : wp.array (H * W,) uint8, empty ndarray, or None
            Pixels whose region or ``(S, T)`` changed, flagged on the device
            (None when ``full``: every pixel is drawn again; empty when the
            maps were kept).
        """
        recomputed = full or not same_geometry(self.model, model)
        dirty = None if full else np.zeros(0, bool)
        if recomputed:
            # the curves drawn once for the region map and the border coverage
            self._drawn = curves.as_drawn(model, W, H, cache=self._drawn_cache)
            # the patches uploaded once for the pixels' (S, T) and the border pixels' across
            self._patches = PatchSet.build([r.patch for r in model.regions], self.device, cache=self._patch_cache)
            pm = pixel_map(self._drawn, W, H, self.device, patch_set=self._patches)
            if not full:
                dirty = changed_pixels(self._pm.index_d, pm.index_d, self._pm.st_d, pm.st_d)
            self.W, self.H = W, H
            self._pm = pm
            self._mix = None
        elif not same_edge_widths(self.model, model):
            # the same maps, but the borders mix over other widths: drawn again from the new
            # model (its polygons from the cache), their pixels found again
            self._drawn = curves.as_drawn(model, W, H, cache=self._drawn_cache)
            self._mix = None
        return recomputed, dirty

    def _update_grouping(self, model, full: bool):
        """Step 2: the kernel set of ``model``, regrouped only when positions or parameters changed.

        Returns
        -------
        ks : KernelSet
        regrouped : bool
        """
        regrouped = full or not same_grouping(self.model, model)
        if regrouped:
            self._duplicates = tps.Duplicates.of_features(model.features)
            return tps.group_kernels(model), True
        return tps.recolor(self.kernels, model.features, self._duplicates), False

    def _match(self, ks, model, full: bool, regrouped: bool) -> np.ndarray:
        """Step 3: for each kernel of ``ks``, an old kernel with the identical system, or -1."""
        n = ks.n_kernels
        old_ks = self.kernels
        if full or self._dk is None or not _same_tps_params(self.model, model):
            return np.full(n, -1, np.int64)
        if not regrouped:
            idx = np.maximum(ks.index, 0)
            act = ks.index >= 0
            same = ((old_ks.lab[idx] == ks.lab[idx]).all(axis=2) | ~act).all(axis=1)
            return np.where(same, np.arange(n), -1)
        lookup = {key.tobytes(): i for i, key in enumerate(kernel_keys(old_ks))}
        return np.array([lookup.get(key.tobytes(), -1) for key in kernel_keys(ks)], np.int64)

    def _unchanged(self, ks, regrouped: bool, reuse: np.ndarray) -> bool:
        """Whether ``ks`` is the current kernel set as it is: same grouping, every kernel reusing its own
        solution, the same fill colours (then the solved kernels on the device serve as they are)."""
        old = self.kernels
        return (self._dk is not None and not regrouped and len(reuse) == old.n_kernels
                and bool((reuse == np.arange(len(reuse))).all()) and np.array_equal(ks.fill, old.fill))

    def _rasterise(self, dk, ks, reuse: np.ndarray, dirty) -> int:
        """Step 4: draw the dirty pixels again (all when ``dirty`` is None); returns how many."""
        pm = self._pm
        if dirty is None:
            self._out = gtps.rasterise(dk, pm.index_d, pm.st_d, threads=self.threads, clamp=self.clamp)
            return self.H * self.W
        stale, near = self._dirty_flags(ks, self.kernels, reuse)
        kept = isinstance(dirty, np.ndarray)  # the maps were kept: only kernels make pixels dirty
        if kept and not (stale.any() or near.any()):
            return 0
        return rasterise_dirty(dk, pm.index_d, pm.st_d, self._out, stale, near, None if kept else dirty,
                               threads=self.threads, clamp=self.clamp)

    def _mix_borders(self, model, dk) -> None:
        """Step 5: the shown image, the frame with the anti-aliased borders mixed in (as ``render`` does).

        The frame of one region per pixel stays as it is, so an update
        redraws only its dirty pixels; the border pixels (a thin set) are
        mixed again after every update, their ``(S, T)`` across kept while
        the geometry stays.
        """
        if self._mix is None:
            # found, and their (S, T) across, on the device: nothing crosses to the host
            mix = DeviceBorders(self._drawn, self.W, self.H, self.device).mix_device(self._pm.index_d,
                                                                             threads=self.threads)
            self._mix = (mix, border_st_device(self._patches, mix) if mix.n else None)
        mix, st = self._mix
        self._shown = warp().clone(self._out)
        if mix.n:
            gtps.mix_border_device(dk, self._shown, mix, *st, threads=self.threads, clamp=self.clamp)

    def _add_detail(self, model) -> None:
        """Step 6: the detail layer added to the shown image (as ``render`` does)."""
        if model.detail is None:
            return
        from ..gpu.detail import DeviceDetail, add_detail

        src, dd = self._detail
        if src is None or src != model.detail:
            dd = DeviceDetail(model.detail, self.device)
            self._detail = (model.detail, dd)
        add_detail(dd, self._shown, self._pm.index_d, self._pm.st_d, threads=self.threads)

    def _dirty_flags(self, ks, old_ks, reuse):
        """Per region and per kernel, which pixels may depend on a re-solved kernel or a changed grid or fill.

        Returns
        -------
        stale : (R,) bool
            Regions whose grid (or, without features, fill colour) changed: every pixel is dirty.
        near : (n_kernels,) bool
            Kernels whose own cell or a neighbouring cell (8-neighbourhood) was
            re-solved: the pixels of their cell are dirty.
        """
        solved = reuse < 0
        R = ks.grid.shape[0]
        stale = np.ones(R, bool)
        if old_ks is not None and old_ks.grid.shape == ks.grid.shape:
            stale = (old_ks.grid[:, :2] != ks.grid[:, :2]).any(axis=1)
        featureless = ks.grid[:, 0] == 0
        if old_ks is not None and old_ks.fill.shape == ks.fill.shape:
            stale |= featureless & (old_ks.fill != ks.fill).any(axis=1)
        near = np.zeros(ks.n_kernels, bool)
        for r in np.unique(ks.region[solved]):
            gx, gy, k0 = (int(v) for v in ks.grid[r])
            m = solved[k0 : k0 + gx * gy].reshape(gy, gx)
            p = np.pad(m, 1)
            d = np.zeros_like(m)
            for dy in (0, 1, 2):
                for dx in (0, 1, 2):
                    d |= p[dy : dy + gy, dx : dx + gx]
            near[k0 : k0 + gx * gy] = d.ravel()
        return stale, near


__all__ = ["LiveImage", "UpdateStats", "same_edge_widths", "same_geometry", "same_grouping", "kernel_keys"]
