"""Rate-distortion curves of tpsv against JPEG and WebP, and Bjontegaard delta PSNR.

:func:`rd_table` sweeps tpsv's quality knob (with the texture detail layer and
without it) and the raster codecs' quality settings over one image;
:func:`bd_psnr` condenses two such curves into one number: how many dB one
curve lies above the other on average over a common range of rates.
"""

from __future__ import annotations

import cv2
import numpy as np

from . import baseline
from .. import metrics

#: tpsv qualities swept (``--quality``; the same list with and without detail).
RD_QUALITIES = (10, 30, 50, 75, 90, 100)
#: JPEG / WebP qualities swept.
RD_CODEC_QUALITIES = (5, 10, 20, 30, 40, 50, 60, 70, 80, 90, 95)
#: The bpp range the BD-PSNR figures are restricted to (issue 11: where the
#: detail layer competes; below it every codec is a blur, above it PSNR saturates).
BD_RANGE = (0.25, 2.0)
#: The curves of :func:`rd_table`, in the order they are printed.
CURVES = ("tpsv", "tpsv_no_detail", "jpeg", "webp")
#: The BD-PSNR comparisons of :func:`rd_table`: (name, curve b, curve a), b against a.
COMPARISONS = (
    ("tpsv_vs_jpeg", "tpsv", "jpeg"),
    ("tpsv_vs_webp", "tpsv", "webp"),
    ("tpsv_no_detail_vs_jpeg", "tpsv_no_detail", "jpeg"),
    ("tpsv_no_detail_vs_webp", "tpsv_no_detail", "webp"),
)


def _curve(rate, psnr) -> tuple[np.ndarray, np.ndarray]:
    """log10 rate (strictly increasing) and PSNR of one curve's usable points.

    Points with a non-finite PSNR (a lossless point has infinite PSNR) or a
    rate that is not positive and finite cannot be placed on a log-rate axis
    and are dropped. The rest are sorted by rate; where several points share
    a rate only the one with the highest PSNR is kept, because PCHIP needs
    strictly increasing abscissae and an encoder would never pick the worse
    of two equal-sized files. Points whose PSNR falls while the rate rises are
    kept: they are what the encoder produced, and dropping them would flatter
    the curve.
    """
    r = np.asarray(rate, dtype=np.float64).ravel()
    p = np.asarray(psnr, dtype=np.float64).ravel()
    if r.shape != p.shape:
        raise ValueError(f"{r.size} rates but {p.size} PSNR values")
    ok = np.isfinite(r) & (r > 0) & np.isfinite(p)
    r, p = r[ok], p[ok]
    # lexsort: by rate, then by PSNR descending, so the first of each rate is its best
    order = np.lexsort((-p, r))
    r, p = r[order], p[order]
    first = np.ones(r.size, bool)
    first[1:] = r[1:] > r[:-1]
    return np.log10(r[first]), p[first]


def bd_psnr(rate_a, psnr_a, rate_b, psnr_b, *, lo: float | None = None, hi: float | None = None) -> float:
    """Bjontegaard delta PSNR of curve b against curve a (positive: b is better).

    Each curve's PSNR is interpolated over log10 of its rate by a monotone
    piecewise cubic (:class:`scipy.interpolate.PchipInterpolator`, which,
    unlike the original cubic polynomial fit, neither overshoots between
    points nor depends on points far away) and integrated over the log-rate
    range both curves cover; the result is the mean vertical distance, b - a.
    Nothing is extrapolated.

    Parameters
    ----------
    rate_a, psnr_a : array_like
        Rates (any positive unit, e.g. bpp or bytes; the same for both
        curves) and PSNR (dB) of the reference curve. Points need not be
        sorted; see :func:`_curve` for the points that are dropped.
    rate_b, psnr_b : array_like
        The same for the curve under test.
    lo, hi : float, optional
        Restrict the integration to rates in ``[lo, hi]`` (in the unit of
        the rates), intersected with the curves' common range.

    Returns
    -------
    float
        Mean PSNR difference in dB; nan when a curve has fewer than 2 usable
        points or the range left to integrate over is empty.
    """
    from scipy.interpolate import PchipInterpolator

    xa, ya = _curve(rate_a, psnr_a)
    xb, yb = _curve(rate_b, psnr_b)
    if xa.size < 2 or xb.size < 2:
        return float("nan")
    x0 = max(xa[0], xb[0])
    x1 = min(xa[-1], xb[-1])
    if lo is not None:
        x0 = max(x0, np.log10(lo)) if lo > 0 else x0
    if hi is not None:
        x1 = min(x1, np.log10(hi)) if hi > 0 else -np.inf
    if not x1 > x0:
        return float("nan")
    ia = PchipInterpolator(xa, ya).integrate(x0, x1)
    ib = PchipInterpolator(xb, yb).integrate(x0, x1)
    return float((ib - ia) / (x1 - x0))


def _codec_point(rgb: np.ndarray, ext: str, flag: int, quality: int) -> dict:
    ok, buf = cv2.imencode(ext, baseline._bgr8(rgb), [flag, int(quality)])
    if not ok:
        raise RuntimeError(f"{ext} encoding failed")
    dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    h, w = rgb.shape[:2]
    return {"quality": int(quality), "bpp": metrics.bpp(buf.size, w, h), "psnr": metrics.psnr(rgb, dec),
            "bytes": int(buf.size)}


