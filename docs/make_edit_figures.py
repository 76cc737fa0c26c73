"""Make the before/after pictures of docs/EDITING.md with the tool itself, and time the edits.

Run from the repository root: ``.venv/bin/python docs/make_edit_figures.py``
(``--timings-only`` skips the pictures). The samples are vectorised with
``search=False`` (the gradient-histogram thresholds) to keep this fast.

Timings (CPU, best of 3): for each edit, the library call that makes the new
model (``edit``), the incremental rebuild of :class:`tpsv.rendering.live.LiveImage`
from the unedited model's state (``live``: regroup or reuse, solve the
changed kernels, rasterise the dirty pixels), and a full rebuild
(``full``: ``tpsv.rendering.raster.render`` of the new model: group, solve every
kernel, rasterise every pixel).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

from tpsv.edit import crossmap, deform, recolor, stylize
from tpsv.image import read_image, read_labels, write_image
from tpsv.rendering.live import LiveImage
from tpsv.rendering.raster import render
from tpsv.encode.vectorize import vectorize

ROOT = Path(__file__).resolve().parent.parent
IMG = ROOT / "docs" / "img"
SEPIA = [[0.393, 0.769, 0.189], [0.349, 0.686, 0.168], [0.272, 0.534, 0.131]]


def load(name: str):
    rgb = read_image(ROOT / "samples" / f"{name}.png")
    labels = read_labels(ROOT / "samples" / f"{name}-labels.png", shape=rgb.shape[:2])
    t0 = time.perf_counter()
    model = vectorize(rgb, labels, search=False).model
    print(f"{name}: {rgb.shape[1]}x{rgb.shape[0]}, {len(model.regions)} regions, {len(model.features)} features, "
          f"vectorised in {time.perf_counter() - t0:.1f} s")
    return rgb, model


def row(images, gap: int = 6) -> np.ndarray:
    """Images side by side (same height) with white gaps, as uint8."""
    tiles = []
    for im in images:
        if im.dtype != np.uint8:
            im = np.clip(np.rint(im * 255.0), 0, 255).astype(np.uint8)
        tiles.append(im)
        tiles.append(np.full((im.shape[0], gap, 3), 255, np.uint8))
    return np.concatenate(tiles[:-1], axis=1)


def col(rows, gap: int = 6) -> np.ndarray:
    w = max(r.shape[1] for r in rows)
    out = []
    for r in rows:
        if r.shape[1] < w:
            r = np.concatenate([r, np.full((r.shape[0], w - r.shape[1], 3), 255, np.uint8)], axis=1)
        out.append(r)
        out.append(np.full((gap, w, 3), 255, np.uint8))
    return np.concatenate(out[:-1], axis=0)


def half(img, height: int = 200) -> np.ndarray:
    """A tile ``height`` px high (area downscale), uint8."""
    h, w = img.shape[:2]
    if img.dtype != np.uint8:
        img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    return cv2.resize(img, (round(w * height / h), height), interpolation=cv2.INTER_AREA)


def figures(coffee, chelsea) -> None:
    c_rgb, cm = coffee
    k_rgb, km = chelsea
    base_c, base_k = render(cm), render(km)

    # recolor: the coffee (seed point), sepia gradation matrix, harmonisation; the cat's nose
    coffee_red = recolor.recolor(cm, at=(235, 118), tolerance=30, radius=80, hue=160)
    sepia = recolor.recolor(cm, region=3, matrix=SEPIA)
    harm = recolor.recolor(cm, region=3, shift_ab=(-25, -10), harmonize="auto")
    nose = recolor.recolor(km, region=4, hue=-120, lightness=-10)
    write_image(IMG / "edit-recolor.png", col([
        row([half(base_c), half(render(coffee_red)), half(render(sepia))]),
        row([half(render(harm)), half(base_k), half(render(nose))]),
    ]))

    # crossmap: the coffee onto the saucer (replace; blend with colour statistics); eye swap
    foam = crossmap.crossmap(cm, 3, cm, 2)
    blend = crossmap.crossmap(cm, 3, cm, 2, alpha=0.5, match_stats=True)
    eyes = crossmap.crossmap(km, 2, km, 3, flip=True)
    write_image(IMG / "edit-crossmap.png", col([
        row([half(base_c), half(render(foam)), half(render(blend))]),
        row([half(base_k), half(render(eyes))]),
    ]))

    # deform: bigger eyes and nose (affine about the centroid), the spoon moved, two control points of the rim
    cartoon = deform.affine(km, 2, [1.35, 0, 0, 0, 1.35, 0])
    cartoon = deform.affine(cartoon, 3, [1.35, 0, 0, 0, 1.35, 0])
    cartoon = deform.affine(cartoon, 4, [1.5, 0, 0, 0, 1.3, 4])
    th = np.radians(25)
    spoon = deform.affine(cm, 5, [np.cos(th), -np.sin(th), 30, np.sin(th), np.cos(th), 25])
    cup = deform.move_points(cm, [(1, 2, 0, 0, -25), (1, 3, 0, 0, -25)])
    write_image(IMG / "edit-deform.png", col([
        row([half(base_k), half(render(cartoon))]),
        row([half(base_c), half(render(spoon)), half(render(cup))]),
    ]))

    # stylize: levels 1-3, strokes at level 2 and 3
    write_image(IMG / "edit-stylize.png", col([
        row([half(base_k), half(stylize.stylize(km, level=1, with_strokes=False)),
             half(stylize.stylize(km, level=3, with_strokes=False))]),
        row([half(stylize.stylize(km, level=2)), half(stylize.stylize(km, level=3, stroke_width=1.5)),
             half(stylize.stylize(km, level=4, stroke_width=2))]),
    ]))
    print("pictures written to", IMG)


def best(fn, repeat=3):
    t = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return out, t


def timings(model) -> None:
    live = LiveImage(model)
    render(model)  # warm-up: every Warp module loaded
    M, N = model.regions[5].patch.shape
    edits = {
        "recolor --at (seed, radius 40)": lambda m: recolor.recolor(m, at=(250, 250), radius=40, tolerance=20, hue=60),
        "recolor --region (one region)": lambda m: recolor.recolor(m, region=2, hue=90),
        "recolor --matrix (all gradation)": lambda m: recolor.recolor(m, matrix=SEPIA),
        "recolor --harmonize (one region)": lambda m: recolor.recolor(m, region=5, harmonize="auto"),
        "crossmap replace": lambda m: crossmap.crossmap(m, 1, m, 3),
        "crossmap --alpha 0.5": lambda m: crossmap.crossmap(m, 1, m, 3, alpha=0.5),
        "deform --affine (translate)": lambda m: deform.affine(m, 1, [1, 0, 12, 0, 1, -6]),
        "deform --affine (scale 1.2)": lambda m: deform.affine(m, 1, [1.2, 0, 0, 0, 1.2, 0]),
        "deform --move (one point)": lambda m: deform.move_points(m, [(5, M // 2, N // 2, 6, -4)]),
    }
    print(f"\n{model.width}x{model.height}, {len(model.features)} features, "
          f"{live.stats.kernels} kernels, CPU, best of 3 (seconds)\n")
    print("| edit | edit | live rebuild + render | kernels solved | pixels | full rebuild + render |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, fn in edits.items():
        new, t_edit = best(lambda: fn(model))

        def upd():
            live.update(model)
            t0 = time.perf_counter()
            st = live.update(new)
            return st, time.perf_counter() - t0

        runs = [upd() for _ in range(3)]
        st, t_live = min(runs, key=lambda r: r[1])
        img, t_full = best(lambda: render(new))
        assert np.array_equal(live.image, img)
        print(f"| {name} | {t_edit:.3f} | {t_live:.3f} | {st.solved} / {st.kernels} | {st.pixels} | {t_full:.3f} |")
    t0 = time.perf_counter()
    stylize.stylize(model, level=2)
    print(f"\nstylize --level 2 (abstraction + render + strokes): {time.perf_counter() - t0:.3f} s")


if __name__ == "__main__":
    IMG.mkdir(parents=True, exist_ok=True)
    if "--timings-only" not in sys.argv:
        figures(load("coffee"), load("chelsea"))
    timings(load("astronaut")[1])
