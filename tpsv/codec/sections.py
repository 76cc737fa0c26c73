"""The three sections of a .tpsv file as msgpack, before zstd.

Bulk data sits in msgpack ``bin`` fields as byte planes of fixed-width
little-endian integers: an array of ``n`` k-byte integers is stored as its
``n`` lowest bytes, then its ``n`` next bytes, and so on. Coordinates are
delta coded and zigzag mapped first, so most high planes are runs of zeros that
zstd reduces to almost nothing. ``docs/FORMAT.md`` gives every field.
"""

from __future__ import annotations

import msgpack
import numpy as np

from ..errors import TpsvFormatError
from . import chains, layout
from .quant import PARAM_FIELDS, Quantized

#: Lags of the delta coding of feature columns (measured on the samples).
#: Curvilinear features come in adjacent pairs that straddle an edge: the
#: position of feature i-1 (its partner, or the neighbouring pair) predicts S, T
#: best. Colour is best predicted by feature i-2 (the previous sample on the
#: same side of the same edge) when pairs dominate, by feature i-1 when
#: features are in scan order with few pairs; the encoder writes the lag of
#: ``LAB_LAGS`` whose codes are smaller (``lab_lag`` in the file).
ST_LAG = 1
LAB_LAG = 2
LAB_LAGS = (1, 2)
MAX_LAB_LAG = 8
#: Outline coordinates are stored divided by ``2**xy_shift``, the largest power
#: of two (at most ``2**MAX_XY_SHIFT``) dividing all of them.
MAX_XY_SHIFT = 4
#: Versions before 5 store outline coordinates in 1/8 px, not 1/16: one more shift.
OLD_XY_UNIT_SHIFT = 1
#: Lag of outline and control-grid coordinates: neighbours along the polygon
#: or along the grid row.
GEOMETRY_LAG = 1

#: Version 1 stored every polygon's vertices; version 2 stores chains (shared borders once).
REGION_KEYS_V1 = ("label", "grid", "polys", "verts", "xy_shift", "xy", "ctrl")
#: Version 4 adds ``alpha`` (a bit per region, least significant bit first) when flag 2 is set.
REGION_KEYS = ("label", "grid", "polys", "chains", "chain_verts", "refs", "ref", "xy_shift", "xy", "ctrl", "blurs",
               "blur")
FEATURE_KEYS = ("st_bits", "count", "st", "lab_lag", "lab", "kind", "pair")
PARAM_KEYS = tuple(PARAM_FIELDS) + ("extra",)

_UNSIGNED = {1: np.uint8, 2: np.uint16, 4: np.uint32}
_SIGNED = {1: np.int8, 2: np.int16, 4: np.int32}


# ---------------------------------------------------------------- transforms


def to_planes(values: np.ndarray, width: int) -> bytes:
    """Unsigned ``width``-byte integers as byte planes, lowest byte plane first."""
    a = np.ascontiguousarray(values, dtype=np.dtype(_UNSIGNED[width]).newbyteorder("<"))
    return a.view(np.uint8).reshape(-1, width).T.tobytes()


def from_planes(buf: bytes, n: int, width: int) -> np.ndarray:
    """Inverse of :func:`to_planes`: ``n`` unsigned integers, native byte order."""
    planes = np.frombuffer(buf, np.uint8).reshape(width, n)
    le = np.ascontiguousarray(planes.T).view(np.dtype(_UNSIGNED[width]).newbyteorder("<"))
    return le.ravel().astype(_UNSIGNED[width])


def delta_zigzag(values: np.ndarray, width: int, lag: int) -> np.ndarray:
    """``zigzag(x[i] - x[i - lag])`` in ``width``-byte wrapping arithmetic.

    ``x[i - lag]`` is 0 for the first ``lag`` items. Wrapping makes every
    ``width``-byte input round-trip, however far apart neighbours are.
    """
    x = np.asarray(values).astype(_SIGNED[width]).view(_UNSIGNED[width])
    d = x.copy()
    d[lag:] -= x[:-lag]
    s = d.view(_SIGNED[width])
    bits = 8 * width
    return ((s << 1) ^ (s >> (bits - 1))).view(_UNSIGNED[width])


