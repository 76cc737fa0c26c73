"""Quantisation: Model <-> the integers a .tpsv file stores.

``Quantized`` holds a model exactly as the file does (integers, plus the params
as plain Python values). ``from_model`` rounds a model to it, ``to_model``
turns it back into floats, and ``validate`` checks every rule of
``docs/FORMAT.md`` on it. The encoder and the decoder share ``validate``, so the
encoder never writes a file the decoder would refuse.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..errors import TpsvError, TpsvFormatError
from ..geometry import crossing
from ..model import CURVILINEAR, Features, Model, Params, Patch, Region
from . import layout

#: Outline vertices are stored in units of 1/OUTLINE_SCALE px (1/8 before format version 5).
OUTLINE_SCALE = 16
#: Control vectors are stored in units of 1/CTRL_SCALE px.
CTRL_SCALE = 16
#: Edge widths are stored in units of 1/BLUR_SCALE px, at most MAX_BLUR of them.
BLUR_SCALE = 16
MAX_BLUR = 255
#: S, T aim at this many steps per pixel across a patch as wide as the image.
ST_STEPS_PER_PX = 16
MIN_ST_BITS = 8
MAX_ST_BITS = 16

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1

#: Params fields other than ``extra``: name -> (type, lowest, highest, lowest
#: is exclusive). Every dataclass field of Params must be listed here (a test
#: checks), or it would be dropped silently.
PARAM_FIELDS = {
    "t_canny": (float, 0.0, math.inf, False),
    "t_super": (float, 0.0, math.inf, False),
    "kernel_size": (int, min(layout.SUPPORTED_KERNEL_SIZES), max(layout.SUPPORTED_KERNEL_SIZES), False),
    "overlap": (float, 0.0, 0.5, True),
    "smoothing": (float, 0.0, math.inf, False),
    "st_steps": (int, 1, 64, False),
    "l_step": (int, 1, 16, False),
    "ab_step": (int, 1, 16, False),
}
#: Params fields that take one of a few values, not any in their range.
PARAM_CHOICES = {"kernel_size": layout.SUPPORTED_KERNEL_SIZES}
MAX_EXTRA_ITEMS = 256
MAX_EXTRA_KEY = 256
MAX_EXTRA_STR = 65536


@dataclass
class Quantized:
    """A model as stored: integer arrays, counts, and plain-Python params.

    Attributes
    ----------
    width, height : int
    params : dict
        ``PARAM_FIELDS`` names plus ``"extra"`` (a dict sorted by key).
    labels : list of int
        One per region.
    grid : ndarray, shape (R, 2), int64
        ``(M, N)`` per region.
    poly_counts : ndarray, shape (R,), int64
        Outline polygons per region (outer first, then holes).
    vert_counts : ndarray, shape (P,), int64
        Vertices per polygon, all regions in order.
    xy : ndarray, shape (V, 2), int32
        Outline vertices in 1/16 px (``OUTLINE_SCALE``).
    ctrl : ndarray, shape (C * 8,), int32
        Control vectors in 1/16 px: each region's ``(M, N, 4, 2)`` array,
        flattened in C order, regions concatenated.
    feature_counts : ndarray, shape (R,), int64
        Features per region (features are sorted by region).
    st_bits : int
        ``S`` and ``T`` are integers in ``[0, 2**st_bits - 1]``.
    st : ndarray, shape (F, 2), int64
    lab : ndarray, shape (F, 3), uint8
        ``round(L * 255 / 100 / l_step)``, ``round(a / ab_step) + 128``,
        ``round(b / ab_step) + 128`` (steps from ``params``).
    kind : ndarray, shape (F,), uint8
    pair : ndarray, shape (F,), int64
    blur : ndarray, shape (n, 3), int64
        Edge widths: rows ``(a, b, s)``, regions ``a < b`` sorted, ``s =
        round(16 sigma)`` in ``1..255`` (version 2; empty in version 1).
    """

    width: int
    height: int
    params: dict
    labels: list
    grid: np.ndarray
    poly_counts: np.ndarray
    vert_counts: np.ndarray
    xy: np.ndarray
    ctrl: np.ndarray
    feature_counts: np.ndarray
    st_bits: int
    st: np.ndarray
    lab: np.ndarray
    kind: np.ndarray
    pair: np.ndarray
    blur: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3), np.int64))
    #: Per region: transparent (``Region.transparent``; version 4, else all False). None: all False.
    transparent: np.ndarray | None = None
    #: Outlines drawn as curves (``Model.curves``; header flag 4, version 6).
    curves: bool = False
    #: Blur map (``Model.blur_map``; header flag 8, version 7): cell side (px) and the width of each cell
    #: a shared border passes through (``geometry.edgewidth.border_cells``), ``round(16 sigma)``, uint8.
    map_cell: int = 0
    map_values: np.ndarray | None = None


def st_bits_for(width: int, height: int, steps_per_px: int = ST_STEPS_PER_PX) -> int:
    """Bits per S and T for an image: about ``1 / steps_per_px`` px across a full-width patch.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    steps_per_px : int
        ``Params.st_steps`` of the model.

    Returns
    -------
    int
        ``clamp(bit_length(steps_per_px * max(width, height) - 1), 8, 16)``.
    """
    steps = int(steps_per_px) * max(int(width), int(height), 1)
    return min(MAX_ST_BITS, max(MIN_ST_BITS, (steps - 1).bit_length()))


#: ``Model.encoding`` keys the codec writes: the stored ``st_bits``, and the
#: ``(width, height, st_steps)`` it was stored for.
ST_BITS_KEY = "st_bits"
ST_BITS_FOR_KEY = "st_bits_for"


def model_st_bits(model: Model, width: int, height: int, st_steps: int) -> int:
    """Bits per S and T to encode ``model`` with.

    A decoded model keeps the ``st_bits`` of its file (``model.encoding``), so
    that encoding it again gives the same S, T and the same bytes, even when
    another encoder chose a ``st_bits`` other than :func:`st_bits_for`'s. The
    kept value applies only while width, height and ``st_steps`` are those of
    the file; a model resized or given another precision is quantised afresh.

    Raises
    ------
    ValueError
        ``model.encoding`` holds a ``st_bits`` the format cannot store.
    """
    encoding = getattr(model, "encoding", None) or {}
    bits = encoding.get(ST_BITS_KEY)
    if bits is None or tuple(encoding.get(ST_BITS_FOR_KEY, ())) != (width, height, st_steps):
        return st_bits_for(width, height, st_steps)
    if isinstance(bits, (bool, np.bool_)) or not isinstance(bits, (int, np.integer)) or not (
        MIN_ST_BITS <= bits <= MAX_ST_BITS
    ):
        raise ValueError(f"model.encoding[{ST_BITS_KEY!r}] = {bits!r} not in {MIN_ST_BITS}..{MAX_ST_BITS}")
    return int(bits)


def lab_limits(l_step: int, ab_step: int) -> tuple[int, int, int]:
    """Largest stored ``l``, and the range ``lo..hi`` of stored ``A``/``B`` (u8 with offset 128)."""
    return 255 // l_step, 128 - 128 // ab_step, 128 + 127 // ab_step


# ---------------------------------------------------------------- model -> ints


def from_model(model: Model) -> Quantized:
    """Round a model to what the file stores.

    Raises
    ------
    ValueError
        The model cannot be represented (wrong shapes, non-finite values,
        coordinates beyond 32-bit range, features not sorted by region).
    """
    width, height = _as_int(model.width, "width"), _as_int(model.height, "height")
    regions = list(model.regions)
    if len(regions) > layout.MAX_REGIONS:
        # refused before the outlines are mended one polygon at a time (seconds for thousands)
        raise layout.FormatLimitError(f"model too large for the .tpsv format: {len(regions)} regions exceed the limit "
                                      f"{layout.MAX_REGIONS}")
    grid, poly_counts, vert_counts, xy, ctrl, labels = _quantize_regions(regions)
    # rounding to the grid (or an edit) may fold a thin part of an outline over itself
    try:
        xy, vert_counts = mend_outlines(xy, vert_counts)
    except TpsvError as exc:
        raise ValueError(str(exc)) from None
    params = quantize_params(model.params)
    _validate_params(params, ValueError, layout.FormatLimitError)
    counts, st_bits, st, lab, kind, pair = _quantize_features(
        model.features, len(regions), model_st_bits(model, width, height, params["st_steps"]),
        params["l_step"], params["ab_step"],
    )
    return Quantized(
        width=width, height=height, params=params,
        labels=labels, grid=grid, poly_counts=poly_counts, vert_counts=vert_counts,
        xy=xy, ctrl=ctrl, feature_counts=counts, st_bits=st_bits, st=st, lab=lab,
        kind=kind, pair=pair, blur=_quantize_blur(getattr(model, "blur", None), len(regions)),
        transparent=np.array([bool(getattr(r, "transparent", False)) for r in regions], bool),
        curves=bool(getattr(model, "curves", False)),
        **_quantize_blur_map(getattr(model, "blur_map", None), width, height, xy, poly_counts, vert_counts),
    )


def _stored_outlines(xy: np.ndarray, poly_counts: np.ndarray, vert_counts: np.ndarray) -> list:
    """Regions as bare outlines (``.outline``, px) from the stored integer vertices."""
    from types import SimpleNamespace

    polys = _split(np.asarray(xy, np.float64) / OUTLINE_SCALE, vert_counts)
    start = np.concatenate([[0], np.cumsum(poly_counts)]).astype(np.int64).tolist()
    return [SimpleNamespace(outline=polys[start[r]:start[r + 1]]) for r in range(len(poly_counts))]


def map_cells(outlines: tuple, width: int, height: int, cell: int) -> np.ndarray:
    """The blur map's stored cells for outlines ``(xy, poly_counts, vert_counts)`` as stored
    (:func:`tpsv.geometry.edgewidth.border_cells`; ValueError when the borders are too long to map)."""
    from ..geometry.edgewidth import border_cells

    return border_cells(_stored_outlines(*outlines), width, height, cell)


def _quantize_blur_map(bmap, width: int, height: int, xy, poly_counts, vert_counts) -> dict:
    if bmap is None:
        return {}
    cell = int(bmap.cell)
    if not 2 <= cell <= layout.MAX_MAP_CELL:
        raise ValueError(f"blur map cell {cell} not in 2..{layout.MAX_MAP_CELL}")
    sigma = np.asarray(bmap.sigma, np.float64)
    if sigma.shape != (-(-height // cell), -(-width // cell)):
        raise ValueError(f"blur map has shape {sigma.shape} for a {width}x{height} image in cells of {cell} px")
    if not np.isfinite(sigma).all():
        raise ValueError("blur map: non-finite value")
    cells = map_cells((xy, poly_counts, vert_counts), width, height, cell)
    v = np.rint(sigma.ravel()[cells] * BLUR_SCALE)
    if np.any(v < 0) or np.any(v > MAX_BLUR):
        raise ValueError(f"blur map: widths must be in [0, {MAX_BLUR / BLUR_SCALE}] px")
    return {"map_cell": cell, "map_values": v.astype(np.uint8)}


def blur_map_of(q: Quantized, cells: np.ndarray | None = None):
    """The :class:`~tpsv.model.BlurMap` ``q`` stands for, or None (``cells``: its cells, when
    :func:`validate` has found them)."""
    if q.map_values is None:
        return None
    from ..geometry.edgewidth import fill_map

    if cells is None:
        cells = map_cells((q.xy, q.poly_counts, q.vert_counts), q.width, q.height, q.map_cell)
    return fill_map(q.width, q.height, q.map_cell, cells, q.map_values.astype(np.float32) / BLUR_SCALE)


def mend_outlines(xy: np.ndarray, vert_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stored outlines (``xy`` int32, ``vert_counts`` per polygon) with every self-crossing
    mended (:func:`tpsv.geometry.crossing.mend`, crossing points on the grid).

    What the encoder applies before writing, and the decoder to files of
    versions before 6, which did not forbid crossings (``docs/FORMAT.md``).

    Raises
    ------
    TpsvError
        A polygon too complex to check, or with too many crossings.
    """
    if xy.shape[0] == 0:
        return xy, vert_counts
    polys = np.split(xy, np.cumsum(vert_counts)[:-1])
    changed = False
    # crossing points on the grid the outlines already keep: a finer one would cost every vertex a bit
    from .sections import xy_shift  # (sections builds on this module)

    step = 1 << xy_shift(xy)
    owners: dict = {}  # vertex -> polygons that have (or had) it, made at the first mend

    def own(j: int, p: np.ndarray) -> None:
        for v in map(tuple, p.tolist()):
            owners.setdefault(v, set()).add(j)

    for k in range(len(polys)):
        cuts: list = []
        mended = crossing.mend(polys[k], step=step, cuts=cuts)
        if mended is polys[k]:
            continue
        if not changed:
            for j, p in enumerate(polys):
                own(j, p)
        changed = True
        polys[k] = mended
        own(k, mended)
        # the regions across the cut edges take the crossing point too: the border stays shared. Only a
        # polygon with both ends of a cut edge can take its point (every polygon was tried: with 2000
        # regions and 300 mends, 546 000 calls and two minutes)
        near = set()
        for a, b, _ in cuts:
            near |= owners.get(tuple(a.tolist()), set()) & owners.get(tuple(b.tolist()), set())
        for other in sorted(near - {k}):
            cut = crossing.insert_cuts(polys[other], cuts)
            if cut is not polys[other]:
                polys[other] = cut
                own(other, cut)
    if not changed:
        return xy, vert_counts
    return (np.concatenate(polys).astype(np.int32),
            np.array([len(p) for p in polys], np.int64))


