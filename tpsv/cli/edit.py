"""Editing in vector space: ``recolor``, ``crossmap``, ``deform`` (.tpsv -> .tpsv) and ``stylize`` (.tpsv -> image).

Each edit reads a .tpsv (``-``: stdin) and writes a .tpsv (``-``: stdout), so
edits chain in a pipeline; ``--render P.png [--scale S]`` also writes a
picture of the result (PNG, JPEG, WebP or TIFF by its extension, with
``--quality`` and ``--depth``; ``-``: PNG on stdout). Every output is claimed
before any work and written only once everything succeeded (:mod:`tpsv.cli.outputs`): a failed run
changes no file. Malformed option values are usage errors (exit
2, from the value types of :mod:`tpsv.cli.options`); values that do not fit
the model (an unknown region, a point outside the image, a deformation that
folds) are data errors (exit 1). docs/EDITING.md describes each edit.
"""

from __future__ import annotations

import json
import time

import click

from . import main, say
from .options import (AFFINE, COLOR, FINITE, GRID, IMAGE_HELP, MATRIX, MOVE, NON_NEGATIVE, PAIR, POINT, POSITIVE,
                      STROKE_WIDTH, UNIT_INTERVAL, check_json_target, device_for, device_option,
                      emit_json, image_format, image_options, json_option, output_option, render_options,
                      scale_option)
from .outputs import check_targets, claim_outputs, encode_model, read_json
from .render import render_file
from .. import codec
from ..edit import crossmap as cm, deform as df, recolor as rc, stylize as st
from ..image import OutputFormat, encode_image
from ..rendering.raster import output_size

#: Template names of ``recolor --harmonize`` ('auto': the best fit).
TEMPLATE = click.Choice(["auto", *rc.TEMPLATES])


def stage_edit(out, model, output, render_path, scale, device, info: dict, t0: float,
               fmt: OutputFormat | None = None) -> dict:
    """Encode (and render) the edited model and stage the outputs; returns the summary.

    Parameters
    ----------
    out : tpsv.fileio.Outputs
        The command's claimed outputs.
    model : Model
        The edited model.
    output, render_path : str, str or None
        The .tpsv to write and the optional picture of ``model`` at ``scale``.
    scale : float
    device : str
        Warp device of the render.
    info : dict
        The edit's own summary figures.
    t0 : float
        ``time.perf_counter()`` at the start of the command.
    fmt : OutputFormat, optional
        The picture's format (default: 8-bit PNG).

    Returns
    -------
    dict
        The summary :func:`report_edit` prints.
    """
    data = encode_model(model)
    out.write(output, data)
    if render_path is not None:
        W, H = output_size(model, scale=scale)
        out.write(render_path, render_file(model, W, H, fmt or OutputFormat(), device=device))
    s = {"width": model.width, "height": model.height, "regions": len(model.regions),
         "features": len(model.features), "bytes": len(data), "seconds": time.perf_counter() - t0, **info}
    if render_path is not None:
        s["render"] = render_path
    return s


def report_edit(ctx, output, s: dict, info: dict, as_json: bool) -> None:
    """The summary of a committed edit: JSON on stdout, else one line on stderr."""
    if as_json:
        emit_json(s)
    else:
        extra = ", ".join(f"{k} {v}" for k, v in info.items() if not isinstance(v, (dict, list)))
        say(ctx, f"{output}: {s['regions']} regions, {s['features']} features, {s['bytes']} bytes"
                 + (f"; {extra}" if extra else ""))


# --------------------------------------------------------------------------- recolor


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout).")
@click.option("--at", "at", type=POINT, default=None, help="Seed point (pixels): select by the feature nearest to it.")
@click.option("--color", type=COLOR, default=None, help="Select features of this colour (#rrggbb or R,G,B).")
@click.option("--radius", type=POSITIVE, default=None, help="Only features within this many pixels of --at.")
@click.option("--tolerance", type=NON_NEGATIVE, default=rc.DEFAULT_TOLERANCE, show_default=True,
              help="Largest colour difference (CIE76 Delta E) from the reference colour.")
@click.option("--region", type=int, default=None, help="Only features of this region.")
@click.option("--hue", type=FINITE, default=0.0, help="Rotate the ab hue by this many degrees.")
@click.option("--shift-ab", type=PAIR, default=None, help="Add (DA, DB) to a and b.")
@click.option("--lightness", type=FINITE, default=0.0, help="Add this to L.")
@click.option("--matrix", type=MATRIX, default=None,
              help="3x3 matrix applied to the selected gradation features' colours.")
@click.option("--matrix-space", type=click.Choice(["rgb", "lab"]), default="rgb", show_default=True,
              help="--matrix acts on sRGB column vectors in [0, 1] or on (L, a, b).")
