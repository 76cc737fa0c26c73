"""The benchmark behind ``tpsv bench``: timing and quality tables in the style of
the paper's Tables I-III, a rate-distortion plot, the rate-distortion table of
tpsv against JPEG and WebP (:mod:`tpsv.bench.rd`), and the magnification test.

Every figure here is measured when the benchmark runs; nothing is copied in.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import cv2
import numpy as np

from . import baseline
from . import rd as rate_distortion
from .. import metrics
from .. import tps
from ..errors import TpsvError
from ..geometry.patch import patch_pixel_scale
from ..encode.features import FeatureExtractor
from ..model import Model
from ..encode.vectorize import build_geometry, evaluate, make_model, vectorize

#: JPEG qualities swept for the rate-distortion curve and the best-w search.
JPEG_QUALITIES = tuple(range(5, 101, 5))
#: A global (whole-region) TPS solve is timed directly up to this many features;
#: beyond, it is timed on a subset and scaled by n^3 (marked as estimated).
GLOBAL_EXACT_MAX = 3000


def _point(rgb: np.ndarray, nbytes: int, err: float, **extra) -> dict:
    h, w = rgb.shape[:2]
    return {
        "psnr": metrics.psnr_of_mse(err),
        "w": metrics.efficiency(err, nbytes, w, h),
        "bpp": metrics.bpp(nbytes, w, h),
        "bytes": int(nbytes),
        **extra,
    }


def jpeg_table(rgb: np.ndarray, tpsv_bytes: int) -> dict:
    """JPEG at every quality of the sweep, at the best w, and at tpsv's byte count."""
    sweep = []
    for q in JPEG_QUALITIES:
        n, dec = baseline.jpeg(rgb, q)
        sweep.append(_point(rgb, n, metrics.mse(rgb, dec), quality=q))
    best = max(sweep, key=lambda p: p["w"])
    q, n, dec = baseline.jpeg_at_bytes(rgb, tpsv_bytes)
    same = _point(rgb, n, metrics.mse(rgb, dec), quality=q)
    return {"sweep": sweep, "best_w": best, "same_bytes": same}


