"""The detail section: the texture detail layer's frames, modes and AVIF image.

Layout (``docs/FORMAT.md``, "Detail"): a msgpack map, zstd-framed like every
section, with ``codec`` ("avif"), ``width`` and ``height`` of the texture,
``quality`` (1-100), ``frame`` (``R x 6`` little-endian int32, 1/16 px:
origin, d/dS, d/dT of each region's rest frame), ``mode`` (``R`` bytes) and
``image`` (monochrome AVIF, 10 bits: the residual's Y, Cb and Cr planes one
below the other, ``width x 3 height``, or side by side when the texture is
taller than wide; OpenCV's AVIF writer subsamples the chroma of colour images
2:1, which capped the PSNR of red on black at 37 dB, while planes in one grey
image keep every texel). Since version 8 a texture may instead be coded plane
by plane, each plane in bands of rows, each band an AVIF file of its own
(``image`` an array of them; tpsv writes one band a plane): OpenCV codes one
AVIF image on one thread, and the files are coded (and decoded) on the host's
cores at once (:func:`plane_bands`). Since version 9 (codec ``"av1"``) each
file is stored as its AV1 bitstream alone and wrapped in its AVIF boxes again
when read (:mod:`tpsv.codec.avif`).

The AVIF image is decoded by OpenCV's libavif. Before it is, the image's own
declared sizes (every ``ispe`` property of its ISO-BMFF boxes) must fit the
texture's: a hostile payload cannot make the decoder allocate more than the
texture the header counts allow, and the decoded array must have exactly the
declared shape and depth.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np

from ..errors import TpsvError, TpsvFormatError
from ..model import DETAIL_LUMA, Detail
from ..quiet import quiet_stderr
from . import avif, layout
from . import sections
from .sections import _expect_bin, _expect_int, _expect_map, _packb

#: Frame vectors are stored in units of 1/FRAME_SCALE px.
FRAME_SCALE = 16
CODEC = "avif"
#: The codec of a version-9 section whose images are AV1 bitstreams, each wrapped by the decoder
#: in the AVIF boxes tpsv's encoder writes (:mod:`tpsv.codec.avif`).
CODEC_AV1 = "av1"
KEYS = ("codec", "width", "height", "quality", "frame", "mode", "image")
#: AVIF encoder effort (libaom speed 0-10, lower is slower and smaller), careful and fast. On
#: the samples' textures (qualities 20-90, BD-PSNR against speed 6): speed 5 +0.31 to +0.56 dB
#: for 3-5 times the time (astronaut at quality 75: 28974 B in 2.0-2.4 s against 30837 B
#: in 0.5-0.7 s on this 2-core CPU), speed 4 +0.42 to +0.61 dB for 1-1.8 times more again,
#: speed 7 -0.14 to -0.41 dB, speeds 8-9 -0.41 to -1.0 dB (docs/DESIGN.md, "Detail layer").
AVIF_SPEED, FAST_AVIF_SPEED = 5, 6
#: Textures larger than this (texels) are coded at the fast speed: at speed 5 a 12-megapixel
#: texture would take about a minute of the encoder.
CAREFUL_TEXELS = 1 << 20
#: Smaller textures take more effort: ``(texels a plane below, speed)``, so that one coding stays
#: under about a second on a 2-core CPU. BD-PSNR against speed 5 (AVIF qualities 20-95, the
#: samples area-downscaled 2x and 4x and chelsea's 128 x 96 eye, coded in one piece): speed 4
#: +0.03..+0.15 dB, 3 +0.21..+0.35, 2 +0.27..+0.44, 1 +0.33..+0.46, for 1.5, 2.6, 3.6 and 4.4
#: times the time; the samples themselves (plane by plane, through ``encode_quality``) at speed 4
#: +0.09..+0.10 dB for 0.1-0.35 s more a ``vectorize`` (docs/DESIGN.md, "Detail layer").
SMALL_SPEEDS = ((1 << 14, 1), (1 << 15, 2), (1 << 16, 3), ((1 << 18) + 1, 4))
#: Textures of fewer texels a plane than this are coded in one piece (the planes stacked in one
#: image, as before version 8); larger ones plane by plane, a file a plane, so that the host's
#: cores code them at once (:func:`plane_bands`). Every file costs its own AVIF headers (mostly
#: the same bytes, which the section's zstd takes back) and libaom's choices made per image:
#: 100-200 bytes, which a small file would feel. The format also lets a plane be cut into bands
#: of rows; tpsv does not cut them: bands coded apart meet in a faint seam (a row where each
#: side keeps its own coding error, a coherent step of about one 8-bit level across the width,
#: seen in flat parts magnified), and more files cost more bytes (docs/DESIGN.md, "Planes and bands").
ONE_PIECE_TEXELS = 1 << 17
#: Band heights are multiples of this (AV1's 64-px superblocks stay where one image has them).
BAND_ALIGN = 64
#: The most files the image may be stored in (3 planes of 341 bands).
MAX_BANDS = 1023
#: AVIF quality at tpsv quality 100 (100 would be lossless: ~16 bpp).
MAX_AVIF_QUALITY = 98
DEPTH = 10
#: Box types that contain other boxes (ISO/IEC 14496-12, 23008-12), walked for ``ispe``.
_CONTAINERS = {b"meta": 4, b"iprp": 0, b"ipco": 0, b"moov": 0, b"trak": 0, b"mdia": 0, b"minf": 0, b"stbl": 0}


def avif_quality(quality: int) -> int:
    """The AVIF encoder quality for tpsv quality 1-100 (monotonic, at most :data:`MAX_AVIF_QUALITY`)."""
    return int(round(1 + (int(quality) - 1) * (MAX_AVIF_QUALITY - 1) / 99))


#: AVIF quality steps the chroma planes of a texture coded plane by plane are below its luma (fewer
#: toward quality 100, none there). Measured (2026-11-27, BD-PSNR over AVIF qualities 20-95 against
#: equal qualities): the samples with their label maps +0.08 / +0.10 / +0.11 / +0.03 dB (chelsea,
#: coffee, astronaut, rocket), four photos the encoder never saw (scikit-image's retina, motorcycle,
#: ihc and hubble at 448 px) -0.01 / +0.14 / +0.07 / +0.07 dB; 8 steps gained more on most (up to
#: +0.18) but lost 0.02-0.09 dB on the saturated reds of rocket and retina.
CHROMA_STEPS = 4


def chroma_quality(quality: int) -> int:
    """The AVIF encoder quality of the Cb and Cr planes of a texture coded plane by plane at tpsv
    ``quality``: :func:`avif_quality` less :data:`CHROMA_STEPS`, and less only ``100 - quality`` at
    the top (quality 100 codes every plane at the highest quality). Monotonic, at least 1."""
    return max(1, avif_quality(quality) - min(CHROMA_STEPS, 100 - int(quality)))


def plane_axis(width: int, height: int) -> int:
    """Axis along which the three planes are stacked: 0 (one below the other) unless the
    texture is taller than wide, then 1 (side by side). Along its shorter side a texture
    of at most 40 Mpx stays under libavif's default 32768-px side limit three times over."""
    return 0 if height <= width else 1


