"""The .tpsv container: exact round trips, determinism, and a hostile decoder input.

Model builders live here (not in conftest.py) so that this file stands alone.
"""

from __future__ import annotations

import dataclasses
import struct
import time
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tpsv import codec
from tpsv.codec import layout, quant, sections
from tpsv.geometry.crossing import is_simple
from tpsv.errors import TpsvError, TpsvFormatError
from tpsv.model import CURVILINEAR, Features, Model, Params, Patch, Region

# ------------------------------------------------------------------ builders


def grid_ctrl(m: int, n: int, x0: float, y0: float, w: float, h: float) -> np.ndarray:
    """Control vectors of an axis-aligned ``w x h`` rectangle patch."""
    c = np.zeros((m, n, 4, 2))
    s = np.linspace(0.0, 1.0, m)[:, None]
    t = np.linspace(0.0, 1.0, n)[None, :]
    c[..., 0, 0] = x0 + s * w + 0.0 * t
    c[..., 0, 1] = y0 + t * h + 0.0 * s
    c[..., 1, 0] = w / (m - 1)
    c[..., 2, 1] = h / (n - 1)
    c[..., 3, :] = 0.013  # a twist that is not on the 1/16 px grid
    return c


def square(x0: float, y0: float, size: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + size, y0], [x0 + size, y0 + size], [x0, y0 + size]])


def hand_model() -> Model:
    """Three regions: one with a hole, one with a single feature, one with none.

    Pairs: adjacent halves, and one pair across regions 0 and 1.
    """
    regions = [
        Region(
            label=3,
            outline=[square(0, 0, 20), square(5.25, 5.5, 4)[::-1].copy()],
            patch=Patch(grid_ctrl(4, 3, -0.5, -0.5, 21, 21)),
        ),
        Region(label=9, outline=[square(20, 0, 10) + 0.0371], patch=Patch(grid_ctrl(2, 2, 20, 0, 10, 10))),
        Region(label=-4, outline=[np.array([[20.0, 10], [30, 10], [25, 20.5]])],
               patch=Patch(grid_ctrl(3, 5, 20, 10, 10, 10.5))),
    ]
    st_ = np.array([[0.1, 0.2], [0.1003, 0.21], [0.5, 0.5], [0.77777, 0.123456],
                    [0.99, 0.0001], [1.0, 0.0]])
    lab = np.array([[50.2, -3.4, 7.6], [12.0, 100.3, -127.9], [99.9, 0.49, 0.51],
                    [0.0, -128.0, 127.0], [33.3, 5.5, -5.5], [100.0, 140.0, -200.0]], np.float32)
    features = Features(
        region=np.array([0, 0, 0, 0, 0, 1], np.int32),
        st=st_,
        lab=lab,
        kind=np.array([1, 1, 0, 0, 1, 1], np.uint8),
        pair=np.array([1, 0, -1, -1, 5, 4], np.int32),
    )
    params = Params(t_canny=37.5, t_super=12.25, kernel_size=64, overlap=0.25, smoothing=1e-6,
                    st_steps=16, l_step=1, ab_step=1,  # the finest steps, whatever Params() defaults to
                    extra={"seed": 7, "search": True, "source": "chelsea.png", "psnr": 27.125})
    return Model(width=31, height=21, regions=regions, features=features, params=params)


def tiny_model() -> Model:
    """One region, two paired features: the small file the corruption tests use."""
    region = Region(label=0, outline=[square(0, 0, 4)], patch=Patch(grid_ctrl(2, 2, 0, 0, 4, 4)))
    features = Features(
        region=np.zeros(2, np.int32), st=np.array([[0.25, 0.5], [0.75, 0.5]]),
        lab=np.array([[20, 1, 2], [80, -1, -2]], np.float32),
        kind=np.ones(2, np.uint8), pair=np.array([1, 0], np.int32),
    )
    return Model(width=4, height=4, regions=[region], features=features)


def coarse_model() -> Model:
    """``hand_model`` with coarse colour steps and positions at 2 steps per pixel."""
    m = hand_model()
    m.params = dataclasses.replace(m.params, st_steps=2, l_step=6, ab_step=8)
    return m


def half_pixel_model() -> Model:
    """Outline vertices on the half-pixel grid (stored with xy_shift 2)."""
    m = tiny_model()
    m.regions[0].outline = [np.array([[0.0, 0.5], [4.0, 0.5], [3.5, 4.0], [0.0, 3.0]])]
    return m


def no_features_model() -> Model:
    m = hand_model()
    return dataclasses.replace(m, features=Features.empty())


def no_regions_model() -> Model:
    return Model(width=1, height=1, regions=[], features=Features.empty())


def edge_model(n_pairs: int = 2000, seed: int = 0) -> Model:
    """Realistic-ish features: pairs across a wavy edge in raster order, then a
    grid of gradation features, colours varying smoothly with noise."""
    rng = np.random.default_rng(seed)
    w = h = 256
    y = np.linspace(2, h - 2, n_pairs)
    x = 128 + 60 * np.sin(y / 30)
    g = np.stack([np.ones_like(y), -2 * np.cos(y / 30)], 1)
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    xy = np.empty((2 * n_pairs, 2))
    xy[0::2] = np.stack([x, y], 1) - 0.5 * g
    xy[1::2] = np.stack([x, y], 1) + 0.5 * g
    lab = np.empty((2 * n_pairs, 3))
    lab[0::2] = [30, 10, -20]
    lab[1::2] = [70, -5, 30]
    lab += rng.normal(0, 2, lab.shape) + (y.repeat(2) / 10)[:, None]
    gy, gx = np.mgrid[4:h:8, 4:w:8]
    gxy = np.stack([gx.ravel(), gy.ravel()], 1) + 0.5
    glab = np.stack([50 + gx.ravel() / 8, gy.ravel() / 10 - 10, 5 + 0 * gx.ravel()], 1)
    glab = glab + rng.normal(0, 1, glab.shape)
    n = 2 * n_pairs + gxy.shape[0]
    features = Features(
        region=np.zeros(n, np.int32),
        st=np.concatenate([xy, gxy]) / [w, h],
        lab=np.concatenate([lab, glab]).astype(np.float32),
        kind=np.r_[np.ones(2 * n_pairs), np.zeros(gxy.shape[0])].astype(np.uint8),
        pair=np.r_[np.arange(2 * n_pairs) ^ 1, -np.ones(gxy.shape[0])].astype(np.int32),
    )
    region = Region(0, [square(0, 0, 256)], Patch(grid_ctrl(8, 8, 0, 0, w, h)))
    return Model(width=w, height=h, regions=[region], features=features)


# ------------------------------------------------------------------ comparison


def assert_arrays_identical(a: np.ndarray, b: np.ndarray, what: str) -> None:
    assert a.dtype == b.dtype, f"{what}: dtype {a.dtype} != {b.dtype}"
    assert a.shape == b.shape, f"{what}: shape {a.shape} != {b.shape}"
    assert a.tobytes() == b.tobytes(), f"{what}: values differ"


