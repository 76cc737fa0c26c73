"""Model -> pixels at any size (paper V and VII-A).

1-2. :func:`tpsv.rendering.pixelmap.pixel_map`: the region and the ``(S, T)`` of
   every output pixel (outline rasterisation in drawing order on the device,
   :mod:`tpsv.gpu.regions`, then the inverse patch map).
3. ``tps.group_kernels``: sub-patch kernels (derived at load time).
4. ``gpu.tps``: build + solve every kernel, then rasterise with the blend;
   by default each kernel is clamped to its features' Lab range before
   blending (removes TPS overshoot; ``clamp=False`` for the plain TPS).

5. :mod:`tpsv.gpu.coverage` (the device kernel of what
   :mod:`tpsv.rendering.borders` specifies): every pixel a region border
   crosses gets its box-filter coverage of the region across, mixed in on
   the device (``antialias=False``: one region per pixel, its centre's).

Steps 3-5 are :func:`shade`, which the encoder calls on pixel maps it keeps.

Output pixel ``(X, Y)`` at scale ``k`` samples ``((X + 0.5) / k, (Y + 0.5) / k)``
of the model's pixel space (``tpsv.model``); for a size ``W x H`` the scale is
per axis, ``W / model.width`` and ``H / model.height``. Where outlines
overlap, the draw order decides (:mod:`tpsv.rendering.pixelmap`).

Memory: :func:`render` draws an output of at most :data:`ONE_PIECE_PIXELS`
pixels in one piece; a larger one, and any output of :func:`render_bands`
over :data:`TILE_PIXELS`, in bands of rows of at most :data:`TILE_PIXELS`
pixels, each band's pixels identical to the same rows of a
one-piece render: the same sample points, the outlines prepared once, the
pixels no outline covers given the same region (``outline.GapFill``), the
kernels grouped and solved once. Peak memory then stays under
:data:`MEMORY_BUDGET` for any output size that :func:`output_size` accepts
(at most :data:`MAX_SIDE` px a side and :data:`MAX_PIXELS` px);
:func:`render` returns one array up to :data:`MAX_ARRAY_PIXELS` pixels.

A region without features (``vectorize`` never makes one) renders flat in the
mean colour of all the model's features (mid grey, Lab (50, 0, 0), when the
model has none); a pixel outside every region (only when the model has no
regions) is mid grey.
"""

from __future__ import annotations

import time

import numpy as np

from .. import tps
from ..errors import TpsvError
from ..geometry import curves
from ..image import to_uint8, to_uint16
from ..gpu import resolve_device, warp
from .borders import BorderMix
from .pixelmap import BandMaps, no_tick, pixel_map

from .limits import MAX_ARRAY_PIXELS, MAX_PIXELS, MAX_SIDE, MEMORY_BUDGET, ONE_PIECE_PIXELS, TILE_PIXELS


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
        fw, fh = model.width * k, model.height * k
        if not (fw <= 4 * MAX_SIDE and fh <= 4 * MAX_SIDE):  # checked before rounding: 1e308 stays a float
            raise TpsvError(_too_large(_size_text(fw), _size_text(fh)))
        W = int(round(fw))
        H = int(round(fh))
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
        raise TpsvError(_too_large(W, H))
    return W, H


def _size_text(v: float) -> str:
    return str(int(round(v))) if v < 1e15 else f"{v:.3g}"


def _too_large(W, H) -> str:
    return f"output {W}x{H} px is larger than tpsv renders (at most {MAX_SIDE} px a side, {MAX_PIXELS:,} px in all)"


def _as_int(v) -> int:
    f = float(v)
    if not np.isfinite(f) or f != int(f):
        raise ValueError(v)
    return int(f)