def _quantize_blur(blur, n_regions: int) -> np.ndarray:
    """Edge widths as stored: ``(a, b, round(16 sigma))``, sorted, zero widths dropped."""
    b = np.asarray(np.zeros((0, 3)) if blur is None else blur, np.float64)
    if b.size == 0:
        return np.zeros((0, 3), np.int64)
    if b.ndim != 2 or b.shape[1] != 3:
        raise ValueError(f"blur has shape {b.shape}, expected (n, 3)")
    if not np.isfinite(b).all():
        raise ValueError("blur: non-finite value")
    ab = b[:, :2]
    if np.any(ab != np.rint(ab)) or np.any(ab < 0) or np.any(ab >= n_regions) or np.any(ab[:, 0] >= ab[:, 1]):
        raise ValueError(f"blur: region pairs must be integers a < b < {n_regions}")
    s = np.rint(b[:, 2] * BLUR_SCALE)
    if np.any(s < 0) or np.any(s > MAX_BLUR):
        raise ValueError(f"blur: sigma must be in [0, {MAX_BLUR / BLUR_SCALE}] px")
    q = np.column_stack([ab.astype(np.int64), s.astype(np.int64)])
    q = q[q[:, 2] > 0]
    q = q[np.lexsort((q[:, 1], q[:, 0]))]
    if len(q) > 1 and np.any(np.all(q[1:, :2] == q[:-1, :2], axis=1)):
        raise ValueError("blur: a region pair is listed twice")
    return q