def assert_models_identical(a: Model, b: Model) -> None:
    """Field by field, arrays bit-exact (dtype, shape and bytes)."""
    assert (a.width, a.height) == (b.width, b.height)
    assert a.params == b.params
    assert list(a.params.extra) == list(b.params.extra)
    assert len(a.regions) == len(b.regions)
    for r, (ra, rb) in enumerate(zip(a.regions, b.regions)):
        assert ra.label == rb.label and type(ra.label) is type(rb.label)
        assert len(ra.outline) == len(rb.outline)
        for k, (pa, pb) in enumerate(zip(ra.outline, rb.outline)):
            assert_arrays_identical(pa, pb, f"region {r} polygon {k}")
        assert_arrays_identical(ra.patch.ctrl, rb.patch.ctrl, f"region {r} ctrl")
    for name in ("region", "st", "lab", "kind", "pair"):
        assert_arrays_identical(getattr(a.features, name), getattr(b.features, name), name)
    assert_arrays_identical(a.blur, b.blur, "blur")
    assert (a.blur_map is None) == (b.blur_map is None)
    if a.blur_map is not None:
        assert a.blur_map.cell == b.blur_map.cell
        assert_arrays_identical(a.blur_map.sigma, b.blur_map.sigma, "blur map")


# ------------------------------------------------------------------ file surgery


def reseal(data: bytes | bytearray) -> bytes:
    """Recompute both checksums, so that validation (not a CRC) must catch a patch."""
    out = bytearray(data)
    struct.pack_into("<I", out, 64, zlib.crc32(bytes(out[layout.HEADER_SIZE:])))
    struct.pack_into("<I", out, 68, zlib.crc32(bytes(out[:68])))
    return bytes(out)


def patch_header(data: bytes, **fields) -> bytes:
    """Overwrite named header fields (see layout.Header), then reseal."""
    offsets = {"version": (8, "<H"), "flags": (10, "<H"), "width": (12, "<I"),
               "height": (16, "<I"), "regions": (20, "<I"), "polygons": (24, "<I"),
               "vertices": (28, "<I"), "ctrl_points": (32, "<I"), "features": (36, "<I")}
    for i, name in enumerate(layout.SECTIONS):
        offsets[f"{name}_comp"] = (40 + 8 * i, "<I")
        offsets[f"{name}_raw"] = (44 + 8 * i, "<I")
    out = bytearray(data)
    for name, value in fields.items():
        off, fmt = offsets[name]
        struct.pack_into(fmt, out, off, value)
    return reseal(out)


def raw_sections(data: bytes) -> list[bytes]:
    """The three decompressed sections of a valid file."""
    h = layout.parse_header(data)
    out, start = [], layout.HEADER_SIZE
    for size in h.compressed:
        out.append(zstandard.ZstdDecompressor().decompress(data[start:start + size]))
        start += size
    return out


def assemble(data: bytes, raws: dict[str, bytes] | None = None,
             frames: dict[str, bytes] | None = None, **fields) -> bytes:
    """A copy of ``data`` with some sections replaced (raw, or as zstd frames),
    sizes and checksums made consistent, header fields optionally patched."""
    raws = dict(zip(layout.SECTIONS, raw_sections(data)), **(raws or {}))
    cctx = zstandard.ZstdCompressor(level=3, write_content_size=True)
    comps = {k: cctx.compress(v) for k, v in raws.items()}
    comps.update(frames or {})
    out = bytes(data[:layout.HEADER_SIZE]) + b"".join(comps[k] for k in layout.SECTIONS)
    sizes = {f"{k}_comp": len(comps[k]) for k in layout.SECTIONS}
    sizes.update({f"{k}_raw": len(raws[k]) for k in layout.SECTIONS})
    sizes.update(fields)
    return patch_header(out, **sizes)