def render(model, width=None, height=None, scale=None, device: str = "cpu", kernels=None, threads=None, clamp: bool = True,
           antialias: bool = True, alpha: bool = False, keep_on_device: bool = False):
    """Render ``model``; returns float32 sRGB ``(H, W, 3)`` in ``[0, 1]`` (RGBA ``(H, W, 4)`` with ``alpha``).

    ``kernels``: a :class:`tpsv.tps.KernelSet` from an earlier
    ``tps.group_kernels(model)`` to reuse (it must belong to this model).
    ``threads``: host threads for CPU launches (default: all cores).
    ``clamp``: clamp each kernel to its features' Lab range before blending
    (``tpsv.gpu.tps``; False gives the plain localised TPS).
    ``antialias``: mix the regions across borders into the pixels the
    borders cross (:mod:`tpsv.rendering.borders`); False gives one region per
    pixel (its centre's).
    ``alpha``: add the opacity, straight (not premultiplied): 0 in
    transparent regions (``Region.transparent``), 1 elsewhere, and along a
    border with a transparent region the opaque side's coverage, that side's
    colour unmixed (:func:`opacity`). Without it a transparent region shows
    its fill, the mean colour along its edge (``tpsv.encode.alpha.straight``).
    ``keep_on_device``: return the frame where it was rendered, a ``(H, W)``
    ``wp.array`` of ``wp.vec3f`` on ``device`` (the same values, not copied
    to the host), for a viewer or an encoder that goes on working on the
    GPU; outputs of at most :data:`ONE_PIECE_PIXELS`, without ``alpha``.

    Outputs over :data:`ONE_PIECE_PIXELS` pixels are rendered in bands
    (:func:`render_bands`, identical pixels) into the array; outputs over
    :data:`MAX_ARRAY_PIXELS` are refused (:class:`TpsvError`): write them
    band by band with :func:`render_bands`.
    """
    W, H = output_size(model, width, height, scale)
    if keep_on_device and (alpha or W * H > ONE_PIECE_PIXELS):
        raise TpsvError(f"keep_on_device renders RGB frames of at most {ONE_PIECE_PIXELS:,} px "
                        f"(asked: {W}x{H}{' with alpha' if alpha else ''})")
    if W * H <= ONE_PIECE_PIXELS:
        img, _ = _render(model, W, H, None, device, kernels, threads, clamp, timed=False, antialias=antialias,
                         alpha=alpha, download=not keep_on_device)
        return img
    if W * H > MAX_ARRAY_PIXELS:
        raise TpsvError(f"output {W}x{H} px is too large to hold in memory as one image "
                        f"(at most {MAX_ARRAY_PIXELS:,} px); render it band by band (render_bands)")
    img = np.empty((H, W, 4 if alpha else 3), np.float32)
    for y0, rows in _bands(model, W, H, device, kernels, threads, clamp, TILE_PIXELS, antialias, alpha):
        img[y0:y0 + rows.shape[0]] = rows
    return img


def render_bands(model, width=None, height=None, scale=None, device: str = "cpu", kernels=None, threads=None,
                 clamp: bool = True, max_pixels: int = TILE_PIXELS, antialias: bool = True, alpha: bool = False,
                 depth: int = 8):
    """Render ``model`` band by band: yields ``(y0, rows)``, top to bottom.

    ``rows`` is uint8 sRGB ``(h, W, 3)`` (uint16 with ``depth=16``), rows
    ``y0 .. y0 + h`` of the output, rounded as ``tpsv.image.encode_image``
    rounds :func:`render`'s floats, so the bands put together are exactly
    the 8- or 16-bit image of :func:`render`.
    Each band holds at most ``max_pixels`` pixels (one row at least); an
    output of at most ``max_pixels`` pixels comes as one band. Memory stays
    in proportion to a band whatever the output size (module docstring).
    Arguments as :func:`render`.

    Yields
    ------
    y0 : int
    rows : ndarray (h, W, 3) uint8 or uint16
        ``(h, W, 4)`` RGBA with ``alpha``.
    """
    if depth not in (8, 16):
        raise TpsvError(f"bands of {depth} bits a sample cannot be rendered (8 or 16)")
    W, H = output_size(model, width, height, scale)
    rounding = to_uint8 if depth == 8 else to_uint16
    for y0, rows in _bands(model, W, H, device, kernels, threads, clamp, max_pixels, antialias, alpha, depth):
        yield y0, rounding(rows)


