"""Structure-aware mutators: each turns a seed .tpsv into a hostile input.

Families (:data:`FAMILIES`), from the outside of the file inwards:

``bytes``
    Plain byte damage (flips, cuts, splices); CRCs usually re-sealed, so the
    decoder's own checks, not a checksum, must catch it.
``header``
    One or two header fields set to boundary values, both CRCs re-sealed.
``section``
    A section decompressed, its msgpack map decoded and mutated (types,
    sizes, nesting, NaN/inf, huge ints, missing and extra keys, duplicate
    keys), packed and recompressed, header sizes and CRCs fixed.
``quantized``
    The stored integers changed past the format's value rules (pairs, kinds,
    grids, S/T, colours, counts, params) and packed without validation.
``model``
    The decoded model changed through the public API and encoded by
    ``codec.encode``: NaN/inf and huge coordinates, self-intersecting and
    degenerate outlines, folded patches, many vertices or regions, duplicated
    features, extreme params. These are valid files with hostile content, the
    inputs that reach ``render`` and the edits.

Every mutant is a pure function of ``(seed, index)`` (:func:`make_case`), so a
finding is reproduced from its index alone.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import random
import struct
import zlib
from dataclasses import dataclass, field

import msgpack
import numpy as np
import zstandard

from tpsv import codec
from tpsv.codec import layout, quant, sections
from tpsv.model import Features, Model, Patch, Region

from .seeds import seed_files

FAMILIES = ("bytes", "header", "section", "quantized", "model")
#: Relative frequency of each family: the model family makes the valid files
#: that exercise render and the edits, the others the decoder's checks.
WEIGHTS = (1, 2, 3, 2, 4)

#: Header fields after the magic: name -> (offset, struct format).
HEADER_FIELDS = {
    "version": (8, "<H"), "flags": (10, "<H"), "width": (12, "<I"), "height": (16, "<I"),
    "regions": (20, "<I"), "polygons": (24, "<I"), "vertices": (28, "<I"), "ctrl_points": (32, "<I"),
    "features": (36, "<I"), "c0": (40, "<I"), "r0": (44, "<I"), "c1": (48, "<I"), "r1": (52, "<I"),
    "c2": (56, "<I"), "r2": (60, "<I"), "payload_crc": (64, "<I"),
}
COUNT_FIELDS = ("regions", "polygons", "vertices", "ctrl_points", "features")

INTERESTING_INTS = (0, 1, 2, 3, 4, 7, 8, 127, 128, 255, 256, 4095, 4096, 65535, 65536, 2**20, 2**24,
                    2**26, 2**28, 2**31 - 1, 2**31, 2**32 - 1)
INTERESTING_FLOATS = (math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324, 1e-300, 1e300, 1.7e308, -1.0, 0.5,
                      0.5000000000000001, 2.0**31, -(2.0**31))
HOSTILE_STRINGS = ("", "\x1b[2J\x1b[H", "\x1b]0;title\x07", "a\rb", "\x00", "é" * 300, "x" * 70000, "0,0,0",
                   "-1", "99999999999999999999", "1,", ",", "0, 1", "nan", "front")


@dataclass
class Case:
    """One fuzz input.

    Attributes
    ----------
    index : int
    family : str
    seed : str
        Name of the seed it was made from.
    ops : list of str
        The mutations applied, in order (for the report).
    data : bytes or None
        The file; for the ``model`` family, set by encoding ``model``
        (:func:`materialize`), and left None when the encoder refuses it.
    model : Model or None
        The mutated model (``model`` family only).
    """

    index: int
    family: str
    seed: str
    ops: list = field(default_factory=list)
    data: bytes | None = None
    model: Model | None = None

    def describe(self) -> str:
        return f"#{self.index} {self.family} from {self.seed}: " + "; ".join(self.ops)


def materialize(case: Case) -> bytes | None:
    """The file of ``case``: its bytes, or its model encoded (None when the encoder refuses it)."""
    if case.data is None and case.model is not None:
        try:
            case.data = codec.encode(case.model)
        except Exception:  # refused (ValueError) or a finding the "encode" target reports
            return None
    return case.data


def make_case(seed: int, index: int) -> Case:
    """The ``index``-th mutant of campaign ``seed`` (deterministic)."""
    rng = random.Random(f"tpsv-fuzz:{seed}:{index}")
    name, data = rng.choice(seed_files())
    family = rng.choices(FAMILIES, WEIGHTS)[0]
    case = Case(index=index, family=family, seed=name)
    MUTATORS[family](case, data, rng)
    return case


# ------------------------------------------------------------------ file helpers


def reseal(data: bytes | bytearray, header_only: bool = False) -> bytes:
    """Both CRC-32s recomputed (or only the header's), so that a check, not a checksum, must refuse."""
    out = bytearray(data)
    if len(out) < layout.HEADER_SIZE:
        return bytes(out)
    if not header_only:
        struct.pack_into("<I", out, 64, zlib.crc32(bytes(out[layout.HEADER_SIZE:])))
    struct.pack_into("<I", out, 68, zlib.crc32(bytes(out[:68])))
    return bytes(out)


def set_field(data: bytes | bytearray, name: str, value: int) -> bytearray:
    """Header field ``name`` set to ``value`` (wrapped to its width)."""
    out = bytearray(data)
    off, fmt = HEADER_FIELDS[name]
    struct.pack_into(fmt, out, off, value % (1 << (8 * struct.calcsize(fmt))))
    return out


def get_field(data: bytes, name: str) -> int:
    off, fmt = HEADER_FIELDS[name]
    return struct.unpack_from(fmt, data, off)[0]


def split_sections(data: bytes) -> list[bytes]:
    """The three compressed sections of a valid file, and its detail section when it has one."""
    sizes = [get_field(data, f"c{k}") for k in range(3)]
    out, start = [], layout.HEADER_SIZE
    for n in sizes:
        out.append(data[start:start + n])
        start += n
    if get_field(data, "flags") & layout.FLAG_DETAIL:
        (n, _) = layout.DETAIL_SIZES.unpack_from(data, start)
        start += layout.DETAIL_SIZES.size
        out.append(data[start:start + n])
    return out


def assemble(header_from: bytes, comps: list[bytes], raws: list[int], counts: dict | None = None) -> bytes:
    """A file from a header template, compressed sections, their raw sizes and optional new counts."""
    head = bytearray(header_from[:layout.HEADER_SIZE])
    for k in range(3):
        head = set_field(head, f"c{k}", len(comps[k]))
        head = set_field(head, f"r{k}", raws[k])
    for name, value in (counts or {}).items():
        head = set_field(head, name, value)
    tail = b""
    if len(comps) > 3:  # the detail section, behind its sizes
        tail = layout.DETAIL_SIZES.pack(len(comps[3]), raws[3]) + comps[3]
    return reseal(bytes(head) + b"".join(comps[:3]) + tail)


def compress(raw: bytes, rng: random.Random) -> bytes:
    """A zstd frame of ``raw``; now and then one the decoder must refuse (no size, a checksum, level 1)."""
    roll = rng.random()
    if roll < 0.03:
        return zstandard.ZstdCompressor(level=1, write_content_size=False).compress(raw)
    if roll < 0.06:
        return zstandard.ZstdCompressor(level=1, write_checksum=True).compress(raw)
    return zstandard.ZstdCompressor(level=1).compress(raw)


# ------------------------------------------------------------------ bytes


def mutate_bytes(case: Case, data: bytes, rng: random.Random) -> None:
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.choice(("flip", "set", "cut", "splice", "insert"))
        pos = rng.randrange(len(out)) if out else 0
        if op == "flip" and out:
            out[pos] ^= 1 << rng.randrange(8)
        elif op == "set" and out:
            out[pos] = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
        elif op == "cut":
            out = out[:pos]
        elif op == "splice" and out:
            n = rng.randint(1, 64)
            src = rng.randrange(len(out))
            out[pos:pos + n] = out[src:src + n]
        elif op == "insert":
            out[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        case.ops.append(f"{op}@{pos}")
    roll = rng.random()
    case.data = reseal(out) if roll < 0.8 else reseal(out, header_only=True) if roll < 0.9 else bytes(out)


# ------------------------------------------------------------------ header


def mutate_header(case: Case, data: bytes, rng: random.Random) -> None:
    out = bytearray(data)
    for _ in range(rng.randint(1, 2)):
        name = rng.choice(list(HEADER_FIELDS))
        cur = get_field(data, name)
        value = rng.choice(INTERESTING_INTS + (cur + 1, cur - 1, cur * 2, cur // 2, rng.getrandbits(32)))
        out = set_field(out, name, value)
        case.ops.append(f"{name}={value}")
    case.data = reseal(out, header_only=rng.random() < 0.1)


# ------------------------------------------------------------------ section (msgpack)


def _deep(depth: int, leaf):
    for _ in range(depth):
        leaf = [leaf]
    return leaf


def _hostile_value(rng: random.Random, cur):
    """A replacement for a msgpack value: another type, a boundary, or a mangled copy."""
    if isinstance(cur, bytes) and cur and rng.random() < 0.5:
        return _mangle_bin(rng, cur)
    choices = [
        lambda: rng.choice(INTERESTING_INTS) * rng.choice((1, -1)),
        lambda: rng.choice((2**63 - 1, -(2**63), 2**64 - 1)),
        lambda: rng.choice(INTERESTING_FLOATS),
        lambda: rng.choice((True, False, None)),
        lambda: rng.choice(HOSTILE_STRINGS),
        lambda: bytes(rng.randrange(256) for _ in range(rng.randint(0, 32))),
        lambda: [cur] * rng.randint(0, 3),
        lambda: {"k": cur},
        lambda: _deep(rng.choice((10, 200, 2000)), cur if not isinstance(cur, (list, dict)) else 0),
        lambda: type(cur).__name__,  # a str where something else was
    ]
    if isinstance(cur, int) and not isinstance(cur, bool):
        choices += [lambda: cur + 1, lambda: cur - 1, lambda: float(cur), lambda: bool(cur)]
    if isinstance(cur, float):
        choices += [lambda: int(cur) if math.isfinite(cur) else 0, lambda: cur * 1e300, lambda: -cur]
    return rng.choice(choices)()


def _mangle_bin(rng: random.Random, b: bytes) -> bytes:
    """A ``bin`` cut, lengthened, or with bytes set: plane data decoding to boundary values."""
    out = bytearray(b)
    op = rng.choice(("cut", "extend", "fill", "poke", "poke"))
    if op == "cut":
        return bytes(out[:rng.randrange(len(out) + 1)])
    if op == "extend":
        return bytes(out + bytes([rng.choice((0, 0xFF))]) * rng.randint(1, 64))
    if op == "fill":
        return bytes([rng.choice((0, 0xFF, 0x80, 1))]) * len(out)
    for _ in range(rng.randint(1, 8)):
        out[rng.randrange(len(out))] = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
    return bytes(out)


def _mutate_map(obj: dict, rng: random.Random, ops: list) -> dict:
    obj = dict(obj)
    op = rng.choice(("replace", "replace", "replace", "delete", "add", "extra"))
    key = rng.choice(list(obj)) if obj else None
    if op == "replace" and key is not None:
        obj[key] = _hostile_value(rng, obj[key])
        ops.append(f"{key}:replace->{type(obj[key]).__name__}")
    elif op == "delete" and key is not None:
        del obj[key]
        ops.append(f"{key}:delete")
    elif op == "add":
        new = rng.choice(("zzz", "", "label", 1, b"bin"))
        obj[new] = _hostile_value(rng, 0)
        ops.append(f"add {new!r}")
    elif op == "extra" and isinstance(obj.get("extra"), dict):
        extra = dict(obj["extra"])
        k = rng.choice(("front", "scheme", "t_canny", "kernel_size", "\x1b[31m", "k" * 300, "x"))
        extra[k] = _hostile_value(rng, rng.choice(HOSTILE_STRINGS))
        if rng.random() < 0.1:
            extra.update({f"k{i}": i for i in range(300)})
        obj["extra"] = extra
        ops.append(f"extra[{k[:8]!r}]")
    return obj


def _pack(obj, rng: random.Random, ops: list) -> bytes:
    """msgpack bytes of ``obj``; sometimes with a duplicated key or single floats."""
    duplicate = isinstance(obj, dict) and obj and rng.random() < 0.05
    single = rng.random() < 0.05
    try:
        if duplicate:
            pairs = list(obj.items())
            pairs.append(rng.choice(pairs))
            ops.append("duplicate key")
            return msgpack.Packer(use_bin_type=True).pack_map_pairs(pairs)
        return msgpack.packb(obj, use_bin_type=True, use_single_float=single)
    except (OverflowError, ValueError, TypeError):  # a value msgpack cannot hold: 2**64, 2000 levels deep
        ops.append("unpackable value dropped")
        return msgpack.packb(0)


def mutate_section(case: Case, data: bytes, rng: random.Random) -> None:
    comps = split_sections(data)
    raws = [zstandard.ZstdDecompressor().decompress(c) for c in comps]
    k = rng.randrange(len(comps))
    obj = msgpack.unpackb(raws[k], raw=False, strict_map_key=False)
    case.ops.append(f"section {(layout.SECTIONS + ('detail',))[k]}")
    files = obj.get("image") if isinstance(obj, dict) else None
    files = [files] if isinstance(files, bytes) else files
    if k == 3 and isinstance(files, list) and files and all(isinstance(f, bytes) and f for f in files) \
            and rng.random() < 0.5:
        # an image's own bytes (an AV1 bitstream, or an AVIF file): flipped bytes, a cut, or a lie
        # about its size in its sequence header or boxes
        at = rng.randrange(len(files))
        image = bytearray(files[at])
        for _ in range(rng.randint(1, 8)):
            image[rng.randrange(len(image))] = rng.randrange(256)
        if rng.random() < 0.3:
            image = image[: rng.randrange(len(image))]
        files[at] = bytes(image)
        obj["image"] = files[0] if isinstance(obj["image"], bytes) else files
        if rng.random() < 0.1:
            obj["codec"] = "avif" if obj.get("codec") == "av1" else "av1"
        case.ops.append("detail image bytes")
    for _ in range(rng.randint(1, 3)):
        obj = _mutate_map(obj, rng, case.ops) if isinstance(obj, dict) else _hostile_value(rng, obj)
    if rng.random() < 0.03:
        obj = _hostile_value(rng, obj)  # not a map at all
        case.ops.append("section not a map")
    raw = _pack(obj, rng, case.ops)
    if rng.random() < 0.05:
        raw += b"\xc0"  # trailing msgpack
        case.ops.append("trailing byte")
    raws[k] = raw
    comps[k] = compress(raw, rng)
    case.data = assemble(data, comps, [len(r) for r in raws])


# ------------------------------------------------------------------ quantized (integers past the rules)


def _quantized_ops(q: quant.Quantized, rng: random.Random, ops: list) -> quant.Quantized:
    n, r = q.st.shape[0], len(q.labels)
    op = rng.choice(("pair", "kind", "st", "st_bits", "lab", "grid", "verts", "polys", "label", "param",
                     "counts", "xy", "blur", "alpha"))
    ops.append(op)
    if op == "pair" and n:
        pair = q.pair.copy()
        i = rng.randrange(n)
        pair[i] = rng.choice((-2, n, n + 5, i, rng.randrange(n), 2**31 - 1 - n))
        return dataclasses.replace(q, pair=pair)
    if op == "kind" and n:
        kind = q.kind.copy()
        kind[rng.randrange(n)] = rng.choice((2, 255))
        return dataclasses.replace(q, kind=kind)
    if op == "st" and n:
        st = q.st.copy()
        # one past the top of the declared range (an earlier op may have made st_bits absurd)
        st[rng.randrange(n), rng.randrange(2)] = rng.choice((min(2 ** max(q.st_bits, 0), 2**62), 65535))
        return dataclasses.replace(q, st=st)
    if op == "st_bits":
        return dataclasses.replace(q, st_bits=rng.choice((0, 7, 8, 16, 17, 64, -1)))
    if op == "lab" and n:
        lab = q.lab.copy()
        lab[rng.randrange(n)] = rng.choice(((255, 128, 128), (0, 0, 0), (0, 255, 255)))
        return dataclasses.replace(q, lab=lab)
    if op == "grid" and r:
        grid = q.grid.copy()
        grid[rng.randrange(r)] = rng.choice(((1, 2), (2, 1), (256, 256), (256, 2)))
        return dataclasses.replace(q, grid=grid, ctrl=np.resize(q.ctrl, int(grid.prod(axis=1).sum()) * 8))
    if op == "verts" and q.vert_counts.size:
        vc = q.vert_counts.copy()
        p = rng.randrange(vc.size)
        vc[p] = rng.choice((0, 1, 2))
        return dataclasses.replace(q, vert_counts=vc, xy=q.xy[:int(vc.sum())])
    if op == "polys" and r:
        pc = q.poly_counts.copy()
        pc[rng.randrange(r)] = 0
        vc = q.vert_counts[:int(pc.sum())]
        return dataclasses.replace(q, poly_counts=pc, vert_counts=vc, xy=q.xy[:int(vc.sum())])
    if op == "label" and r:
        labels = list(q.labels)
        labels[rng.randrange(r)] = rng.choice((2**63 - 1, -(2**63), 2**64 - 1, 1.5, "x", None))
        return dataclasses.replace(q, labels=labels)
    if op == "param":
        params = dict(q.params)
        name = rng.choice(list(quant.PARAM_FIELDS))
        params[name] = rng.choice((0, 1, 2, 3, 33, 4096, 4097, -1, 0.0, 1e-300, 0.5, 0.51, math.nan, math.inf,
                                   1.7e308, True, "32", 2**63 - 1))
        ops[-1] = f"param {name}={params[name]!r}"
        return dataclasses.replace(q, params=params)
    if op == "counts" and r:
        fc = q.feature_counts.copy()
        a, b = rng.randrange(r), rng.randrange(r)
        moved = rng.choice((1, int(fc[a]), 2**31))
        fc[a] -= moved
        fc[b] += moved
        return dataclasses.replace(q, feature_counts=fc)
    if op == "xy" and q.xy.size:
        xy = q.xy.copy()
        xy[rng.randrange(xy.shape[0]), rng.randrange(2)] = rng.choice((2**31 - 1, -(2**31), 0))
        return dataclasses.replace(q, xy=xy)
    if op == "blur":
        # a pair out of range or order, a width of 0 or 255, a pair listed twice, or many pairs
        rows = [(rng.randrange(-1, r + 2), rng.randrange(-1, r + 2), rng.choice((0, 1, 16, 255)))
                for _ in range(rng.choice((1, 2, 3, 64)))]
        blur = np.array(rows, np.int64).clip(0, 2**32 - 1).reshape(-1, 3)
        blur[:, 2] = blur[:, 2].clip(0, 255)
        return dataclasses.replace(q, blur=blur)
    if op == "alpha" and r:
        # a region marked transparent or not (every one, none: then the flag and the key disagree)
        clear = np.zeros(r, bool) if q.transparent is None else q.transparent.copy()
        pick = rng.choice(("one", "all", "none"))
        if pick == "one":
            clear[rng.randrange(r)] ^= True
        else:
            clear[:] = pick == "all"
        return dataclasses.replace(q, transparent=clear)
    return q


def mutate_quantized(case: Case, data: bytes, rng: random.Random) -> None:
    q = quant.from_model(codec.decode(data))
    for _ in range(rng.randint(1, 2)):
        q = _quantized_ops(q, rng, case.ops)
    try:
        raws = [sections.pack_params(q), sections.pack_regions(q), sections.pack_features(q)]
    except (ValueError, TypeError, OverflowError) as exc:  # not even packable: fall back to the seed
        case.ops.append(f"unpackable ({type(exc).__name__})")
        case.data = data
        return
    counts = dict(regions=len(q.labels), polygons=int(q.vert_counts.size), vertices=int(q.xy.shape[0]),
                  ctrl_points=int(q.ctrl.size // 8), features=int(q.st.shape[0]))
    detail = split_sections(data)[3:]  # kept as it is (its frames and modes count the regions)
    sizes = [len(r) for r in raws] + [layout.parse_header(data).detail[1] for _ in detail]
    case.data = assemble(data, [compress(r, rng) for r in raws] + detail, sizes, counts)


# ------------------------------------------------------------------ model (valid files, hostile content)


def _pick_region(m: Model, rng: random.Random) -> int | None:
    return rng.randrange(len(m.regions)) if m.regions else None


def _poly(m: Model, rng: random.Random) -> tuple[int, int] | None:
    r = _pick_region(m, rng)
    return None if r is None else (r, rng.randrange(len(m.regions[r].outline)))


def op_nonfinite(m: Model, rng: random.Random) -> str:
    value = rng.choice((math.nan, math.inf, -math.inf))
    where = rng.choice(("outline", "ctrl", "st", "lab"))
    if where in ("outline", "ctrl") and m.regions:
        r = _pick_region(m, rng)
        a = m.regions[r].outline[0] if where == "outline" else m.regions[r].patch.ctrl
        a.reshape(-1)[rng.randrange(a.size)] = value
    elif len(m.features):
        col = getattr(m.features, where)
        col.reshape(-1)[rng.randrange(col.size)] = value
    return f"{where} {value}"


def op_huge_coords(m: Model, rng: random.Random) -> str:
    if not m.regions:
        return "huge: no region"
    r = _pick_region(m, rng)
    scale = rng.choice((1e3, 1e6, 2.6e8))
    if rng.random() < 0.5:
        m.regions[r].outline[0] = m.regions[r].outline[0] * scale
        return f"outline x{scale:g}"
    m.regions[r].patch.ctrl[..., rng.randrange(4), :] *= scale
    return f"ctrl x{scale:g}"


def op_self_intersecting(m: Model, rng: random.Random) -> str:
    pk = _poly(m, rng)
    if pk is None:
        return "bowtie: no region"
    r, k = pk
    p = m.regions[r].outline[k]
    m.regions[r].outline[k] = p[np.array(rng.sample(range(len(p)), len(p)))]
    return f"region {r} polygon {k} shuffled"


def op_degenerate(m: Model, rng: random.Random) -> str:
    pk = _poly(m, rng)
    if pk is None:
        return "degenerate: no region"
    r, k = pk
    p = m.regions[r].outline[k]
    kind = rng.choice(("point", "line", "tiny", "reverse"))
    if kind == "point":
        m.regions[r].outline[k] = np.repeat(p[:1], max(3, len(p)), axis=0)
    elif kind == "line":
        t = np.linspace(0, 1, max(3, len(p)))[:, None]
        m.regions[r].outline[k] = p[0] + t * (p[-1] - p[0])
    elif kind == "tiny":
        m.regions[r].outline[k] = p[0] + (p - p[0]) * 1e-3
    else:
        m.regions[r].outline[k] = p[::-1].copy()
    return f"region {r} polygon {k} {kind}"


def op_many_vertices(m: Model, rng: random.Random) -> str:
    pk = _poly(m, rng)
    if pk is None:
        return "vertices: no region"
    r, k = pk
    n = rng.choice((1000, 20000, 100000))
    p = m.regions[r].outline[k]
    lo, hi = p.min(0), p.max(0)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    zig = 0.5 + 0.5 * np.where(np.arange(n) % 2, 1.0, 0.3)[:, None]
    m.regions[r].outline[k] = (lo + hi) / 2 + (hi - lo) / 2 * zig * np.stack([np.cos(t), np.sin(t)], 1)
    return f"region {r} polygon {k}: {n} vertices"


def op_many_regions(m: Model, rng: random.Random) -> str:
    n = rng.choice((200, 2000, 10000))
    side = int(math.ceil(math.sqrt(n)))
    cw, ch = m.width / side, m.height / side
    regions = []
    for i in range(n):
        x0, y0 = (i % side) * cw, (i // side) * ch
        sq = np.array([[x0, y0], [x0 + cw, y0], [x0 + cw, y0 + ch], [x0, y0 + ch]])
        ctrl = np.zeros((2, 2, 4, 2))
        ctrl[:, :, 0] = [[[x0, y0], [x0, y0 + ch]], [[x0 + cw, y0], [x0 + cw, y0 + ch]]]
        ctrl[:, :, 1], ctrl[:, :, 2] = (cw, 0), (0, ch)
        regions.append(Region(i, [sq], Patch(ctrl)))
    f = m.features
    keep = f.region < 0  # none
    m.regions = regions
    m.features = f.subset(keep)
    if rng.random() < 0.5:
        idx = np.arange(n, dtype=np.int32)
        m.features = Features(idx, np.full((n, 2), 0.5), np.tile(np.float32([50, 10, -10]), (n, 1)),
                              np.zeros(n, np.uint8), np.full(n, -1, np.int32))
    return f"{n} regions"


def op_many_holes(m: Model, rng: random.Random) -> str:
    if not m.regions:
        return "holes: no region"
    r = _pick_region(m, rng)
    outer = m.regions[r].outline[0]
    c = outer.mean(0)
    n = rng.choice((10, 500, 5000))
    holes = [np.array([[c[0], c[1]], [c[0], c[1] + 0.5], [c[0] + 0.5, c[1] + 0.5]]) + 0.01 * i for i in range(n)]
    m.regions[r].outline = [outer] + holes
    return f"region {r}: {n} holes"


def op_fold_patch(m: Model, rng: random.Random) -> str:
    if not m.regions:
        return "fold: no region"
    r = _pick_region(m, rng)
    c = m.regions[r].patch.ctrl
    kind = rng.choice(("swap", "flip-deriv", "zero", "twist", "collapse"))
    if kind == "swap" and c.shape[0] > 1:
        c[[0, -1]] = c[[-1, 0]]
    elif kind == "flip-deriv":
        c[:, :, 1:3] *= -3
    elif kind == "zero":
        c[:, :, 1:] = 0
    elif kind == "twist":
        c[:, :, 3] = rng.choice((1e3, -1e5))
    else:
        c[:, :, 0] = c[0, 0, 0]
    return f"region {r} patch {kind}"


def op_grid_size(m: Model, rng: random.Random) -> str:
    if not m.regions:
        return "grid: no region"
    r = _pick_region(m, rng)
    mm, nn = rng.choice(((2, 2), (256, 2), (2, 256), (64, 64), (256, 256)))
    old = m.regions[r].patch.ctrl
    lo, hi = old[..., 0, :].reshape(-1, 2).min(0), old[..., 0, :].reshape(-1, 2).max(0)
    w, h = max(hi[0] - lo[0], 1.0), max(hi[1] - lo[1], 1.0)
    ii, jj = np.meshgrid(np.arange(mm, dtype=float), np.arange(nn, dtype=float), indexing="ij")
    ctrl = np.zeros((mm, nn, 4, 2))
    ctrl[..., 0, 0] = lo[0] + ii * w / (mm - 1)
    ctrl[..., 0, 1] = lo[1] + jj * h / (nn - 1)
    ctrl[..., 1, :] = (w / (mm - 1), 0)
    ctrl[..., 2, :] = (0, h / (nn - 1))
    m.regions[r].patch = Patch(ctrl)
    return f"region {r} grid {mm}x{nn}"


def op_duplicate_features(m: Model, rng: random.Random) -> str:
    n = len(m.features)
    if not n:
        return "dup: no features"
    i = rng.randrange(n)
    copies = rng.choice((1, 10, 1000, 50000))
    idx = np.sort(np.concatenate([np.arange(n), np.full(copies, i)]))
    f = m.features.subset(idx)
    f.pair[:] = np.where(np.isin(np.arange(len(f)), np.nonzero(idx == i)[0][1:]), -1, f.pair)
    f.pair = _symmetric(f.pair)
    if rng.random() < 0.5:
        f.lab[idx == i] = np.float32([rng.uniform(0, 100), rng.uniform(-128, 127), rng.uniform(-128, 127)])
    m.features = f
    return f"feature {i} x{copies}"


def _symmetric(pair: np.ndarray) -> np.ndarray:
    """Pairs whose partner does not point back become -1 (the encoder refuses asymmetric pairs)."""
    pair = pair.copy()
    ok = pair >= 0
    back = np.where(ok, pair[np.where(ok, pair, 0)], -1)
    pair[ok & (back != np.arange(pair.size))] = -1
    return pair


def op_feature_positions(m: Model, rng: random.Random) -> str:
    n = len(m.features)
    if not n:
        return "st: no features"
    kind = rng.choice(("one-point", "corners", "edge", "random"))
    st = m.features.st
    if kind == "one-point":
        st[:] = 0.5
    elif kind == "corners":
        st[:] = np.array([(0, 0), (1, 1), (0, 1), (1, 0)], float)[np.arange(n) % 4]
    elif kind == "edge":
        st[:, 0] = 1.0
    else:
        st[:] = np.random.default_rng(rng.getrandbits(32)).random((n, 2))
    return f"features {kind}"


def op_pairs(m: Model, rng: random.Random) -> str:
    n = len(m.features)
    if n < 2:
        return "pairs: too few"
    f = m.features
    kind = rng.choice(("cross-region", "all-curvilinear", "unpaired", "asymmetric", "gradation-pair"))
    if kind == "cross-region":
        a, b = 0, n - 1
        f.pair[f.pair == a] = -1
        f.pair[f.pair == b] = -1
        f.pair[a], f.pair[b] = b, a
        f.kind[[a, b]] = 1
    elif kind == "all-curvilinear":
        f.kind[:] = 1
    elif kind == "unpaired":
        f.pair[:] = -1
    elif kind == "asymmetric":
        f.pair[0] = n - 1
        f.kind[0] = 1
    else:
        f.pair[0], f.pair[1] = 1, 0
        f.kind[[0, 1]] = 0
    return f"pairs {kind}"


def op_params(m: Model, rng: random.Random) -> str:
    p = copy.deepcopy(m.params)
    name = rng.choice(("kernel_size", "overlap", "smoothing", "t_canny", "st_steps", "l_step", "front", "scheme",
                       "extra-junk"))
    if name == "kernel_size":
        p.kernel_size = rng.choice((3, 8, 16, 24, 32, 64, 128, 129, 4096))
    elif name == "overlap":
        p.overlap = rng.choice((1e-300, 1e-6, 0.5, 0.25))
    elif name == "smoothing":
        p.smoothing = rng.choice((0.0, 5e-324, 1e-12, 1.0, 1e6, 1.7e308))
    elif name == "t_canny":
        p.t_canny = rng.choice((0.0, 1.7e308))
    elif name == "st_steps":
        p.st_steps = rng.choice((1, 64))
    elif name == "l_step":
        p.l_step, p.ab_step = rng.choice(((16, 16), (1, 16), (16, 1)))
    elif name == "front":
        p.extra["front"] = rng.choice(HOSTILE_STRINGS + ("0,0", "1,0", str(2**40), "0," * 5000))
    elif name == "scheme":
        p.extra["scheme"] = rng.choice(("paper", "tpsv", "", "\x1b[2J"))
    else:
        p.extra[rng.choice(("\x1b]0;t\x07", "kernel_size", "t_canny", "a\rb"))] = rng.choice(HOSTILE_STRINGS)
    m.params = p
    return f"params {name}"


def op_canvas(m: Model, rng: random.Random) -> str:
    w, h = rng.choice(((1, 1), (1, 65535), (65535, 1), (16384, 16384), (8192, 8192), (3, 2), (4096, 4096)))
    m.width, m.height = w, h
    return f"canvas {w}x{h}"


def op_labels(m: Model, rng: random.Random) -> str:
    if not m.regions:
        return "labels: no region"
    value = rng.choice((2**63 - 1, -(2**63), 0, -1))
    for reg in m.regions:
        reg.label = value
    return f"labels {value}"


def op_drop_features(m: Model, rng: random.Random) -> str:
    if not m.regions or not len(m.features):
        return "drop: nothing"
    r = _pick_region(m, rng)
    m.features = m.features.subset(m.features.region != r)
    return f"region {r} without features"


MODEL_OPS = (op_nonfinite, op_huge_coords, op_self_intersecting, op_degenerate, op_many_vertices, op_many_regions,
             op_many_holes, op_fold_patch, op_grid_size, op_duplicate_features, op_feature_positions, op_pairs,
             op_params, op_canvas, op_labels, op_drop_features)
#: Rare on purpose: non-finite values only test the encoder's refusal.
MODEL_WEIGHTS = (1, 2, 3, 3, 2, 1, 1, 3, 2, 2, 2, 2, 4, 2, 1, 1)


def mutate_model(case: Case, data: bytes, rng: random.Random) -> None:
    m = codec.decode(data)
    m.encoding = {}  # quantise afresh (as any edited model would be)
    for _ in range(rng.randint(1, 3)):
        op = rng.choices(MODEL_OPS, MODEL_WEIGHTS)[0]
        case.ops.append(op(m, rng))
    case.model = m  # the "encode" target turns it into case.data


MUTATORS = {
    "bytes": mutate_bytes,
    "header": mutate_header,
    "section": mutate_section,
    "quantized": mutate_quantized,
    "model": mutate_model,
}
