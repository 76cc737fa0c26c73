"""A ``.tpsv`` model as a resolution-independent PDF page (docs/PDF.md).

The page is the model's canvas, one model pixel per point at the default
72 dpi. What is drawn, bottom to top:

1. **Under-paint.** Every region's patch mesh (:mod:`tpsv.export.mesh`: PDF
   shading type 6, or 7 for a deformed patch), through a shading pattern,
   filled over its outline and stroked along it as wide as the border needs
   (``1.5 + 2 sigma`` px beyond it: :data:`SHARP_REACH_PX`,
   :data:`UNDER_SIGMAS`), the regions in reverse painting order: where two
   regions meet, the one painted first in step 2 ends on top here.
2. **Regions.** Each region's mesh again, in painting order (the reverse of
   the renderer's drawing order, ``tpsv.rendering.pixelmap.draw_order``, so
   that front regions end on top), clipped to its outline (the viewer's
   anti-aliased clip) or, where it has soft borders with regions painted
   before it, through a soft mask (the blurred step,
   :mod:`tpsv.export.edges`). Step 1 left the region across beneath each
   border pixel, so a border pixel becomes ``coverage * this + (1 -
   coverage) * across``, the renderer's mix, not a blend with the page
   white (a *conflation seam*); and the region painted first needs no soft
   edge there, it is beneath already.
3. **Detail.** The detail layer (when the model has one and ``detail`` is
   True) as one page-sized image at the model's resolution in blend mode
   HardLight: with backdrop ``B`` (the vector render) and image value ``S``,
   HardLight gives ``2 S B`` for ``S <= 1/2`` and
   ``B + (2 S - 1)(1 - B)`` above, so ``S = 1/2`` leaves ``B`` unchanged and
   any target colour in ``[0, 1]`` is reachable from any ``B``. ``S`` is
   solved per pixel from the renderer's colours with and without the
   detail layer; the vector colours stay vectors underneath.

Colours are sRGB, tagged ICCBased with an sRGB profile built here
(:mod:`tpsv.export.icc`). Streams are Flate-compressed; the detail image is
JPEG (4:4:4) at ``detail_quality``, or Flate (lossless) when that is None.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import TpsvError
from .edges import Ribbon, Ribbons, edge_sigmas, reach
from .icc import srgb_profile
from .mesh import MeshStats, RegionMesh, build_meshes

#: Default ``tolerance`` (8-bit sRGB levels; docs/PDF.md for what it gives).
DEFAULT_TOLERANCE = 3.0
#: Default JPEG quality of the detail image.
DEFAULT_DETAIL_QUALITY = 92
#: Pixels the under-paint reaches beyond a sharp border (a border pixel at 1x is within 0.71 px).
SHARP_REACH_PX = 1.5
#: The under-paint reaches this many sigmas beyond a soft border (the mask there is Phi(-2) = 2.3 %).
UNDER_SIGMAS = 2.0
#: Largest page side in points (PDF 1.x viewers' limit, ISO 32000-1 annex C).
MAX_PAGE_PT = 14400.0
#: Largest detail image side in pixels (the renderer's limit on one image).
MAX_DETAIL_PIXELS = 1 << 25

# corner order of a patch in the stream: (i, j) of p00 p01 p02 p03 p13 p23 p33 p32 p31 p30 p20 p10 [p11 p12 p22 p21]
_BOUNDARY = [(0, 0), (0, 1), (0, 2), (0, 3), (1, 3), (2, 3), (3, 3), (3, 2), (3, 1), (3, 0), (2, 0), (1, 0)]
_INTERIOR = [(1, 1), (1, 2), (2, 2), (2, 1)]
# colours: c00 c03 c33 c30 (corners (i, j) in {0, 1}^2)
_CORNERS = [(0, 0), (0, 1), (1, 1), (1, 0)]


@dataclass
class ExportStats:
    """What :func:`export_pdf` made (``stats`` argument).

    Attributes
    ----------
    regions : int
        Regions painted.
    pieces : int
        Patches in all the meshes.
    soft_edges : int
        Outline edges drawn soft (through a mask).
    detail : bool
        The detail layer went in.
    mesh : MeshStats
    seconds : float
    """

    regions: int = 0
    pieces: int = 0
    soft_edges: int = 0
    detail: bool = False
    mesh: MeshStats = field(default_factory=MeshStats)
    seconds: float = 0.0


def export_pdf(model, tolerance: float = DEFAULT_TOLERANCE, detail: bool = True, dpi: float = 72.0,
               detail_quality: int | None = DEFAULT_DETAIL_QUALITY, device: str = "cpu",
               stats: ExportStats | None = None) -> bytes:
    """The model as a one-page PDF: vector patch meshes, vector borders, the detail layer as an image.

    Parameters
    ----------
    model : Model
    tolerance : float
        Largest colour difference (8-bit sRGB levels, any channel) between a
        patch's bilinear colour and the renderer's, at the test points of
        every patch (:mod:`tpsv.export.mesh`). Smaller: more patches, a
        closer match.
    detail : bool
        Include the detail layer, when the model has one.
    dpi : float
        Model pixels per inch (72: one pixel per point).
    detail_quality : int or None
        JPEG quality (1-100) of the detail image; None: lossless (Flate).
    device : str
        Warp device for the colour evaluations and renders.
    stats : ExportStats, optional
        Filled in with what was made.

    Returns
    -------
    bytes
        The PDF file.

    Raises
    ------
    TpsvError
        A tolerance, dpi or quality out of range, or a page too large.
    """
    import pikepdf

    t0 = time.perf_counter()
    tolerance = float(tolerance)
    if not (np.isfinite(tolerance) and 0.05 <= tolerance <= 255):
        raise TpsvError(f"tolerance {tolerance!r} must lie in [0.05, 255] (8-bit sRGB levels)")
    dpi = float(dpi)
    if not (np.isfinite(dpi) and dpi > 0):
        raise TpsvError(f"dpi {dpi!r} must be a positive number")
    if detail_quality is not None and not (1 <= int(detail_quality) <= 100):
        raise TpsvError(f"detail quality {detail_quality!r} must lie in 1-100")
    W, H = int(model.width), int(model.height)
    if W <= 0 or H <= 0:
        raise TpsvError(f"model size {W}x{H} is empty")
    k = 72.0 / dpi
    if W * k > MAX_PAGE_PT or H * k > MAX_PAGE_PT:
        raise TpsvError(f"page {W * k:.0f} x {H * k:.0f} pt is larger than PDF viewers take "
                        f"(at most {MAX_PAGE_PT:.0f} pt a side): give a higher dpi")
    st = stats if stats is not None else ExportStats()
    from ..geometry.curves import as_drawn
    from ..rendering.pixelmap import draw_order, region_index

    # outlines drawn as curves become polygons within 0.01 model px of them (finer ones
    # made the soft-edge ribbons a lattice of slivers: 41.1 -> 38.9 dB in pdfium, test_export)
    model = as_drawn(model)

    vector = model if model.detail is None else _without_detail(model)
    sigmas, across = edge_sigmas(model)
    reaches = reach(sigmas, SHARP_REACH_PX)
    index = region_index(model, W, H)
    meshes, st.mesh = build_meshes(vector, tolerance, reaches, device=device, index=index)
    soft = Ribbons(model, sigmas)

    pdf = pikepdf.new()
    cs = pikepdf.Array([pikepdf.Name.ICCBased, _stream(pdf, srgb_profile(), N=3, Alternate=pikepdf.Name.DeviceRGB)])
    flip = [k, 0, 0, -k, 0, H * k]
    shadings, patterns, gstates, xobjects = {}, {}, {}, {}
    clear = np.array([bool(getattr(reg, "transparent", False)) for reg in model.regions] + [False])
    paint = [r for r in reversed(draw_order(model)) if not clear[r]]
    # painting rank: a transparent region is never painted (it is "beneath" everything: the page),
    # no region across (-1, the last entry) is never painted before
    rank = np.full(len(model.regions) + 1, -1, np.int64)
    rank[paint] = np.arange(len(paint))
    rank[-1] = len(paint)
    under, over = [], []
    for r in paint:
        mesh = meshes[r]
        if len(mesh.points) == 0:
            continue
        name = f"R{r}"
        shadings[name] = _mesh_shading(pdf, mesh, cs)
        patterns[name] = pdf.make_indirect(pikepdf.Dictionary(
            Type=pikepdf.Name.Pattern, PatternType=2, Shading=shadings[name], Matrix=pikepdf.Array(flip)))
        path = _path(model.regions[r].outline)
        under.append(f"q /Pattern cs /{name} scn /Pattern CS /{name} SCN 1 j 1 J\n{path} f*\n"
                     f"{_underpaint_strokes(model.regions[r].outline, sigmas[r], across[r], clear)} Q")
        # only the region painted second needs the soft edge: the one painted first is beneath it already
        earlier = [rank[a] < rank[r] for a in across[r]]
        rib = soft.region(r, earlier)
        st.soft_edges += int(sum(((s > 0) & e).sum() for s, e in zip(sigmas[r], earlier)))
        if rib:
            gstates[f"M{r}"] = _soft_mask(pdf, path, rib, W, H)
            x0, y0, x1, y1 = _bounds(mesh)
            over.append(f"q /M{r} gs {_num(x0)} {_num(y0)} {_num(x1 - x0)} {_num(y1 - y0)} re W n /{name} sh Q")
        else:
            over.append(f"q {path} W* n /{name} sh Q")
        st.regions += 1
        st.pieces += len(mesh.points)
    parts = [f"{_nums(flip)} cm"] + under[::-1] + over
    st.detail = bool(detail and model.detail is not None)
    if st.detail:
        xobjects["D"] = _detail_image(pdf, model, vector, cs, detail_quality, device, clear[index])
        gstates["HL"] = pikepdf.Dictionary(Type=pikepdf.Name.ExtGState, BM=pikepdf.Name.HardLight)
        parts.append(f"q /HL gs {W} 0 0 {-H} 0 {H} cm /D Do Q")
    resources = pikepdf.Dictionary()
    for key, d in (("Shading", shadings), ("Pattern", patterns), ("ExtGState", gstates), ("XObject", xobjects)):
        if d:
            resources[f"/{key}"] = pikepdf.Dictionary({f"/{n}": v for n, v in d.items()})
    page = pikepdf.Dictionary(
        Type=pikepdf.Name.Page,
        MediaBox=pikepdf.Array([0, 0, _round(W * k), _round(H * k)]),
        Resources=resources,
        Contents=_stream(pdf, "\n".join(parts).encode("ascii")),
        Group=pikepdf.Dictionary(Type=pikepdf.Name.Group, S=pikepdf.Name.Transparency, CS=cs),
    )
    pdf.pages.append(pikepdf.Page(page))
    from .. import __version__

    pdf.docinfo["/Producer"] = f"tpsv {__version__}"
    import io

    buf = io.BytesIO()
    pdf.save(buf, compress_streams=True, object_stream_mode=pikepdf.ObjectStreamMode.generate,
             deterministic_id=True)
    st.seconds = time.perf_counter() - t0
    return buf.getvalue()


def _without_detail(model):
    import dataclasses

    return dataclasses.replace(model, detail=None)


def _rows_stream(pdf, rows: np.ndarray, **keys):
    """A Flate stream of fixed-length records ``rows`` (n, m) uint8, each PNG-Up-predicted from the one before.

    Neighbouring patches (and ribbon rows) have close coordinates, so their
    byte differences compress far better than the records (40 % smaller
    meshes on the samples).
    """
    import zlib

    import pikepdf

    n, m = rows.shape
    diff = rows.copy()
    diff[1:] -= rows[:-1]  # uint8 arithmetic wraps, as the PNG Up filter does
    data = np.concatenate([np.full((n, 1), 2, np.uint8), diff], axis=1)
    s = pikepdf.Stream(pdf, b"")
    s.write(zlib.compress(data.tobytes(), 9), filter=pikepdf.Name.FlateDecode,
            decode_parms=pikepdf.Dictionary(Predictor=12, Colors=1, BitsPerComponent=8, Columns=m))
    for key, value in keys.items():
        s[f"/{key}"] = value
    return s


def _stream(pdf, data: bytes, **keys):
    import pikepdf

    s = pikepdf.Stream(pdf, data)
    for key, value in keys.items():
        s[f"/{key}"] = value
    return s


def _round(v: float) -> float:
    return float(f"{v:.4f}")


def _num(v: float) -> str:
    s = f"{float(v):.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _nums(vs) -> str:
    return " ".join(_num(v) for v in vs)


def _path(outline) -> str:
    """The outline's polygons as a PDF path (model pixels): ``m``, ``l``..., ``h`` each."""
    out = []
    for poly in outline:
        poly = np.asarray(poly, np.float64)
        if len(poly) < 2:
            continue
        txt = [f"{_num(x)} {_num(y)}" for x, y in poly]
        out.append(txt[0] + " m " + " l ".join(txt[1:]) + " l h")
    return "\n".join(out)