def _fit(pts: np.ndarray, vals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A TPS through distinct points (duplicates dropped; collinear sets fall back
    to least squares), for timing."""
    pts, first = np.unique(pts, axis=0, return_index=True)
    try:
        return tps.tps_fit(pts, vals[first]), pts
    except np.linalg.LinAlgError:
        n = pts.shape[0]
        d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
        A = np.zeros((n + 3, n + 3))
        A[:n, :n] = tps.tps_phi(d2)
        A[:n, n] = A[n, :n] = 1
        A[:n, n + 1 :] = pts
        A[n + 1 :, :n] = pts.T
        rhs = np.zeros((n + 3, vals.shape[1]))
        rhs[:n] = vals[first]
        return np.linalg.lstsq(A, rhs, rcond=None)[0], pts


def _global_solve_seconds(model: Model, n_eval: int = 2000) -> dict:
    """Seconds of one dense TPS per region (construction + solve + evaluation at
    every pixel of the region), on the CPU with numpy/LAPACK."""
    total = 0.0
    estimated = False
    rng = np.random.default_rng(0)
    feats = model.features
    for r, reg in enumerate(model.regions):
        sel = np.flatnonzero(feats.region == r)
        n = sel.size
        if n < 3:
            continue
        sx, sy = patch_pixel_scale(reg.patch)
        pts = feats.st[sel] * [sx, sy]
        vals = feats.lab[sel].astype(np.float64)
        m = n if n <= GLOBAL_EXACT_MAX else GLOBAL_EXACT_MAX
        sub = rng.choice(n, m, replace=False) if m < n else np.arange(n)
        t0 = time.perf_counter()
        coef, used = _fit(pts[sub], vals[sub])
        solve = time.perf_counter() - t0
        q = rng.random((n_eval, 2)) * [sx, sy]
        t0 = time.perf_counter()
        tps.tps_eval(coef, used, q)
        ev = time.perf_counter() - t0
        # Pixels of the region ~ its share of the image; evaluation is linear in
        # pixels and in features.
        area = model.width * model.height * (np.sum(feats.region == r) / max(len(feats), 1))
        if m < n:
            estimated = True
            solve *= (n / m) ** 3
        total += solve + ev * (area / n_eval) * (n / m)
    return {"seconds": total, "estimated": estimated}


def _local_unpacked_seconds(model: Model) -> dict:
    """Seconds of the localised scheme without packing: each sub-patch solves only
    its own cell's features (unequal sizes, one LAPACK solve each, CPU) and
    evaluates only its own cell's share of the pixels (no overlap)."""
    ks = tps.group_kernels(model)
    feats = model.features
    pix_per_feature = model.width * model.height / max(len(feats), 1)
    t0 = time.perf_counter()
    for k in range(ks.n_kernels):
        r = ks.region[k]
        s0, s1, t0c, t1c = ks.cell[k]
        sel = np.flatnonzero(
            (feats.region == r) & (feats.st[:, 0] >= s0) & (feats.st[:, 0] < s1)
            & (feats.st[:, 1] >= t0c) & (feats.st[:, 1] < t1c)
        )
        if sel.size < 3:
            continue
        sx, sy = ks.scale[r]
        pts = feats.st[sel] * [sx, sy]
        coef, used = _fit(pts, feats.lab[sel].astype(np.float64))
        npix = max(1, int(sel.size * pix_per_feature))
        q = pts[0] + np.random.default_rng(k).random((npix, 2))
        tps.tps_eval(coef, used, q)
    return {"seconds": time.perf_counter() - t0, "kernels": ks.n_kernels}


def timing_table(model: Model, device: str) -> dict:
    """Table I: construction + solve + rasterisation, three ways."""
    from ..rendering.raster import render_timed

    _, t = render_timed(model, device=device, repeat=3)
    ks = tps.group_kernels(model)
    return {
        "global_cpu": _global_solve_seconds(model),
        "local_unpacked_cpu": _local_unpacked_seconds(model),
        "local_packed": {
            "device": device,
            "seconds": t["solve"] + t["rasterise"] + t["patchmap"],
            "stages": t,
            "kernels": ks.n_kernels,
            "kernel_size": ks.kernel_size,
        },
    }


#: Output sizes of the device table: full HD and 4K UHD.
DEVICE_SIZES = ((1920, 1080), (3840, 2160))


def device_table(model: Model, device: str, sizes=DEVICE_SIZES, repeat: int = 10) -> dict:
    """Renders on ``device`` at each of ``sizes``: stage timings (best of
    ``repeat``), end to end, and the largest difference from the CPU render.

    ``end_to_end_ms`` is every stage from a loaded model to the image in device
    memory (host stages and uploads included, the download not: a viewer keeps
    the frame on the GPU, ``render(..., keep_on_device=True)``);
    ``device_ms`` the device stages alone; ``prepared_ms`` a frame by a
    :class:`~tpsv.rendering.raster.Renderer` into device memory once the
    model (kernels) and the size (outlines, border pieces) are prepared:
    what a viewer pays per frame; ``new_size_ms`` a frame of that renderer at
    a size it has not prepared (2, 4, ... px smaller each time: a viewer
    zooming), best of ``min(repeat, 5)``.
    """
    import time

    from ..gpu import warp
    from ..rendering.raster import Renderer, render, render_timed

    rows = []
    prepared = Renderer(model, device=device)
    for size in sizes:
        img, t = render_timed(model, width=size[0], height=size[1], device=device, repeat=repeat)
        ref = render(model, width=size[0], height=size[1], device="cpu")
        best = np.inf
        for _ in range(max(1, repeat)):
            t0 = time.perf_counter()
            prepared.render(size[0], size[1], keep_on_device=True)
            warp().synchronize_device(prepared.device)
            best = min(best, time.perf_counter() - t0)
        zoom = np.inf
        for i in range(min(max(1, repeat), 5)):
            t0 = time.perf_counter()
            prepared.render(max(1, size[0] - 2 * (i + 1)), max(1, size[1] - 2 * (i + 1)), keep_on_device=True)
            warp().synchronize_device(prepared.device)
            zoom = min(zoom, time.perf_counter() - t0)
        rows.append({
            "size": list(size),
            "stages_ms": {k: v * 1e3 for k, v in t.items()},
            "device_ms": (t["patchmap"] + t["solve"] + t["rasterise"] + t.get("borders", 0.0)
                          + t.get("detail", 0.0)) * 1e3,
            "end_to_end_ms": (t["total"] - t["download"]) * 1e3,
            "prepared_ms": best * 1e3,
            "new_size_ms": zoom * 1e3,
            "max_abs_diff_vs_cpu": float(np.abs(img - ref).max()),
        })
        del img, ref
    return {"device": device, "sizes": rows}


#: Output size of the second edit table on a GPU (a viewer's window).
EDIT_SIZE = (1920, 1080)


def edit_table(model: Model, device: str, size: tuple[int, int] | None = None) -> dict:
    """Rebuild + render seconds of typical edits through :class:`tpsv.rendering.live.LiveImage`
    (only kernels whose features changed are solved again), best of 3, at ``size``
    (width, height; default the model's); ``stages``: the stage split of one more, timed, update."""
    from ..edit.deform import affine
    from ..rendering.live import LiveImage
    from ..edit.recolor import recolor

    if not model.regions or not len(model.features):
        return {}
    # the largest region: the edits then touch a good share of the image
    big = int(np.argmax(np.bincount(model.features.region, minlength=len(model.regions))))
    cx, cy = model.width / 2.0, model.height / 2.0
    edits = {
        "recolor_point": lambda m: recolor(m, at=(cx, cy), radius=40, tolerance=30, hue=90),
        "recolor_region": lambda m: recolor(m, region=big, tolerance=1000, hue=60),
        "deform_translate": lambda m: affine(m, big, [[1, 0, 6], [0, 1, 4]]),
        "deform_scale": lambda m: affine(m, big, [[1.1, 0, 0], [0, 1.1, 0]]),
    }
    out = {}
    for name, edit in edits.items():
        edited = edit(model)
        best = None
        for _ in range(3):
            live = LiveImage(model, *(size or (None, None)), device=device)
            stats = live.update(edited)
            if best is None or stats.seconds["total"] < best["seconds"]["total"]:
                best = stats.as_dict()
        # the stages of one more update, timed apart (each then ends with a synchronisation: slower)
        timed = LiveImage(model, *(size or (None, None)), device=device, timed=True)
        best["stages"] = timed.update(edited).as_dict()["seconds"]
        out[name] = best
    return out


def magnification_table(rgb: np.ndarray, factor: int, device: str) -> dict:
    """Area-downscale by ``factor``, magnify back (``tpsv.rendering.magnify``: dense model,
    back-projected colours, one region, the picture refined); compare with the original."""
    h, w = rgb.shape[:2]
    h, w = h - h % factor, w - w % factor
    ref = rgb[:h, :w]
    small = baseline.downscale_area(ref, factor)
    from ..rendering.magnify import magnify_raster

    _, big = magnify_raster(small, (w, h), device=device)
    rows = {"tpsv": big}
    for method in ("bicubic", "lanczos"):
        rows[method] = baseline.upscale(small, factor, method)[:h, :w]
    return {
        name: {"psnr": metrics.psnr(ref, img), "ssim": metrics.ssim(ref, img), "gmsd": metrics.gmsd(ref, img),
               "edge_sharpness": edge_sharpness(img)}
        for name, img in rows.items()
    } | {"reference_edge_sharpness": edge_sharpness(ref)}


#: Width (output px) of the band along region borders that :func:`file_magnification_table` also scores.
BORDER_BAND = 4


def file_magnification_table(rgb: np.ndarray, labels: np.ndarray | None, factor: int, device: str) -> dict:
    """A ``.tpsv`` file magnified: the picture area-downscaled by ``factor`` is vectorised at the
    default quality (its label map sampled at each block's centre, or segmented when there is none)
    and rendered at ``factor`` (``tpsv``: ``tpsv render``; ``magnify``: ``tpsv magnify``, the
    render refined under the area constraint of the file's own scale-1 render); compared with the
    original, next to bicubic upscaling of the same small picture and of the file's own scale-1
    render (what a raster viewer would show).

    Each method gets PSNR and GMSD over the picture and ``border_psnr`` over the pixels within
    :data:`BORDER_BAND` output px of the file's region borders (as drawn at ``factor``): where
    the vector outlines and their edge widths decide the picture.

    Returns
    -------
    dict
        ``{"bytes", "regions", "tpsv": {"psnr", "gmsd", "border_psnr"}, "magnify": ..., "file_bicubic": ...,
        "bicubic": ...}``
    """
    from ..encode.rate import encode_quality
    from ..rendering.pixelmap import region_index
    from ..rendering.raster import render

    h, w = rgb.shape[:2]
    h, w = h - h % factor, w - w % factor
    ref = rgb[:h, :w]
    small = baseline.downscale_area(ref, factor)
    small_labels = None
    if labels is not None:
        c = factor // 2
        small_labels = np.ascontiguousarray(labels[c:h:factor, c:w:factor][:small.shape[0], :small.shape[1]])
    res = encode_quality(small, small_labels, seed=0, device=device)
    from ..rendering.magnify import magnify_model

    rows = {"tpsv": render(res.model, width=w, height=h, device=device),
            "magnify": magnify_model(res.model, (w, h), device=device),
            "file_bicubic": baseline.upscale(render(res.model, device=device), factor, "bicubic")[:h, :w],
            "bicubic": baseline.upscale(small, factor, "bicubic")[:h, :w]}
    index = region_index(res.model, w, h)
    border = np.zeros((h, w), bool)
    border[:, 1:] |= index[:, 1:] != index[:, :-1]
    border[1:] |= index[1:] != index[:-1]
    side = 2 * BORDER_BAND + 1
    band = cv2.dilate(border.astype(np.uint8), np.ones((side, side), np.uint8)) > 0
    out: dict = {"bytes": len(res.data), "regions": len(res.model.regions)}
    for name, img in rows.items():
        err = ((np.asarray(img, np.float64) - ref) ** 2).mean(axis=2)
        out[name] = {"psnr": metrics.psnr(ref, img), "gmsd": metrics.gmsd(ref, img),
                     "border_psnr": float(10 * np.log10(1.0 / max(err[band].mean(), 1e-12))) if band.any() else None}
    return out


#: Columns of the edge table.
EDGE_METHODS = ("tpsv", "default", "auto", "bicubic", "lanczos")


def edge_table(variants: int = 3, size: int = 96, scale: int = 8, *, iterations: int = 20,
               device: str = "cpu") -> dict:
    """Edges at magnification: the synthetic shapes of :mod:`tpsv.bench.shapes`.

    For each variant (seeds ``0 .. variants-1``) the ``size`` px picture, quantised
    to 8 bits as a PNG would be, is vectorised with its label map twice: by the
    paper's threshold search (``tpsv``: ``iterations`` of it; the pure vector
    image of ``vectorize --search``) and at the default quality with the detail
    layer (``default``: ``vectorize --labels``), and without its label map
    (``auto``: ``vectorize`` without options, the regions found by
    :func:`tpsv.geometry.segment.segment_auto`); each is rendered at
    ``scale``, and bicubic and Lanczos upscale the same pixels. Each is
    compared with the analytic picture at ``scale`` (PSNR and GMSD).

    Returns
    -------
    dict
        ``{"size", "scale", "variants": [{"seed", "tpsv": {"psnr", "gmsd", "bytes"},
        "default": ..., "auto": ..., "bicubic": {"psnr", "gmsd"}, "lanczos": ...}],
        "mean": {method: {"psnr", "gmsd"}}}``
    """
    from .shapes import shapes
    from ..encode.rate import encode_quality
    from ..rendering.raster import render

    rows = []
    for seed in range(variants):
        rgb, labels = shapes(size, 1, seed)
        rgb = np.round(rgb * 255.0).astype(np.float32) / 255.0
        ref, _ = shapes(size, scale, seed)
        res = vectorize(rgb, labels, iterations=iterations, seed=seed, device=device)
        default = encode_quality(rgb, labels, seed=seed, device=device)
        auto = encode_quality(rgb, None, seed=seed, device=device)
        outs = {"tpsv": render(res.model, scale=scale, device=device),
                "default": render(default.model, scale=scale, device=device),
                "auto": render(auto.model, scale=scale, device=device)}
        for method in ("bicubic", "lanczos"):
            outs[method] = baseline.upscale(rgb, scale, method)
        row = {"seed": seed} | {k: {"psnr": metrics.psnr(ref, v), "gmsd": metrics.gmsd(ref, v)}
                                for k, v in outs.items()}
        for k, v in (("tpsv", res), ("default", default), ("auto", auto)):
            row[k]["bytes"] = len(v.data)
        row["auto"]["regions"] = len(auto.model.regions)
        rows.append(row)
    mean = {k: {m: float(np.mean([r[k][m] for r in rows])) for m in ("psnr", "gmsd")}
            for k in EDGE_METHODS} if rows else {}
    return {"size": size, "scale": scale, "variants": rows, "mean": mean}


def edge_table_text(edges: dict) -> str:
    """The printed edge table."""
    out = [f"Edges: synthetic shapes {edges['size']}x{edges['size']} rendered at {edges['scale']}x "
           f"against the analytic picture: PSNR (dB) / GMSD (tpsv: --search, pure vector; "
           f"default: quality 75 with detail; auto: the same without the label map)",
           f"{'variant':<12}" + "".join(f"{k:>18}" for k in EDGE_METHODS) + f"{'tpsv - lanczos':>16}"]
    rows = [(f"seed {r['seed']}", r) for r in edges["variants"]]
    if edges["variants"]:
        rows.append(("mean", edges["mean"]))
    for name, r in rows:
        cells = [f"{_fmt(r[k]['psnr'])} / {_fmt(r[k]['gmsd'], '.4f')}" for k in EDGE_METHODS]
        out.append(f"{name:<12}" + "".join(f"{c:>18}" for c in cells)
                   + f"{_fmt(r['tpsv']['psnr'] - r['lanczos']['psnr'], '+.2f'):>16}")
    return "\n".join(out)


#: Columns of the graphics table.
GRAPHICS_METHODS = ("tpsv", "magnify", "bicubic", "lanczos")


def graphics_table(scale: int = 8, device: str = "cpu") -> dict:
    """Flat-colour drawings magnified: the pictures of :mod:`tpsv.bench.drawings`.

    Each drawing is vectorised without a label map at the default quality
    (``tpsv``: ``vectorize`` then ``render --scale``; its regions found by
    :func:`tpsv.geometry.segment.segment_auto`, which reads a flat graphic's
    patches) and magnified as a raster (``magnify``: ``tpsv magnify``),
    next to bicubic and Lanczos, all at ``scale`` against the exact picture
    (PSNR and GMSD).

    Returns
    -------
    dict
        ``{"scale", "drawings": [{"name", "tpsv": {"psnr", "gmsd", "bytes", "regions"}, "magnify": ...,
        "bicubic": ..., "lanczos": ...}], "mean": {method: {"psnr", "gmsd"}}}``
    """
    from .drawings import NAMES, drawing
    from ..encode.rate import encode_quality
    from ..rendering.magnify import magnify_raster
    from ..rendering.raster import render

    rows = []
    for name in NAMES:
        rgb, ref = drawing(name), drawing(name, scale)
        h, w = rgb.shape[:2]
        res = encode_quality(rgb, None, seed=0, device=device)
        outs = {"tpsv": render(res.model, scale=scale, device=device),
                "magnify": magnify_raster(rgb, (w * scale, h * scale), device=device)[1]}
        for method in ("bicubic", "lanczos"):
            outs[method] = baseline.upscale(rgb, scale, method)
        row = {"name": name} | {k: {"psnr": metrics.psnr(ref, v), "gmsd": metrics.gmsd(ref, v)}
                                for k, v in outs.items()}
        row["tpsv"] |= {"bytes": len(res.data), "regions": len(res.model.regions)}
        rows.append(row)
    mean = {k: {m: float(np.mean([r[k][m] for r in rows])) for m in ("psnr", "gmsd")} for k in GRAPHICS_METHODS}
    return {"scale": scale, "drawings": rows, "mean": mean}


def graphics_table_text(graphics: dict) -> str:
    """The printed graphics table."""
    out = [f"Graphics: flat-colour drawings magnified {graphics['scale']}x against the exact picture: PSNR (dB) / "
           f"GMSD (tpsv: vectorize without a label map, quality 75, render; magnify: the raster magnified)",
           f"{'drawing':<12}{'regions':>8}{'bytes':>7}" + "".join(f"{k:>18}" for k in GRAPHICS_METHODS)]
    rows = [(r["name"], r) for r in graphics["drawings"]] + [("mean", graphics["mean"])]
    for name, r in rows:
        t = r["tpsv"]
        cells = [f"{_fmt(r[k]['psnr'])} / {_fmt(r[k]['gmsd'], '.4f')}" for k in GRAPHICS_METHODS]
        out.append(f"{name:<12}{t.get('regions', ''):>8}{t.get('bytes', ''):>7}" + "".join(f"{c:>18}" for c in cells))
    return "\n".join(out)


def edge_sharpness(rgb: np.ndarray) -> float:
    """Mean gradient magnitude on the strongest 5 % of edges (higher = sharper)."""
    grey = cv2.cvtColor(np.clip(rgb, 0, 1).astype(np.float32), cv2.COLOR_RGB2GRAY)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1)
    mag = np.hypot(gx, gy).ravel()
    top = np.sort(mag)[-max(1, mag.size // 20):]
    return float(top.mean())


def bench_image(
    name: str,
    rgb: np.ndarray,
    labels: np.ndarray | None,
    *,
    device: str = "cpu",
    iterations: int = 20,
    grid: int = 4,
    seed: int = 0,
    magnify: int = 4,
    rd: bool = True,
    step: Callable[[str], None] | None = None,
) -> dict:
    """All benchmark figures for one image (see the module docstring).

    With ``rd`` the result also has ``"rd"``, the rate-distortion table of
    :func:`tpsv.bench.rd.rd_table` (tpsv with and without the detail layer,
    JPEG, WebP and BD-PSNR); reported steps are then also ``"rd"``.
    """
    from ..encode import search as selection

    tick = step or (lambda label: None)
    h, w = rgb.shape[:2]
    t0 = time.perf_counter()
    res = vectorize(rgb, labels, search=True, iterations=iterations, seed=seed, device=device)
    vec_seconds = time.perf_counter() - t0
    tick("search")
    start = res.history[0] if res.history else None
    optimum = _point(rgb, len(res.data), res.mse, t_canny=res.model.params.t_canny, t_super=res.model.params.t_super)

    # The same geometry and precomputed extractor serve the initial guess and the grid.
    label_map = labels if labels is not None else _auto_labels(rgb, seed)
    geometry = build_geometry(label_map, rgb)
    extractor = FeatureExtractor(rgb, geometry.index)
    c0, s0 = selection.initial_thresholds(rgb, geometry.index)
    base = res.model.params

    def point_at(tc: float, ts: float) -> dict:
        model = make_model(rgb, geometry, extractor, replace(base, t_canny=float(tc), t_super=float(ts)))
        data, _, err = evaluate(rgb, model, device)
        return _point(rgb, len(data), err, t_canny=float(tc), t_super=float(ts), features=len(model.features))

    initial = point_at(c0, s0)
    tick("initial")
    brute = []
    if grid > 0:
        for tc in np.geomspace(c0 / 2, c0 * 8, grid):
            for ts in np.geomspace(s0 / 2, s0 * 8, grid):
                brute.append(point_at(tc, ts))
        tick("grid")
    best_brute = max(brute + [optimum], key=lambda p: p["w"])

    model = res.model
    t0 = time.perf_counter()
    from ..rendering.raster import render

    render(model, device=device)
    render_seconds = time.perf_counter() - t0
    jp = jpeg_table(rgb, len(res.data))
    tick("jpeg")
    rd_points = None
    if rd:
        # the label map the search used: rd_table would otherwise segment with its own seed
        rd_points = rate_distortion.rd_table(rgb, label_map, device=device)
        tick("rd")
    timing = timing_table(model, device)
    tick("timing")
    mag = magnification_table(rgb, magnify, device) if min(h, w) >= 8 * magnify else None
    file_mag = file_magnification_table(rgb, labels, magnify, device) if min(h, w) >= 8 * magnify else None
    tick("magnify")
    dev = device_table(model, device) if device != "cpu" else None
    edits = edit_table(model, device)
    edits_window = edit_table(model, device, EDIT_SIZE) if device != "cpu" else None
    tick("edits")
    return {
        "name": name,
        "width": w,
        "height": h,
        "regions": len(model.regions),
        "features": len(model.features),
        "vectorize_seconds": vec_seconds,
        "render_seconds": render_seconds,
        "initial": initial,
        "search_start": None if start is None else {"t_canny": start.t_canny, "t_super": start.t_super, "w": start.w},
        "optimal": optimum | {"features": len(model.features)},
        "brute_force": best_brute,
        "grid": brute,
        "history": [
            {"t_canny": t.t_canny, "t_super": t.t_super, "E": t.E, "C": t.C, "w": t.w} for t in res.history
        ],
        "jpeg": jp,
        **({"rd": rd_points} if rd else {}),
        "timing": timing,
        "magnification": mag,
        "file_magnification": file_mag,
        "device_check": dev,
        "edits": edits,
        "edits_window": edits_window,
    }


def bench_model(name: str, model: Model, *, device: str = "cpu") -> dict:
    """Timing figures for an existing model (no source image: no quality tables)."""
    return {
        "name": name,
        "width": model.width,
        "height": model.height,
        "regions": len(model.regions),
        "features": len(model.features),
        "timing": timing_table(model, device),
        "device_check": device_table(model, device) if device != "cpu" else None,
        "edits": edit_table(model, device),
        "edits_window": edit_table(model, device, EDIT_SIZE) if device != "cpu" else None,
    }


def _auto_labels(rgb: np.ndarray, seed: int) -> np.ndarray:
    from ..geometry import segment

    return segment.segment_auto(rgb, seed=seed)


# --------------------------------------------------------------------------- presentation


def _fmt(v, spec=".2f") -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and not np.isfinite(v):
        return "inf"
    return format(v, spec)


def device_table_text(results: list[dict], device: str) -> str:
    """The printed device table of the results that have one (``device_check``)."""
    out = []
    out.append(f"Renders on {device}: ms per stage (best of 10), end to end, max |{device} - cpu|")
    out.append(f"{'image':<12}{'size':>10}{'patchmap':>9}{'solve':>7}{'raster':>7}{'borders':>8}{'detail':>7}"
               f"{'device':>7}{'regions*':>9}{'edges*':>8}{'upload*':>8}{'group*':>7}{'e2e':>8}{'prep.':>7}{'zoom':>7}"
               f"{'max diff':>10}")
    for r in results:
        for d in r["device_check"]["sizes"]:
            st = d["stages_ms"]
            up = st.get("upload_regions", 0.0) + st.get("upload", 0.0)
            out.append(f"{r['name']:<12}{'x'.join(map(str, d['size'])):>10}{st['patchmap']:>9.2f}{st['solve']:>7.2f}"
                       f"{st['rasterise']:>7.2f}{st.get('borders', 0.0):>8.2f}{st.get('detail', 0.0):>7.2f}"
                       f"{d['device_ms']:>7.2f}{st['regions']:>9.1f}{st.get('edges', 0.0):>8.1f}{up:>8.1f}"
                       f"{st['group']:>7.1f}{d['end_to_end_ms']:>8.1f}{d['prepared_ms']:>7.1f}"
                       f"{d['new_size_ms']:>7.1f}"
                       f"{d['max_abs_diff_vs_cpu']:>10.2e}")
    out.append("  * host stages and host-to-device copies (outline rasterisation, border pixels and their")
    out.append("    coverage, region map and kernel upload, kernel grouping); 'device' is the sum of the")
    out.append("    device stages (inverse patch map, build/solve, rasterise, border mix, detail); 'e2e' every")
    out.append("    stage from a loaded model to the image in device memory (the download not included);")
    out.append("    'prep.' a frame by a Renderer once the model's kernels and the size's outlines are prepared;")
    out.append("    'zoom' a frame of that Renderer at a size it has not prepared")
    return "\n".join(out)


def edit_table_text(results: list[dict], device: str) -> list[str]:
    """The printed edit tables (lines, each table after a blank line): at the model's size and,
    on a GPU, at :data:`EDIT_SIZE`."""
    out = []
    for key, where in (("edits", "at the model's size"), ("edits_window", "at {}x{}".format(*EDIT_SIZE))):
        eds = [r for r in results if r.get(key)]
        if eds:
            out.append("")
            out.append(f"Edits on {device} {where}: live rebuild + render, ms (kernels solved / total)")
            out.append(f"{'image':<12}" + "".join(f"{n:>22}" for n in eds[0][key]))
            for r in eds:
                cells = [f"{e['seconds']['total'] * 1e3:.1f} ({e['solved']}/{e['kernels']})"
                         for e in r[key].values()]
                out.append(f"{r['name']:<12}" + "".join(f"{c:>22}" for c in cells))
    return out


def tables(results: list[dict], device: str, edges: dict | None = None, graphics: dict | None = None) -> str:
    """The printed report (``edges``: an :func:`edge_table`, ``graphics``: a :func:`graphics_table`,
    printed after the magnification tables)."""
    out = []
    out.append(f"Table I: construction + solve + rasterisation, seconds per image (local packed on {device})")
    out.append(f"{'image':<12}{'global CPU':>14}{'local CPU':>12}{'packed':>10}{'kernels':>9}{'K':>5}")
    for r in results:
        t = r["timing"]
        g = t["global_cpu"]
        gs = _fmt(g["seconds"], ".3g") + ("*" if g["estimated"] else "")
        out.append(
            f"{r['name']:<12}{gs:>14}{_fmt(t['local_unpacked_cpu']['seconds'], '.3g'):>12}"
            f"{_fmt(t['local_packed']['seconds'], '.3g'):>10}{t['local_packed']['kernels']:>9}"
            f"{t['local_packed']['kernel_size']:>5}"
        )
    out.append("  * estimated: solved on 3000 features and scaled by n^3")
    out.append("")
    out.append("Table II: PSNR (dB), w = 1/(E*C), bpp")
    hdr = f"{'image':<12}" + "".join(f"{c:>26}" for c in ("initial", "optimal", "brute-force", "JPEG best w", "JPEG same bytes"))
    out.append(hdr)
    for r in results:
        if "initial" not in r:
            continue
        cells = []
        for p in (r["initial"], r["optimal"], r["brute_force"], r["jpeg"]["best_w"], r["jpeg"]["same_bytes"]):
            cells.append(f"{_fmt(p['psnr'])} {_fmt(p['w'], '.3g')} {_fmt(p['bpp'])}")
        out.append(f"{r['name']:<12}" + "".join(f"{c:>26}" for c in cells))
    for r in results:
        if r.get("rd"):
            out.append("")
            out.append(rate_distortion.rd_table_text(r["name"], r["rd"]))
    out.append("")
    out.append("Magnification 4x (area-downscaled, then upscaled): PSNR / SSIM / GMSD / edge sharpness")
    out.append(f"{'image':<12}{'tpsv':>31}{'bicubic':>31}{'lanczos':>31}{'original sharpness':>20}")
    for r in results:
        m = r.get("magnification")
        if not m:
            continue
        cells = [f"{_fmt(m[k]['psnr'])} / {_fmt(m[k]['ssim'], '.3f')} / {_fmt(m[k].get('gmsd'), '.4f')}"
                 f" / {_fmt(m[k]['edge_sharpness'], '.2f')}" for k in ("tpsv", "bicubic", "lanczos")]
        out.append(f"{r['name']:<12}" + "".join(f"{c:>31}" for c in cells) + f"{_fmt(m['reference_edge_sharpness']):>20}")
    files = [r for r in results if r.get("file_magnification")]
    if files:
        out.append("")
        out.append("A .tpsv magnified 4x (the area-downscaled picture vectorised at the default quality, rendered"
                   " at 4x):")
        out.append(f"PSNR / GMSD / PSNR within {BORDER_BAND} px of region borders; 'tpsv': tpsv render,"
                   " 'magnify': tpsv magnify (refined); 'file bicubic': the file's scale-1 render upscaled")
        out.append(f"{'image':<12}{'bytes':>7}{'tpsv':>26}{'magnify':>26}{'file bicubic':>26}{'bicubic':>26}")
        for r in files:
            m = r["file_magnification"]
            cells = [f"{_fmt(m[k]['psnr'])} / {_fmt(m[k]['gmsd'], '.4f')} / {_fmt(m[k]['border_psnr'])}"
                     for k in ("tpsv", "magnify", "file_bicubic", "bicubic") if k in m]
            out.append(f"{r['name']:<12}{m['bytes']:>7}" + "".join(f"{c:>26}" for c in cells))
    if edges:
        out.append("")
        out.append(edge_table_text(edges))
    if graphics:
        out.append("")
        out.append(graphics_table_text(graphics))
    devs = [r for r in results if r.get("device_check")]
    if devs:
        out.append("")
        out.append(device_table_text(devs, device))
    out.extend(edit_table_text(results, device))
    out.append("")
    out.append("CPU seconds (this machine)")
    out.append(f"{'image':<12}{'size':>10}{'features':>10}{'vectorize':>11}{'render':>9}")
    for r in results:
        if "vectorize_seconds" not in r:
            continue
        out.append(f"{r['name']:<12}{str(r['width']) + 'x' + str(r['height']):>10}{r['features']:>10}"
                   f"{_fmt(r['vectorize_seconds']):>11}{_fmt(r['render_seconds'], '.3f'):>9}")
    return "\n".join(out)


#: Colours (BGR) of the rate-distortion table's curves in :func:`rd_plot_png`, and their legend names.
RD_STYLE = {
    "tpsv": ((30, 30, 30), "tpsv"),
    "tpsv_no_detail": ((180, 0, 180), "tpsv no-detail"),
    "jpeg": ((200, 80, 0), "JPEG"),
    "webp": ((0, 140, 230), "WebP"),
}


def rd_plot_png(result: dict, size: tuple[int, int] = (640, 420)) -> bytes:
    """PSNR against bpp: tpsv (grid and search points) and the JPEG sweep, as PNG bytes.

    When ``result`` has a rate-distortion table (``"rd"``), its curves are drawn
    too: tpsv with and without the detail layer, JPEG and WebP, with a legend.
    """
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    tp = [(p["bpp"], p["psnr"]) for p in result["grid"] + [result["optimal"], result["initial"]]]
    jp = [(p["bpp"], p["psnr"]) for p in result["jpeg"]["sweep"]]
    rd_curves = {k: [(p["bpp"], p["psnr"]) for p in v] for k, v in (result.get("rd") or {}).get("curves", {}).items()
                 if k in RD_STYLE}
    pts = [p for p in tp + jp + [q for c in rd_curves.values() for q in c] if np.isfinite(p[1])]
    if not pts:
        raise TpsvError("nothing to plot")
    x0, x1 = 0.0, max(p[0] for p in pts) * 1.05
    y0 = np.floor(min(p[1] for p in pts) / 5) * 5
    y1 = np.ceil(max(p[1] for p in pts) / 5) * 5
    L, R, T, B = 60, 20, 30, 50

    def xy(bpp, db):
        return (int(L + (bpp - x0) / (x1 - x0) * (W - L - R)), int(H - B - (db - y0) / max(y1 - y0, 1e-9) * (H - T - B)))

    cv2.rectangle(img, (L, T), (W - R, H - B), (0, 0, 0), 1)
    for db in np.arange(y0, y1 + 0.1, 5):
        p = xy(x0, db)
        cv2.line(img, (L, p[1]), (W - R, p[1]), (220, 220, 220), 1)
        cv2.putText(img, f"{db:.0f}", (8, p[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    for k in range(6):
        b = x0 + (x1 - x0) * k / 5
        p = xy(b, y0)
        cv2.putText(img, f"{b:.1f}", (p[0] - 10, H - B + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.putText(img, "bpp", (W // 2, H - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
    cv2.putText(img, "PSNR dB", (4, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    jp_sorted = sorted(p for p in jp if np.isfinite(p[1]))
    for a, b in zip(jp_sorted, jp_sorted[1:]):
        cv2.line(img, xy(*a), xy(*b), (200, 80, 0), 2, cv2.LINE_AA)
    # the rate-distortion curves under the search points, so those stay visible
    for k, curve in rd_curves.items():
        colour = RD_STYLE[k][0]
        c = sorted(p for p in curve if np.isfinite(p[1]))
        for a, b in zip(c, c[1:]):
            cv2.line(img, xy(*a), xy(*b), colour, 1, cv2.LINE_AA)
        for p in c:
            cv2.drawMarker(img, xy(*p), colour, cv2.MARKER_SQUARE, 7, 1, cv2.LINE_AA)
    for p in tp:
        if np.isfinite(p[1]):
            cv2.circle(img, xy(*p), 4, (0, 0, 220), -1, cv2.LINE_AA)
    o = result["optimal"]
    cv2.circle(img, xy(o["bpp"], o["psnr"]), 8, (0, 160, 0), 2, cv2.LINE_AA)
    cv2.putText(img, f"{result['name']}: tpsv (red, green = searched optimum), JPEG (blue)", (L, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    if rd_curves:
        # legend in the lower right, where PSNR curves rarely go (they rise with bpp)
        for i, k in enumerate(k for k in RD_STYLE if k in rd_curves):
            colour, label = RD_STYLE[k]
            y = H - B - 10 - 16 * (len(rd_curves) - 1 - i)
            x = W - R - 150
            cv2.line(img, (x, y - 4), (x + 20, y - 4), colour, 2, cv2.LINE_AA)
            cv2.putText(img, f"Q sweep: {label}", (x + 26, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)
    ok, buf = cv2.imencode(".png", img)
    return buf.tobytes()
