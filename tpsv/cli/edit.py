"""Editing in vector space: ``recolor``, ``crossmap``, ``deform`` (.tpsv -> .tpsv) and ``stylize`` (.tpsv -> PNG).

Each edit reads a .tpsv (``-``: stdin) and writes a .tpsv (``-``: stdout), so
edits chain in a pipeline; ``--render P.png [--scale S]`` also writes a
picture of the result. Everything is computed before anything is written:
a failed run writes nothing. Malformed option values are usage errors (exit
2); values that do not fit the model (an unknown region, a point outside the
image, a deformation that folds) are data errors (exit 1). docs/EDITING.md
describes each edit.
"""

from __future__ import annotations

import os
import re
import time

import click

from . import main, say
from .options import check_json_target, device_for, device_option, emit_json, json_option, output_option
from .. import codec
from ..errors import TpsvError
from ..fileio import write_bytes_atomic

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


# --------------------------------------------------------------------------- parsing (usage errors)


def _numbers(text: str, n: int | None, hint: str, what: str) -> list[float]:
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise click.BadParameter(f"{text!r} is not {what}", param_hint=hint) from None
    if (n is not None and len(vals) != n) or not all(v == v and abs(v) != float("inf") for v in vals):
        raise click.BadParameter(f"{text!r} is not {what}", param_hint=hint)
    return vals


def parse_point(text, hint="--at"):
    return None if text is None else tuple(_numbers(text, 2, hint, "X,Y"))


def parse_color(text, hint="--color"):
    """``#rrggbb`` or ``R,G,B`` (0-255) -> sRGB in [0, 1]."""
    if text is None:
        return None
    t = text.strip()
    m = re.fullmatch(r"#?([0-9a-fA-F]{6})", t)
    if m:
        h = m.group(1)
        return tuple(int(h[i : i + 2], 16) / 255.0 for i in (0, 2, 4))
    vals = _numbers(t, 3, hint, "a colour (#rrggbb or R,G,B with 0-255 values)")
    if min(vals) < 0 or max(vals) > 255:
        raise click.BadParameter(f"{text!r}: R,G,B values must lie in 0..255", param_hint=hint)
    return tuple(v / 255.0 for v in vals)


def parse_matrix(text, hint="--matrix"):
    """``a,b,c;d,e,f;g,h,i`` (or 9 comma-separated numbers) -> 3 x 3 list."""
    if text is None:
        return None
    rows = [r for r in str(text).split(";")]
    if len(rows) == 3:
        return [_numbers(r, 3, hint, "a 3x3 matrix 'a,b,c;d,e,f;g,h,i'") for r in rows]
    vals = _numbers(text, 9, hint, "a 3x3 matrix 'a,b,c;d,e,f;g,h,i'")
    return [vals[0:3], vals[3:6], vals[6:9]]


def _region_prefix(text: str, hint: str, what: str):
    m = re.fullmatch(r"\s*(\d+)\s*:(.*)", str(text), re.S)
    if not m:
        raise click.BadParameter(f"{text!r} is not {what}", param_hint=hint)
    return int(m.group(1)), m.group(2)


def parse_move(text, hint="--move"):
    """``R:I,J:DX,DY`` -> (R, I, J, DX, DY)."""
    what = "REGION:I,J:DX,DY (e.g. 2:1,3:10,-4.5)"
    r, rest = _region_prefix(text, hint, what)
    m = re.fullmatch(r"\s*(\d+)\s*,\s*(\d+)\s*:\s*(" + _NUM + r")\s*,\s*(" + _NUM + r")\s*", rest)
    if not m:
        raise click.BadParameter(f"{text!r} is not {what}", param_hint=hint)
    return r, int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4))


def parse_affine(text, hint="--affine"):
    """``R:a,b,c,d,e,f`` -> (R, [[a,b,c],[d,e,f]])."""
    what = "REGION:a,b,c,d,e,f (x' = a x + b y + c, y' = d x + e y + f)"
    r, rest = _region_prefix(text, hint, what)
    v = _numbers(rest, 6, hint, what)
    return r, [v[0:3], v[3:6]]


def parse_grid(text, hint="--grid"):
    """``R:path.json`` -> (R, path)."""
    r, rest = _region_prefix(text, hint, "REGION:GRID.json")
    if not rest.strip():
        raise click.BadParameter(f"{text!r} is not REGION:GRID.json", param_hint=hint)
    return r, rest.strip()