def _underpaint_strokes(outline, sigmas, across, clear) -> str:
    """Strokes along the outline, each edge as wide as its under-paint needs: ``2 (UNDER_SIGMAS sigma + SHARP_REACH_PX)``.

    Consecutive edges of one width are one open sub-path (round joins and
    caps). Edges facing a transparent region (``clear[across]``) get none:
    the page shows there, and the region's own edge is its coverage.
    """
    by_width: dict = {}
    for poly, sig, acr in zip(outline, sigmas, across):
        poly = np.asarray(poly, np.float64)
        n = len(poly)
        if n < 2:
            continue
        width = np.round(2.0 * (UNDER_SIGMAS * np.asarray(sig) + SHARP_REACH_PX), 2)
        width[clear[acr]] = 0.0
        # runs of equal width, starting where the width changes (or anywhere on a uniform polygon)
        change = np.flatnonzero(width != np.roll(width, 1))
        start = int(change[0]) if change.size else 0
        run = [start]
        for i in range(1, n + 1):
            e = (start + i) % n
            if i == n or width[e] != width[run[0]]:
                if width[run[0]] > 0:
                    pts = poly[[*run, (run[-1] + 1) % n]]
                    txt = [f"{_num(x)} {_num(y)}" for x, y in pts]
                    by_width.setdefault(float(width[run[0]]), []).append(txt[0] + " m " + " l ".join(txt[1:]) + " l")
                run = [e]
            else:
                run.append(e)
    return "\n".join(f"{_num(w)} w " + "\n".join(paths) + " S" for w, paths in sorted(by_width.items()))