def undelta_zigzag(codes: np.ndarray, width: int, lag: int) -> np.ndarray:
    """Inverse of :func:`delta_zigzag`, as signed ``width``-byte integers."""
    u = np.asarray(codes, _UNSIGNED[width])
    one = _UNSIGNED[width](1)
    d = (u >> one) ^ (np.zeros_like(u) - (u & one))
    x = np.empty_like(d)
    for phase in range(lag):
        x[phase::lag] = np.cumsum(d[phase::lag], dtype=_UNSIGNED[width])
    return x.view(_SIGNED[width])


def zigzag64(d: np.ndarray) -> np.ndarray:
    """Zigzag of int64 values known to fit 32 bits signed, as uint32."""
    d = np.asarray(d, np.int64)
    return ((d << 1) ^ (d >> 63)).astype(np.uint32)


def unzigzag64(z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zigzag64`, as int64."""
    z = np.asarray(z, np.int64)
    return (z >> 1) ^ -(z & 1)


# ---------------------------------------------------------------- packing


def _packb(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True, use_single_float=False, strict_types=True)


def pack_params(q: Quantized) -> bytes:
    """The params section: a map of the Params fields plus ``extra``."""
    return _packb({**{k: q.params[k] for k in PARAM_FIELDS}, "extra": dict(q.params["extra"])})


def xy_shift(xy: np.ndarray) -> int:
    """Largest ``k <= MAX_XY_SHIFT`` such that ``2**k`` divides every outline coordinate."""
    xy = np.asarray(xy, np.int64)
    k = 0
    while k < MAX_XY_SHIFT and not np.any(xy & ((1 << (k + 1)) - 1)):
        k += 1
    return k


def lab_lag(lab: np.ndarray) -> int:
    """The lag of ``LAB_LAGS`` with the smallest sum of ``log2(1 + zigzag code)`` (first on ties)."""
    best, cost = LAB_LAGS[0], None
    for g in LAB_LAGS:
        c = sum(
            float(np.log2(1.0 + delta_zigzag(lab[:, k], 1, g).astype(np.float64)).sum()) for k in range(3)
        )
        if cost is None or c < cost:
            best, cost = g, c
    return best


def pack_regions(q: Quantized) -> bytes:
    """The regions section: labels, grids, outlines (as chains) and control vectors."""
    grid = (q.grid - 1).astype(np.uint8)
    polys = np.split(np.asarray(q.xy, np.int32), np.cumsum(q.vert_counts)[:-1]) if q.vert_counts.size else []
    chain_list, refs = chains.decompose(polys)
    chain_xy = np.concatenate(chain_list) if chain_list else np.zeros((0, 2), np.int32)
    shift = xy_shift(chain_xy)
    xy = chain_xy.astype(np.int64) >> shift
    alpha = {} if q.transparent is None or not q.transparent.any() else {
        "alpha": np.packbits(q.transparent, bitorder="little").tobytes()}
    bmap = {} if q.map_values is None else {"map_cell": int(q.map_cell),
                                            "map": np.asarray(q.map_values, np.uint8).tobytes()}
    return _packb({
        **alpha,
        **bmap,
        "label": list(q.labels),
        "grid": grid[:, 0].tobytes() + grid[:, 1].tobytes(),
        "polys": to_planes(q.poly_counts, 4),
        "chains": len(chain_list),
        "chain_verts": to_planes(np.array([len(c) for c in chain_list], np.int64), 4),
        "refs": to_planes(np.array([len(r) for r in refs], np.int64), 4),
        "ref": to_planes(chains.ref_codes(np.array([c for r in refs for c in r], np.int64)), 4),
        "xy_shift": shift,
        "xy": b"".join(
            to_planes(delta_zigzag(xy[:, k].astype(np.int32), 4, GEOMETRY_LAG), 4) for k in range(2)
        ),
        "ctrl": to_planes(delta_zigzag(_ctrl_planar(q), 4, GEOMETRY_LAG), 4),
        "blurs": int(len(q.blur)),
        "blur": to_planes(q.blur[:, 0], 4) + to_planes(q.blur[:, 1], 4) + q.blur[:, 2].astype(np.uint8).tobytes(),
    })


def _ctrl_planar(q: Quantized) -> np.ndarray:
    """Control values reordered per region to (vector, axis, i, j): smooth runs."""
    return q.ctrl[_ctrl_permutation(q.grid)]


def _ctrl_unplanar(values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    out = np.empty_like(values)
    out[_ctrl_permutation(grid)] = values
    return out


def _ctrl_permutation(grid: np.ndarray) -> np.ndarray:
    """Index ``p`` such that ``ctrl[p]`` is in stored (planar) order.

    Built per distinct grid shape rather than per region: a file may hold tens
    of thousands of regions.
    """
    sizes = grid[:, 0] * grid[:, 1] * 8
    starts = np.cumsum(sizes) - sizes
    perm = np.empty(int(sizes.sum()), np.int64)
    shapes, inverse = np.unique(grid, axis=0, return_inverse=True)
    for k, (m, n) in enumerate(shapes.tolist()):
        size = m * n * 8
        local = np.arange(size).reshape(m, n, 4, 2).transpose(2, 3, 0, 1).ravel()
        first = starts[inverse.ravel() == k][:, None]
        perm[first + np.arange(size)] = first + local
    return perm


def pack_features(q: Quantized) -> bytes:
    """The features section: columns of S, T, Lab, kind and pair."""
    n = q.st.shape[0]
    pair_code = np.where(q.pair >= 0, zigzag64(q.pair - np.arange(n)), 0)
    lag = lab_lag(q.lab)
    return _packb({
        "st_bits": int(q.st_bits),
        "count": to_planes(q.feature_counts, 4),
        "st": b"".join(
            to_planes(delta_zigzag(q.st[:, k], 2, ST_LAG), 2) for k in range(2)
        ),
        "lab_lag": lag,
        "lab": b"".join(
            delta_zigzag(q.lab[:, k], 1, lag).tobytes() for k in range(3)
        ),
        "kind": q.kind.astype(np.uint8).tobytes(),
        "pair": to_planes(pair_code, 4),
    })


# ---------------------------------------------------------------- unpacking


def unpack(raw: bytes, name: str):
    """msgpack-decode a section, turning every failure into TpsvFormatError.

    Limits are the section's own size (msgpack's default), so no length field
    can make it allocate more than the section already holds.
    """
    try:
        return msgpack.unpackb(
            raw, raw=False, strict_map_key=True, use_list=True,
            object_pairs_hook=_unique_map, max_ext_len=0,
        )
    except TpsvFormatError as exc:
        raise TpsvFormatError(f"section {name}: {exc}") from None
    except Exception as exc:  # msgpack raises several types, some undocumented
        detail = str(exc) or type(exc).__name__
        raise TpsvFormatError(f"section {name}: bad msgpack ({detail})") from None


def _unique_map(pairs: list) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise TpsvFormatError("duplicate map key")
    return out


def _expect_map(obj, keys: tuple, name: str) -> dict:
    if not isinstance(obj, dict):
        raise TpsvFormatError(f"section {name}: expected a map, got {type(obj).__name__}")
    missing = [k for k in keys if k not in obj]
    if missing:
        raise TpsvFormatError(f"section {name}: missing key {missing[0]!r}")
    unknown = sorted(str(k) for k in obj if k not in keys)
    if unknown:
        raise TpsvFormatError(f"section {name}: unknown key {unknown[0]!r}")
    return obj


def _expect_bin(obj: dict, key: str, size: int, name: str) -> bytes:
    value = obj[key]
    if not isinstance(value, bytes):
        raise TpsvFormatError(f"section {name}: {key} is not a bin")
    if len(value) != size:
        raise TpsvFormatError(
            f"section {name}: {key} has {len(value)} bytes, expected {size}"
        )
    return value


def _expect_int(obj: dict, key: str, lo: int, hi: int, name: str) -> int:
    value = obj[key]
    if type(value) is not int:
        raise TpsvFormatError(f"section {name}: {key} is not an int")
    if not lo <= value <= hi:
        raise TpsvFormatError(f"section {name}: {key} = {value} not in {lo}..{hi}")
    return value


def unpack_params(raw: bytes) -> dict:
    """Params dict from the params section (types are checked by validate)."""
    obj = _expect_map(unpack(raw, "params"), PARAM_KEYS, "params")
    if not isinstance(obj["extra"], dict):
        raise TpsvFormatError("section params: extra is not a map")
    if not all(isinstance(k, str) for k in obj["extra"]):
        raise TpsvFormatError("section params: an extra key is not a str")
    # Stored sorted; re-sorting makes quantize(decode(x)) == decode(x) hold.
    obj["extra"] = dict(sorted(obj["extra"].items()))
    return obj


def unpack_regions(raw: bytes, h: layout.Header) -> dict:
    """Region arrays from the regions section, sized and summed against ``h``."""
    name = "regions"
    keys = (REGION_KEYS if h.version >= 2 else REGION_KEYS_V1) + (("alpha",) if h.has_alpha else ()) \
        + (("map_cell", "map") if h.has_blur_map else ())
    obj = _expect_map(unpack(raw, name), keys, name)
    r = h.regions
    transparent = None
    if h.has_alpha:
        bits = np.frombuffer(_expect_bin(obj, "alpha", (r + 7) // 8, name), np.uint8)
        transparent = np.unpackbits(bits, bitorder="little").astype(bool)
        if transparent[r:].any() or not transparent.any():
            raise TpsvFormatError(f"section {name}: alpha must mark at least one of the {r} regions and nothing past them")
        transparent = transparent[:r]
    labels = obj["label"]
    if not isinstance(labels, list) or len(labels) != r:
        raise TpsvFormatError(f"section {name}: label is not an array of {r} ints")
    g = np.frombuffer(_expect_bin(obj, "grid", 2 * r, name), np.uint8).astype(np.int64) + 1
    grid = np.stack([g[:r], g[r:]], axis=1)
    ctrl_points = int((grid[:, 0] * grid[:, 1]).sum())
    if ctrl_points != h.ctrl_points:
        raise TpsvFormatError(
            f"section {name}: grids hold {ctrl_points} control points, header says {h.ctrl_points}"
        )
    poly_counts = from_planes(_expect_bin(obj, "polys", 4 * r, name), r, 4).astype(np.int64)
    if int(poly_counts.sum()) != h.polygons:
        raise TpsvFormatError(
            f"section {name}: regions hold {int(poly_counts.sum())} polygons, header says {h.polygons}"
        )
    p, v = h.polygons, h.vertices
    if h.version >= 2:
        # every chain gives at least one vertex to some polygon, every reference too:
        # K <= V, sum(refs) <= V and sum(chain_verts) <= V + K, all before reading them
        k = _expect_int(obj, "chains", 0, v, name)
        chain_counts = from_planes(_expect_bin(obj, "chain_verts", 4 * k, name), k, 4).astype(np.int64)
        stored = int(chain_counts.sum())
        if stored > v + k:
            raise TpsvFormatError(f"section {name}: chains hold {stored} vertices, more than {v + k}")
        ref_counts = from_planes(_expect_bin(obj, "refs", 4 * p, name), p, 4).astype(np.int64)
        n_refs = int(ref_counts.sum())
        if n_refs > v:
            raise TpsvFormatError(f"section {name}: {n_refs} chain references for {v} vertices")
        refs = chains.ref_values(from_planes(_expect_bin(obj, "ref", 4 * n_refs, name), n_refs, 4).astype(np.int64))
    else:
        vert_counts = from_planes(_expect_bin(obj, "verts", 4 * p, name), p, 4).astype(np.int64)
        if int(vert_counts.sum()) != v:
            raise TpsvFormatError(
                f"section {name}: polygons hold {int(vert_counts.sum())} vertices, header says {v}"
            )
        stored = v
    old_unit = 0 if h.version >= 5 else OLD_XY_UNIT_SHIFT
    shift = _expect_int(obj, "xy_shift", 0, MAX_XY_SHIFT - old_unit, name)
    xy_buf = _expect_bin(obj, "xy", 8 * stored, name)
    xy = np.stack([
        undelta_zigzag(from_planes(xy_buf[4 * stored * k:4 * stored * (k + 1)], stored, 4), 4, GEOMETRY_LAG)
        for k in range(2)
    ], axis=1).astype(np.int64)
    unit = shift + old_unit
    lim = 2**31 >> unit
    if stored and (xy.min() < -lim or xy.max() >= lim):
        raise TpsvFormatError(f"section {name}: outline coordinate beyond the 32-bit range after xy_shift {shift}")
    xy = (xy << unit).astype(np.int32)
    if h.version >= 2:
        vert_counts, xy = chains.assemble(chain_counts, xy, ref_counts, refs, v)
    c = 8 * h.ctrl_points
    ctrl = undelta_zigzag(
        from_planes(_expect_bin(obj, "ctrl", 4 * c, name), c, 4), 4, GEOMETRY_LAG
    )
    blur = np.zeros((0, 3), np.int64)
    if h.version >= 2:
        # a listed pair shares a border, so there are fewer pairs than vertices
        n = _expect_int(obj, "blurs", 0, v, name)
        buf = _expect_bin(obj, "blur", 9 * n, name)
        blur = np.column_stack([from_planes(buf[:4 * n], n, 4), from_planes(buf[4 * n:8 * n], n, 4),
                                np.frombuffer(buf[8 * n:], np.uint8)]).astype(np.int64).reshape(-1, 3)
    bmap = {}
    if h.has_blur_map:
        cell = _expect_int(obj, "map_cell", 2, layout.MAX_MAP_CELL, name)
        values = obj["map"]
        if not isinstance(values, bytes) or len(values) > -(-h.width // cell) * -(-h.height // cell):
            raise TpsvFormatError(f"section {name}: map is not a bin of at most one byte per cell")
        bmap = {"map_cell": cell, "map_values": np.frombuffer(values, np.uint8).copy()}
    return dict(
        labels=labels, grid=grid, poly_counts=poly_counts, vert_counts=vert_counts,
        xy=xy, ctrl=_ctrl_unplanar(ctrl, grid), blur=blur, transparent=transparent, **bmap,
    )


def unpack_features(raw: bytes, h: layout.Header) -> dict:
    """Feature arrays from the features section, sized against ``h``."""
    name = "features"
    obj = _expect_map(unpack(raw, name), FEATURE_KEYS, name)
    st_bits = obj["st_bits"]
    if type(st_bits) is not int:
        raise TpsvFormatError(f"section {name}: st_bits is not an int")
    r, n = h.regions, h.features
    counts = from_planes(_expect_bin(obj, "count", 4 * r, name), r, 4).astype(np.int64)
    st_buf = _expect_bin(obj, "st", 4 * n, name)
    st = np.stack([
        undelta_zigzag(from_planes(st_buf[2 * n * k:2 * n * (k + 1)], n, 2), 2, ST_LAG)
        .view(np.uint16)
        for k in range(2)
    ], axis=1).astype(np.int64)
    lag = _expect_int(obj, "lab_lag", 1, MAX_LAB_LAG, name)
    lab_buf = _expect_bin(obj, "lab", 3 * n, name)
    lab = np.stack([
        undelta_zigzag(np.frombuffer(lab_buf[n * k:n * (k + 1)], np.uint8), 1, lag)
        .view(np.uint8)
        for k in range(3)
    ], axis=1)
    kind = np.frombuffer(_expect_bin(obj, "kind", n, name), np.uint8).copy()
    code = from_planes(_expect_bin(obj, "pair", 4 * n, name), n, 4)
    pair = np.where(code != 0, np.arange(n) + unzigzag64(code), -1)
    return dict(
        feature_counts=counts, st_bits=st_bits, st=st, lab=lab.reshape(n, 3),
        kind=kind, pair=pair.astype(np.int64),
    )
