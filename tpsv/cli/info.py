"""``tpsv info``: what a .tpsv file holds."""

from __future__ import annotations

import json

import click

from . import main
from .. import codec
from ..fileio import read_bytes
from ..model import CURVILINEAR


def summary(data: bytes) -> dict:
    """Figures about an encoded model: size, counts, bytes per section, parameters."""
    model = codec.decode(data)
    kinds = model.features.kind
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
        "params": {
            "t_canny": model.params.t_canny,
            "t_super": model.params.t_super,
            "kernel_size": model.params.kernel_size,
            "overlap": model.params.overlap,
            "smoothing": model.params.smoothing,
            **model.params.extra,
        },
    }


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable summary on stdout.")
def info(path: str, as_json: bool) -> None:
    """Size, regions, features, bytes and parameters of a .tpsv file."""
    try:
        data = read_bytes(path, limit=codec.MAX_FILE_BYTES)
    except OSError as exc:
        raise click.FileError(path, exc.strerror) from None
    s = summary(data)
    if as_json:
        click.echo(json.dumps(s, indent=2, sort_keys=True))
        return
    click.echo(f"{path}: {s['width']}x{s['height']} px, {s['bytes']} bytes ({s['bpp']:.3f} bpp)")
    click.echo(f"  regions   {s['regions']}  (control grids {', '.join('x'.join(map(str, g)) for g in s['grids'][:8])}"
               + (" ..." if len(s["grids"]) > 8 else "") + ")")
    click.echo(f"  features  {s['features']}  ({s['curvilinear']} curvilinear, {s['gradation']} gradation)")
    click.echo("  sections  " + ", ".join(f"{k} {v} B" for k, v in s["sections"].items()))
    click.echo("  params    " + ", ".join(f"{k}={v}" for k, v in s["params"].items()))