def _as_int(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int, got {type(value).__name__}")
    return int(value)


def _fixed_point(values: np.ndarray, scale: int, what: str, starts: np.ndarray) -> np.ndarray:
    """``round(values * scale)`` as int32 (half to even), refusing what does not fit.

    ``starts[r]`` is the first row of region ``r``, to name it in errors.
    """
    q = np.rint(values * scale)
    bad = ~np.isfinite(q) | (q < INT32_MIN) | (q > INT32_MAX)
    if bad.any():
        row = int(np.nonzero(bad.reshape(bad.shape[0], -1).any(axis=1))[0][0])
        r = int(np.searchsorted(starts, row, side="right")) - 1
        raise ValueError(
            f"region {r}: {what} coordinate non-finite or beyond the 32-bit fixed-point range"
        )
    return q.astype(np.int32)


def _quantize_regions(regions: list[Region]):
    labels, grid, poly_counts, vert_counts, polys, ctrls = [], [], [], [], [], []
    for r, region in enumerate(regions):
        labels.append(_as_int(region.label, f"region {r}: label"))
        c = np.asarray(region.patch.ctrl, np.float64)
        if c.ndim != 4 or c.shape[2:] != (4, 2):
            raise ValueError(f"region {r}: ctrl has shape {c.shape}, expected (M, N, 4, 2)")
        grid.append(c.shape[:2])
        ctrls.append(c.reshape(-1, 8))
        poly_counts.append(len(region.outline))
        for k, poly in enumerate(region.outline):
            p = np.asarray(poly, np.float64)
            if p.ndim != 2 or p.shape[1] != 2:
                raise ValueError(
                    f"region {r}: outline polygon {k} has shape {p.shape}, expected (k, 2)"
                )
            vert_counts.append(p.shape[0])
            polys.append(p)
    grid = np.array(grid, np.int64).reshape(-1, 2)
    poly_counts = np.array(poly_counts, np.int64)
    vert_counts = np.array(vert_counts, np.int64)
    # Quantise all regions at once: per-region numpy calls dominate otherwise.
    vert_start = np.concatenate([[0], np.cumsum(vert_counts)])[np.cumsum(poly_counts) - poly_counts]
    ctrl_start = np.cumsum(grid.prod(axis=1)) - grid.prod(axis=1)
    xy = np.concatenate(polys) if polys else np.zeros((0, 2))
    ctrl = np.concatenate(ctrls) if ctrls else np.zeros((0, 8))
    return (
        grid, poly_counts, vert_counts,
        _fixed_point(xy, OUTLINE_SCALE, "outline", vert_start),
        _fixed_point(ctrl, CTRL_SCALE, "ctrl", ctrl_start).ravel(),
        labels,
    )


def _column(values, shape_tail: tuple, n: int | None, what: str) -> np.ndarray:
    a = np.asarray(values)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail or (
        n is not None and a.shape[0] != n
    ):
        want = ("F",) + shape_tail
        raise ValueError(f"features.{what} has shape {a.shape}, expected {want} with F={n}")
    return a


def _quantize_features(f: Features, n_regions: int, st_bits: int, l_step: int = 1, ab_step: int = 1):
    region = _column(f.region, (), None, "region")
    n = region.shape[0]
    st = _column(f.st, (2,), n, "st").astype(np.float64)
    lab = _column(f.lab, (3,), n, "lab").astype(np.float64)
    kind = _column(f.kind, (), n, "kind")
    pair = _column(f.pair, (), n, "pair")
    for name, a in (("region", region), ("kind", kind), ("pair", pair)):
        if n and a.dtype.kind not in "iub":
            raise ValueError(f"features.{name} must be integers, got {a.dtype}")
    region = region.astype(np.int64)
    if n and (region.min() < 0 or region.max() >= n_regions):
        raise ValueError(f"features.region out of range for {n_regions} regions")
    if n and np.any(np.diff(region) < 0):
        raise ValueError("features are not sorted by region")
    if not (np.all(np.isfinite(st)) and np.all(np.isfinite(lab))):
        raise ValueError("features: non-finite S, T or Lab value")
    q = 2**st_bits - 1
    st_q = np.rint(np.clip(st, 0.0, 1.0) * q).astype(np.int64)
    lab_q = np.empty((n, 3), np.uint8)
    l_max, ab_lo, ab_hi = lab_limits(l_step, ab_step)
    lab_q[:, 0] = np.clip(np.rint(lab[:, 0] * (255.0 / 100.0) / l_step), 0, l_max)
    lab_q[:, 1:] = np.clip(np.rint(lab[:, 1:] / ab_step) + 128, ab_lo, ab_hi)
    kind = np.asarray(kind).astype(np.int64)
    if n and (kind.min() < 0 or kind.max() > 255):
        raise ValueError("features.kind out of range")
    counts = np.bincount(region, minlength=n_regions).astype(np.int64)
    return counts, st_bits, st_q, lab_q, kind.astype(np.uint8), np.asarray(pair).astype(np.int64)


def quantize_params(params: Params) -> dict:
    """Params as the plain-Python dict the file stores (``extra`` sorted by key).

    Raises
    ------
    ValueError
        A field of the wrong type, or an ``extra`` value of an unsupported type.
    """
    names = {f.name for f in dataclasses.fields(Params)} - {"extra"}
    if names != set(PARAM_FIELDS):
        # A field added to Params but not to the format would be lost silently.
        raise ValueError(
            f"Params fields {sorted(names)} do not match the format's {sorted(PARAM_FIELDS)}"
        )
    out = {}
    for name, (typ, *_range) in PARAM_FIELDS.items():
        value = getattr(params, name)
        if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)
        ):
            raise ValueError(f"params.{name} must be a number, got {type(value).__name__}")
        if typ is int and float(value) != int(value):
            raise ValueError(f"params.{name} must be an integer, got {value}")
        out[name] = typ(value)
    if not isinstance(params.extra, dict):
        raise ValueError("params.extra must be a dict")
    extra = {}
    for key in sorted(params.extra, key=str):
        if not isinstance(key, str):
            raise ValueError(f"params.extra key {key!r} is not a str")
        extra[key] = _plain_value(params.extra[key], key)
    out["extra"] = extra
    return out


