"""Shared fixtures: small images (CI runs on 2 cores), written once per session."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tpsv.model import Patch

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples"


def small_sample(name: str = "chelsea", width: int = 64) -> np.ndarray:
    """A bundled sample downscaled to ``width`` px wide, float32 RGB in [0, 1]."""
    img = cv2.imread(str(SAMPLES / f"{name}.png"), cv2.IMREAD_COLOR)[:, :, ::-1]
    h, w = img.shape[:2]
    img = cv2.resize(img, (width, round(h * width / w)), interpolation=cv2.INTER_AREA)
    return img.astype(np.float32) / 255.0


def rect_patch(x0, y0, w, h, M=3, N=3) -> Patch:
    """An axis-aligned rectangular (affine) Hermite patch."""
    ii, jj = np.meshgrid(np.arange(M, dtype=float), np.arange(N, dtype=float), indexing="ij")
    a = np.array([w / (M - 1), 0.0])
    b = np.array([0.0, h / (N - 1)])
    ctrl = np.zeros((M, N, 4, 2))
    ctrl[..., 0, :] = np.array([x0, y0]) + ii[..., None] * a + jj[..., None] * b
    ctrl[..., 1, :] = a
    ctrl[..., 2, :] = b
    return Patch(ctrl)


@pytest.fixture(scope="session")
def small_rgb() -> np.ndarray:
    return small_sample()


@pytest.fixture(scope="session")
def small_png(tmp_path_factory, small_rgb) -> Path:
    path = tmp_path_factory.mktemp("img") / "small.png"
    cv2.imwrite(str(path), np.round(small_rgb[:, :, ::-1] * 255).astype(np.uint8))
    return path


@pytest.fixture(scope="session")
def small_labels(small_rgb) -> np.ndarray:
    """Two regions: left and right of a vertical line at 40% of the width."""
    h, w = small_rgb.shape[:2]
    lab = np.zeros((h, w), np.int32)
    lab[:, int(w * 0.4):] = 1
    return lab


@pytest.fixture
def every_band(monkeypatch):
    """CPU launches split into 4 bands a host thread however little work they hold (tests' pictures are
    too small to pay for bands), so that tests of the split see one."""
    from tpsv.gpu import device

    monkeypatch.setattr(device, "BAND_SECONDS", 1e-12)