def image_shape(width: int, height: int) -> tuple[int, int]:
    """(rows, columns) of the AVIF image of a ``width x height`` texture."""
    return (3 * height, width) if plane_axis(width, height) == 0 else (height, 3 * width)


def avif_speed(width: int, height: int) -> int:
    """The AVIF encoder speed for a ``width x height`` texture: slower the smaller it is up to
    2^18 texels (:data:`SMALL_SPEEDS`), :data:`AVIF_SPEED` up to :data:`CAREFUL_TEXELS` texels,
    :data:`FAST_AVIF_SPEED` above."""
    n = int(width) * int(height)
    if n > CAREFUL_TEXELS:
        return FAST_AVIF_SPEED
    return next((speed for below, speed in SMALL_SPEEDS if n < below), AVIF_SPEED)


def band_height(rows: int, n: int) -> int:
    """Rows of each of ``n`` bands of a plane of ``rows`` rows (the last takes what is left):
    ``rows / n`` rounded up to a multiple of :data:`BAND_ALIGN`."""
    return BAND_ALIGN * -(-int(rows) // (BAND_ALIGN * int(n)))


def band_rows(rows: int, n: int) -> list[tuple[int, int]]:
    """``(first, end)`` rows of each of ``n`` bands of a plane of ``rows`` rows.

    Raises
    ------
    TpsvFormatError
        ``n`` bands of :func:`band_height` rows leave a band empty, or ``3 n`` files would be
        more than :data:`MAX_BANDS`.
    """
    if not 1 <= n <= MAX_BANDS // 3:
        raise TpsvFormatError(f"section detail: planes in {n} bands, expected 1..{MAX_BANDS // 3}")
    step = band_height(rows, n)
    if (n - 1) * step >= rows:
        raise TpsvFormatError(f"section detail: {rows} rows cannot be cut into {n} bands")
    return [(k * step, min(rows, (k + 1) * step)) for k in range(n)]


def plane_bands(width: int, height: int) -> int:
    """How the texture of a ``width x height`` picture is coded: 0 in one piece (the planes stacked,
    a plane of fewer than :data:`ONE_PIECE_TEXELS` texels), else 1, plane by plane, each plane
    one file (in one band). It depends on the size alone, so a file's bytes do not depend on
    the machine that wrote it."""
    return 0 if int(width) * int(height) < ONE_PIECE_TEXELS else 1


def _pool(files: int):
    """The host threads that code or decode ``files`` AVIF files at once: one a core. Three planes
    at once hold about what the stacked image in one piece did (libaom's encoder holds about 20
    bytes a texel)."""
    from ..threads import host_cores, pool

    return pool("avif", max(1, min(host_cores(), int(files))))


def _avif(image: np.ndarray, params: list) -> bytes:
    try:
        ok, buf = cv2.imencode(".avif", np.ascontiguousarray(image), params)
    except cv2.error:
        ok = False
    if not ok:
        raise TpsvError("this OpenCV cannot write AVIF images (the detail layer needs opencv>=5.0 with libavif)")
    return buf.tobytes()


def encode_texels(texels: np.ndarray, quality: int) -> tuple[bytes, ...]:
    """The AVIF files of ``texels`` (h, w, 3) uint16 in 0..1023 at tpsv ``quality`` (the
    encoder's speed by the texture's size, :func:`avif_speed`): one file of the three planes
    stacked, or (:func:`plane_bands`) each plane's bands of rows, plane by plane, coded at once
    on the host's cores, the chroma planes at :func:`chroma_quality`."""
    h, w = texels.shape[:2]

    def params(avif_q: int) -> list:
        return [cv2.IMWRITE_AVIF_QUALITY, avif_q, cv2.IMWRITE_AVIF_SPEED, avif_speed(w, h), cv2.IMWRITE_AVIF_DEPTH, DEPTH]

    n = plane_bands(w, h)
    if n == 0:
        return (_avif(np.concatenate([texels[..., k] for k in range(3)], axis=plane_axis(w, h)),
                      params(avif_quality(quality))),)
    by_plane = [params(avif_quality(quality))] + [params(chroma_quality(quality))] * 2
    pieces = [(k, a, b) for k in range(3) for a, b in band_rows(h, n)]
    return tuple(_pool(len(pieces)).map(lambda p: _avif(texels[p[1]:p[2], :, p[0]], by_plane[p[0]]), pieces))


def _boxes(data: bytes, start: int, end: int, depth: int = 0):
    """``(type, body_start, body_end)`` of every box in ``data[start:end]``, containers walked."""
    pos = start
    while pos < end:
        if end - pos < 8:
            raise TpsvFormatError("section detail: image has a truncated box")
        size, kind = struct.unpack_from(">I4s", data, pos)
        head = 8
        if size == 1:
            if end - pos < 16:
                raise TpsvFormatError("section detail: image has a truncated box")
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            head = 16
        elif size == 0:
            size = end - pos
        if size < head or pos + size > end:
            raise TpsvFormatError("section detail: image has a box of a bad size")
        yield kind, pos + head, pos + size
        if kind in _CONTAINERS and depth < 8:
            yield from _boxes(data, pos + head + _CONTAINERS[kind], pos + size, depth + 1)
        pos += size


def image_sizes(data: bytes) -> list[tuple[int, int]]:
    """Every ``(width, height)`` an AVIF file declares (its ``ispe`` properties).

    Raises
    ------
    TpsvFormatError
        Not an AVIF still image, or its boxes are malformed.
    """
    if len(data) < 12 or data[4:8] != b"ftyp" or data[8:12] not in (b"avif", b"mif1"):
        raise TpsvFormatError("section detail: image is not an AVIF file")
    sizes = []
    for kind, a, b in _boxes(data, 0, len(data)):
        if kind == b"ispe":
            if b - a < 12:
                raise TpsvFormatError("section detail: image has a truncated ispe box")
            sizes.append(struct.unpack_from(">II", data, a + 4))
    if not sizes:
        raise TpsvFormatError("section detail: image declares no size")
    return sizes


def _decoded(data: bytes, shape: tuple[int, int]) -> tuple[np.ndarray | None, str | None]:
    """An AVIF file decoded, checked to be ``shape`` uint16 in 0..1023: ``(image, None)`` or ``(None, problem)``."""
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None:
        return None, "the AVIF image cannot be decoded"
    if img.dtype != np.uint16 or img.shape != shape:
        return None, f"image decodes to {img.shape} {img.dtype}, expected {shape} uint16"
    if int(img.max(initial=0)) > 1023:
        return None, "image is not 10-bit"
    return img, None


def _check_sizes(data: bytes, cols: int, rows: int, what: str) -> None:
    for w, h in image_sizes(data):
        if w > cols or h > rows:
            raise TpsvFormatError(f"section detail: image declares {w}x{h}, the texture's {what} is {cols}x{rows}")


def decode_texels(files, width: int, height: int) -> np.ndarray:
    """The texels (height, width, 3) uint16 of a detail image: one AVIF file of the planes stacked,
    or ``3 n`` files, each plane's ``n`` bands of rows (:func:`band_rows`) plane by plane; every
    file's declared sizes checked before it is decoded, its pixels after."""
    sizes = file_sizes(width, height, len(files))
    for data, (cols, rows) in zip(files, sizes):
        _check_sizes(data, cols, rows, "image" if len(files) == 1 else "band")
    if len(files) == 1:
        (cols, rows), = sizes
        with quiet_stderr():  # libaom and OpenCV log corrupt data themselves; the error below is the one line
            img, problem = _decoded(files[0], (rows, cols))
        if problem:
            raise TpsvFormatError(f"section detail: {problem}")
        return np.ascontiguousarray(np.stack(np.split(img, 3, axis=plane_axis(width, height)), axis=-1))
    pieces = [(k, a, b) for k in range(3) for a, b in band_rows(height, len(files) // 3)]
    texels = np.empty((height, width, 3), np.uint16)

    def decode(i):
        k, a, b = pieces[i]
        img, problem = _decoded(files[i], (b - a, width))
        if img is not None:
            texels[a:b, :, k] = img
        return problem

    with quiet_stderr():
        problems = list(_pool(len(files)).map(decode, range(len(files))))
    for problem in problems:
        if problem is not None:
            raise TpsvFormatError(f"section detail: {problem}")
    return texels


def quantize_frame(frame: np.ndarray, n_regions: int) -> np.ndarray:
    """Frames as stored: int32 (R, 6) in 1/16 px (ValueError when they cannot be)."""
    f = np.asarray(frame, np.float64)
    if f.shape != (n_regions, 3, 2):
        raise ValueError(f"detail frame has shape {f.shape}, expected ({n_regions}, 3, 2)")
    if not np.isfinite(f).all():
        raise ValueError("detail frame: non-finite value")
    q = np.rint(f.reshape(n_regions, 6) * FRAME_SCALE)
    if np.abs(q).max(initial=0) > 2**31 - 1:
        raise ValueError("detail frame: value out of range")
    return q.astype(np.int32)


def quantize(detail: Detail | None, n_regions: int) -> Detail | None:
    """``detail`` exactly as ``unpack_section(pack_section(detail))`` returns it (ValueError when it cannot be stored)."""
    if detail is None:
        return None
    mode = np.asarray(detail.mode)
    if mode.shape != (n_regions,) or mode.dtype.kind not in "iub" or mode.min(initial=0) < 0 or mode.max(initial=0) > DETAIL_LUMA:
        raise ValueError(f"detail mode must be {n_regions} values in 0..{DETAIL_LUMA}")
    t = np.asarray(detail.texels)
    if t.ndim != 3 or t.shape[2] != 3 or t.dtype != np.uint16:
        raise ValueError("detail texels must be (h, w, 3) uint16")
    if not 1 <= int(detail.quality) <= 100:
        raise ValueError(f"detail quality {detail.quality} not in 1..100")
    frame = quantize_frame(detail.frame, n_regions).reshape(n_regions, 3, 2) / FRAME_SCALE
    return Detail(payload=payload_bands(detail.payload), texels=t, frame=frame,
                  mode=mode.astype(np.uint8), quality=int(detail.quality))


def payload_bands(payload) -> tuple[bytes, ...]:
    """A detail payload as stored: its AVIF files as a tuple (one ``bytes`` object is one file),
    1..:data:`MAX_BANDS` of them (ValueError otherwise)."""
    bands = (payload,) if isinstance(payload, (bytes, bytearray, memoryview)) else tuple(payload)
    if not (len(bands) == 1 or (3 <= len(bands) <= MAX_BANDS and len(bands) % 3 == 0)) \
            or not all(isinstance(b, (bytes, bytearray, memoryview)) for b in bands):
        raise ValueError(f"detail payload must be 1 AVIF file, or 3 n (at most {MAX_BANDS}), as bytes")
    return tuple(bytes(b) for b in bands)


def file_sizes(width: int, height: int, files: int) -> list[tuple[int, int]]:
    """``(columns, rows)`` of each AVIF file of a ``width x height`` texture in ``files`` files
    (:func:`decode_texels`' layouts; TpsvFormatError for a count that is neither 1 nor 3 bands)."""
    if files % 3 and files != 1:
        raise TpsvFormatError(f"section detail: image in {files} files, not 3 planes' bands")
    if files == 1:
        rows, cols = image_shape(width, height)
        return [(cols, rows)]
    return [(width, b - a) for _ in range(3) for a, b in band_rows(height, files // 3)]


def pack_section(detail: Detail, n_regions: int) -> bytes:
    """The raw detail section of ``detail`` (already :func:`quantize`-d or not): its images as
    AV1 bitstreams (codec ``"av1"``) when every AVIF file is the standard wrapping of one
    (:func:`tpsv.codec.avif.unwrap`), else as the AVIF files."""
    h, w = detail.texels.shape[:2]
    bands = payload_bands(detail.payload)
    bare = [avif.unwrap(f, c, r) for f, (c, r) in zip(bands, file_sizes(w, h, len(bands)))]
    codec, image = (CODEC, bands) if any(b is None for b in bare) else (CODEC_AV1, bare)
    return _packb({
        "codec": codec, "width": int(w), "height": int(h), "quality": int(detail.quality),
        "frame": quantize_frame(detail.frame, n_regions).astype("<i4").tobytes(),
        "mode": np.asarray(detail.mode, np.uint8).tobytes(),
        # one band is stored as before version 8
        "image": image[0] if len(image) == 1 else list(image),
    })


def unpack_section(raw: bytes, h: layout.Header) -> Detail:
    """The detail layer of a raw detail section, every field checked (TpsvFormatError)."""
    name = "detail"
    obj = _expect_map(sections.unpack(raw, name), KEYS, name)
    bare = h.version >= layout.AV1_DETAIL_SINCE and obj["codec"] == CODEC_AV1
    if obj["codec"] != CODEC and not bare:
        raise TpsvFormatError(f"section detail: unknown codec {obj['codec']!r}")
    w = _expect_int(obj, "width", 1, h.width, name)
    hh = _expect_int(obj, "height", 1, h.height, name)
    quality = _expect_int(obj, "quality", 1, 100, name)
    R = h.regions
    frame = np.frombuffer(_expect_bin(obj, "frame", 24 * R, name), "<i4").astype(np.float64)
    mode = np.frombuffer(_expect_bin(obj, "mode", R, name), np.uint8).copy()
    if mode.max(initial=0) > DETAIL_LUMA:
        raise TpsvFormatError(f"section detail: region mode {int(mode.max())} not in 0..{DETAIL_LUMA}")
    image = obj["image"]
    banded = h.version >= layout.BANDED_DETAIL_SINCE
    if isinstance(image, list) and banded:
        if not 3 <= len(image) <= MAX_BANDS or not all(isinstance(b, bytes) for b in image):
            raise TpsvFormatError(f"section detail: image is not an array of 3..{MAX_BANDS} bins")
        image = tuple(image)
    elif isinstance(image, bytes):
        image = (image,)
    else:
        raise TpsvFormatError("section detail: image is not a bin" + (" or an array of bins" if banded else ""))
    if bare:
        image = tuple(avif.wrap(b, c, r) for b, (c, r) in zip(image, file_sizes(w, hh, len(image))))
    texels = decode_texels(image, w, hh)
    return Detail(payload=image, texels=texels, frame=frame.reshape(R, 3, 2) / FRAME_SCALE, mode=mode,
                  quality=quality)