def with_quantized(model: Model, **changes) -> bytes:
    """A file whose sections encode ``from_model(model)`` with fields replaced,
    bypassing the encoder's validation (the decoder must catch it)."""
    data = codec.encode(model)
    q = dataclasses.replace(quant.from_model(model), **changes)
    raws = {"params": sections.pack_params(q), "regions": sections.pack_regions(q),
            "features": sections.pack_features(q)}
    counts = dict(regions=len(q.labels), polygons=int(q.vert_counts.size),
                  vertices=int(q.xy.shape[0]), ctrl_points=int(q.ctrl.size // 8),
                  features=int(q.st.shape[0]))
    return assemble(data, raws, **counts)


def reject(data: bytes, match: str | None = None) -> str:
    with pytest.raises(TpsvFormatError) as info:
        codec.decode(data)
    msg = str(info.value)
    assert "\n" not in msg and msg
    if match is not None:
        assert match in msg, msg
    return msg


# ------------------------------------------------------------------ round trips

MODELS = [hand_model, tiny_model, no_features_model, no_regions_model, edge_model, coarse_model, half_pixel_model]


@pytest.mark.parametrize("make", MODELS, ids=lambda f: f.__name__)
def test_round_trip_is_exactly_quantize(make):
    m = make()
    assert_models_identical(codec.decode(codec.encode(m)), codec.quantize(m))


@pytest.mark.parametrize("make", MODELS, ids=lambda f: f.__name__)
def test_quantize_is_idempotent_and_encode_deterministic(make):
    m = make()
    q = codec.quantize(m)
    assert_models_identical(codec.quantize(q), q)
    data = codec.encode(m)
    assert codec.encode(m) == data
    assert codec.encode(q) == data


def test_quantisation_error_bounds():
    m = hand_model()
    q = codec.quantize(m)
    for ra, rq in zip(m.regions, q.regions):
        for pa, pq in zip(ra.outline, rq.outline):
            assert np.abs(pa - pq).max() <= 1 / 16
        assert np.abs(ra.patch.ctrl - rq.patch.ctrl).max() <= 1 / 32
    steps = 2 ** quant.st_bits_for(m.width, m.height) - 1
    assert np.abs(m.features.st - q.features.st).max() <= 0.5 / steps + 1e-12
    lab, lq = m.features.lab.astype(np.float64), q.features.lab.astype(np.float64)
    inside = (np.abs(lab[:, 1:]) <= 127).all(axis=1)
    assert np.abs(lab[:, 0] - lq[:, 0]).max() <= 50 / 255 + 1e-5
    assert np.abs(lab[inside, 1:] - lq[inside, 1:]).max() <= 0.5 + 1e-5
    # Out-of-gamut a, b are clamped to [-128, 127].
    assert lq[-1, 1] == 127 and lq[-1, 2] == -128
    assert q.features.st.min() >= 0 and q.features.st.max() <= 1


def test_st_bits_follow_image_size():
    assert quant.st_bits_for(1, 1) == 8
    assert quant.st_bits_for(512, 300) == 13  # 512 / 8191 ~ 1/16 px
    assert quant.st_bits_for(1920, 1080) == 15
    assert quant.st_bits_for(65535, 1) == 16
    assert quant.st_bits_for(512, 300, 2) == 10  # Params.st_steps
    assert quant.st_bits_for(100, 100, 2) == 8


def test_coarse_steps_quantise_within_half_a_step():
    m = coarse_model()
    q = codec.quantize(m)
    lab, lq = m.features.lab.astype(np.float64), q.features.lab.astype(np.float64)
    inside = (np.abs(lab[:, 1:]) <= 120).all(axis=1) & (lab[:, 0] <= 99)
    assert np.abs(lab[inside, 0] - lq[inside, 0]).max() <= 6 * 50 / 255 + 1e-5
    assert np.abs(lab[inside, 1:] - lq[inside, 1:]).max() <= 4 + 1e-5
    # values are multiples of the steps, clamped into the stored range
    assert np.allclose(np.rint(lq[:, 0] * 255 / 100 / 6), lq[:, 0] * 255 / 100 / 6, atol=1e-4)
    assert np.allclose(lq[:, 1:] / 8, np.rint(lq[:, 1:] / 8))
    assert lq[:, 1:].min() >= -128 and lq[:, 1:].max() <= 127 and lq[:, 0].max() <= 100
    steps = 2 ** quant.st_bits_for(m.width, m.height, 2) - 1
    assert np.abs(m.features.st - q.features.st).max() <= 0.5 / steps + 1e-12
    assert len(codec.encode(m)) < len(codec.encode(hand_model()))


def test_encoder_picks_the_colour_lag():
    def lag_of(m):
        return msgpack.unpackb(raw_sections(codec.encode(m))[2])["lab_lag"]

    m = edge_model(300)  # pairs first: i-2 is the same side of the edge
    pairs = m.features.subset(np.arange(600))
    assert lag_of(dataclasses.replace(m, features=pairs)) == 2
    grid = m.features.subset(np.arange(600, len(m.features)))
    assert lag_of(dataclasses.replace(m, features=grid)) == 1
    for f in (pairs, grid):
        mm = dataclasses.replace(m, features=f)
        assert_models_identical(codec.decode(codec.encode(mm)), codec.quantize(mm))


def test_outline_shift():
    assert sections.xy_shift(np.array([[8, 4], [16, -12]])) == 2
    assert sections.xy_shift(np.array([[8, 16], [64, -8]])) == 3
    assert sections.xy_shift(np.array([[1, 4]])) == 0
    assert sections.xy_shift(np.array([[16, 32], [64, -16]])) == 4
    assert sections.xy_shift(np.zeros((0, 2), np.int32)) == 4
    shifted = msgpack.unpackb(raw_sections(codec.encode(half_pixel_model()))[1])
    assert shifted["xy_shift"] == 3  # half pixels in 1/16 px units
    # a shift that takes a stored coordinate beyond 32 bits is refused
    data = codec.encode(half_pixel_model())
    base = msgpack.unpackb(raw_sections(data)[1])
    big = np.zeros(len(base["xy"]) // 8, np.int64)
    big[0] = 2**28
    xy = b"".join(sections.to_planes(sections.delta_zigzag(v.astype(np.int32), 4, 1), 4) for v in (big, big))
    reject(assemble(data, {"regions": pack({**base, "xy_shift": 4, "xy": xy})}), "beyond the 32-bit range")
    reject(assemble(data, {"regions": pack({**base, "xy_shift": 5})}), "xy_shift")
    m = half_pixel_model()
    m.regions[0].outline[0][1, 0] = 4.0625
    assert msgpack.unpackb(raw_sections(codec.encode(m))[1])["xy_shift"] == 0
    assert_models_identical(codec.decode(codec.encode(m)), codec.quantize(m))


def test_old_versions_count_outlines_in_eighths():
    """Before version 5 outlines are in 1/8 px: xy_shift stops at 3, and the stored values mean twice as much."""
    data = (Path(__file__).parent / "data" / "v2" / "chelsea.tpsv").read_bytes()
    regions = msgpack.unpackb(raw_sections(data)[1])
    reject(assemble(data, {"regions": pack({**regions, "xy_shift": 4})}), "xy_shift = 4 not in 0..3")
    m = codec.decode(data)
    n = len(regions["xy"]) // 8
    xs = sections.undelta_zigzag(sections.from_planes(regions["xy"][:4 * n], n, 4), 4, sections.GEOMETRY_LAG)
    assert m.regions[0].outline[0][0, 0] == (int(xs[0]) << regions["xy_shift"]) / 8


def test_extra_order_does_not_change_bytes():
    a, b = hand_model(), hand_model()
    b.params.extra = dict(reversed(list(a.params.extra.items())))
    assert codec.encode(a) == codec.encode(b)
    assert list(codec.decode(codec.encode(b)).params.extra) == sorted(a.params.extra)


def test_numpy_scalars_in_params_become_plain():
    m = tiny_model()
    m.params = Params(t_canny=np.float32(3.5), kernel_size=np.int64(32),
                      extra={"n": np.int16(-3), "x": np.float64(0.5), "b": np.bool_(True)})
    p = codec.decode(codec.encode(m)).params
    assert p == codec.quantize(m).params
    assert type(p.t_canny) is float and type(p.kernel_size) is int
    assert [type(p.extra[k]) for k in ("b", "n", "x")] == [bool, int, float]


def test_params_table_covers_every_params_field():
    fields = {f.name for f in dataclasses.fields(Params)} - {"extra"}
    assert fields == set(quant.PARAM_FIELDS)


def test_section_sizes_break_down_the_file():
    data = codec.encode(hand_model())
    sizes = codec.section_sizes(data)
    assert list(sizes) == ["header", "params", "regions", "features"]
    assert sizes["header"] == codec.HEADER_SIZE == 72
    assert sum(sizes.values()) == len(data)


def test_file_starts_with_magic_and_version():
    data = codec.encode(tiny_model())
    assert data[:8] == codec.MAGIC == b"TPSV\r\n\x1a\n"
    assert struct.unpack_from("<H", data, 8)[0] == codec.VERSION == 9


def test_compact_features():
    """Size guard (not speed): realistic features cost under 5 bytes each."""
    m = edge_model()
    data = codec.encode(m)
    per_feature = codec.section_sizes(data)["features"] / len(m.features)
    assert per_feature < 5.0, per_feature


# ------------------------------------------------------------------ property tests


@st.composite
def models(draw) -> Model:
    """Valid models: small, but every structure (holes, empty regions, pairs
    across regions, out-of-range S, T and Lab to be clamped) may occur."""
    width = draw(st.integers(1, 400))
    height = draw(st.integers(1, 400))
    coord = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)
    regions = []
    n_regions = draw(st.integers(0, 4))
    for _ in range(n_regions):
        polys = []
        # holes hold other regions: at most one polygon per region of the model
        for _ in range(draw(st.integers(1, min(3, n_regions)))):
            k = draw(st.integers(3, 7))
            polys.append(np.array(draw(st.lists(coord, min_size=2 * k, max_size=2 * k))).reshape(k, 2))
        m, n = draw(st.integers(2, 5)), draw(st.integers(2, 5))
        ctrl = np.array(draw(st.lists(coord, min_size=m * n * 8, max_size=m * n * 8))).reshape(m, n, 4, 2)
        label = draw(st.integers(-(2**63), 2**63 - 1))
        regions.append(Region(label=label, outline=polys, patch=Patch(ctrl)))
    n_feat = draw(st.integers(0, 40)) if regions else 0
    region = np.sort(np.array(draw(st.lists(st.integers(0, max(len(regions) - 1, 0)),
                                            min_size=n_feat, max_size=n_feat)), np.int32))
    unit = st.floats(-0.1, 1.1, allow_nan=False)
    st_ = np.array(draw(st.lists(unit, min_size=2 * n_feat, max_size=2 * n_feat))).reshape(n_feat, 2)
    lab = np.array(draw(st.lists(st.floats(-300, 300, allow_nan=False, width=32),
                                 min_size=3 * n_feat, max_size=3 * n_feat)), np.float32).reshape(n_feat, 3)
    order = draw(st.permutations(range(n_feat))) if n_feat else []
    n_pairs = draw(st.integers(0, n_feat // 2))
    pair = np.full(n_feat, -1, np.int32)
    for i in range(n_pairs):
        a, b = order[2 * i], order[2 * i + 1]
        pair[a], pair[b] = b, a
    kind = np.where(pair >= 0, CURVILINEAR,
                    np.array(draw(st.lists(st.integers(0, 1), min_size=n_feat, max_size=n_feat)),
                             dtype=np.int64).reshape(n_feat)).astype(np.uint8)
    extra_value = st.one_of(st.booleans(), st.integers(-(2**63), 2**63 - 1),
                            st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=20))
    extra = draw(st.dictionaries(st.text(min_size=1, max_size=10), extra_value, max_size=4))
    params = Params(
        t_canny=draw(st.floats(0, 1e3)), t_super=draw(st.floats(0, 1e3)),
        kernel_size=draw(st.sampled_from(layout.SUPPORTED_KERNEL_SIZES)), overlap=draw(st.floats(1e-6, 0.5)),
        smoothing=draw(st.floats(0, 1)), st_steps=draw(st.integers(1, 64)),
        l_step=draw(st.integers(1, 16)), ab_step=draw(st.integers(1, 16)), extra=extra,
    )
    features = Features(region=region, st=st_, lab=lab, kind=kind, pair=pair)
    return Model(width=width, height=height, regions=regions, features=features, params=params)


PROPERTY = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@PROPERTY
@given(models())
def test_property_round_trip(m):
    data = codec.encode(m)
    q = codec.quantize(m)
    assert_models_identical(codec.decode(data), q)
    assert_models_identical(codec.quantize(q), q)
    assert codec.encode(q) == data
    assert sum(codec.section_sizes(data).values()) == len(data)


@PROPERTY
@given(st.binary(max_size=200))
def test_property_garbage_is_rejected(blob):
    reject(blob)
    reject(codec.MAGIC + blob)
    reject(codec.MAGIC + b"\x01\x00" + blob)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_property_mutated_sections_fail_cleanly(data):
    """Mutate the *decompressed* sections and reseal: the parsers and validators
    (not the checksum) must answer, with a valid model or TpsvFormatError."""
    base = codec.encode(hand_model())
    raws = dict(zip(layout.SECTIONS, raw_sections(base)))
    name = data.draw(st.sampled_from(layout.SECTIONS))
    raw = bytearray(raws[name])
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(raw) - 1))
        raw[pos] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        cut = data.draw(st.integers(0, len(raw)))
        raw = raw[:cut]
    try:
        model = codec.decode(assemble(base, {name: bytes(raw)}))
    except TpsvFormatError:
        return
    # Whatever decodes is a valid model: it encodes again.
    assert isinstance(model, Model)
    assert isinstance(codec.decode(codec.encode(model)), Model)


