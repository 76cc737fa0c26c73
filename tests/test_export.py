"""PDF export: an independent renderer (PDFium) against tpsv's own, tolerance, page, errors, CLI."""

from __future__ import annotations

import dataclasses
import io
import json

import numpy as np
import pikepdf
import pytest
from click.testing import CliRunner

from tpsv import codec
from tpsv.cli import main
from tpsv.export import ExportStats, export_pdf
from tpsv.export.edges import edge_sigmas
from tpsv.export.icc import srgb_profile
from tpsv.export.pdf import hardlight_source
from tpsv.metrics import psnr
from tpsv.rendering.raster import render

from conftest import SAMPLES
from editfixtures import scene_model

pdfium = pytest.importorskip("pypdfium2")


def pdfium_render(data: bytes, scale: float = 2.0) -> np.ndarray:
    """The first page rendered by PDFium, float RGB in [0, 1]."""
    page = pdfium.PdfDocument(data)[0]
    return page.render(scale=scale, rev_byteorder=True).to_numpy()[..., :3].astype(np.float32) / 255.0


def tpsv_render(model, scale: float = 2.0) -> np.ndarray:
    """``tpsv render --scale`` as its 8-bit PNG holds it."""
    return np.round(render(model, scale=scale) * 255.0) / 255.0


@pytest.fixture(scope="module")
def photo():
    """A 96 x 64 crop of chelsea with its labels (eye, fur, background) at the default quality: with detail."""
    from tpsv.encode.rate import encode_quality
    from tpsv.image import read_image, read_labels

    rgb = np.ascontiguousarray(read_image(SAMPLES / "chelsea.png")[80:144, 270:366])
    lab = np.ascontiguousarray(read_labels(SAMPLES / "chelsea-labels.png")[80:144, 270:366])
    model = codec.decode(codec.encode(encode_quality(rgb, lab).model))
    assert model.detail is not None and len(model.regions) >= 3 and (model.blur[:, 2] > 0).any()
    return model


def test_pdfium_matches_render_without_detail():
    """A synthetic scene with sharp borders and striped (curvilinear) colour: measured 36.5 dB at 2x."""
    model = scene_model()
    st = ExportStats()
    data = export_pdf(model, stats=st)
    got = pdfium_render(data)
    assert got.shape == (2 * model.height, 2 * model.width, 3)
    assert psnr(tpsv_render(model), got) > 35.0
    assert st.regions == len(model.regions) and st.pieces > 0 and not st.detail


def test_pdfium_matches_render_with_and_without_detail(photo):
    """A photo crop with soft borders and a detail layer: measured 38.2 dB with, 41.2 dB without."""
    bare = dataclasses.replace(photo, detail=None)
    st = ExportStats()
    with_detail = export_pdf(photo, stats=st)
    assert st.detail and st.soft_edges > 0
    assert psnr(tpsv_render(photo), pdfium_render(with_detail)) > 36.0
    # --no-detail is the vector image: the render of the model without its detail layer
    for data in (export_pdf(photo, detail=False), export_pdf(bare)):
        assert psnr(tpsv_render(bare), pdfium_render(data)) > 39.0


def test_smaller_tolerance_more_patches_closer(photo):
    bare = dataclasses.replace(photo, detail=None)
    ref = tpsv_render(bare)
    out = []
    for tol in (12.0, 1.0):
        st = ExportStats()
        data = export_pdf(bare, tolerance=tol, stats=st)
        out.append((st.pieces, psnr(ref, pdfium_render(data)), len(data)))
        assert st.mesh.max_error <= tol + 1e-6 or st.mesh.levels > 1
    (n_coarse, p_coarse, b_coarse), (n_fine, p_fine, b_fine) = out
    assert n_fine > 2 * n_coarse and b_fine > b_coarse
    assert p_fine > p_coarse + 3.0  # measured 36.3 -> 42.1 dB (116 -> 1644 patches)


def test_page_size_regions_and_objects(photo):
    data = export_pdf(photo)
    with pikepdf.open(io.BytesIO(data)) as pdf:
        assert len(pdf.pages) == 1
        page = pdf.pages[0]
        assert [float(v) for v in page.MediaBox] == [0, 0, photo.width, photo.height]
        shadings = page.Resources.Shading
        assert sorted(shadings.keys()) == sorted(f"/R{r}" for r in range(len(photo.regions)))
        for sh in shadings.values():
            assert int(sh.ShadingType) == 6  # fresh patches are affine: Coons patches hold them exactly
            assert sh.ColorSpace[0] == pikepdf.Name.ICCBased and int(sh.ColorSpace[1].N) == 3
            assert sh.get("/Filter") == pikepdf.Name.FlateDecode
        assert page.Resources.ExtGState.HL.BM == pikepdf.Name.HardLight
        assert int(page.Resources.XObject.D.Width) == photo.width
    # --dpi: the same picture on a page of another size
    with pikepdf.open(io.BytesIO(export_pdf(photo, dpi=144.0, detail=False))) as pdf:
        assert [float(v) for v in pdf.pages[0].MediaBox] == [0, 0, photo.width / 2, photo.height / 2]