def _plain_value(value, key: str):
    """An ``extra`` value as a plain bool, int, float or str."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(
        f"params.extra[{key!r}] is a {type(value).__name__}; only bool, int, float, str are stored"
    )


# ---------------------------------------------------------------- validation


def validate(q: Quantized) -> np.ndarray | None:
    """Check every value rule of the format on ``q``.

    Returns
    -------
    ndarray or None
        The blur map's cells, which its count of widths was checked against
        (None without a map): :func:`to_model` takes them instead of finding
        them again from the borders.

    Raises
    ------
    TpsvFormatError
        The first rule broken, in one line.
    """
    _validate_params(q.params)
    layout.check_header_limits(_header(q))
    _validate_regions(q)
    _validate_blur(q)
    cells = _validate_blur_map(q)
    _validate_features(q)
    return cells


def check_limits(q: Quantized) -> None:
    """The encoder's budget check: canvas, counts and polygon sizes within the format's limits.

    Raises
    ------
    layout.FormatLimitError
        The first limit passed (a ``TpsvError`` and a ``ValueError``).
    """
    what = "model too large for the .tpsv format: "
    layout.check_size_limits(_header(q), layout.FormatLimitError, what)
    big = np.nonzero(q.vert_counts > layout.MAX_POLYGON_VERTICES)[0]
    if big.size:
        raise layout.FormatLimitError(
            f"{what}outline polygon {big[0]} has {q.vert_counts[big[0]]} vertices "
            f"(at most {layout.MAX_POLYGON_VERTICES})"
        )


def _header(q: Quantized) -> layout.Header:
    """The header counts of ``q`` (section sizes left out)."""
    return layout.Header(
        version=layout.VERSION, flags=0, width=q.width, height=q.height,
        regions=len(q.labels), polygons=int(q.vert_counts.size),
        vertices=int(q.xy.shape[0]),
        ctrl_points=int(q.ctrl.size // 8), features=int(q.st.shape[0]),
        compressed=(1, 1, 1), raw=(0, 0, 0),
    )


def _validate_params(p: dict, error=TpsvFormatError, unsupported=None) -> None:
    """Raise ``error`` at the first bad params value (``unsupported`` for a kernel_size outside the set)."""
    for name, (typ, lo, hi, lo_open) in PARAM_FIELDS.items():
        value = p[name]
        # bool is an int subclass; msgpack keeps them apart, so must we.
        if type(value) is not typ:
            raise error(f"params: {name} must be {typ.__name__}, got {type(value).__name__}")
        if typ is float and not math.isfinite(value):
            raise error(f"params: {name} is not finite")
        if value < lo or value > hi or (lo_open and value == lo):
            bracket = "(" if lo_open else "["
            raise error(f"params: {name} = {value} not in {bracket}{lo}, {hi}]")
        if name in PARAM_CHOICES and value not in PARAM_CHOICES[name]:
            raise (unsupported or error)(
                f"params: {name} = {value} not one of {', '.join(map(str, PARAM_CHOICES[name]))}"
            )
    extra = p["extra"]
    if len(extra) > MAX_EXTRA_ITEMS:
        raise error(f"params: {len(extra)} extra items exceed the limit {MAX_EXTRA_ITEMS}")
    for key, value in extra.items():
        if not isinstance(key, str) or not 1 <= len(key) <= MAX_EXTRA_KEY:
            raise error(f"params: extra key {key!r} is not a str of 1..{MAX_EXTRA_KEY} characters")
        if type(value) not in (bool, int, float, str):
            raise error(f"params: extra[{key!r}] has unsupported type {type(value).__name__}")
        if type(value) is int and not INT64_MIN <= value <= INT64_MAX:
            raise error(f"params: extra[{key!r}] beyond 64-bit range")
        if type(value) is float and not math.isfinite(value):
            raise error(f"params: extra[{key!r}] is not finite")
        if type(value) is str and len(value) > MAX_EXTRA_STR:
            raise error(f"params: extra[{key!r}] longer than {MAX_EXTRA_STR} characters")


def _validate_regions(q: Quantized) -> None:
    for r, label in enumerate(q.labels):
        if type(label) is not int or not INT64_MIN <= label <= INT64_MAX:
            raise TpsvFormatError(f"region {r}: label {label!r} is not a 64-bit integer")
    bad = np.nonzero((q.grid < layout.MIN_GRID) | (q.grid > layout.MAX_GRID))[0]
    if bad.size:
        m, n = q.grid[bad[0]]
        raise TpsvFormatError(
            f"region {bad[0]}: control grid {m}x{n} not in "
            f"{layout.MIN_GRID}..{layout.MAX_GRID} per side"
        )
    bad = np.nonzero(q.poly_counts < 1)[0]
    if bad.size:
        raise TpsvFormatError(f"region {bad[0]}: no outline polygon")
    bad = np.nonzero(q.vert_counts < 3)[0]
    if bad.size:
        raise TpsvFormatError(
            f"outline polygon {bad[0]} has {q.vert_counts[bad[0]]} vertices (at least 3)"
        )
    # a hole holds at least one other region and two holes never hold the same one,
    # so a region has at most (regions - 1) holes; more is a hostile file (deform and
    # render pay per polygon)
    bad = np.nonzero(q.poly_counts > len(q.labels))[0]
    if bad.size:
        raise TpsvFormatError(
            f"region {bad[0]}: {q.poly_counts[bad[0]]} outline polygons, but a region has at most "
            f"one per region of the file ({len(q.labels)})"
        )
    bad = np.nonzero(q.vert_counts > layout.MAX_POLYGON_VERTICES)[0]
    if bad.size:
        raise TpsvFormatError(
            f"outline polygon {bad[0]} has {q.vert_counts[bad[0]]} vertices "
            f"(at most {layout.MAX_POLYGON_VERTICES})"
        )
    _validate_simple(q)


def _validate_simple(q: Quantized) -> None:
    """No outline polygon crosses itself (an outline's inside would depend on the fill rule)."""
    for k, p in enumerate(np.split(q.xy, np.cumsum(q.vert_counts)[:-1]) if q.xy.shape[0] else []):
        try:
            c = crossing.crossings(p, limit=1)
        except TpsvError as exc:
            raise TpsvFormatError(f"outline polygon {k}: {exc}") from None
        if len(c):
            raise TpsvFormatError(f"outline polygon {k} crosses itself (edges {c[0, 0]} and {c[0, 1]})")


def _validate_blur(q: Quantized) -> None:
    b = q.blur
    if b.size == 0:
        return
    r = len(q.labels)
    if len(b) > q.xy.shape[0]:
        raise TpsvFormatError(f"blur: {len(b)} region pairs for {q.xy.shape[0]} outline vertices")
    bad = np.flatnonzero((b[:, 0] >= b[:, 1]) | (b[:, 1] >= r) | (b[:, 0] < 0))
    if bad.size:
        raise TpsvFormatError(f"blur {bad[0]}: region pair ({b[bad[0], 0]}, {b[bad[0], 1]}) is not a < b < {r}")
    bad = np.flatnonzero((b[:, 2] < 1) | (b[:, 2] > MAX_BLUR))
    if bad.size:
        raise TpsvFormatError(f"blur {bad[0]}: width {b[bad[0], 2]} not in 1..{MAX_BLUR}")
    key = b[:, 0] * r + b[:, 1]
    bad = np.flatnonzero(key[1:] <= key[:-1])
    if bad.size:
        raise TpsvFormatError(f"blur {bad[0] + 1}: region pairs not in increasing order")


def _validate_blur_map(q: Quantized) -> np.ndarray | None:
    if q.map_values is None:
        return None
    if not 2 <= q.map_cell <= layout.MAX_MAP_CELL:
        raise TpsvFormatError(f"blur map: cell side {q.map_cell} not in 2..{layout.MAX_MAP_CELL}")
    try:
        cells = map_cells((q.xy, q.poly_counts, q.vert_counts), q.width, q.height, q.map_cell)
    except ValueError as exc:
        raise TpsvFormatError(f"blur map: {exc}") from None
    if len(q.map_values) != len(cells):
        raise TpsvFormatError(f"blur map: {len(q.map_values)} widths for the {len(cells)} cells the borders "
                              "pass through")
    return cells


def _validate_features(q: Quantized) -> None:
    n = q.st.shape[0]
    if int(q.feature_counts.sum()) != n:
        raise TpsvFormatError(
            f"features: per-region counts sum to {int(q.feature_counts.sum())}, expected {n}"
        )
    if not MIN_ST_BITS <= q.st_bits <= MAX_ST_BITS:
        raise TpsvFormatError(f"features: st_bits {q.st_bits} not in {MIN_ST_BITS}..{MAX_ST_BITS}")
    if n == 0:
        return
    top = 2**q.st_bits - 1
    bad = np.nonzero((q.st < 0) | (q.st > top))[0]
    if bad.size:
        raise TpsvFormatError(f"feature {bad[0]}: S or T beyond {top} (st_bits {q.st_bits})")
    l_max, ab_lo, ab_hi = lab_limits(q.params["l_step"], q.params["ab_step"])
    bad = np.nonzero((q.lab[:, 0] > l_max) | (q.lab[:, 1:] < ab_lo).any(1) | (q.lab[:, 1:] > ab_hi).any(1))[0]
    if bad.size:
        raise TpsvFormatError(
            f"feature {bad[0]}: colour {q.lab[bad[0]].tolist()} out of range for "
            f"l_step {q.params['l_step']}, ab_step {q.params['ab_step']}"
        )
    bad = np.nonzero(q.kind > CURVILINEAR)[0]
    if bad.size:
        raise TpsvFormatError(f"feature {bad[0]}: kind {q.kind[bad[0]]} not in {{0, 1}}")
    _validate_pairs(q.pair, q.kind)


def _validate_pairs(pair: np.ndarray, kind: np.ndarray) -> None:
    n = pair.shape[0]
    idx = np.arange(n)
    bad = np.nonzero((pair < -1) | (pair >= n))[0]
    if bad.size:
        raise TpsvFormatError(f"feature {bad[0]}: pair {pair[bad[0]]} not in [-1, {n})")
    bad = np.nonzero(pair == idx)[0]
    if bad.size:
        raise TpsvFormatError(f"feature {bad[0]}: paired with itself")
    paired = pair >= 0
    back = np.where(paired, pair[np.where(paired, pair, 0)], idx)
    bad = np.nonzero(paired & (back != idx))[0]
    if bad.size:
        i = bad[0]
        raise TpsvFormatError(
            f"feature {i}: pair is {pair[i]} but feature {pair[i]}'s pair is "
            f"{pair[pair[i]]} (pairs must be symmetric)"
        )
    bad = np.nonzero(paired & (kind != CURVILINEAR))[0]
    if bad.size:
        raise TpsvFormatError(f"feature {bad[0]}: paired but not curvilinear")


# ---------------------------------------------------------------- ints -> model


def to_model(q: Quantized, map_cells: np.ndarray | None = None) -> Model:
    """The float model a valid ``Quantized`` stands for (``map_cells``: what :func:`validate` returned)."""
    p = q.params
    params = Params(**{name: p[name] for name in PARAM_FIELDS}, extra=dict(p["extra"]))
    return Model(
        width=q.width, height=q.height, regions=_dequantize_regions(q),
        features=_dequantize_features(q, p["l_step"], p["ab_step"]), params=params,
        encoding={ST_BITS_KEY: q.st_bits, ST_BITS_FOR_KEY: (q.width, q.height, p["st_steps"])},
        blur=np.column_stack([q.blur[:, :2].astype(np.float64), q.blur[:, 2] / BLUR_SCALE]).reshape(-1, 3),
        curves=bool(q.curves), blur_map=blur_map_of(q, map_cells),
    )


def _dequantize_regions(q: Quantized) -> list[Region]:
    polys = _split(q.xy.astype(np.float64) / OUTLINE_SCALE, q.vert_counts)
    ctrls = _split(q.ctrl.astype(np.float64) / CTRL_SCALE, q.grid.prod(axis=1) * 8)
    poly_start = np.concatenate([[0], np.cumsum(q.poly_counts)]).tolist()
    regions = []
    clear = np.zeros(len(q.labels), bool) if q.transparent is None else q.transparent
    for r, (label, (m, n)) in enumerate(zip(q.labels, q.grid.tolist())):
        outline = polys[poly_start[r]:poly_start[r + 1]]
        regions.append(Region(label=label, outline=outline, patch=Patch(ctrls[r].reshape(m, n, 4, 2)),
                              transparent=bool(clear[r])))
    return regions


def _split(values: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    """``values`` cut into consecutive pieces of ``counts`` rows (copies, so
    that each piece owns its memory like a freshly built model's arrays)."""
    if counts.size == 0:
        return []
    return [piece.copy() for piece in np.split(values, np.cumsum(counts)[:-1])]


def _dequantize_features(q: Quantized, l_step: int = 1, ab_step: int = 1) -> Features:
    n = q.st.shape[0]
    lab = np.empty((n, 3), np.float64)
    lab[:, 0] = (q.lab[:, 0].astype(np.int64) * l_step) * (100.0 / 255.0)
    lab[:, 1:] = (q.lab[:, 1:].astype(np.float64) - 128.0) * ab_step
    return Features(
        region=np.repeat(np.arange(q.feature_counts.size), q.feature_counts).astype(np.int32),
        st=q.st.astype(np.float64) / (2**q.st_bits - 1),
        lab=lab.astype(np.float32),
        kind=q.kind.astype(np.uint8),
        pair=q.pair.astype(np.int32),
    )