# ------------------------------------------------------------------ corruption


def test_truncated_at_every_length():
    data = codec.encode(tiny_model())
    for n in range(len(data)):
        msg = reject(data[:n])
        if 0 < n < len(data):
            assert "truncated" in msg, (n, msg)


def test_every_flipped_byte_is_rejected():
    data = codec.encode(tiny_model())
    for i in range(len(data)):
        for mask in (0x01, 0x80, 0xFF):
            bad = bytearray(data)
            bad[i] ^= mask
            reject(bytes(bad))


def test_flips_in_a_larger_file_sampled():
    data = codec.encode(hand_model())
    rng = np.random.default_rng(1234)
    for i in rng.choice(len(data), size=min(len(data), 200), replace=False):
        bad = bytearray(data)
        bad[i] ^= 1 << int(rng.integers(8))
        reject(bytes(bad))


def test_trailing_data_rejected():
    reject(codec.encode(tiny_model()) + b"\x00", "trailing data")


def test_empty_and_wrong_magic():
    reject(b"", "empty file")
    reject(b"\x89PNG\r\n\x1a\n" + bytes(100), "bad magic")
    reject(b"{}", "bad magic")
    data = codec.encode(tiny_model())
    reject(b"X" + data[1:], "bad magic")


def test_text_mode_mangling_is_named():
    data = codec.encode(tiny_model())
    reject(data.replace(b"\r\n", b"\n", 1), "text mode")
    reject(data[:4] + data[4:8].replace(b"\n", b"\r\n") + data[8:], "text mode")


@pytest.mark.parametrize("version", [10, 11, 65535])
def test_future_version_rejected(version):
    data = patch_header(codec.encode(tiny_model()), version=version)
    reject(data, f"unsupported format version {version} (this tpsv reads up to 9)")
    # Even a short file of a future version gets the version message.
    reject(data[:12], f"unsupported format version {version}")


def test_version_zero_and_flags_rejected():
    data = codec.encode(tiny_model())
    reject(patch_header(data, version=0), "unsupported format version 0")
    reject(patch_header(data, flags=16), "unsupported flags 0x0010")
    reject(patch_header(patch_header(data, flags=8), version=6), "unsupported flags 0x0008")
    reject(patch_header(patch_header(data, flags=4), version=5), "unsupported flags 0x0004")


def test_header_checksum():
    data = bytearray(codec.encode(tiny_model()))
    data[12] ^= 1
    reject(bytes(data), "header checksum")


def test_payload_checksum():
    data = bytearray(codec.encode(tiny_model()))
    data[-1] ^= 1
    reject(bytes(data), "checksum mismatch")


@pytest.mark.parametrize("fields, match", [
    ({"width": 0}, "width 0"),
    ({"height": 70000}, "height 70000"),
    ({"width": 65535, "height": 65535}, "exceeds 67108864 pixels"),
    ({"width": 8193, "height": 8192}, "exceeds 67108864 pixels"),
    ({"regions": 4097}, "4097 regions exceed"),
    ({"polygons": 8193}, "polygons exceed"),
    ({"vertices": 2**19 + 1}, "vertices exceed"),
    ({"ctrl_points": 2**18 + 1}, "control points exceed"),
    ({"features": 2**20 + 1}, "features exceed"),
    ({"features": 2**32 - 1}, "features exceed"),
    ({"regions": 2}, "polygons for 2 regions"),
    ({"vertices": 2}, "2 vertices for 1 polygons"),
    ({"vertices": 5}, "4 vertices, header says 5"),
    ({"ctrl_points": 3}, "control points for 1 regions"),
    ({"features": 3}, "features"),
    ({"regions": 0, "polygons": 0, "vertices": 0, "ctrl_points": 0}, "2 features but no regions"),
    ({"features_raw": 2**31}, "exceeds the bound"),
    ({"params_raw": 2**20 + 1}, "exceeds the bound"),
    ({"features_comp": 0}, "empty"),
    ({"features_comp": 2**31}, "truncated file"),
])
def test_header_counts_validated_not_checksummed(fields, match):
    reject(patch_header(codec.encode(tiny_model()), **fields), match)