# --------------------------------------------------------------------------- output


def _check_targets(as_json: bool, output: str, render_path: str | None) -> None:
    check_json_target(as_json, output, render_path)
    if render_path is not None:
        if render_path == "-" and output == "-":
            raise click.UsageError("-o and --render cannot both be stdout ('-')")
        if render_path != "-" and output != "-" and os.path.abspath(render_path) == os.path.abspath(output):
            raise click.UsageError("-o and --render name the same file")


def _check_dir(path: str) -> None:
    if path == "-":
        return
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise TpsvError(f"{path}: cannot write (no directory {d})")


def _write(path: str, data: bytes) -> None:
    try:
        write_bytes_atomic(path, data)
    except OSError as exc:
        raise TpsvError(f"{path}: cannot write ({exc.strerror or exc})") from None


def _encode(model) -> bytes:
    try:
        return codec.encode(model)
    except ValueError as exc:
        raise TpsvError(f"the edited model cannot be stored: {exc}") from None


def finish_edit(ctx, model, output, render_path, scale, device, as_json, info: dict, t0: float) -> None:
    """Encode (and render) the edited model, then write the outputs and the summary."""
    from ..image import encode_png
    from ..render.raster import render

    data = _encode(model)
    png = None
    if render_path is not None:
        png = encode_png(render(model, scale=scale, device=device))
    _check_dir(output)
    if render_path is not None:
        _check_dir(render_path)
    _write(output, data)
    if png is not None:
        _write(render_path, png)
    s = {"width": model.width, "height": model.height, "regions": len(model.regions),
         "features": len(model.features), "bytes": len(data), "seconds": time.perf_counter() - t0, **info}
    if render_path is not None:
        s["render"] = render_path
    if as_json:
        emit_json(s)
    else:
        extra = ", ".join(f"{k} {v}" for k, v in info.items() if not isinstance(v, (dict, list)))
        say(ctx, f"{output}: {s['regions']} regions, {s['features']} features, {s['bytes']} bytes"
                 + (f"; {extra}" if extra else ""))


def render_options(f):
    f = click.option("--scale", type=float, default=1.0, show_default=True, help="Scale of the --render picture.")(f)
    f = click.option("--render", "render_path", type=click.Path(dir_okay=False, allow_dash=True), default=None,
                     help="Also write a PNG of the result ('-': stdout).")(f)
    return f


def _positive_scale(scale):
    if not (scale == scale and 0 < scale < float("inf")):
        raise click.BadParameter(f"must be a positive number (got {scale})", param_hint="--scale")


# --------------------------------------------------------------------------- recolor


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout).")
@click.option("--at", "at", default=None, metavar="X,Y", help="Seed point (pixels): select by the feature nearest to it.")
@click.option("--color", default=None, metavar="#RRGGBB", help="Select features of this colour (#rrggbb or R,G,B).")
@click.option("--radius", type=float, default=None, help="Only features within this many pixels of --at.")
@click.option("--tolerance", type=float, default=20.0, show_default=True,
              help="Largest colour difference (CIE76 Delta E) from the reference colour.")
@click.option("--region", type=int, default=None, help="Only features of this region.")
@click.option("--hue", type=float, default=0.0, help="Rotate the ab hue by this many degrees.")
@click.option("--shift-ab", default=None, metavar="DA,DB", help="Add (DA, DB) to a and b.")
@click.option("--lightness", type=float, default=0.0, help="Add this to L.")
@click.option("--matrix", default=None, metavar="'a,b,c;d,e,f;g,h,i'",
              help="3x3 matrix applied to the selected gradation features' colours.")
@click.option("--matrix-space", type=click.Choice(["rgb", "lab"]), default="rgb", show_default=True,
              help="--matrix acts on sRGB column vectors in [0, 1] or on (L, a, b).")
@click.option("--harmonize", is_flag=False, flag_value="auto", default=None, metavar="[TEMPLATE]",
              help="Harmonise hues (Cohen-Or templates i, V, L, I, T, Y, X; no value: best fit).")
