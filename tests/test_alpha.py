"""Transparency: RGBA input -> transparent regions -> straight-alpha renders at any scale."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from tpsv import codec
from tpsv.codec import layout
from tpsv.encode import alpha as alpha_mod
from tpsv.encode.rate import encode_quality
from tpsv.errors import TpsvError
from tpsv.image import to_uint8
from tpsv.rendering import raster
from tpsv.rendering.borders import Borders
from tpsv.rendering.pixelmap import region_index

from test_codec import assemble, hand_model, patch_header, raw_sections, reject

SIZE = 40
SS = 8


def logo(scale: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """An orange disc with a blue ring on a transparent background, anti-aliased (supersampled), at ``scale``."""
    n = SIZE * scale * SS
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / (scale * SS)
    r = np.hypot(x - 20.0, y - 19.0)
    disc = (r < 14.0).astype(np.float32)
    col = np.empty((n, n, 3), np.float32)
    col[...] = (0.95, 0.55, 0.1)
    col[(r > 6.0) & (r < 9.5)] = (0.1, 0.3, 0.8)
    m = SIZE * scale
    a = disc.reshape(m, SS, m, SS).mean(axis=(1, 3))
    c = (col * disc[..., None]).reshape(m, SS, m, SS, 3).mean(axis=(1, 3)) / np.maximum(a, 1e-6)[..., None]
    return c.astype(np.float32), a.astype(np.float32)


@pytest.fixture(scope="module")
def encoded():
    rgb, a = logo()
    res = encode_quality(rgb, None, quality=75, alpha=a)
    return res, codec.decode(res.data)


def test_the_transparent_part_becomes_transparent_regions(encoded):
    res, model = encoded
    clear = [r for r in model.regions if r.transparent]
    assert len(clear) == 1 and len(clear) < len(model.regions)
    assert (res.model.regions[model.regions.index(clear[0])].transparent)
    # flags: alpha; flat colours need no texture (it would not pay for its bytes)
    version, flags = np.frombuffer(res.data[8:12], "<u2")
    assert version == layout.VERSION
    assert flags == layout.FLAG_ALPHA | layout.FLAG_CURVES | layout.FLAG_BLUR_MAP
    assert model.detail is None


def test_a_textured_rgba_picture_keeps_its_texture_but_not_on_the_transparent_part():
    rgb, a = logo()
    grain = np.random.default_rng(0).normal(0.0, 0.04, rgb.shape).astype(np.float32)
    res = encode_quality(np.clip(rgb + grain, 0, 1), None, quality=75, alpha=a)
    model = codec.decode(res.data)
    version, flags = np.frombuffer(res.data[8:12], "<u2")
    assert flags & layout.FLAG_DETAIL and flags & layout.FLAG_ALPHA
    clear = [i for i, r in enumerate(model.regions) if r.transparent]
    assert len(clear) == 1 and model.detail.mode[clear[0]] == 0
    assert (model.detail.mode[[i for i in range(len(model.regions)) if i != clear[0]]] != 0).all()


@pytest.mark.parametrize("scale", [1, 8])
def test_an_rgba_logo_comes_back_transparent_and_anti_aliased(encoded, scale):
    _, model = encoded
    rgb, a = logo(scale)
    img = raster.render(model, scale=scale, alpha=True)
    assert img.shape == (SIZE * scale, SIZE * scale, 4)
    got = img[..., 3]
    # transparent outside, opaque inside (beyond half an output pixel and the outline fit's
    # error on this circle, up to 0.6 px), and an anti-aliased edge like the analytic one
    y, x = (np.mgrid[0:SIZE * scale, 0:SIZE * scale] + 0.5) / scale
    r = np.hypot(x - 20.0, y - 19.0)
    margin = 0.65 + 0.5 / scale
    assert got[r > 14.0 + margin].max() == 0.0 and got[r < 14.0 - margin].min() == 1.0
    edge = (a > 0.02) & (a < 0.98)
    assert 0.02 < got[edge].mean() < 0.98 and np.abs(got - a).mean() < 0.01
    # composited over white: the picture as an image editor would show it
    white = lambda c, al: c * al[..., None] + (1.0 - al[..., None])  # noqa: E731
    mse = ((white(img[..., :3], got) - white(rgb, a)) ** 2).mean()
    assert 10 * np.log10(1.0 / mse) > 26.0
    # no dark or light fringe: edge pixels keep the disc's colour
    ring_free = edge & (np.abs(rgb - (0.95, 0.55, 0.1)).max(axis=2) < 0.05)
    # (a backdrop mixed into them would be 0.3 or more; the colour quantisation of quality 75 is up
    # to 0.1, and a pixel where three of the automatic regions meet the edge reaches 0.17, at alpha 0.3)
    dev = np.abs(img[..., :3][ring_free] - (0.95, 0.55, 0.1)).max(axis=1)
    assert dev.max() < 0.2 and dev.mean() < 0.08


def test_opacity_is_the_coverage_of_the_opaque_side(encoded):
    _, model = encoded
    W = H = SIZE * 3
    index = region_index(model, W, H)
    mix = Borders(model, W, H).mix(index)
    alpha, straight = raster.opacity(model, index, mix)
    clear = np.array([r.transparent for r in model.regions])
    own, across = clear[index.ravel()[mix.pixels]], clear[mix.other]
    flat = alpha.ravel()
    one_side = own != across
    # a border with the transparent part: alpha is the opaque side's share of the pixel
    np.testing.assert_allclose(flat[mix.pixels][one_side & ~own], mix.alpha[one_side & ~own])
    np.testing.assert_allclose(flat[mix.pixels][one_side & own], 1.0 - mix.alpha[one_side & own])
    # elsewhere 0 in the transparent part, 1 in the picture
    rest = np.ones(W * H, bool)
    rest[mix.pixels] = False
    assert np.array_equal(flat[rest], (~clear[index.ravel()[rest]]).astype(np.float32))
    # the colour of such a pixel is the opaque side's alone
    kept = dict(zip(straight.pixels.tolist(), straight.alpha.tolist()))
    for p, o, a in zip(mix.pixels[one_side], own[one_side], mix.alpha[one_side]):
        assert (kept[p] == 0.0) if o else (p not in kept)


@pytest.mark.parametrize("depth", [8, 16])
def test_bands_give_the_one_piece_rgba(encoded, depth):
    """Bands rounded on the device (colours) and on the host (alpha): the one-piece RGBA render rounded."""
    from tpsv.image import to_uint16

    _, model = encoded
    whole = raster.render(model, scale=3, alpha=True)
    bands = list(raster.render_bands(model, scale=3, max_pixels=120 * 7, alpha=True, depth=depth))
    assert len(bands) > 3
    rows = np.concatenate([r for _, r in bands])
    assert rows.shape == whole.shape and rows.dtype == (np.uint8 if depth == 8 else np.uint16)
    assert np.array_equal(rows, (to_uint8 if depth == 8 else to_uint16)(whole))


def test_without_alpha_the_render_is_rgb_and_opaque_models_are_opaque(encoded):
    _, model = encoded
    assert raster.render(model, alpha=False).shape == (SIZE, SIZE, 3)
    opaque = hand_model()
    assert not alpha_mod.has_transparency(opaque)
    assert np.all(raster.render(opaque, alpha=True)[..., 3] == 1.0)


def test_no_transparent_pixel_means_no_transparent_region():
    rgb, a = logo()
    assert alpha_mod.transparent_mask(np.ones_like(a)) is None
    with pytest.raises(TpsvError, match="fully transparent"):
        encode_quality(rgb, None, quality=10, alpha=np.zeros_like(a))
    # translucent all over (alpha 0.4 everywhere) is translucency, not a transparent picture
    with pytest.raises(TpsvError, match="partly transparent in"):
        alpha_mod.transparent_mask(np.full_like(a, 0.4))


def test_transparency_survives_encode_decode_and_edits(encoded):
    from tpsv.edit import recolor

    _, model = encoded
    again = codec.decode(codec.encode(model))
    assert [r.transparent for r in again.regions] == [r.transparent for r in model.regions]
    edited = recolor.recolor(model, hue=40)
    assert [r.transparent for r in edited.regions] == [r.transparent for r in model.regions]


def test_hostile_alpha_fields_are_refused():
    model = hand_model()
    model.regions[1].transparent = True
    data = codec.encode(model)
    assert codec.decode(data).regions[1].transparent
    regions = msgpack.unpackb(raw_sections(data)[1])
    R = len(model.regions)

    def with_alpha(value):
        obj = dict(regions)
        if value is None:
            obj.pop("alpha")
        else:
            obj["alpha"] = value
        return assemble(data, {"regions": msgpack.packb(obj, use_bin_type=True)})

    reject(with_alpha(None), "missing key 'alpha'")
    reject(with_alpha(b"\x00" * ((R + 7) // 8)), "alpha must mark at least one")
    reject(with_alpha(b"\xff" * ((R + 7) // 8)), "alpha must mark at least one")  # bits past the last region
    reject(with_alpha(b"\x02" * ((R + 7) // 8 + 1)), "alpha has")
    reject(with_alpha(7), "alpha is not a bin")
    # the flag is version 4's: a version-3 file may not set it
    reject(patch_header(data, version=3), "unsupported flags 0x0002")
    # an opaque model's file has neither the flag nor the key
    plain = codec.encode(hand_model())
    assert np.frombuffer(plain[10:12], "<u2")[0] == 0 and "alpha" not in msgpack.unpackb(raw_sections(plain)[1])
    reject(patch_header(plain, flags=layout.FLAG_ALPHA), "missing key 'alpha'")


def test_translucency_away_from_an_edge_is_refused():
    rgb, a = logo()
    glass = a.copy()
    glass[18:22, 18:22] = 0.6  # a translucent patch inside the disc
    with pytest.raises(TpsvError, match="partly transparent in 16 px away from the edges"):
        encode_quality(rgb, None, quality=10, alpha=glass)
    with pytest.raises(TpsvError, match="partly transparent"):
        alpha_mod.transparent_mask(np.full_like(a, 0.5))


def test_the_command_line_keeps_a_logo_transparent(tmp_path):
    import json

    import cv2
    from click.testing import CliRunner

    from tpsv.cli import main

    rgb, a = logo()
    rgba = np.dstack([rgb, a])
    cv2.imwrite(str(tmp_path / "logo.png"), cv2.cvtColor(to_uint8(rgba), cv2.COLOR_RGBA2BGRA))
    run = CliRunner().invoke
    r = run(main, ["vectorize", str(tmp_path / "logo.png"), "-o", str(tmp_path / "logo.tpsv"), "--quality", "60"])
    assert r.exit_code == 0, r.output
    info = json.loads(run(main, ["info", str(tmp_path / "logo.tpsv"), "--json"]).stdout)
    assert len(info["transparent"]) == 1
    for scale in (1, 8):
        out = tmp_path / f"x{scale}.png"
        assert run(main, ["render", str(tmp_path / "logo.tpsv"), "-o", str(out), "--scale", str(scale)]).exit_code == 0
        img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
        n = SIZE * scale
        assert img.shape == (n, n, 4)
        assert img[0, 0, 3] == 0 and img[n - 1, n - 1, 3] == 0 and img[19 * scale, 20 * scale, 3] == 255
    # JPEG has no alpha: the picture over white
    assert run(main, ["render", str(tmp_path / "logo.tpsv"), "-o", str(tmp_path / "x.jpg")]).exit_code == 0
    jpg = cv2.imread(str(tmp_path / "x.jpg"), cv2.IMREAD_UNCHANGED)
    assert jpg.shape == (SIZE, SIZE, 3) and jpg[0, 0].min() >= 250
    # the other readers of photos say why they refuse it
    r = run(main, ["segment", str(tmp_path / "logo.png"), "-o", str(tmp_path / "l.png")])
    assert r.exit_code == 1 and "vectorize keeps transparency" in r.output