def test_zstd_bomb_rejected_quickly():
    data = codec.encode(tiny_model())
    bomb = zstandard.ZstdCompressor(level=1, write_content_size=True).compress(bytes(2**26))
    assert len(bomb) < 10_000
    t0 = time.perf_counter()
    # Declared as huge: over the bound the header counts allow.
    reject(assemble(data, frames={"features": bomb}, features_raw=2**26), "exceeds the bound")
    # Declared small, but the frame says huge: refused before inflating.
    reject(assemble(data, frames={"features": bomb}), "zstd frame holds 67108864 bytes")
    # Counts at their limits: the bound, not a ratio, caps what is inflated
    # (12 MiB here), and the zeros are not one msgpack map.
    raw = layout.raw_size_bounds(layout.Header(1, 0, 4, 4, 1, 1, 4, 4, codec.MAX_FEATURES, (1, 1, 1), (0, 0, 0)))[2]
    flat = zstandard.ZstdCompressor(level=1, write_content_size=True).compress(bytes(raw))
    huge = assemble(data, frames={"features": flat}, features=codec.MAX_FEATURES, features_raw=raw)
    reject(huge, "section features: bad msgpack")
    assert time.perf_counter() - t0 < 2.0


def test_zstd_frame_problems():
    data = codec.encode(tiny_model())
    raw = raw_sections(data)[2]
    stream = zstandard.ZstdCompressor().compressobj()
    no_size = stream.compress(raw) + stream.flush()
    reject(assemble(data, frames={"features": no_size}, features_raw=len(raw)), "does not state its size")
    frame = zstandard.ZstdCompressor(write_content_size=True).compress(raw)
    reject(assemble(data, frames={"features": frame + frame}, features_raw=len(raw)), "bad zstd data")
    reject(assemble(data, frames={"features": frame[:-3]}, features_raw=len(raw)), "bad zstd data")
    skippable = b"\x50\x2a\x4d\x18" + struct.pack("<I", 4) + b"abcd"
    reject(assemble(data, frames={"features": skippable}, features_raw=len(raw)), "not a zstd frame")
    reject(assemble(data, frames={"features": b"\x28\xb5"}, features_raw=len(raw)), "not a zstd frame")


# ------------------------------------------------------------------ section contents


def pack(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def test_bad_msgpack_rejected():
    data = codec.encode(tiny_model())
    reject(assemble(data, {"params": b"\xc1"}), "bad msgpack")
    reject(assemble(data, {"params": b""}), "bad msgpack")
    reject(assemble(data, {"params": pack({}) + b"\x00"}), "bad msgpack")
    reject(assemble(data, {"params": b"\x91" * 5000 + b"\xc0"}), "section params")
    reject(assemble(data, {"params": pack([1, 2])}), "expected a map")
    reject(assemble(data, {"params": b"\xd6\xff\x00\x00\x00\x00"}), "section params")  # ext
    dup = b"\x82" + pack("t_canny") + pack(1.0) + pack("t_canny") + pack(2.0)
    reject(assemble(data, {"params": dup}), "duplicate map key")
    reject(assemble(data, {"params": pack({1: 2})}), "section params")


def test_params_validated():
    data = codec.encode(tiny_model())
    base = msgpack.unpackb(raw_sections(data)[0])
    cases = [
        ({"t_canny": float("nan")}, "not finite"),
        ({"t_canny": 40}, "must be float"),
        ({"kernel_size": 64.0}, "must be int"),
        ({"kernel_size": True}, "must be int"),
        ({"kernel_size": 0}, "kernel_size = 0"),
        ({"overlap": 0.0}, "overlap = 0.0 not in (0.0, 0.5]"),
        ({"smoothing": -1.0}, "smoothing"),
        ({"l_step": 0}, "l_step = 0"),
        ({"ab_step": 17}, "ab_step = 17"),
        ({"st_steps": 2.0}, "st_steps must be int"),
        ({"extra": {"x": [1]}}, "unsupported type list"),
        ({"extra": {"x": float("inf")}}, "not finite"),
        ({"extra": {"": 1}}, "extra key"),
        ({"extra": {"x": 2**64 - 1}}, "64-bit"),
        ({"extra": [1]}, "extra is not a map"),
        ({"extra": {b"k": 1}}, "not a str"),
        ({"unknown": 1}, "unknown key 'unknown'"),
    ]
    for change, match in cases:
        obj = {**base, **change}
        reject(assemble(data, {"params": pack(obj)}), match)
    obj = dict(base)
    del obj["overlap"]
    reject(assemble(data, {"params": pack(obj)}), "missing key 'overlap'")


def test_region_section_validated():
    data = codec.encode(tiny_model())
    base = msgpack.unpackb(raw_sections(data)[1])
    cases = [
        ({"label": ["a"]}, "label"),
        ({"label": [1, 2]}, "array of 1 ints"),
        ({"label": [2**64 - 1]}, "64-bit integer"),
        ({"grid": b"\x01\x01\x01"}, "grid has 3 bytes"),
        ({"grid": b"\x02\x01"}, "grids hold 6 control points, header says 4"),
        ({"polys": 5}, "polys is not a bin"),
        ({"polys": struct.pack("<I", 2)}, "2 polygons, header says 1"),
        ({"verts": bytes([5, 0, 0, 0])}, "unknown key 'verts'"),
        ({"chains": 5}, "chains = 5 not in 0..4"),
        ({"chains": 2, "chain_verts": bytes([4, 1, 0, 0, 0, 0, 0, 0])}, "chain 1 has 1 vertices (at least 2)"),
        ({"chain_verts": bytes([9, 0, 0, 0])}, "chains hold 9 vertices, more than 5"),
        ({"refs": bytes([0, 0, 0, 0]), "ref": b""}, "polygon 0 refers to no chain"),
        ({"refs": bytes([5, 0, 0, 0])}, "5 chain references for 4 vertices"),
        ({"ref": bytes([3, 0, 0, 0])}, "reference 0 to chain 1, but there are 1"),
        ({"xy": b"\x00" * 7}, "xy has 7 bytes"),
        ({"ctrl": b""}, "ctrl has 0 bytes"),
        ({"xy_shift": 5}, "xy_shift = 5 not in 0..4"),
        ({"xy_shift": 1.0}, "xy_shift is not an int"),
    ]
    for change, match in cases:
        reject(assemble(data, {"regions": pack({**base, **change})}), match)


def test_grid_and_polygon_rules():
    m = tiny_model()
    q = quant.from_model(m)
    # Two polygons of 2 and 4 vertices: the header totals pass, the rule does not.
    reject(with_quantized(m, poly_counts=np.array([2]), vert_counts=np.array([2, 4]),
                          xy=np.concatenate([q.xy[:2], q.xy])), "polygon 0 has 2 vertices (at least 3)")
    data = with_quantized(m, grid=np.array([[1, 4]]))
    reject(data, "control grid 1x4")


def test_feature_section_validated():
    m = tiny_model()
    reject(with_quantized(m, pair=np.array([1, -1])), "pairs must be symmetric")
    reject(with_quantized(m, kind=np.array([2, 2], np.uint8)), "kind 2")
    reject(with_quantized(m, kind=np.array([0, 1], np.uint8)), "paired but not curvilinear")
    reject(with_quantized(m, st=np.array([[0, 0], [9000, 0]])), "S or T beyond")
    reject(with_quantized(m, st_bits=17), "st_bits 17")
    reject(with_quantized(m, feature_counts=np.array([1])), "sum to 1, expected 2")
    base = msgpack.unpackb(raw_sections(codec.encode(m))[2])
    for change, match in [({"st_bits": 8.0}, "st_bits is not an int"),
                          ({"pair": b"\x00" * 7}, "pair has 7 bytes"),
                          ({"lab": "x"}, "lab is not a bin"),
                          ({"lab_lag": 0}, "lab_lag = 0 not in 1..8"),
                          ({"lab_lag": True}, "lab_lag is not an int")]:
        reject(assemble(codec.encode(m), {"features": pack({**base, **change})}), match)
    # colours beyond the range their steps allow
    c = coarse_model()
    q = quant.from_model(c)
    bad = q.lab.copy()
    bad[0, 0] = 255 // 6 + 1
    reject(with_quantized(c, lab=bad), "out of range for l_step 6")
    bad = q.lab.copy()
    bad[1, 2] = 128 - 128 // 8 - 1
    reject(with_quantized(c, lab=bad), "ab_step 8")
    # A pair index beyond the feature count, written directly as its code.
    code = sections.zigzag64(np.array([5, -1]))
    raw = pack({**base, "pair": sections.to_planes(code, 4)})
    reject(assemble(codec.encode(m), {"features": raw}), "not in [-1, 2)")


def test_asymmetric_pair_refused_by_encoder():
    m = hand_model()
    m.features.pair[0] = 4
    with pytest.raises(ValueError, match="symmetric"):
        codec.encode(m)
    m = hand_model()
    m.features.pair[2] = 2
    with pytest.raises(ValueError, match="paired with itself"):
        codec.encode(m)


@pytest.mark.parametrize("mutate, match", [
    (lambda m: setattr(m.features, "region", m.features.region[::-1].copy()), "not sorted"),
    (lambda m: m.features.st.__setitem__((0, 0), np.nan), "non-finite"),
    (lambda m: setattr(m.regions[0].patch, "ctrl", np.zeros((2, 2, 3, 2))), "expected (M, N, 4, 2)"),
    (lambda m: setattr(m.regions[0].patch, "ctrl", np.zeros((1, 2, 4, 2))), "control grid 1x2"),
    (lambda m: m.regions[0].outline.__setitem__(0, np.full((4, 2), 3e8)), "32-bit"),
    (lambda m: setattr(m.regions[1], "outline", []), "no outline polygon"),
    (lambda m: setattr(m, "width", 0), "width 0"),
    (lambda m: setattr(m, "width", 2.5), "width must be an int"),
    (lambda m: setattr(m.params, "overlap", 0.75), "overlap"),
    (lambda m: setattr(m.params, "kernel_size", 1.5), "kernel_size must be an integer"),
    (lambda m: m.params.extra.__setitem__("bad", [1, 2]), "only bool, int, float, str"),
    (lambda m: setattr(m.features, "region", np.full(6, 7, np.int32)), "out of range"),
    (lambda m: setattr(m.features, "kind", np.zeros(5, np.uint8)), "features.kind has shape"),
])
def test_encoder_refuses_invalid_models(mutate, match):
    m = hand_model()
    mutate(m)
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)")):
        codec.encode(m)