def rd_table(
    rgb: np.ndarray,
    labels: np.ndarray | None,
    device: str = "cpu",
    qualities=RD_QUALITIES,
    codec_qualities=RD_CODEC_QUALITIES,
) -> dict:
    """Rate-distortion points of tpsv (with and without the detail layer), JPEG and WebP, and BD-PSNR.

    tpsv is encoded by :func:`tpsv.encode.rate.encode_quality` at each of
    ``qualities``; its PSNR is that of the decoded file rendered at scale 1.
    JPEG and WebP are OpenCV's encoders at each of ``codec_qualities``, on
    the image quantised to 8 bits. PSNR is :func:`tpsv.metrics.psnr` (8-bit
    RGB), bpp :func:`tpsv.metrics.bpp` of the whole file.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
        Label map for tpsv; segmented automatically (seed 0) when None.
    device : str
        Warp device of tpsv's renders.
    qualities : sequence of int
        tpsv qualities (1-100), the same for both tpsv curves.
    codec_qualities : sequence of int
        JPEG and WebP qualities (1-100).

    Returns
    -------
    dict
        ``{"curves": {name: [{"quality", "bpp", "psnr", "bytes"}, ...]},
        "bd_psnr": {comparison: {"range": dB, "overlap": dB}}, "bd_range":
        [lo, hi]}``. Curve names are :data:`CURVES` (tpsv points also carry
        ``"seconds"``), comparisons :data:`COMPARISONS`; ``"range"`` is
        restricted to :data:`BD_RANGE` bpp, ``"overlap"`` covers all rates
        both curves reach. A BD figure is nan where the curves do not overlap.
    """
    from ..encode.rate import encode_quality
    from ..encode.vectorize import label_map

    h, w = rgb.shape[:2]
    # Segment once here: encode_quality would otherwise segment again on each of its calls.
    labels = label_map(rgb, labels)
    curves: dict[str, list[dict]] = {}
    for name, detail in (("tpsv", True), ("tpsv_no_detail", False)):
        pts = []
        for q in qualities:
            res = encode_quality(rgb, labels, quality=int(q), detail=detail, device=device)
            pts.append({"quality": int(q), "bpp": metrics.bpp(len(res.data), w, h), "psnr": float(res.psnr),
                        "bytes": len(res.data), "seconds": float(res.seconds)})
        curves[name] = pts
    curves["jpeg"] = [_codec_point(rgb, ".jpg", cv2.IMWRITE_JPEG_QUALITY, q) for q in codec_qualities]
    curves["webp"] = [_codec_point(rgb, ".webp", cv2.IMWRITE_WEBP_QUALITY, q) for q in codec_qualities]

    def rp(name):
        return [p["bpp"] for p in curves[name]], [p["psnr"] for p in curves[name]]

    bd = {}
    for key, b, a in COMPARISONS:
        ra, pa = rp(a)
        rb, pb = rp(b)
        bd[key] = {"range": bd_psnr(ra, pa, rb, pb, lo=BD_RANGE[0], hi=BD_RANGE[1]),
                   "overlap": bd_psnr(ra, pa, rb, pb)}
    return {"curves": curves, "bd_psnr": bd, "bd_range": list(BD_RANGE)}


def rd_table_text(name: str, rd: dict) -> str:
    """The printed rate-distortion table of one image: a row per quality, bpp / PSNR per curve, then BD-PSNR."""
    titles = {"tpsv": "tpsv", "tpsv_no_detail": "tpsv no-detail", "jpeg": "JPEG", "webp": "WebP"}
    curves = rd["curves"]
    rows = sorted({p["quality"] for pts in curves.values() for p in pts})
    at = {c: {p["quality"]: p for p in curves[c]} for c in CURVES if c in curves}

    def cell(p):
        return "-" if p is None else f"{p['bpp']:.3f} / {_db(p['psnr'])}"

    out = [f"Rate-distortion, {name}: bpp / PSNR (dB) per quality (tpsv: --quality; JPEG, WebP: OpenCV)",
           f"{'Q':>4}" + "".join(f"{titles[c]:>20}" for c in at)]
    for q in rows:
        out.append(f"{q:>4}" + "".join(f"{cell(at[c].get(q)):>20}" for c in at))
    lo, hi = rd["bd_range"]
    out.append(f"BD-PSNR (dB, positive: first better){'':<4}{f'{lo:g}-{hi:g} bpp':>14}{'overlap':>10}")
    for key, b, a in COMPARISONS:
        if key not in rd["bd_psnr"]:
            continue
        v = rd["bd_psnr"][key]
        out.append(f"  {titles[b] + ' vs ' + titles[a]:<38}{_db(v['range'], '+.2f'):>14}{_db(v['overlap'], '+.2f'):>10}")
    return "\n".join(out)


def _db(v: float, spec: str = ".2f") -> str:
    if np.isnan(v):
        return "n/a"
    if not np.isfinite(v):
        return "inf"
    return format(v, spec)