def _bounds(mesh: RegionMesh):
    p = mesh.points.reshape(-1, 2)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _coord_bits(span: float) -> int:
    """Bits per coordinate for a 1/64-px grid over ``span`` px (16, 24 or 32)."""
    for bits in (16, 24, 32):
        if span / (2.0**bits - 1) <= 1.0 / 64:
            return bits
    return 32


def _pack_uint(q: np.ndarray, bits: int) -> np.ndarray:
    """Unsigned integers (..., n) as big-endian bytes (..., n * bits / 8) uint8."""
    nb = bits // 8
    q = q.astype(np.uint64)
    shifts = np.arange(nb - 1, -1, -1, dtype=np.uint64) * np.uint64(8)
    return ((q[..., None] >> shifts) & np.uint64(255)).astype(np.uint8).reshape(q.shape[:-1] + (q.shape[-1] * nb,))


def _quantize(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits: int) -> np.ndarray:
    top = 2.0**bits - 1
    return np.clip(np.round((xy - lo) / (hi - lo) * top), 0, top)


def _mesh_shading(pdf, mesh: RegionMesh, cs):
    """A region's mesh as a type 6 (affine patch: Coons) or type 7 (tensor-product) shading stream."""
    import pikepdf

    order = _BOUNDARY if mesh.affine else _BOUNDARY + _INTERIOR
    n = len(mesh.points)
    pts = np.stack([mesh.points[:, i, j] for i, j in order], axis=1)  # (n, P, 2)
    lo = pts.reshape(-1, 2).min(axis=0) - 1.0
    hi = pts.reshape(-1, 2).max(axis=0) + 1.0
    bits = _coord_bits(float((hi - lo).max()))
    q = _quantize(pts, lo, hi, bits).reshape(n, -1)
    col = np.stack([mesh.colors[:, i, j] for i, j in _CORNERS], axis=1).reshape(n, 12)
    data = np.concatenate([np.zeros((n, 1), np.uint8), _pack_uint(q, bits),
                           np.round(np.clip(col, 0, 1) * 255).astype(np.uint8)], axis=1)
    return _rows_stream(pdf, data, ShadingType=6 if mesh.affine else 7, ColorSpace=cs,
                   BitsPerCoordinate=bits, BitsPerComponent=8, BitsPerFlag=8,
                   Decode=pikepdf.Array([float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), 0, 1, 0, 1, 0, 1]))


