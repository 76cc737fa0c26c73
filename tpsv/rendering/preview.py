"""Diagnostic picture of a model: patches, outlines and features over the photo.

Like the paper's Fig. 1(a)(b): each region's Hermite control grid drawn as
iso-curves ``s = i`` and ``t = j`` through the control points (sampled densely
with ``patch.forward``, so a deformed patch shows its curves), its outline,
and the colour features: curvilinear pairs as red (first of the pair) and
blue (second) dots, gradation features as green dots.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.patch import forward
from ..geometry.regions import to_pixel_space
from ..geometry.segment import palette
from ..model import CURVILINEAR, GRADATION, Model

_SHIFT = 4  # sub-pixel bits for cv2 drawing


def _pts(xy: np.ndarray, scale: float) -> np.ndarray:
    return np.round(np.asarray(xy, np.float64) * scale * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)


def draw_preview(rgb: np.ndarray, model: Model, scale: int = 2, features: bool = True, grid: bool = True) -> np.ndarray:
    """RGB uint8 picture ``(H * scale, W * scale, 3)``.

    Parameters
    ----------
    rgb : ndarray (H, W, 3), float in [0, 1] or uint8
        The photo (the model's size); drawn dimmed, upscaled bilinearly.
    model : Model
    scale : int
        Upscaling for legibility (pixel-space coordinates are multiplied by it).
    features : bool
        Draw the colour features.
    grid : bool
        Draw the patch control grids.
    """
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.rint(np.asarray(rgb, np.float64) * 255), 0, 255).astype(np.uint8)
    H, W = rgb.shape[:2]
    scale = max(1, int(scale))
    img = cv2.resize(rgb, (W * scale, H * scale), interpolation=cv2.INTER_LINEAR) if scale > 1 else rgb.copy()
    img = (0.65 * img.astype(np.float32) + 0.35 * 255 * 0.15).astype(np.uint8)
    img = np.ascontiguousarray(img)
    pal = palette(len(model.regions))
    k = float(scale) * W / float(model.width) if model.width else float(scale)
    # outlines
    for reg in model.regions:
        polys = [_pts(p, k) for p in reg.outline if len(p) >= 2]
        if polys:
            cv2.polylines(img, polys, True, (255, 255, 255), 1, cv2.LINE_AA, _SHIFT)
    # control grids
    if grid:
        for r, reg in enumerate(model.regions):
            col = tuple(int(c) for c in pal[r])
            patch = reg.patch
            M, N = patch.shape
            ts = np.linspace(0, N - 1, 12 * (N - 1) + 1)
            ss = np.linspace(0, M - 1, 12 * (M - 1) + 1)
            lines = [_pts(forward(patch, np.full_like(ts, i), ts), k) for i in range(M)]
            lines += [_pts(forward(patch, ss, np.full_like(ss, j)), k) for j in range(N)]
            cv2.polylines(img, lines, False, col, 1, cv2.LINE_AA, _SHIFT)
            for p in patch.ctrl[..., 0, :].reshape(-1, 2):
                c = _pts(p, k).reshape(2)
                cv2.circle(img, (int(c[0]), int(c[1])), 2 << _SHIFT, col, -1, cv2.LINE_AA, _SHIFT)
    # features
    f = model.features
    if features and f is not None and len(f):
        xy = to_pixel_space([r.patch for r in model.regions], f.region, f.st)
        idx = np.arange(len(f))
        colours = np.zeros((len(f), 3), np.uint8)
        colours[f.kind == GRADATION] = (40, 220, 40)
        curv = f.kind == CURVILINEAR
        first = curv & ((f.pair < 0) | (idx < f.pair))
        colours[first] = (235, 40, 40)
        colours[curv & ~first] = (40, 90, 255)
        rad = max(1, scale // 2)
        pts = np.round(xy * k).astype(np.int64)
        ok = (pts[:, 0] >= 0) & (pts[:, 0] < img.shape[1]) & (pts[:, 1] >= 0) & (pts[:, 1] < img.shape[0])
        for p, c in zip(pts[ok], colours[ok]):
            cv2.circle(img, (int(p[0]), int(p[1])), rad, tuple(int(v) for v in c), -1)
    return img