def render_png(model, width=None, height=None, scale=None, device: str = "cpu", kernels=None, threads=None,
               clamp: bool = True, max_pixels: int = TILE_PIXELS, antialias: bool = True, alpha: bool = False):
    """The PNG file of the render, piece by piece: what ``tpsv render`` writes.

    An output of at most ``max_pixels`` pixels is one piece,
    ``tpsv.image.encode_png(render(...))`` (the bytes tpsv has always
    written). A larger one is streamed (:mod:`tpsv.png`) from
    :func:`render_bands`: memory stays bounded, and the decoded pixels are the
    same 8-bit image. Arguments as :func:`render_bands` (``alpha``: an RGBA PNG).

    Yields
    ------
    bytes
        Consecutive pieces of the file.
    """
    from ..image import encode_png
    from ..png import png_chunks

    W, H = output_size(model, width, height, scale)
    if W * H <= max_pixels:
        yield encode_png(render(model, W, H, None, device, kernels, threads, clamp, antialias, alpha))
        return
    yield from png_chunks(W, H, render_bands(model, W, H, None, device, kernels, threads, clamp, max_pixels, antialias,
                                             alpha), channels=4 if alpha else 3)


def _bands(model, W: int, H: int, device, kernels, threads, clamp, max_pixels: int, antialias: bool = True,
           alpha: bool = False, depth: int | None = None):
    """``(y0, float32 rows)`` of the ``W x H`` render, in bands of at most ``max_pixels`` pixels.

    With ``depth`` (8 or 16), the bands of an output of more than one are rounded to uint8 or
    uint16 by the host's rule (:func:`tpsv.image.to_uint8`), the colours on the device
    (:mod:`tpsv.gpu.quantize`) before they are copied.
    """
    max_pixels = max(int(max_pixels), 1)
    if W * H <= max_pixels:
        img, _ = _render(model, W, H, None, device, kernels, threads, clamp, timed=False, antialias=antialias,
                         alpha=alpha)
        yield 0, img
        return
    from ..gpu import tps as gtps
    from ..gpu.coverage import DeviceBorders
    from ..gpu.quantize import to_uint

    device = resolve_device(device)
    rounding = to_uint8 if depth == 8 else to_uint16
    rows = max(1, max_pixels // W)
    ks = kernels if kernels is not None else tps.group_kernels(model)
    if ks.grid.shape[0] != len(model.regions):
        raise TpsvError("the kernel set does not belong to this model")
    drawn = curves.as_drawn(model, W, H)
    maps = BandMaps(drawn, W, H, device, max_gap_bytes=MEMORY_BUDGET // 4, threads=threads)
    borders = DeviceBorders(drawn, W, H, device) if antialias else None
    dk = gtps.solve(gtps.upload(ks, device), threads=threads)
    dd = device_detail(model, device)
    for y0 in range(0, H, rows):
        y1 = min(y0 + rows, H)
        pm = maps.band(y0, y1)
        out = gtps.rasterise(dk, pm.index_d, pm.st_d, threads=threads, clamp=clamp)
        mix = None
        if borders is not None:
            hr = borders.halo
            halo = (maps.index(max(0, y0 - hr), y0) if y0 > 0 else None,
                    maps.index(y1, min(H, y1 + hr)) if y1 < H else None)
            mix = borders.mix_device(pm.index_d, y0, halo=halo, threads=threads)
        opaque, mix = opacity(model, pm.index, None if mix is None else mix.numpy()) if alpha else (None, mix)
        _mix_borders(model, dk, out, mix, threads, clamp, maps.patch_set)
        _add_detail(model, out, pm.index_d, pm.st_d, device, threads, dd)
        if depth is not None:
            out = to_uint(out, depth, threads)
        band = out.numpy().reshape(y1 - y0, W, 3)
        del pm, out
        if opaque is not None:
            band = np.dstack([band, opaque if depth is None else rounding(opaque)])
        yield y0, band


def render_timed(model, width=None, height=None, scale=None, device: str = "cpu", repeat: int = 1, threads=None, clamp: bool = True):
    """Render and time each stage (seconds, best of ``repeat``): returns ``(image, timings)``.

    Stages: ``regions`` (outline rasterisation, host), ``upload_regions``
    (the region map to the device), ``patchmap``, ``edges`` (the border
    pixels and their coverage, host), ``group`` (host), ``upload``,
    ``solve`` (build + solve), ``rasterise``, ``borders`` (the regions
    across mixed in), ``detail`` (the detail layer added; with its upload),
    ``download``, and ``total`` (their sum). Device stages end
    with a device synchronisation. The first call on a device also compiles
    or loads Warp modules: call once before timing (``repeat >= 2``).
    """
    W, H = output_size(model, width, height, scale)
    if W * H > ONE_PIECE_PIXELS:
        raise TpsvError(f"output {W}x{H} px is rendered in bands; stage timings are for at most {ONE_PIECE_PIXELS:,} px")
    best: dict = {}
    img = None
    for _ in range(max(1, int(repeat))):
        img, t = _render(model, W, H, None, device, None, threads, clamp, timed=True)
        for k, v in t.items():
            best[k] = min(best.get(k, np.inf), v)
    best["total"] = sum(v for k, v in best.items() if k != "total")
    return img, best


class Stopwatch:
    """Wall time per stage, each stage ending with a device synchronisation.

    Call it with a stage name when the stage is done; ``times`` maps names to
    seconds since the previous call (or since the stopwatch was made), summed
    over the calls with that name.

    Parameters
    ----------
    device : str
        Warp device to synchronise.
    """

    def __init__(self, device: str):
        self.device = device
        self.times: dict = {}
        self._wp = warp()
        self._t0 = time.perf_counter()

    def __call__(self, name: str) -> None:
        self._wp.synchronize_device(self.device)
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + (now - self._t0)
        self._t0 = now


def shade(model, index, st, device: str = "cpu", kernels=None, threads=None, clamp: bool = True, tick=no_tick,
          borders=None, download: bool = True):
    """Render steps 3-4: the colours of pixels whose region and ``(S, T)`` are known.

    Parameters
    ----------
    model : Model
    index : (H, W) int32 ndarray or device array
        Region of every pixel (``PixelMap.index`` / ``index_d``).
    st : (H, W, 2) float32 ndarray or (H, W) vec2 device array
        ``(S, T)`` of every pixel (``PixelMap.st`` / ``st_d``).
    device : str
        Warp device.
    kernels : KernelSet, optional
        ``tps.group_kernels(model)`` (or :func:`tpsv.tps.recolor` of one) to reuse.
    threads : int, optional
        Host threads for CPU launches.
    clamp : bool
        Clamp each kernel to its features' Lab range before blending.
    tick : callable(str), optional
        Called after the ``group``, ``upload``, ``solve``, ``rasterise``,
        ``borders`` and ``download`` stages.
    borders : BorderMix, optional
        Anti-aliased border pixels (:mod:`tpsv.rendering.borders`) to mix in.
    download : bool
        Copy the result to the host (else return the device frame).

    Returns
    -------
    ndarray (H, W, 3) float32
        sRGB in ``[0, 1]``; without ``download`` the ``(H, W)`` ``wp.vec3f``
        array on ``device``.
    """
    return Renderer(model, device, threads, clamp, kernels, tick).shade(index, st, borders, download, tick)


def border_st(model, borders, device, patch_set=None) -> tuple[np.ndarray, np.ndarray]:
    """``(S, T)`` of each of ``borders``' pixels in the patch of the region across, and of the region
    across a second border (zeros where there is none)."""
    from ..gpu.patchmap import inverse_points

    patches = [r.patch for r in model.regions]
    return tuple(inverse_points(patches, other, borders.xy, device=device, patch_set=patch_set)
                 for other in (borders.other, borders.other2))


def border_st_device(patch_set, mix) -> tuple:
    """:func:`border_st` of a :class:`tpsv.gpu.coverage.DeviceBorderMix`, left on the device (``vec2f`` arrays)."""
    from ..gpu.patchmap import inverse_points_device

    return tuple(inverse_points_device(patch_set, other, mix.xy) for other in (mix.other, mix.other2))


def device_detail(model, device: str):
    """The model's detail layer on ``device`` (:class:`tpsv.gpu.detail.DeviceDetail`), or None."""
    if model.detail is None:
        return None
    from ..gpu.detail import DeviceDetail

    return DeviceDetail(model.detail, resolve_device(device))


def _add_detail(model, out, index, st, device, threads, dd=None) -> None:
    """Add the model's detail layer (if any) to ``out`` (device frame)."""
    if model.detail is None:
        return
    from ..gpu.detail import add_detail

    add_detail(dd if dd is not None else device_detail(model, device), out, index, st, threads=threads)


def _mix_borders(model, dk, out, borders, threads, clamp, patch_set=None) -> None:
    """Mix the regions across borders into ``out`` (device frame) at ``borders``' pixels.

    ``borders``: a host :class:`BorderMix`, or a
    :class:`tpsv.gpu.coverage.DeviceBorderMix` whose pixels never leave the
    device (the same ``(S, T)`` across and the same mix).
    """
    if borders is None or borders.pixels.size == 0:
        return
    from ..gpu import tps as gtps

    if not isinstance(borders, BorderMix):
        from ..gpu.patchmap import PatchSet

        ps = patch_set if patch_set is not None else PatchSet.build([r.patch for r in model.regions], dk.device)
        gtps.mix_border_device(dk, out, borders, *border_st_device(ps, borders), threads=threads, clamp=clamp)
        return

    st, st2 = border_st(model, borders, dk.device, patch_set)
    gtps.mix_border(dk, out, borders, st, st2, threads=threads, clamp=clamp)


def opacity(model, index: np.ndarray, mix: BorderMix | None) -> tuple[np.ndarray, BorderMix | None]:
    """The alpha channel of a frame or band, and its border mix for straight alpha.

    A pixel of a transparent region has alpha 0, any other 1. A border
    pixel's alpha is the share of its opaque sides (own, across, across a
    second border); its colour is the opaque sides' alone (mixed as usual
    when all are opaque), so that compositing the straight-alpha image over
    a background gives the anti-aliased edge.

    Parameters
    ----------
    model : Model
    index : ndarray (h, W) int32
        Region of every pixel (-1: none, shown opaque).
    mix : BorderMix or None

    Returns
    -------
    alpha : ndarray (h, W) float32
    mix : BorderMix or None
        ``mix`` with its shares renormalised over the opaque sides, without
        the pixels that then take only their own colour.
    """
    clear = np.array([bool(getattr(r, "transparent", False)) for r in model.regions] + [False])
    alpha = (~clear[index]).astype(np.float32)
    if mix is None or mix.pixels.size == 0 or not clear.any():
        return alpha, mix
    a1, a2 = mix.alpha.astype(np.float64), mix.alpha2.astype(np.float64)
    # each side's share of the pixel, counted only where its region is opaque
    w0 = np.where(clear[index.reshape(-1)[mix.pixels]], 0.0, a1 * a2)
    w1 = np.where(clear[mix.other], 0.0, (1.0 - a1) * a2)
    w2 = np.where(clear[mix.other2], 0.0, 1.0 - a2)  # (other2 -1: the last entry, opaque, with share 0)
    total = w0 + w1 + w2
    alpha.reshape(-1)[mix.pixels] = total
    # the colour is the opaque sides' alone: the same two steps with their shares renormalised
    first = w0 + w1
    b2 = np.where(total > 0, first / np.maximum(total, 1e-300), 1.0)
    b1 = np.where(first > 0, w0 / np.maximum(first, 1e-300), 1.0)
    keep = (b1 < 1.0) | (b2 < 1.0)
    return alpha, BorderMix(pixels=mix.pixels[keep], other=mix.other[keep], alpha=b1[keep].astype(np.float32),
                            xy=mix.xy[keep], other2=mix.other2[keep], alpha2=b2[keep].astype(np.float32))


def _render(model, width, height, scale, device, kernels, threads, clamp, timed: bool, antialias: bool = True,
            alpha: bool = False, download: bool = True):
    """:func:`render` and, when ``timed``, the seconds per stage (else an empty dict)."""
    W, H = output_size(model, width, height, scale)
    device = resolve_device(device)
    watch = Stopwatch(device) if timed else None
    tick = watch if timed else no_tick
    img = Renderer(model, device, threads, clamp, kernels, tick).render(W, H, antialias=antialias, alpha=alpha,
                                                                       keep_on_device=not download, tick=tick)
    return img, (watch.times if timed else {})


class Renderer:
    """A model prepared once for rendering on a device, then rendered at any size.

    What does not depend on the output size is done here, once: the features
    grouped into kernels, the kernels uploaded and solved, the detail texture
    uploaded. Each :meth:`render` then does only the per-size work (region
    map, inverse patch map, border coverage, rasterise, border mix, detail),
    so a viewer that zooms, or a batch that renders one model at several
    sizes, pays the preparation once; the outlines and border pieces prepared
    for the last output size are kept, so frames of one size (a viewer's
    window) pay only the device stages. The pixels are :func:`render`'s.

    :func:`render` and :func:`shade` are a renderer used once.

    Parameters
    ----------
    model : Model
        Not copied: do not change it while the renderer is in use.
    device : str
        Warp device.
    threads : int, optional
        Host threads for CPU launches.
    clamp : bool
        As :func:`render`.
    kernels : KernelSet, optional
        ``tps.group_kernels(model)`` (or :func:`tpsv.tps.recolor` of one) to reuse.
    tick : callable(str), optional
        Called after the ``group``, ``upload`` and ``solve`` stages.

    Examples
    --------
    >>> r = Renderer(model, device="cuda")                        # doctest: +SKIP
    >>> frame = r.render(1920, 1080, keep_on_device=True)         # doctest: +SKIP
    >>> big = r.render(scale=4)                                   # doctest: +SKIP
    """

    def __init__(self, model, device: str = "cpu", threads=None, clamp: bool = True, kernels=None, tick=no_tick):
        # gpu.tps imports Warp and defines its kernels: only commands that render pay for it
        from ..gpu import tps as gtps

        self.model = model
        self.device = resolve_device(device)
        self.threads = threads
        self.clamp = bool(clamp)
        self.kernels = kernels if kernels is not None else tps.group_kernels(model)
        if self.kernels.grid.shape[0] != len(model.regions):
            raise TpsvError("the kernel set does not belong to this model")
        tick("group")
        self._dk = gtps.upload(self.kernels, self.device)
        tick("upload")
        gtps.solve(self._dk, threads=threads)
        tick("solve")
        self._dd = device_detail(model, self.device)  # its upload counts as the detail stage
        tick("detail")
        # the last output size rendered, the model as drawn there, its DeviceOutlines and DeviceBorders once made
        self._size, self._drawn, self._outlines, self._borders = None, None, None, None
        self._patches = None
        self._breaks = None

    @property
    def patch_set(self):
        """The model's patches on the device (:class:`tpsv.gpu.patchmap.PatchSet`), made at first use.

        Every frame maps its pixels and its border pixels through them; they do
        not depend on the output size, so they are flattened and uploaded once.
        """
        if self._patches is None:
            from ..gpu.patchmap import PatchSet

            self._patches = PatchSet.build([r.patch for r in self.model.regions], self.device)
        return self._patches

    def _for_size(self, W: int, H: int) -> None:
        if self._size != (W, H):
            # the old size's device arrays go before the new ones come
            self._size, self._outlines, self._borders = (W, H), None, None
            # the outlines as drawn at this size (curves as polygons), made once for both; where
            # their curves break depends on the model alone
            if self._breaks is None and getattr(self.model, "curves", False):
                self._breaks = curves.breaks([p for r in self.model.regions for p in r.outline],
                                             self.model.width, self.model.height)
            self._drawn = curves.as_drawn(self.model, W, H, self._breaks)

    def _outlines_for(self, W: int, H: int):
        from ..gpu.regions import DeviceOutlines

        self._for_size(W, H)
        if self._outlines is None:
            self._outlines = DeviceOutlines(self._drawn, W, H, self.device, self.threads)
        return self._outlines

    def _borders_for(self, W: int, H: int):
        from ..gpu.coverage import DeviceBorders

        self._for_size(W, H)
        if self._borders is None:
            self._borders = DeviceBorders(self._drawn, W, H, self.device)
        return self._borders

    def render(self, width=None, height=None, scale=None, antialias: bool = True, alpha: bool = False,
               keep_on_device: bool = False, tick=no_tick):
        """The render at ``width x height`` or ``scale``, as :func:`render` (outputs of at most
        :data:`ONE_PIECE_PIXELS`; ``keep_on_device``: the frame on the device, RGB only).

        ``tick`` is called after the ``regions``, ``patchmap``, ``edges`` and
        :meth:`shade`'s stages.
        """
        model = self.model
        W, H = output_size(model, width, height, scale)
        if W * H > ONE_PIECE_PIXELS:
            raise TpsvError(f"output {W}x{H} px is rendered in bands: use render_bands or render_png")
        if keep_on_device and alpha:
            raise TpsvError("keep_on_device renders RGB frames; alpha is on the host")
        pm = pixel_map(model, W, H, self.device, tick, outlines=self._outlines_for(W, H), patch_set=self.patch_set)
        mix = self._borders_for(W, H).mix_device(pm.index_d, threads=self.threads) if antialias else None
        # straight alpha changes which pixels mix: on the host; otherwise the border pixels stay on the device
        opaque, mix = opacity(model, pm.index, None if mix is None else mix.numpy()) if alpha else (None, mix)
        tick("edges")
        img = self.shade(pm.index_d, pm.st_d, mix, download=not keep_on_device, tick=tick)
        return img if opaque is None else np.dstack([img, opaque])

    def shade(self, index, st, borders=None, download: bool = True, tick=no_tick):
        """Render steps 3-5 for pixels whose region and ``(S, T)`` are known (:func:`shade`).

        ``tick`` is called after the ``rasterise``, ``borders``, ``detail``
        and ``download`` stages.
        """
        from ..gpu import tps as gtps

        H, W = index.shape[:2]
        out = gtps.rasterise(self._dk, index, st, threads=self.threads, clamp=self.clamp)
        tick("rasterise")
        if borders is not None and borders.pixels.size:
            _mix_borders(self.model, self._dk, out, borders, self.threads, self.clamp, self.patch_set)
        tick("borders")
        _add_detail(self.model, out, index, st, self.device, self.threads, self._dd)
        tick("detail")
        if not download:
            return out
        img = out.numpy().reshape(H, W, 3)
        tick("download")
        return img
