"""``tpsv bench``: timing and quality tables (paper Tables I-III style)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from . import main, progress_bar, say
from .options import SEED, device_for, device_option, is_tpsv, json_option
from .outputs import claim_outputs
from .. import codec
from ..bench import tables as b
from ..errors import TpsvError
from ..fileio import display
from ..image import read_image, read_labels

SAMPLES = Path(__file__).resolve().parents[2] / "samples"


def _inputs(images: tuple[str, ...]) -> list[tuple[str, Path, Path | None]]:
    if not images:
        if not SAMPLES.is_dir():
            raise TpsvError("no images given and no samples/ folder beside the package")
        paths = sorted(p for p in SAMPLES.glob("*.png") if not p.stem.endswith(("-labels", "-strokes")))
    else:
        paths = [Path(p) for p in images]
    out = []
    for p in paths:
        lab = p.with_name(f"{p.stem}-labels.png")
        out.append((p.stem, p, lab if lab.exists() else None))
    return out


def _outputs(out_dir: str | None, plotted: list[str]) -> list[tuple[str, Path]]:
    """``--out``'s files (the folder is made here): bench.json and a plot per raster image."""
    if not out_dir:
        return []
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise TpsvError(f"cannot make folder {display(out_dir)}: {exc.strerror or exc}") from None
    return [("--out", out / "bench.json")] + [("--out", out / f"rd-{name}.png") for name in plotted]


def _run(ctx, inputs, device: str, iterations: int, grid: int, seed: int, edges: int,
         rd: bool = True) -> tuple[list[dict], dict | None, dict | None]:
    """The benchmark of each input (a .tpsv: its timing tables only; ``rd``: with the
    rate-distortion table), then the edge table (``edges`` variants, 0: none) and the
    graphics table once (only when some input is a raster image and ``edges``), with a
    progress bar on a terminal."""
    if all(model for *_, model in inputs):
        edges = 0
    stages = ["search", "initial", "grid", "jpeg"] + (["rd"] if rd else []) + ["timing", "magnify", "edits"]
    results = []
    with progress_bar(ctx, len(inputs) * len(stages) + (2 if edges else 0), "bench") as bar:
        for name, path, lab_path, model in inputs:
            if model:
                results.append(b.bench_model(name, codec.load(path), device=device))
                if bar:
                    bar.update(len(stages))
                continue
            rgb = read_image(path)
            labels = read_labels(lab_path, shape=rgb.shape[:2]) if lab_path else None
            results.append(b.bench_image(name, rgb, labels, device=device, iterations=iterations, grid=grid,
                                         seed=seed, rd=rd, step=(lambda s: bar.update(1)) if bar else None))
        edge = b.edge_table(edges, iterations=iterations, device=device) if edges else None
        if bar and edges:
            bar.update(1)
        graphics = b.graphics_table(device=device) if edges else None
        if bar and edges:
            bar.update(1)
    return results, edge, graphics


@main.command()
@click.argument("images", nargs=-1, type=click.Path(dir_okay=False, exists=True))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for bench.json and the rate-distortion plots (PNG).")
@click.option("--iterations", type=click.IntRange(1, 1000), default=20, show_default=True,
              help="N_total of the threshold search.")
@click.option("--grid", type=click.IntRange(0, 20), default=4, show_default=True,
              help="Brute-force grid of N x N thresholds (0: skip).")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--edges", "edge_variants", type=click.IntRange(0, 20), default=3, show_default=True,
              help="Variants of the synthetic shapes in the edge table (0: skip it and the graphics table).")
@click.option("--codecs", is_flag=True, default=False,
              help="Also compare detail-texture codecs (own DCT, WebP, AVIF colour, AVIF planes) on each image.")
@click.option("--rd/--no-rd", default=True, show_default=True,
              help="The rate-distortion table: tpsv --quality sweep with and without detail, JPEG, WebP, BD-PSNR.")