@render_options
@device_option
@json_option
@click.pass_context
def recolor(ctx, path, output, at, color, radius, tolerance, region, hue, shift_ab, lightness, matrix,
            matrix_space, harmonize, render_path, scale, device, as_json):
    """Edit the colours of selected features (paper VII-B)."""
    from ..edit import recolor as rc

    t0 = time.perf_counter()
    _check_targets(as_json, output, render_path)
    _positive_scale(scale)
    if at is not None and color is not None:
        raise click.UsageError("--at and --color cannot both be used")
    if radius is not None and at is None:
        raise click.UsageError("--radius needs --at")
    if radius is not None and not radius > 0:
        raise click.BadParameter(f"must be positive (got {radius})", param_hint="--radius")
    if not tolerance >= 0:
        raise click.BadParameter(f"must be >= 0 (got {tolerance})", param_hint="--tolerance")
    if harmonize is not None and harmonize != "auto" and harmonize not in rc.TEMPLATES:
        raise click.BadParameter(f"{harmonize!r} is not one of {', '.join(rc.TEMPLATES)}", param_hint="--harmonize")
    at_p = parse_point(at)
    color_p = parse_color(color)
    shift = tuple(_numbers(shift_ab, 2, "--shift-ab", "DA,DB")) if shift_ab is not None else (0.0, 0.0)
    mat = parse_matrix(matrix)
    if not (hue or lightness or shift != (0.0, 0.0) or mat is not None or harmonize):
        raise click.UsageError("nothing to do: give --hue, --shift-ab, --lightness, --matrix or --harmonize")
    device = device_for(ctx, device)
    model = codec.load(path)
    mask = rc.select(model, at=at_p, color=color_p, radius=radius, tolerance=tolerance, region=region)
    out = rc.recolor_features(model, mask, hue=hue, shift_ab=shift, lightness=lightness, matrix=mat,
                              matrix_space=matrix_space, harmonize=harmonize)
    info = {"selected": int(mask.sum()),
            "changed": int((out.features.lab != model.features.lab).any(axis=1).sum())}
    if harmonize:
        import numpy as np

        from ..edit.common import clip_lab

        pre = rc.recolor_features(model, mask, hue=hue, shift_ab=shift, lightness=lightness, matrix=mat,
                                  matrix_space=matrix_space)
        name, rot, _ = rc.harmonic_template(clip_lab(pre.features.lab[np.asarray(mask)]), harmonize)
        info["template"] = name
        info["rotation"] = rot
    finish_edit(ctx, out, output, render_path, scale, device, as_json, info, t0)


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
@click.option("--alpha", type=float, default=None,
              help="Blend (0..1): keep both feature sets, colours alpha*source + (1-alpha)*target. Default: replace.")
@click.option("--match-stats", is_flag=True, help="Match the source colours' Lab mean/std to the target region's.")
@render_options
@device_option
@json_option
@click.pass_context
def crossmap(ctx, path, output, target_region, source, source_region, rotate, flip, alpha, match_stats,
             render_path, scale, device, as_json):
    """Map a source region's features onto a target region (paper VII-C)."""
    from ..edit import crossmap as cm

    t0 = time.perf_counter()
    _check_targets(as_json, output, render_path)
    _positive_scale(scale)
    if alpha is not None and not 0.0 <= alpha <= 1.0:
        raise click.BadParameter(f"must lie in [0, 1] (got {alpha})", param_hint="--alpha")
    if path == "-" and source == "-":
        raise click.UsageError("PATH and --source cannot both be stdin ('-')")
    device = device_for(ctx, device)
    target = codec.load(path)
    src = target if source is None else codec.load(source)
    out = cm.crossmap(target, target_region, src, source_region, rotate=int(rotate), flip=flip, alpha=alpha,
                      match_stats=match_stats, device=device)
    sr = target_region if source_region is None else source_region
    info = {"mode": "replace" if alpha is None else "blend",
            "mapped": int((src.features.region == sr).sum()),
            "target_features": int((out.features.region == target_region).sum())}
    finish_edit(ctx, out, output, render_path, scale, device, as_json, info, t0)


# --------------------------------------------------------------------------- deform


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option(".tpsv file to write ('-': stdout); with --export-grid, the JSON grid.")
@click.option("--move", "moves", multiple=True, metavar="R:I,J:DX,DY",
              help="Move control point (I, J) of region R by (DX, DY) pixels (repeatable).")
@click.option("--affine", "affines", multiple=True, metavar="R:a,b,c,d,e,f",
              help="Apply x' = a x + b y + c, y' = d x + e y + f to region R (repeatable).")