@click.option("--harmonize", type=TEMPLATE, is_flag=False, flag_value="auto", default=None, metavar="[TEMPLATE]",
              help="Harmonise hues (Cohen-Or templates i, V, L, I, T, Y, X; no value: best fit).")
@render_options
@device_option
@json_option
@click.pass_context
def recolor(ctx, path, output, at, color, radius, tolerance, region, hue, shift_ab, lightness, matrix,
            matrix_space, harmonize, render_path, scale, quality, depth, device, as_json):
    """Edit the colours of selected features (paper VII-B)."""
    t0 = time.perf_counter()
    check_targets(as_json, output, render_path)
    if at is not None and color is not None:
        raise click.UsageError("--at and --color cannot both be used")
    if radius is not None and at is None:
        raise click.UsageError("--radius needs --at")
    shift = shift_ab or (0.0, 0.0)
    if not (hue or lightness or shift != (0.0, 0.0) or matrix is not None or harmonize):
        raise click.UsageError("nothing to do: give --hue, --shift-ab, --lightness, --matrix or --harmonize")
    with claim_outputs([path], ("-o", output), ("--render", render_path)) as out:
        fmt = image_format(render_path, quality=quality, depth=depth, option="--render")
        device = device_for(ctx, device)
        model = codec.load(path)
        mask = rc.select(model, at=at, color=color, radius=radius, tolerance=tolerance, region=region)
        done = rc.recolor_selected(model, mask, hue=hue, shift_ab=shift, lightness=lightness, matrix=matrix,
                                   matrix_space=matrix_space, harmonize=harmonize)
        info = done.summary()
        s = stage_edit(out, done.model, output, render_path, scale, device, info, t0, fmt)
    report_edit(ctx, output, s, info, as_json)


# --------------------------------------------------------------------------- crossmap


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout).")
@click.option("--target-region", type=int, required=True, help="Region of PATH whose features are replaced or blended.")
@click.option("--source", type=click.Path(dir_okay=False, allow_dash=True), default=None,
              help="Source .tpsv (default: PATH itself).")
@click.option("--source-region", type=int, default=None, help="Region of the source (default: --target-region).")
@click.option("--rotate", type=click.Choice(["0", "90", "180", "270"]), default="0", show_default=True,
              help="Turn the corner correspondence by quarter turns.")
@click.option("--flip", is_flag=True, help="Mirror the correspondence (S -> 1 - S) before turning.")
@click.option("--alpha", type=UNIT_INTERVAL, default=None,
              help="Blend (0..1): keep both feature sets, colours alpha*source + (1-alpha)*target. Default: replace.")
@click.option("--match-stats", is_flag=True, help="Match the source colours' Lab mean/std to the target region's.")
@render_options
@device_option
@json_option
@click.pass_context
def crossmap(ctx, path, output, target_region, source, source_region, rotate, flip, alpha, match_stats,
             render_path, scale, quality, depth, device, as_json):
    """Map a source region's features onto a target region (paper VII-C)."""
    t0 = time.perf_counter()
    check_targets(as_json, output, render_path)
    if path == "-" and source == "-":
        raise click.UsageError("PATH and --source cannot both be stdin ('-')")
    with claim_outputs([path, source], ("-o", output), ("--render", render_path)) as out:
        fmt = image_format(render_path, quality=quality, depth=depth, option="--render")
        device = device_for(ctx, device)
        target = codec.load(path)
        src = target if source is None else codec.load(source)
        mapped = cm.crossmap(target, target_region, src, source_region, rotate=int(rotate), flip=flip, alpha=alpha,
                             match_stats=match_stats, device=device)
        sr = target_region if source_region is None else source_region
        info = {"mode": "replace" if alpha is None else "blend",
                "mapped": int((src.features.region == sr).sum()),
                "target_features": int((mapped.features.region == target_region).sum())}
        s = stage_edit(out, mapped, output, render_path, scale, device, info, t0, fmt)
    report_edit(ctx, output, s, info, as_json)


# --------------------------------------------------------------------------- deform


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout); with --export-grid, the JSON grid.")
@click.option("--move", "moves", type=MOVE, multiple=True,
              help="Move control point (I, J) of region R by (DX, DY) pixels (repeatable).")
@click.option("--affine", "affines", type=AFFINE, multiple=True,
              help="Apply x' = a x + b y + c, y' = d x + e y + f to region R (repeatable).")
@click.option("--about", type=click.Choice(["centroid", "origin"]), default="centroid", show_default=True,
              help="--affine acts about the region's centroid or the image origin.")
