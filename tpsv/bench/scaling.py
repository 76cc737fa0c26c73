"""How vectorize scales with the photo: seconds and peak memory at growing sizes.

Each size runs ``tpsv vectorize`` in a child process (its own interpreter,
so its peak resident memory is its own: ``ru_maxrss`` of the child from
``os.wait4``), on the first input resized to that size: at the default
quality, and as the pure vector image (``--no-detail``, whose colour fit on
every pixel sets the peak: ``tpsv.encode.fit``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

#: The sizes of ``tpsv bench --scaling`` (issue 12: 512^2, 1024^2, 2048^2).
SIZES = (512, 1024, 2048)
#: The encodings each size runs: name and ``vectorize`` options.
MODES = (("default", ()), ("no-detail", ("--no-detail",)))


def _child(args: list[str]) -> tuple[int, str, str, int]:
    """``(exit status, stdout, stderr, peak RSS in bytes)`` of a child process."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(args, stdout=out, stderr=err, stdin=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return proc.returncode, out.read().decode(), err.read().decode(), usage.ru_maxrss * 1024


def scaling_table(rgb: np.ndarray, sizes=SIZES, device: str = "cpu", modes=MODES) -> dict:
    """Vectorize ``rgb`` resized to each ``size x size`` in each of ``modes``; seconds, peak RSS, bytes per pixel.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    sizes : iterable of int
    device : str
        Warp device of the child's ``vectorize``.
    modes : iterable of (name, options)
        ``vectorize`` options of each row of a size (:data:`MODES`).

    Returns
    -------
    dict
        ``{"device", "rows": [{"size", "mode", "pixels", "seconds",
        "peak_rss_bytes", "bytes_per_pixel", "file_bytes", "psnr"}],
        "baseline_rss_bytes"}``; the baseline is the peak of a child that
        only imports the package and loads Warp (the fixed part of every row).
    """
    src = cv2.cvtColor((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)
    rows = []
    cmd = [sys.executable, "-m", "tpsv.cli", "--device", device, "--quiet", "vectorize"]
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            photo = str(Path(tmp) / f"photo{n}.png")
            cv2.imwrite(photo, cv2.resize(src, (int(n), int(n)), interpolation=cv2.INTER_CUBIC))
            for mode, options in modes:
                status, out, err, rss = _child(cmd + [photo, "-o", str(Path(tmp) / f"photo{n}.tpsv"), "--json",
                                                      *options])
                if status != 0:
                    rows.append({"size": int(n), "mode": mode,
                                 "error": err.strip().splitlines()[-1] if err.strip() else str(status)})
                    continue
                s = json.loads(out)
                rows.append({"size": int(n), "mode": mode, "pixels": int(n) * int(n), "seconds": s["seconds"],
                             "peak_rss_bytes": rss, "bytes_per_pixel": rss / (int(n) * int(n)),
                             "file_bytes": s["bytes"], "psnr": s["psnr"]})
        base = _child([sys.executable, "-c", "import tpsv.cli, tpsv.gpu; tpsv.gpu.warp()"])[3]
    return {"device": device, "rows": rows, "baseline_rss_bytes": base}


def scaling_text(table: dict) -> str:
    """The printed scaling table."""
    out = [f"Vectorize by size on {table['device']}, at the default quality and --no-detail (a child process "
           f"each; peak RSS, its bytes per input pixel)",
           f"{'size':>11}{'mode':>11}{'seconds':>9}{'peak MB':>9}{'B/px':>7}{'bytes':>9}{'PSNR':>7}"]
    for r in table["rows"]:
        head = f"{r['size']:>5}x{r['size']:<5}{r.get('mode', 'default'):>11}"
        if "error" in r:
            out.append(f"{head} failed: {r['error']}")
            continue
        out.append(f"{head}{r['seconds']:>9.1f}{r['peak_rss_bytes'] / 2**20:>9.0f}"
                   f"{r['bytes_per_pixel']:>7.0f}{r['file_bytes']:>9}{r['psnr']:>7.2f}")
    out.append(f"  fixed part (interpreter, libraries, Warp loaded): {table['baseline_rss_bytes'] / 2**20:.0f} MB")
    return "\n".join(out)


__all__ = ["MODES", "SIZES", "scaling_table", "scaling_text"]
