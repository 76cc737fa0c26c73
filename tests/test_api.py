"""The public API: ``import tpsv`` and the example of docs/API.md."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import tpsv

ROOT = Path(__file__).resolve().parents[1]


def test_every_public_name_resolves_and_is_documented():
    for name in tpsv.__all__:
        value = getattr(tpsv, name)
        if callable(value) and name != "TpsvError":
            assert value.__doc__ and len(value.__doc__.strip()) > 20, name
    assert "vectorize" in dir(tpsv)
    with pytest.raises(AttributeError):
        tpsv.no_such_function  # noqa: B018


def test_import_is_light():
    # Warp and the encoder load only when a function is used.
    code = "import sys, tpsv; print('warp' in sys.modules, 'tpsv.encode' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.split() == ["False", "False"]


def test_the_documented_example_runs(tmp_path, monkeypatch):
    text = (ROOT / "docs" / "API.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    # the example on a small crop of the sample, so the test stays quick
    (tmp_path / "samples").mkdir()
    (tmp_path / "out").mkdir()
    photo = cv2.imread(str(ROOT / "samples" / "chelsea.png"))[100:164, 180:276]
    labels = cv2.imread(str(ROOT / "samples" / "chelsea-labels.png"), cv2.IMREAD_UNCHANGED)[100:164, 180:276]
    _, labels = np.unique(labels, return_inverse=True)
    cv2.imwrite(str(tmp_path / "samples" / "chelsea.png"), photo)
    cv2.imwrite(str(tmp_path / "samples" / "chelsea-labels.png"), labels.reshape(photo.shape[:2]).astype(np.uint8))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/API.md", "exec"), {})
    model = tpsv.load(tmp_path / "out" / "chelsea.tpsv")
    assert (model.width, model.height) == (96, 64)
    big = cv2.imread(str(tmp_path / "out" / "chelsea-x2.png"))
    assert big.shape == (128, 192, 3)
    assert (tmp_path / "out" / "chelsea.pdf").read_bytes().startswith(b"%PDF-")
