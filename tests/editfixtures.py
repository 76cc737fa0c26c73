"""Small models for the editing tests (recolor, crossmap, deform, stylize, live), made once per session.

``scene()`` is a 64 x 48 synthetic picture with three labelled regions:

* 0, background: a smooth blue-green gradient (it has a hole where the disc is);
* 1, disc: centre (22, 24), radius 11, red with dark vertical stripes (period 6 px);
* 2, panel: the block ``x >= 46``, ``16 <= y < 44``, a flat yellow with a faint gradient.
"""

from __future__ import annotations

import functools

import numpy as np

W, H = 64, 48
DISC_C, DISC_R = (22.0, 24.0), 11.0
BACKGROUND, DISC, PANEL = 0, 1, 2


def scene() -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64) + 0.5
    rgb = np.zeros((H, W, 3))
    rgb[..., 0] = 0.15
    rgb[..., 1] = 0.35 + 0.4 * xx / W
    rgb[..., 2] = 0.75 - 0.3 * yy / H
    labels = np.zeros((H, W), np.int32)
    disc = (xx - DISC_C[0]) ** 2 + (yy - DISC_C[1]) ** 2 <= DISC_R**2
    stripe = (np.floor(xx / 3.0) % 2) == 0
    rgb[disc] = np.where(stripe[disc, None], [0.85, 0.15, 0.1], [0.35, 0.05, 0.05])
    labels[disc] = DISC
    panel = (xx >= 46) & (yy >= 16) & (yy < 44)
    rgb[panel] = np.stack([0.9 + 0.0 * xx[panel], 0.8 + 0.05 * yy[panel] / H, 0.2 + 0.0 * xx[panel]], 1)
    labels[panel] = PANEL
    return rgb.astype(np.float32), labels


@functools.lru_cache(maxsize=None)
def scene_model():
    """The vectorised scene (quantised, as decoded from its file). Do not mutate it."""
    from tpsv.encode.vectorize import vectorize

    rgb, labels = scene()
    m = vectorize(rgb, labels, search=False).model
    assert [r.label for r in m.regions] == [BACKGROUND, DISC, PANEL], [r.label for r in m.regions]
    return m


@functools.lru_cache(maxsize=None)
def photo_model():
    """A 64-px crop of the chelsea sample with its label map (quantised). Do not mutate it."""
    from pathlib import Path

    from tpsv.image import read_image, read_labels
    from tpsv.encode.vectorize import vectorize

    root = Path(__file__).resolve().parent.parent / "samples"
    rgb = read_image(root / "chelsea.png")[90:138, 150:214]
    lab = read_labels(root / "chelsea-labels.png")[90:138, 150:214]
    return vectorize(np.ascontiguousarray(rgb), np.ascontiguousarray(lab), search=False).model


def same_model(a, b) -> bool:
    """Field-by-field equality of two models (arrays bit for bit)."""
    if (a.width, a.height, len(a.regions)) != (b.width, b.height, len(b.regions)) or a.params != b.params:
        return False
    for ra, rb in zip(a.regions, b.regions):
        if ra.label != rb.label or len(ra.outline) != len(rb.outline):
            return False
        if not np.array_equal(ra.patch.ctrl, rb.patch.ctrl):
            return False
        if not all(np.array_equal(p, q) for p, q in zip(ra.outline, rb.outline)):
            return False
    fa, fb = a.features, b.features
    return all(np.array_equal(getattr(fa, k), getattr(fb, k)) for k in ("region", "st", "lab", "kind", "pair"))