@click.option("--about", type=click.Choice(["centroid", "origin"]), default="centroid", show_default=True,
              help="--affine acts about the region's centroid or the image origin.")
@click.option("--grid", "grids", multiple=True, metavar="R:GRID.json",
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
           render_path, scale, device, as_json):
    """Deform region patches; features ride along in (S, T) (paper VII-D).

    Edits apply in the order --grid, --affine, --move.
    """
    import json

    from ..edit import deform as df

    t0 = time.perf_counter()
    _check_targets(as_json, output, render_path)
    _positive_scale(scale)
    mv = [parse_move(m) for m in moves]
    af = [parse_affine(a) for a in affines]
    gr = [parse_grid(g) for g in grids]
    if export_grid is not None:
        if mv or af or gr or render_path:
            raise click.UsageError("--export-grid cannot be combined with edits or --render")
        model = codec.load(path)
        doc = df.grid_to_json(model, export_grid)
        _check_dir(output)
        _write(output, (json.dumps(doc) + "\n").encode())
        if as_json:
            emit_json({"region": export_grid, "grid": [len(doc["positions"]), len(doc["positions"][0])]})
        return
    if not (mv or af or gr):
        raise click.UsageError("nothing to do: give --move, --affine or --grid")
    device = device_for(ctx, device)
    model = codec.load(path)
    out = model
    attach = not detach
    for r, g in gr:
        out = df.set_grid(out, r, g, keep_order=keep_order, attach=attach)
    for r, m in af:
        out = df.affine(out, r, m, about=about, keep_order=keep_order, attach=attach)
    if mv:
        out = df.move_points(out, mv, derivatives=derivatives, keep_order=keep_order, attach=attach)
    regions = sorted({r for r, *_ in mv} | {r for r, _ in af} | {r for r, _ in gr})
    info = {"deformed": regions}
    finish_edit(ctx, out, output, render_path, scale, device, as_json, info, t0)


# --------------------------------------------------------------------------- stylize


@main.command()
@click.argument("path", type=click.Path(dir_okay=False, allow_dash=True))
@output_option("PNG to write ('-': stdout).")
@click.option("--level", type=click.IntRange(0, 8), default=2, show_default=True,
              help="Abstraction level (0: none; each level thins and quantises more).")
@click.option("--strokes/--no-strokes", default=True, show_default=True,
              help="Draw strokes along linked curvilinear features.")
@click.option("--stroke-width", type=float, default=1.0, show_default=True, help="Stroke width in pixels at scale 1.")
@click.option("--scale", type=float, default=1.0, show_default=True, help="Output scale.")
@click.option("--abstract-out", type=click.Path(dir_okay=False), default=None,
              help="Also write the abstracted model as a .tpsv.")
@device_option
@json_option
@click.pass_context
def stylize(ctx, path, output, level, strokes, stroke_width, scale, abstract_out, device, as_json):
    """Abstraction and strokes (paper VII-E); writes an image."""
    from ..image import encode_png
    from ..render.raster import render
    from ..edit import stylize as st

    t0 = time.perf_counter()
    check_json_target(as_json, output)
    _positive_scale(scale)
    if not (stroke_width == stroke_width and 0 < stroke_width < float("inf")):
        raise click.BadParameter(f"must be a positive number (got {stroke_width})", param_hint="--stroke-width")
    device = device_for(ctx, device)
    model = codec.load(path)
    m = st.abstract(model, level)
    img = render(m, scale=scale, device=device)
    n_chains = 0
    if strokes:
        graph = st.link_graph(m)
        n_chains = len(st.stroke_chains(m, graph=graph))
        img = st.strokes(img, m, scale=scale, width=stroke_width, graph=graph)
    png = encode_png(img)
    data = _encode(m) if abstract_out else None
    _check_dir(output)
    if abstract_out:
        _check_dir(abstract_out)
    _write(output, png)
    if data is not None:
        _write(abstract_out, data)
    h, w = img.shape[:2]
    s = {"width": w, "height": h, "level": level, "features": len(m.features), "strokes": n_chains,
         "seconds": time.perf_counter() - t0}
    if as_json:
        emit_json(s)
    else:
        say(ctx, f"{output}: {w}x{h}, level {level}, {s['features']} features, {n_chains} strokes")