@pytest.mark.parametrize("extra, match", [
    ({"s": "x" * 65537}, "longer than 65536"),
    ({"": 1}, "1..256 characters"),
    ({"k" * 257: 1}, "1..256 characters"),
    ({f"k{i}": i for i in range(257)}, "257 extra items"),
    ({"big": 2**64}, "64-bit range"),
    ({"nan": float("nan")}, "not finite"),
])
def test_encoder_refuses_bad_extra_with_value_error(extra, match):
    """Fuzz finding: these raised TpsvFormatError from encode, which documents ValueError."""
    m = hand_model()
    m.params.extra = extra
    with pytest.raises(ValueError, match=match) as info:
        codec.encode(m)
    assert not isinstance(info.value, TpsvError)


# ------------------------------------------------------------------ transforms


def test_delta_zigzag_round_trips_extremes():
    for width in (1, 2, 4):
        bits = 8 * width
        lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
        x = np.array([0, hi, lo, -1, 1, hi, hi, lo, 0, 5], np.int64)
        for lag in (1, 2, 3):
            codes = sections.delta_zigzag(x, width, lag)
            back = sections.undelta_zigzag(codes, width, lag).astype(np.int64)
            assert np.array_equal(back, x)
    assert list(sections.delta_zigzag(np.array([0, 1, 0, -1]), 2, 1)) == [0, 2, 1, 1]


def test_planes_round_trip():
    x = np.array([0, 1, 2**32 - 1, 0x01020304], np.uint32)
    buf = sections.to_planes(x, 4)
    assert buf[:4] == bytes([0, 1, 0xFF, 0x04])  # lowest bytes first
    assert np.array_equal(sections.from_planes(buf, 4, 4), x)


# ------------------------------------------------------------------ files


def test_save_and_load(tmp_path):
    m = hand_model()
    path = tmp_path / "m.tpsv"
    n = codec.save(m, path)
    assert n == path.stat().st_size
    assert_models_identical(codec.load(path), codec.quantize(m))
    assert_models_identical(codec.load(str(path)), codec.quantize(m))


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(TpsvError, match="missing.tpsv: cannot read"):
        codec.load(tmp_path / "missing.tpsv")
    bad = tmp_path / "bad.tpsv"
    bad.write_bytes(b"hello")
    with pytest.raises(TpsvFormatError, match="bad.tpsv: bad magic"):
        codec.load(bad)


def test_save_error_leaves_nothing(tmp_path):
    with pytest.raises(TpsvError, match="cannot write"):
        codec.save(tiny_model(), tmp_path / "no" / "such" / "dir.tpsv")
    good = tmp_path / "good.tpsv"
    codec.save(tiny_model(), good)
    before = good.read_bytes()
    broken = tiny_model()
    broken.features.pair[0] = -1
    with pytest.raises(ValueError):
        codec.save(broken, good)
    assert good.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.tpsv"]


def test_limits_are_exported():
    assert codec.MAX_FILE_BYTES == 256 * 2**20
    assert codec.MAX_FEATURES == 2**20 and codec.MAX_REGIONS == 4096
    assert (codec.MIN_GRID, codec.MAX_GRID) == (2, 256)
    assert codec.MAX_PIXELS == 2**26 and codec.MAX_SIDE == 65535
    assert codec.SUPPORTED_KERNEL_SIZES == (8, 16, 32, 64, 128)


# ------------------------------------------------------------------ re-encoding (issue 14)