def test_deformed_patch_is_tensor_mesh(photo):
    from tpsv.edit.deform import move_points

    M, N = photo.regions[0].patch.shape
    bent = dataclasses.replace(move_points(photo, [(0, M // 2, N // 2, 5.0, -3.0)]), detail=None)
    data = export_pdf(bent)
    with pikepdf.open(io.BytesIO(data)) as pdf:
        types = {int(s.ShadingType) for s in pdf.pages[0].Resources.Shading.values()}
    assert 7 in types
    # measured 37.9 dB: the soft-edge ribbons follow a bent patch less closely the wider the edge, and the
    # blur map widens the borders' flat stretches to 1.5 px (39.0 dB with one width per pair)
    assert psnr(tpsv_render(bent), pdfium_render(data)) > 37.5


def test_transparent_region_is_left_unpainted():
    model = scene_model()
    regions = list(model.regions)
    regions[1] = dataclasses.replace(regions[1], transparent=True)  # the disc
    model = dataclasses.replace(model, regions=regions)
    got = pdfium_render(export_pdf(model), scale=1.0)
    # inside the disc (centre (22, 24), radius 11), away from its edge: the white page
    assert np.all(got[20:28, 18:26] == 1.0)
    assert got[5, 5].max() < 0.99  # the background is painted
    with pikepdf.open(io.BytesIO(export_pdf(model))) as pdf:
        assert "/R1" not in pdf.pages[0].Resources.Shading


@pytest.mark.parametrize("with_map", [False, True])
def test_shared_edges_find_the_region_across(photo, with_map):
    """Each edge's width: its pair's, or with a blur map the map's at the edge's middle."""
    from tpsv.rendering.borders import blur_at

    model = photo if with_map else dataclasses.replace(photo, blur_map=None)
    assert (model.blur_map is not None) == with_map
    sigmas, across = edge_sigmas(model)
    width = {(int(a), int(b)): s for a, b, s in model.blur}
    for r, region in enumerate(model.regions):
        for poly, sig, acr in zip(region.outline, sigmas[r], across[r]):
            b = np.roll(poly, -1, axis=0)
            frame = (((poly[:, 0] == 0) & (b[:, 0] == 0)) | ((poly[:, 1] == 0) & (b[:, 1] == 0))
                     | ((poly[:, 0] == model.width) & (b[:, 0] == model.width))
                     | ((poly[:, 1] == model.height) & (b[:, 1] == model.height)))
            assert np.all((acr >= 0) | frame) and np.all(acr != r)
            assert np.all(sig[frame] == 0)
            if with_map:
                mid = 0.5 * (poly + b)[acr >= 0]
                grid = (model.blur_map.sigma.astype(np.float64), float(model.blur_map.cell), float(model.blur_map.cell))
                expect = blur_at(grid, mid[:, 0], mid[:, 1])
            else:
                expect = [width.get((min(r, a), max(r, a)), 0.0) for a in acr[acr >= 0]]
            assert np.array_equal(sig[acr >= 0], expect)


def test_hardlight_source_inverts_hardlight():
    rng = np.random.default_rng(1)
    B = rng.random((1000, 3))
    T = rng.random((1000, 3))
    S = hardlight_source(B, T)
    got = np.where(S <= 0.5, 2 * S * B, B + (2 * S - 1) * (1 - B))
    assert np.allclose(got, T, atol=1e-9)
    assert np.allclose(hardlight_source(B, B), 0.5)


def test_icc_profile_is_well_formed():
    icc = srgb_profile()
    assert int.from_bytes(icc[:4], "big") == len(icc) and icc[36:40] == b"acsp" and icc[12:24] == b"mntrRGB XYZ "
    ImageCms = pytest.importorskip("PIL.ImageCms")
    from PIL import Image

    ours = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    to_srgb = ImageCms.buildTransform(ours, ImageCms.createProfile("sRGB"), "RGB", "RGB", renderingIntent=1)
    x = np.random.default_rng(0).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    y = np.asarray(ImageCms.applyTransform(Image.fromarray(x), to_srgb)).astype(int)
    assert np.abs(y - x).max() <= 1


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_cli_json_and_summary(tmp_path):
    src = tmp_path / "scene.tpsv"
    codec.save(scene_model(), src)
    out = tmp_path / "scene.pdf"
    r = run("export", src, "-o", out, "--json", "--tolerance", 4)
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["bytes"] == out.stat().st_size and s["regions"] == 3 and s["patches"] > 0 and s["seconds"] > 0
    assert out.read_bytes().startswith(b"%PDF-")
    r = run("export", src, "-o", out, "--no-detail")
    assert r.exit_code == 0 and "patches" in r.stderr and r.stdout == ""


@pytest.mark.parametrize("kind", ["truncated", "magic", "empty"])
def test_cli_broken_tpsv_one_line_no_pdf(tmp_path, kind):
    good = codec.encode(scene_model())
    data = {"truncated": good[: len(good) // 2], "magic": b"NOTTPSV" + good[7:], "empty": b""}[kind]
    src = tmp_path / "bad.tpsv"
    src.write_bytes(data)
    out = tmp_path / "bad.pdf"
    r = run("export", src, "-o", out)
    assert r.exit_code == 1, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("tpsv: error:")
    assert "Traceback" not in r.output
    assert not out.exists() and list(tmp_path.iterdir()) == [src]
