"""Regenerate the bundled samples: photos from scikit-image, stroke files, label maps.

Run from the repository root: ``.venv/bin/python samples/make_samples.py``.
Label maps are made by ``tpsv segment --strokes`` from the stroke files.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from skimage import data

HERE = Path(__file__).resolve().parent

# Long side of each bundled photo (pixels).
SIZES = {"astronaut": 512, "chelsea": 451, "coffee": 480, "rocket": 480}

# Strokes as polylines in fractions of (width, height); one colour per label.
STROKES = {
    "astronaut": [
        ((200, 200, 200), [[(0.42, 0.04), (0.68, 0.04)], [(0.94, 0.10), (0.95, 0.45)]]),
        ((220, 30, 30), [[(0.03, 0.10), (0.07, 0.60)]]),
        ((240, 200, 150), [[(0.38, 0.12), (0.44, 0.20), (0.44, 0.28)]]),
        ((255, 120, 0), [[(0.15, 0.60), (0.30, 0.90)], [(0.50, 0.55), (0.60, 0.62)]]),
        ((40, 40, 160), [[(0.70, 0.85), (0.85, 0.85)]]),
        ((0, 200, 0), [[(0.82, 0.10), (0.82, 0.40)]]),
    ],
    "chelsea": [
        ((200, 200, 200), [[(0.88, 0.05), (0.97, 0.05), (0.97, 0.70)], [(0.86, 0.95), (0.97, 0.78)]]),
        ((200, 140, 60), [[(0.20, 0.30), (0.50, 0.60), (0.30, 0.90)], [(0.60, 0.10), (0.75, 0.30)],
                          [(0.70, 0.70), (0.78, 0.95)], [(0.10, 0.50), (0.10, 0.90)]]),
        ((0, 200, 0), [[(0.36, 0.36), (0.41, 0.40)]]),
        ((0, 120, 255), [[(0.69, 0.44), (0.73, 0.47)]]),
        ((255, 60, 60), [[(0.56, 0.80), (0.60, 0.80)]]),
    ],
    "coffee": [
        ((150, 90, 40), [[(0.05, 0.30), (0.10, 0.60)], [(0.85, 0.20), (0.95, 0.80)], [(0.80, 0.05), (0.95, 0.05)],
                         [(0.30, 0.02), (0.70, 0.02)], [(0.10, 0.90), (0.20, 0.97)]]),
        ((220, 40, 40), [[(0.20, 0.80), (0.40, 0.90), (0.70, 0.85)], [(0.75, 0.40), (0.78, 0.60)]]),
        ((255, 255, 255), [[(0.33, 0.12), (0.55, 0.08)], [(0.45, 0.55), (0.55, 0.58)]]),
        ((230, 160, 60), [[(0.40, 0.35), (0.55, 0.35)]]),
        ((120, 120, 255), [[(0.58, 0.70), (0.62, 0.72)]]),
    ],
    "rocket": [
        ((20, 40, 200), [[(0.30, 0.10), (0.60, 0.10)], [(0.62, 0.50), (0.66, 0.30)], [(0.20, 0.30), (0.20, 0.60)],
                         [(0.40, 0.20), (0.42, 0.70)], [(0.80, 0.20), (0.85, 0.70)]]),
        ((255, 255, 255), [[(0.50, 0.40), (0.50, 0.80)]]),
        ((200, 160, 40), [[(0.20, 0.96), (0.40, 0.96)], [(0.60, 0.96), (0.80, 0.96)]]),
    ],
}


def photo(name: str) -> np.ndarray:
    img = getattr(data, name)()
    h, w = img.shape[:2]
    s = SIZES[name] / max(h, w)
    if s < 1:
        img = cv2.resize(img, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
    return img


def strokes(name: str, shape: tuple[int, int]) -> np.ndarray:
    h, w = shape
    canvas = np.zeros((h, w, 3), np.uint8)
    for colour, lines in STROKES[name]:
        for line in lines:
            pts = np.array([[x * (w - 1), y * (h - 1)] for x, y in line], np.int32)
            cv2.polylines(canvas, [pts], False, colour[::-1], thickness=3)
    return canvas


def main() -> None:
    tpsv = [sys.executable, "-m", "tpsv.cli.__main__"]
    for name in SIZES:
        img = photo(name)
        cv2.imwrite(str(HERE / f"{name}.png"), img[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
        cv2.imwrite(str(HERE / f"{name}-strokes.png"), strokes(name, img.shape[:2]))
        subprocess.run(
            tpsv + ["segment", str(HERE / f"{name}.png"), "-o", str(HERE / f"{name}-labels.png"),
                    "--strokes", str(HERE / f"{name}-strokes.png")],
            check=True,
        )
        print(name, img.shape)


if __name__ == "__main__":
    main()
