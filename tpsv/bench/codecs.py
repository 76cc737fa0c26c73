"""Which codec for the detail texture: a rate-distortion comparison on real residuals.

``tpsv bench --codecs`` runs :func:`detail_codec_table` per image: the
residual of the quality mode's vector base (``tpsv.encode.rate``) coded by

* ``dct``: a codec of our own: 8x8 DCT of the Y/Cb/Cr residual (chroma at
  half resolution), uniform quantisation with a step rising with frequency,
  coefficients in frequency-major planes, zstd level 19;
* ``webp``: OpenCV's WebP of the 8-bit residual (``128 + residual``; the
  few larger residuals clip);
* ``avif-rgb``: OpenCV's AVIF, 10-bit colour image of the residual (the
  encoder subsamples chroma 2:1 both ways);
* ``avif-planes``: OpenCV's AVIF, 10-bit monochrome image of the Y, Cb, Cr
  planes one below the other: what ``tpsv.codec.detail`` stores.

Each point is ``(bpp, PSNR)`` of base + decoded residual against the photo,
the base's bytes included; BD-PSNR of each codec against ``avif-planes``
(negative: worse than the chosen one).
"""

from __future__ import annotations

import cv2
import numpy as np
import zstandard

from .. import metrics
from ..encode.detail import texel_rgb
from ..encode.rate import Trials
from ..encode.vectorize import build_geometry, scheme_params
from ..codec.detail import decode_texels, encode_texels
from ..model import DETAIL_YCC
from .rd import bd_psnr

QUALITIES = {
    "dct": (24, 12, 8, 5, 3, 2, 1.2),  # quantiser steps (8-bit levels)
    "webp": (10, 30, 50, 70, 85, 95),
    "avif-rgb": (20, 40, 60, 75, 85, 95),
    "avif-planes": (20, 40, 60, 75, 85, 95),
}


def _dct_plane(p: np.ndarray, step: float) -> tuple[bytes, np.ndarray]:
    """Quantised 8x8 DCT coefficients of a plane (bytes) and the plane they decode to."""
    h, w = p.shape
    H, W = -(-h // 8) * 8, -(-w // 8) * 8
    blocks = np.pad(p, ((0, H - h), (0, W - w)), mode="edge").reshape(H // 8, 8, W // 8, 8).transpose(0, 2, 1, 3)
    C = cv2.dct(np.eye(8))
    coef = np.einsum("ij,abjk,lk->abil", C, blocks, C)
    q = step * (1.0 + 0.25 * (np.arange(8)[:, None] + np.arange(8)[None, :]))
    k = np.rint(coef / q).astype(np.int16)
    back = np.einsum("ji,abjk,kl->abil", C, k * q, C).transpose(0, 2, 1, 3).reshape(H, W)[:h, :w]
    return k.transpose(2, 3, 0, 1).tobytes(), back  # frequency-major: zeros run together


def _dct(res: np.ndarray, step: float) -> tuple[int, np.ndarray]:
    """Own DCT codec of an sRGB residual (8-bit units): (bytes, decoded residual)."""
    h, w = res.shape[:2]
    ycc = res @ DETAIL_YCC.T
    half = lambda p: cv2.resize(p, ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)
    by, y = _dct_plane(ycc[..., 0], step)
    bb, cb = _dct_plane(half(ycc[..., 1]), 1.5 * step)
    br, cr = _dct_plane(half(ycc[..., 2]), 1.5 * step)
    full = lambda p: cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR)
    out = np.stack([y, full(cb), full(cr)], -1) @ np.linalg.inv(DETAIL_YCC).T
    return len(zstandard.ZstdCompressor(level=19).compress(by + bb + br)), out


def _code(name: str, q, res8: np.ndarray, texels: np.ndarray) -> tuple[int, np.ndarray]:
    """(bytes, decoded sRGB residual in 8-bit units) of codec ``name`` at setting ``q``."""
    if name == "dct":
        return _dct(res8, float(q))
    if name == "webp":
        x = np.clip(np.rint(res8 + 128), 0, 255).astype(np.uint8)[..., ::-1]
        ok, buf = cv2.imencode(".webp", np.ascontiguousarray(x), [cv2.IMWRITE_WEBP_QUALITY, int(q)])
        return len(buf), cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float64) - 128
    if name == "avif-rgb":
        rgb_tex = np.clip(np.rint(512 + 2 * res8), 0, 1023).astype(np.uint16)[..., ::-1]
        ok, buf = cv2.imencode(".avif", np.ascontiguousarray(rgb_tex), [cv2.IMWRITE_AVIF_QUALITY, int(q),
                                                                         cv2.IMWRITE_AVIF_DEPTH, 10])
        return len(buf), (cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)[..., ::-1].astype(np.float64) - 512) / 2
    payload = encode_texels(texels, int(q))
    h, w = texels.shape[:2]
    return sum(map(len, payload)), 255.0 * texel_rgb(decode_texels(payload, w, h))


def detail_codec_table(rgb: np.ndarray, labels: np.ndarray | None, device: str = "cpu") -> dict:
    """Rate-distortion of each detail codec on this image's residual (module doc).

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    labels : ndarray (H, W) int, optional
    device : str
        Warp device of the base's render.

    Returns
    -------
    dict
        ``base_bytes``, and per codec ``points`` (list of ``{"q", "bytes",
        "bpp", "psnr"}``) and ``bd_vs_avif_planes`` (dB).
    """
    from .tables import _auto_labels

    h, w = rgb.shape[:2]
    labels = _auto_labels(rgb, 0) if labels is None else labels
    trials = Trials(rgb, build_geometry(labels, rgb), scheme_params(), True, device)
    ev, shown, texels = trials.vector_base()
    base = len(ev.data)
    res8 = 255.0 * (np.asarray(rgb, np.float64) - shown)  # what the codecs of other layouts code
    target = np.rint(np.asarray(rgb, np.float64) * 255)
    out: dict = {"base_bytes": base, "codecs": {}}
    for name, qs in QUALITIES.items():
        pts = []
        for q in qs:
            n, dec = _code(name, q, res8, texels)
            img = np.clip(np.rint(255.0 * shown + dec), 0, 255)
            err = float(np.mean((img - target) ** 2)) / 255.0**2
            pts.append({"q": q, "bytes": n + base, "bpp": metrics.bpp(n + base, w, h),
                        "psnr": float(10 * np.log10(1.0 / max(err, 1e-12)))})
        out["codecs"][name] = {"points": pts}
    ref = out["codecs"]["avif-planes"]["points"]
    for name, c in out["codecs"].items():
        c["bd_vs_avif_planes"] = bd_psnr([p["bpp"] for p in ref], [p["psnr"] for p in ref],
                                         [p["bpp"] for p in c["points"]], [p["psnr"] for p in c["points"]])
    return out


def detail_codec_text(name: str, table: dict) -> str:
    """The comparison as printed by ``tpsv bench --codecs``."""
    lines = [f"Detail codecs on {name} (base {table['base_bytes']} B; bpp/PSNR per setting; BD vs avif-planes)"]
    for codec_name, c in table["codecs"].items():
        pts = "  ".join(f"{p['bpp']:.2f}/{p['psnr']:.1f}" for p in c["points"])
        lines.append(f"  {codec_name:<12} {c['bd_vs_avif_planes']:+6.2f} dB   {pts}")
    return "\n".join(lines)