CORPUS = sorted((Path(__file__).parent / "fuzzing" / "corpus").glob("*.tpsv"))
VERSION_1 = sorted((Path(__file__).parent / "data" / "v1").glob("*.tpsv"))
OLD_VERSIONS = VERSION_1 + [p for v in ("v2", "v3", "v4", "v5", "v6", "v7", "v8")
                             for p in sorted((Path(__file__).parent / "data" / v).glob("*.tpsv"))]


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.stem)
def test_reencoding_a_sample_file_gives_its_bytes(path):
    data = path.read_bytes()
    assert struct.unpack_from("<H", data, 8)[0] == codec.VERSION
    assert codec.encode(codec.decode(data)) == data


@pytest.mark.parametrize("path", OLD_VERSIONS, ids=lambda p: f"{p.parent.name}-{p.stem}")
def test_old_version_files_are_read_and_written_back_as_the_current_version(path):
    """docs/FORMAT.md, Versions: a version-1 to -8 file decodes as it always did (an outline
    crossing itself mended; no blur map before version 7; the detail image in one piece before
    version 8); encoding writes the current version, same model, its detail images as bare AV1
    bitstreams (smaller by their AVIF boxes)."""
    data = path.read_bytes()
    version = int(path.parent.name[1:])
    assert struct.unpack_from("<H", data, 8)[0] == version
    m = codec.decode(data)
    assert (m.detail is None) == (version < 3 or struct.unpack_from("<H", data, 10)[0] == 0)
    assert not any(r.transparent for r in m.regions)
    assert (m.blur_map is None) == (version < 7)
    assert m.detail is None or len(m.detail.payload) == (3 if version >= 8 else 1)
    again = codec.encode(m)
    assert struct.unpack_from("<H", again, 8)[0] == codec.VERSION
    # the same flags (detail or not), and from version 3 on the same sections but the regions
    # (whose outlines are now counted in 1/16 px: xy_shift one more; a crossing mended) and the
    # detail (AV1 bitstreams without their AVIF boxes: 269 bytes a file, some 150 after zstd)
    assert struct.unpack_from("<H", again, 10)[0] == struct.unpack_from("<H", data, 10)[0]
    if version >= 3:
        sizes, before = codec.section_sizes(again), codec.section_sizes(data)
        kept = ("regions", "detail") if version < 7 else ("detail",)
        assert {k: v for k, v in sizes.items() if k not in kept} == {k: v for k, v in before.items() if k not in kept}
        if m.detail is not None:
            assert 100 <= before["detail"] - sizes["detail"] <= 300 * len(m.detail.payload)
    assert_models_identical(codec.decode(again), m)
    # shared borders are stored once: never larger than the version-1 file's outlines
    assert codec.section_sizes(again)["regions"] <= codec.section_sizes(data)["regions"] + 16


@pytest.mark.parametrize("make", MODELS, ids=lambda f: f.__name__)
def test_reencoding_a_decoded_model_gives_its_bytes(make):
    data = codec.encode(make())
    assert codec.encode(codec.decode(data)) == data
    assert codec.encode(codec.quantize(codec.decode(data))) == data


@pytest.mark.parametrize("bits", [8, 11, 16])
def test_foreign_st_bits_are_kept(bits):
    """A file whose st_bits is not the encoder's choice (13 here) is not re-quantised."""
    m = edge_model(n_pairs=50)
    assert quant.from_model(m).st_bits != bits
    q = quant.from_model(m)
    top = 2**bits - 1
    data = with_quantized(m, st_bits=bits, st=np.rint(q.st * top / (2**q.st_bits - 1)).astype(np.int64))
    decoded = codec.decode(data)
    assert decoded.encoding["st_bits"] == bits
    again = codec.encode(decoded)
    assert again == as_encoder_compresses(data)
    assert_models_identical(codec.decode(again), decoded)


def as_encoder_compresses(data: bytes) -> bytes:
    """``data`` with its sections recompressed as the encoder does (the tests' files use level 3)."""
    from tpsv.codec.container import ZSTD_LEVEL
    cctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True, write_checksum=False,
                                    write_dict_id=False)
    return assemble(data, frames={k: cctx.compress(v) for k, v in zip(layout.SECTIONS, raw_sections(data))})


def test_kept_st_bits_follow_size_and_precision():
    """A resized model, or one given another st_steps, is quantised afresh."""
    data = with_quantized(tiny_model(), st_bits=16)
    m = codec.decode(data)
    assert quant.from_model(m).st_bits == 16
    m.width = 2000
    assert quant.from_model(m).st_bits == quant.st_bits_for(2000, m.height, m.params.st_steps)
    m = codec.decode(data)
    m.params.st_steps = 64
    assert quant.from_model(m).st_bits == quant.st_bits_for(m.width, m.height, 64)
    m = codec.decode(data)
    m.encoding["st_bits"] = 17
    with pytest.raises(ValueError, match="st_bits"):
        codec.encode(m)


def test_decoded_models_carry_their_encoding():
    m = tiny_model()
    d = codec.decode(codec.encode(m))
    assert not m.encoding
    assert d.encoding == {"st_bits": quant.from_model(m).st_bits, "st_bits_for": (4, 4, m.params.st_steps)}
    assert "encoding" not in repr(d)
    assert codec.quantize(d).encoding == d.encoding


# ------------------------------------------------------------------ budgets (issue 14)


def test_kernel_size_must_be_supported():
    for k in codec.SUPPORTED_KERNEL_SIZES:
        m = tiny_model()
        m.params = Params(kernel_size=k)
        assert codec.decode(codec.encode(m)).params.kernel_size == k
    for k in (1, 3, 48, 129, 4096):
        m = tiny_model()
        m.params = Params(kernel_size=k)
        with pytest.raises(ValueError, match="kernel_size"):
            codec.encode(m)
        q = quant.from_model(tiny_model())
        reject(with_quantized(tiny_model(), params={**q.params, "kernel_size": k}), "kernel_size")


def test_polygon_vertex_limit():
    n = codec.MAX_POLYGON_VERTICES + 1
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    circle = np.stack([8 + 6 * np.cos(t), 8 + 6 * np.sin(t)], 1)
    m = Model(16, 16, [Region(0, [circle], Patch(grid_ctrl(2, 2, 0, 0, 16, 16)))], Features.empty())
    with pytest.raises(ValueError, match="at most 262144"):
        codec.encode(m)
    q = quant.from_model(m)
    small = no_features_model()
    fields = ("width", "height", "labels", "grid", "poly_counts", "vert_counts", "xy", "ctrl", "feature_counts")
    reject(with_quantized(small, **{f: getattr(q, f) for f in fields}), "at most 262144")


def test_smooth_grids_are_not_mistaken_for_bombs():
    """A 256x256 affine grid compresses thousands of times; version 1's ratio rule refused it."""
    region = Region(0, [square(0, 0, 64)], Patch(grid_ctrl(256, 256, 0, 0, 64, 64)))
    m = Model(64, 64, [region], Features.empty())
    data = codec.encode(m)
    sizes = codec.section_sizes(data)
    assert layout.parse_header(data).raw[1] > 1024 * sizes["regions"]
    assert_models_identical(codec.decode(data), codec.quantize(m))