def _ribbon_shading(pdf, rib: Ribbon):
    """A soft-edge ribbon as a type 5 (lattice-form Gouraud) DeviceGray shading."""
    import pikepdf

    rows, cols = rib.xy.shape[:2]
    lo = rib.xy.reshape(-1, 2).min(axis=0) - 1.0
    hi = rib.xy.reshape(-1, 2).max(axis=0) + 1.0
    bits = _coord_bits(float((hi - lo).max()))
    q = _quantize(rib.xy, lo, hi, bits).reshape(rows * cols, 2)
    g = np.round(np.clip(rib.value, 0, 1) * 255).reshape(-1, 1).astype(np.uint8)
    data = np.concatenate([_pack_uint(q, bits), g], axis=1).reshape(rows, -1)
    return _rows_stream(pdf, data, ShadingType=5, ColorSpace=pikepdf.Name.DeviceGray, BitsPerCoordinate=bits,
                   BitsPerComponent=8, VerticesPerRow=cols,
                   Decode=pikepdf.Array([float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), 0, 1]))


def _soft_mask(pdf, path: str, ribs: list[Ribbon], W: int, H: int):
    """An ExtGState whose luminosity soft mask is the region: its outline filled white, soft edges as ribbons."""
    import pikepdf

    sh = {f"/E{i}": _ribbon_shading(pdf, rb) for i, rb in enumerate(ribs)}
    content = "1 g\n" + path + " f*\n" + " ".join(f"/E{i} sh" for i in range(len(ribs)))
    form = _stream(pdf, content.encode("ascii"), Type=pikepdf.Name.XObject, Subtype=pikepdf.Name.Form,
                   BBox=pikepdf.Array([0, 0, W, H]),
                   Group=pikepdf.Dictionary(S=pikepdf.Name.Transparency, CS=pikepdf.Name.DeviceGray),
                   Resources=pikepdf.Dictionary(Shading=pikepdf.Dictionary(sh)))
    return pikepdf.Dictionary(Type=pikepdf.Name.ExtGState, SMask=pikepdf.Dictionary(
        Type=pikepdf.Name.Mask, S=pikepdf.Name.Luminosity, G=form, BC=pikepdf.Array([0])))


