"""``tpsv info``: what a .tpsv file holds."""

from __future__ import annotations

import click
import numpy as np

from . import main
from .options import emit_json, json_option
from .. import codec
from ..errors import TpsvFormatError
from ..fileio import display, read_bytes
from ..model import CURVILINEAR, DETAIL_FULL, DETAIL_LUMA


def summary(data: bytes) -> dict:
    """Figures about an encoded model: size, counts, bytes per section, parameters.

    ``params`` holds the named parameters of :class:`tpsv.model.Params`, and
    ``params["extra"]`` the free-form entries stored beside them (so that an
    extra entry named like a parameter cannot pass for it).
    """
    model = codec.decode(data)
    kinds = model.features.kind
    d = model.detail
    p = model.params
    return {
        "width": model.width,
        "height": model.height,
        "regions": len(model.regions),
        "features": len(model.features),
        "curvilinear": int((kinds == CURVILINEAR).sum()),
        "gradation": int((kinds != CURVILINEAR).sum()),
        "bytes": len(data),
        "bpp": 8.0 * len(data) / (model.width * model.height),
        "sections": codec.section_sizes(data),
        "grids": [list(r.patch.shape) for r in model.regions],
        # regions that are holes in the picture (the transparent part of an RGBA input)
        "transparent": [i for i, r in enumerate(model.regions) if r.transparent],
        # soft borders: (region a, region b, edge width in px); the others are sharp
        "edge_widths": [[int(a), int(b), float(w)] for a, b, w in model.blur],
        # edge widths point by point (format version 7): cell side, the cells stored, widest and narrowest
        "blur_map": None if model.blur_map is None else _map_summary(model),
        "quality": model.params.extra.get("quality"),
        # the texture detail layer: None for a pure vector image
        "detail": None if d is None else {
            "quality": d.quality, "width": int(d.texels.shape[1]), "height": int(d.texels.shape[0]),
            "bytes": codec.section_sizes(data)["detail"], "files": len(d.payload),
            "regions_full": int((d.mode == DETAIL_FULL).sum()), "regions_luma": int((d.mode == DETAIL_LUMA).sum()),
        },
        "params": {
            "t_canny": p.t_canny,
            "t_super": p.t_super,
            "kernel_size": p.kernel_size,
            "overlap": p.overlap,
            "smoothing": p.smoothing,
            "extra": dict(p.extra),
        },
    }


def _map_summary(model) -> dict:
    """The blur map as stored: cell side, cells, narrowest and widest width (px).

    The decoded map holds the stored widths in the cells the borders pass through.
    """
    from ..geometry.edgewidth import border_cells

    bm = model.blur_map
    w = np.asarray(bm.sigma, np.float64).ravel()[border_cells(model.regions, model.width, model.height, bm.cell)]
    return {"cell": int(bm.cell), "cells": int(len(w)), "min": float(w.min()) if w.size else 0.0,
            "max": float(w.max()) if w.size else 0.0}


def _pairs(items: dict) -> str:
    """``k=v, ...`` with every stored string escaped (no terminal control from a file)."""
    return ", ".join(f"{display(k)}={display(v) if isinstance(v, str) else v}" for k, v in items.items())


def _files(n: int) -> str:
    """How the texture is stored (docs/FORMAT.md, detail): in one file, or plane by plane in bands."""
    return "" if n == 1 else f" plane by plane ({n} files, {n // 3} band{'s' if n > 3 else ''} a plane)"


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@json_option
def info(path: str, as_json: bool) -> None:
    """Size, regions, features, bytes and parameters of a .tpsv file.

    Strings stored in the file are shown escaped (\\x1b for ESC...); free-form
    entries stored beside the parameters are listed apart, as "extra".
    """
    try:
        s = summary(read_bytes(path, limit=codec.MAX_FILE_BYTES))
    except TpsvFormatError as exc:
        raise TpsvFormatError(f"{display(path)}: {exc}") from None  # named as render and the others name it
    if as_json:
        emit_json(s)  # JSON escapes control characters itself
        return
    params = dict(s["params"])
    extra = params.pop("extra")
    grids = ", ".join("x".join(map(str, g)) for g in s["grids"][:8]) + (" ..." if len(s["grids"]) > 8 else "")
    click.echo(f"{display(path)}: {s['width']}x{s['height']} px, {s['bytes']} bytes ({s['bpp']:.3f} bpp)")
    clear = f", {len(s['transparent'])} transparent" if s["transparent"] else ""
    click.echo(f"  regions   {s['regions']}{clear}  (control grids {grids})")
    click.echo(f"  features  {s['features']}  ({s['curvilinear']} curvilinear, {s['gradation']} gradation)")
    widths = [w for _, _, w in s["edge_widths"]]
    if widths:
        click.echo(f"  borders   {len(widths)} soft (edge width {min(widths):g}-{max(widths):g} px), the others sharp")
    else:
        click.echo("  borders   all sharp")
    bm = s["blur_map"]
    if bm is not None:
        click.echo(f"  blur map  {bm['cells']} cells of {bm['cell']} px along the borders, "
                   f"edge width {bm['min']:g}-{bm['max']:g} px")
    q = s["quality"]
    click.echo(f"  quality   {q if isinstance(q, int) else 'not set (threshold mode)'}")
    d = s["detail"]
    if d is None:
        click.echo("  detail    none (pure vector image)")
    else:
        luma = f", {d['regions_luma']} luma only" if d["regions_luma"] else ""
        click.echo(f"  detail    {d['width']}x{d['height']} texels, AVIF at quality {d['quality']}"
                   f"{_files(d['files'])}, {d['bytes']} B; "
                   f"{d['regions_full']} regions full{luma}")
    click.echo("  sections  " + ", ".join(f"{k} {v} B" for k, v in s["sections"].items()))
    click.echo("  params    " + _pairs(params))
    if extra:
        click.echo("  extra     " + _pairs(extra))