@click.option("--scaling", is_flag=True, default=False,
              help="Also vectorize the first image resized to 512, 1024 and 2048 px square, at the default "
                   "quality and --no-detail, each in a child process: seconds and peak memory (a few minutes "
                   "on a laptop).")
@device_option
@json_option
@click.pass_context
def bench(ctx, images, out_dir, iterations, grid, seed, edge_variants, codecs, rd, scaling, device, as_json):
    """Benchmark IMAGES (default: the bundled samples, with their label maps).

    An IMAGE may also be a .tpsv file: then only its timing tables are made.

    Prints Table I (construction + solve + rasterisation: global CPU solve,
    localised without and with packing), Table II (PSNR, w and bpp of the initial
    guess, the searched optimum, a brute-force grid and JPEG), the
    rate-distortion table per image (unless --no-rd: bpp and PSNR of tpsv
    --quality 10, 30, 50, 75, 90 with and without the detail layer, and of
    OpenCV's JPEG and WebP at qualities 5-95, then BD-PSNR of each tpsv curve
    against JPEG and WebP over 0.25-2 bpp and over all rates both reach;
    --out's plots draw these curves too), the 4x
    magnification comparison against bicubic and Lanczos (PSNR, SSIM, GMSD),
    a .tpsv magnified 4x (the downscaled picture vectorised at the default
    quality and rendered at 4x, against bicubic of the small picture and of
    the file's scale-1 render; PSNR, GMSD and PSNR along region borders),
    the edge table (synthetic shapes rendered at 8x against the analytic
    picture, PSNR and GMSD, with and without their label map, next to bicubic
    and Lanczos; once per run), the graphics table (flat-colour drawings,
    crisp and anti-aliased, vectorised without a label map and magnified, at
    8x against the exact picture; once per run), the
    edit latencies (recolor and deform through a live image, at the model's
    size and, with --device cuda, at 1920x1080, next to the device table of
    whole renders, prepared frames and new sizes) and CPU seconds.
    """
    inputs = [(name, path, lab, is_tpsv(str(path))) for name, path, lab in _inputs(images)]
    with claim_outputs([p for _, path, lab, _ in inputs for p in (path, lab)],
                       *_outputs(out_dir, [name for name, _, _, model in inputs if not model])) as out:
        device = device_for(ctx, device)
        results, edges, graphics = _run(ctx, inputs, device, iterations, grid, seed, edge_variants, rd)
        report = {"device": device, "iterations": iterations, "grid": grid, "seed": seed, "images": results,
                  "edges": edges, "graphics": graphics}
        if codecs:
            from ..bench.codecs import detail_codec_table

            report["detail_codecs"] = {
                name: detail_codec_table(read_image(path), read_labels(lab, shape=read_image(path).shape[:2])
                                         if lab else None, device=device)
                for name, path, lab, model in inputs if not model}
        if scaling:
            from ..bench.scaling import scaling_table

            first = next((path for _, path, _, model in inputs if not model), None)
            if first is None:
                raise TpsvError("--scaling needs a raster image among the inputs")
            report["scaling"] = scaling_table(read_image(first), device=device)
        if out_dir:
            out.write(Path(out_dir) / "bench.json", json.dumps(report, indent=2, default=float).encode())
            for r in results:
                if "grid" in r:
                    out.write(Path(out_dir) / f"rd-{r['name']}.png", b.rd_plot_png(r))
    if as_json:
        click.echo(json.dumps(report, indent=2, default=float))
    else:
        click.echo(b.tables(results, device, edges, graphics))
        if codecs:
            from ..bench.codecs import detail_codec_text

            for name, table in report["detail_codecs"].items():
                click.echo("\n" + detail_codec_text(name, table))
        if scaling:
            from ..bench.scaling import scaling_text

            click.echo("\n" + scaling_text(report["scaling"]))
        if out_dir:
            say(ctx, f"wrote {out_dir}/bench.json and rate-distortion plots")