@click.option("--grid", "grids", type=GRID, multiple=True,
              help="Replace region R's control grid (JSON, see docs/EDITING.md; repeatable).")
@click.option("--derivatives", type=click.Choice(["catmull-rom", "keep"]), default="catmull-rom", show_default=True,
              help="After --move: re-estimate derivatives near moved points, or keep them.")
@click.option("--keep-order", is_flag=True, help="Do not draw the deformed regions in front of the others.")
@click.option("--detach", is_flag=True, help="Neighbouring outlines do not follow the deformed region's border.")
@click.option("--export-grid", type=int, default=None, metavar="R",
              help="Write region R's control grid as JSON to -o instead of deforming.")
@render_options
@device_option
@json_option
@click.pass_context
def deform(ctx, path, output, moves, affines, about, grids, derivatives, keep_order, detach, export_grid,
           render_path, scale, quality, depth, device, as_json):
    """Deform region patches; features ride along in (S, T) (paper VII-D).

    Edits apply in the order --grid, --affine, --move.
    """
    t0 = time.perf_counter()
    check_targets(as_json, output, render_path)
    if export_grid is not None:
        if moves or affines or grids or render_path:
            raise click.UsageError("--export-grid cannot be combined with edits or --render")
        _export_grid(path, output, export_grid, as_json)
        return
    if not (moves or affines or grids):
        raise click.UsageError("nothing to do: give --move, --affine or --grid")
    with claim_outputs([path, *(g for _, g in grids)], ("-o", output), ("--render", render_path)) as out:
        fmt = image_format(render_path, quality=quality, depth=depth, option="--render")
        device = device_for(ctx, device)
        model = codec.load(path)
        attach = not detach
        for r, g in grids:
            model = df.set_grid(model, r, read_json(g), keep_order=keep_order, attach=attach)
        for r, m in affines:
            model = df.affine(model, r, m, about=about, keep_order=keep_order, attach=attach)
        if moves:
            model = df.move_points(model, list(moves), derivatives=derivatives, keep_order=keep_order,
                                   attach=attach)
        info = {"deformed": sorted({r for r, *_ in moves} | {r for r, _ in affines} | {r for r, _ in grids})}
        s = stage_edit(out, model, output, render_path, scale, device, info, t0, fmt)
    report_edit(ctx, output, s, info, as_json)


def _export_grid(path: str, output: str, region: int, as_json: bool) -> None:
    """``deform --export-grid``: region's control grid as JSON to ``output``."""
    with claim_outputs([path], ("-o", output)) as out:
        doc = df.grid_to_json(codec.load(path), region)
        out.write(output, (json.dumps(doc) + "\n").encode())
    if as_json:
        emit_json({"region": region, "grid": [len(doc["positions"]), len(doc["positions"][0])]})


# --------------------------------------------------------------------------- stylize


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(f"Image to write: {IMAGE_HELP} ('-': stdout).")
@click.option("--level", type=click.IntRange(0, st.MAX_LEVEL), default=2, show_default=True,
              help="Abstraction level (0: none; each level thins and quantises more).")
@click.option("--strokes/--no-strokes", default=True, show_default=True,
              help="Draw strokes along linked curvilinear features.")
@click.option("--stroke-width", type=STROKE_WIDTH, default=1.0, show_default=True,
              help="Stroke width in pixels at scale 1.")
@scale_option("Output scale.")
@click.option("--abstract-out", type=click.Path(dir_okay=False), default=None,
              help="Also write the abstracted model as a .tpsv.")
@image_options(depth=False)
@device_option
@json_option
@click.pass_context
def stylize(ctx, path, output, level, strokes, stroke_width, scale, abstract_out, format_name, quality, device,
            as_json):
    """Abstraction and strokes (paper VII-E); writes an image (8-bit PNG, JPEG, WebP or TIFF)."""
    t0 = time.perf_counter()
    check_targets(as_json, output, abstract_out, "--abstract-out")
    with claim_outputs([path], ("-o", output), ("--abstract-out", abstract_out)) as out:
        fmt = image_format(output, format_name, quality)
        device = device_for(ctx, device)
        done = st.stylize_model(codec.load(path), level, with_strokes=strokes, stroke_width=stroke_width,
                                scale=scale, device=device)
        out.write(output, encode_image(done.image, fmt))
        if abstract_out:
            out.write(abstract_out, encode_model(done.model))
    h, w = done.image.shape[:2]
    s = {"width": w, "height": h, "level": level, "features": len(done.model.features), "strokes": done.strokes,
         "seconds": time.perf_counter() - t0}
    if as_json:
        emit_json(s)
    else:
        say(ctx, f"{output}: {w}x{h}, level {level}, {s['features']} features, {done.strokes} strokes")