#: Image value that HardLight maps to "unchanged": 128 is decoded to exactly 1/2.
_HALF = 128
_DECODE_TOP = 255.0 / (2 * _HALF)


def hardlight_source(base: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The source ``S`` in ``[0, 1]`` that HardLight-blends onto ``base`` to give ``target`` (both sRGB in [0, 1]).

    Parameters
    ----------
    base, target : ndarray (..., 3)

    Returns
    -------
    ndarray (..., 3) float64
    """
    B = np.asarray(base, np.float64)
    T = np.clip(np.asarray(target, np.float64), 0.0, 1.0)
    down = T <= B
    with np.errstate(divide="ignore", invalid="ignore"):
        s_down = np.where(B > 1e-6, T / (2.0 * B), 0.5)
        s_up = np.where(B < 1 - 1e-6, 0.5 + (T - B) / (2.0 * (1.0 - B)), 0.5)
    return np.clip(np.where(down, s_down, s_up), 0.0, 1.0)


def _detail_image(pdf, model, vector, cs, quality: int | None, device: str, clear: np.ndarray):
    """The detail layer as a page-sized HardLight source image (model resolution); neutral where ``clear``."""
    import cv2
    import pikepdf

    from ..rendering.raster import render

    W, H = model.width, model.height
    if W * H > MAX_DETAIL_PIXELS:
        raise TpsvError(f"the detail layer of a {W}x{H} model is too large for one image "
                        f"(at most {MAX_DETAIL_PIXELS:,} px); export with --no-detail")
    base = render(vector, device=device)
    full = render(model, device=device)
    S = hardlight_source(base, full)
    S[clear] = 0.5  # a transparent region is the page, left as it is
    # the image's 128 decodes to exactly 1/2 (HardLight's identity): the Decode top is 255/256
    v = np.clip(np.round(S * 255.0 / _DECODE_TOP), 0, 255).astype(np.uint8)
    img = pikepdf.Stream(pdf, b"")
    if quality is None:
        img.write(v.tobytes())
    else:
        ok, jpg = cv2.imencode(".jpg", np.ascontiguousarray(v[:, :, ::-1]),
                               [cv2.IMWRITE_JPEG_QUALITY, int(quality),
                                cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
        if not ok:
            raise TpsvError("the detail image could not be JPEG-coded")
        img.write(jpg.tobytes(), filter=pikepdf.Name.DCTDecode)
    for key, value in dict(Type=pikepdf.Name.XObject, Subtype=pikepdf.Name.Image, Width=W, Height=H, ColorSpace=cs,
                           BitsPerComponent=8, Decode=pikepdf.Array([0, _DECODE_TOP] * 3),
                           Interpolate=True).items():
        img[f"/{key}"] = value
    return img


__all__ = ["DEFAULT_DETAIL_QUALITY", "DEFAULT_TOLERANCE", "ExportStats", "export_pdf", "hardlight_source"]