def test_largest_inflation_is_bounded():
    h = layout.Header(1, 0, 1, 1, codec.MAX_REGIONS, codec.MAX_POLYGONS, codec.MAX_VERTICES,
                      codec.MAX_CTRL_POINTS, codec.MAX_FEATURES, (1, 1, 1), (0, 0, 0))
    assert sum(layout.raw_size_bounds(h)) < 26 * 2**20


def test_canvas_limit_admits_every_photo_tpsv_reads():
    from tpsv import image
    assert image.MAX_PIXELS <= codec.MAX_PIXELS
    assert getattr(image, "MAX_SIDE", codec.MAX_SIDE) <= codec.MAX_SIDE


def test_models_beyond_the_limits_are_the_users_error():
    """Too large or an unsupported kernel_size: FormatLimitError, a ValueError the CLI shows as one line."""
    m = no_features_model()
    m.width, m.height = 8193, 8192
    with pytest.raises(codec.FormatLimitError, match="8193x8192 exceeds 67108864 pixels") as info:
        codec.encode(m)
    assert isinstance(info.value, TpsvError) and isinstance(info.value, ValueError)
    m = hand_model()
    m.params.kernel_size = 48
    with pytest.raises(codec.FormatLimitError, match="kernel_size = 48 not one of 8, 16, 32, 64, 128"):
        codec.quantize(m)
    n = codec.MAX_FEATURES + 1
    f = Features(np.zeros(n, np.int32), np.full((n, 2), 0.5), np.zeros((n, 3), np.float32),
                 np.zeros(n, np.uint8), np.full(n, -1, np.int32))
    m = Model(4, 4, tiny_model().regions, f)
    with pytest.raises(codec.FormatLimitError, match="1048577 features exceed the limit 1048576"):
        codec.encode(m)
    m = Model(4, 4, tiny_model().regions * (codec.MAX_REGIONS + 1), Features.empty())
    with pytest.raises(codec.FormatLimitError, match="4097 regions exceed the limit 4096"):
        codec.encode(m)  # (before thousands of outlines are checked one by one)
    # other broken models stay plain ValueErrors (a program's mistake, not the user's)
    m = hand_model()
    m.features.st[0, 0] = np.nan
    with pytest.raises(ValueError) as info:
        codec.encode(m)
    assert not isinstance(info.value, TpsvError)


def test_more_holes_than_regions_is_refused():
    """Each hole holds another region: 5000 holes in a 5-region file is hostile (deform paid per polygon)."""
    m = hand_model()
    m.regions[0].outline = list(m.regions[0].outline) + [square(1.0 + 0.01 * i, 1.0, 0.5) for i in range(len(m.regions))]
    with pytest.raises(ValueError, match="at most one per region"):
        codec.encode(m)


# ------------------------------------------------------------------ edge widths (issue 10)


def blurred_hand_model() -> Model:
    m = hand_model()
    m.blur = np.array([[0, 2, 1.3], [0, 1, 0.52], [1, 2, 0.01]])
    return m


def test_edge_widths_round_trip_on_the_sixteenth_pixel():
    m = blurred_hand_model()
    q = codec.quantize(m)
    # sorted by pair, on the 1/16 px grid, zero widths (0.01 px rounds to 0) dropped
    assert q.blur.tolist() == [[0.0, 1.0, 0.5], [0.0, 2.0, 1.3125]]
    data = codec.encode(m)
    assert_models_identical(codec.decode(data), q)
    assert codec.encode(codec.decode(data)) == data


@pytest.mark.parametrize("blur, match", [
    ([[1, 1, 1.0]], "a < b"),
    ([[0, 3, 1.0]], "a < b < 3"),
    ([[0, 1, -1.0]], "sigma"),
    ([[0, 1, 16.0]], "sigma"),
    ([[0, 1, np.nan]], "non-finite"),
    ([[0, 1, 1.0], [0, 1, 2.0]], "listed twice"),
    ([[0.5, 1, 1.0]], "integers"),
])
def test_bad_edge_widths_are_refused_by_the_encoder(blur, match):
    m = hand_model()
    m.blur = np.array(blur, np.float64)
    with pytest.raises(ValueError, match=match):
        codec.encode(m)


def test_hostile_edge_widths_are_refused_in_one_line():
    data = codec.encode(blurred_hand_model())
    base = msgpack.unpackb(raw_sections(data)[1])

    def blur_bin(rows):
        rows = np.array(rows, np.int64).reshape(-1, 3)
        return (sections.to_planes(rows[:, 0], 4) + sections.to_planes(rows[:, 1], 4)
                + rows[:, 2].astype(np.uint8).tobytes())

    cases = [
        ({"blurs": 3}, "blur has 18 bytes, expected 27"),
        ({"blurs": 10**6}, "not in 0.."),
        ({"blur": blur_bin([[0, 2, 21], [0, 1, 8]])}, "not in increasing order"),
        ({"blur": blur_bin([[1, 1, 8], [1, 2, 21]])}, "is not a < b < 3"),
        ({"blur": blur_bin([[0, 1, 0], [0, 2, 21]])}, "width 0 not in 1..255"),
        ({"blur": blur_bin([[0, 1, 8], [0, 7, 21]])}, "is not a < b < 3"),
    ]
    for change, match in cases:
        reject(assemble(data, {"regions": pack({**base, **change})}), match)


def test_version_1_files_have_sharp_borders():
    for path in VERSION_1:
        assert codec.decode(path.read_bytes()).blur.shape == (0, 3)


# ------------------------------------------------------------------ outlines crossing themselves (version 6)

BOW_TIE = np.array([[0, 0], [64, 64], [64, 0], [0, 64]], np.int32)  # 1/16 px: a 4 px square's corners


def test_an_outline_crossing_itself_is_refused():
    data = with_quantized(tiny_model(), xy=BOW_TIE)
    reject(data, "outline polygon 0 crosses itself (edges 0 and 2)")


def test_a_version_5_file_with_a_crossing_outline_is_read_mended():
    """docs/FORMAT.md, Versions: older encoders could fold an outline over itself; it reads mended."""
    data = patch_header(with_quantized(tiny_model(), xy=BOW_TIE), version=5)
    m = codec.decode(data)
    (poly,) = m.regions[0].outline
    assert is_simple(poly) and len(poly) == 3  # the larger half of the bow tie
    assert codec.decode(codec.encode(m)).regions[0].outline[0].tolist() == poly.tolist()


def test_the_encoder_mends_what_rounding_folds():
    """A sliver thinner than the grid whose sides cross once rounded is written mended."""
    m = tiny_model()
    m.regions[0].outline = [np.array([[0, 0], [4, 0], [4, 2.0], [2.76, 2.048], [1.0, 2.015], [3.12, 2.08],
                                      [4.0, 2.1], [4, 4], [0, 4]])]
    assert is_simple(m.regions[0].outline[0])
    assert not is_simple(np.rint(m.regions[0].outline[0] * 16))
    got = codec.decode(codec.encode(m)).regions[0].outline[0]
    assert is_simple(got)
    assert_models_identical(codec.quantize(m), codec.decode(codec.encode(m)))
