"""Fixed header of a .tpsv file, and the limits a decoder enforces.

Everything here is specified byte for byte in ``docs/FORMAT.md``; keep both in
step.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from ..errors import TpsvError, TpsvFormatError

#: The first 8 bytes of every .tpsv file. ``\r\n`` and the trailing ``\n``
#: catch CRLF <-> LF conversion by text-mode transfers (as in PNG); ``\x1a``
#: stops ``type`` on Windows from printing binary garbage.
MAGIC = b"TPSV\r\n\x1a\n"

#: The newest format version this code reads and the one it writes.
VERSION = 9
#: From this version on no outline polygon crosses itself (a file with one is refused);
#: older files are mended as they are read (docs/FORMAT.md, Versions).
SIMPLE_OUTLINES_SINCE = 6
#: From this version on the detail section's image may be cut into bands of rows (docs/FORMAT.md, detail).
BANDED_DETAIL_SINCE = 8
#: From this version on the detail section's images may be bare AV1 bitstreams (codec ``"av1"``).
AV1_DETAIL_SINCE = 9
#: Header flag (version 3): a detail section follows the features section,
#: preceded by its compressed and raw sizes (two little-endian uint32).
FLAG_DETAIL = 1
#: Header flag (version 4): some regions are transparent (the regions section's ``alpha``).
FLAG_ALPHA = 2
#: Header flag (version 6): outlines are drawn as curves through their vertices (``Model.curves``).
FLAG_CURVES = 4
#: Header flag (version 7): the regions section holds a blur map (``Model.blur_map``: ``map_cell``, ``map``).
FLAG_BLUR_MAP = 8
#: Largest cell side (px) of a blur map.
MAX_MAP_CELL = 64
DETAIL_SIZES = struct.Struct("<II")

#: Little-endian header: magic, version, flags, width, height, 5 counts,
#: 3 (compressed, raw) section sizes, payload CRC-32, header CRC-32.
HEADER = struct.Struct("<8sHHIIIIIII6III")
HEADER_SIZE = HEADER.size  # 72

#: Offset of the header CRC-32, which covers every header byte before it.
HEADER_CRC_OFFSET = HEADER_SIZE - 4

#: Section names, in file order.
SECTIONS = ("params", "regions", "features")

# Limits, checked before anything is allocated from a declared size. They are
# budgets as well as sanity checks: each is set so that the largest file the
# decoder accepts can be decoded, rendered and edited by every tpsv command in
# bounded memory (peak RSS under 1 GB) and time; docs/FORMAT.md ("Limits")
# gives the measurement behind each.
MAX_FILE_BYTES = 256 * 2**20
#: Canvas side, and canvas pixels: tpsv reads photos of at most 40 Mpx
#: (``tpsv.image.MAX_PIXELS``) and a model is as large as its photo.
MAX_SIDE = 65535
MAX_PIXELS = 2**26
#: Render time is about 0.6-2.5 ms per region whatever the output size.
MAX_REGIONS = 4096
#: Outer boundaries plus holes; a traced hole holds at least one other region.
MAX_POLYGONS = 2 * MAX_REGIONS
MAX_VERTICES = 2**19
MAX_POLYGON_VERTICES = 2**18
MAX_CTRL_POINTS = 2**18
#: Render and the edits keep several arrays per feature (stylize: ~600 bytes).
MAX_FEATURES = 2**20
MIN_GRID = 2
MAX_GRID = 256
#: Features per TPS kernel the renderer compiles a Warp solve kernel for (each
#: new value costs a compilation, ~10 s on CUDA, written to the user's kernel cache):
#: ``tpsv vectorize`` writes 32 (64 with ``--plain``), magnify 32. The renderer
#: and the CLI take their choices from here.
SUPPORTED_KERNEL_SIZES = (8, 16, 32, 64, 128)
MAX_PARAMS_RAW = 2**20
#: Largest zstd window the decoder accepts (level 19 uses at most 8 MiB).
MAX_WINDOW = 2**27

#: Generous allowance for msgpack map headers, keys and bin headers per section.
SECTION_OVERHEAD = 256


class FormatLimitError(TpsvError, ValueError):
    """A model too large for the format, or with a ``kernel_size`` it does not support.

    Raised by the encoder. A ``ValueError`` as the encoder documents, and a
    ``TpsvError`` because it is the user's data (a photo too large, an option
    value) rather than a program error: the CLI shows it as one line.
    """


@dataclass(frozen=True)
class Header:
    """The fixed 72-byte header, minus magic and checksums.

    Attributes
    ----------
    version, flags : int
    width, height : int
        Image size in pixels.
    regions, polygons, vertices, ctrl_points, features : int
        Counts: regions, outline polygons (all regions), outline vertices (all
        polygons), control points (sum of ``M * N``), features.
    compressed, raw : tuple of 3 int
        Per section (``SECTIONS`` order): bytes in the file, and bytes after
        zstd decompression.
    """

    version: int
    flags: int
    width: int
    height: int
    regions: int
    polygons: int
    vertices: int
    ctrl_points: int
    features: int
    compressed: tuple[int, int, int]
    raw: tuple[int, int, int]
    #: (compressed, raw) size of the detail section; (0, 0) without one.
    detail: tuple[int, int] = (0, 0)

    @property
    def has_detail(self) -> bool:
        return bool(self.flags & FLAG_DETAIL)

    @property
    def has_alpha(self) -> bool:
        return bool(self.flags & FLAG_ALPHA)

    @property
    def has_curves(self) -> bool:
        return bool(self.flags & FLAG_CURVES)

    @property
    def has_blur_map(self) -> bool:
        return bool(self.flags & FLAG_BLUR_MAP)

    @property
    def detail_offset(self) -> int:
        """Where the detail section's sizes start (after the three sections)."""
        return HEADER_SIZE + sum(self.compressed)

    @property
    def file_size(self) -> int:
        """Total file size the header declares (with the detail section's, when flagged)."""
        extra = DETAIL_SIZES.size + self.detail[0] if self.has_detail else 0
        return HEADER_SIZE + sum(self.compressed) + extra


def pack_header(h: Header, payload_crc: int) -> bytes:
    """The 72 header bytes for ``h``, both checksums filled in."""
    sizes = [v for pair in zip(h.compressed, h.raw) for v in pair]
    body = HEADER.pack(
        MAGIC, h.version, h.flags, h.width, h.height, h.regions, h.polygons,
        h.vertices, h.ctrl_points, h.features, *sizes, payload_crc, 0,
    )[:HEADER_CRC_OFFSET]
    return body + struct.pack("<I", zlib.crc32(body))


def raw_size_bounds(h: Header) -> tuple[int, int, int]:
    """Largest raw size each section may declare, given the header counts.

    Every array in a section has a fixed width per item, so the counts bound
    the raw size; a declared size above the bound is a zstd bomb or a lie.
    """
    params = MAX_PARAMS_RAW
    regions = (
        SECTION_OVERHEAD
        + 9 * h.regions  # label: msgpack int, at most 9 bytes each
        + 2 * h.regions  # grid: M-1, N-1 as uint8
        + 4 * h.regions  # polygons per region
        + 32 * h.ctrl_points  # 4 vectors x 2 coordinates x 32-bit
    )
    if h.version >= 2:
        # chains (K <= V): count, vertices per chain, references per polygon,
        # references (at most V), and at most V + K vertices of x, y
        regions += 9 + 4 * h.vertices + 4 * h.polygons + 4 * h.vertices + 16 * h.vertices
        regions += 9 + 9 * h.vertices  # edge widths: count, then at most V pairs of 9 bytes
    else:
        regions += 4 * h.polygons + 8 * h.vertices  # vertices per polygon, x, y as 32-bit
    if h.has_alpha:
        regions += 16 + (h.regions + 7) // 8  # key, bin header, a bit per region
    if h.has_blur_map:
        regions += 32 + (h.width // 2 + 1) * (h.height // 2 + 1)  # keys, cell side, a byte per cell of side >= 2
    features = SECTION_OVERHEAD + 4 * h.regions + 12 * h.features
    return params, regions, features


def detail_raw_bound(h: Header) -> int:
    """Largest raw detail section the header counts allow: frames and modes
    per region, and a texture at most the canvas whose AVIF file is at most
    what lossless 10-bit coding of noise takes (under 4 bytes a pixel)."""
    return SECTION_OVERHEAD + 25 * h.regions + 8 * h.width * h.height + 65536


def known_flags(version: int) -> int:
    """The header flags ``version`` defines."""
    return (FLAG_DETAIL if version >= 3 else 0) | (FLAG_ALPHA if version >= 4 else 0) | (FLAG_CURVES if version >= 6 else 0) \
        | (FLAG_BLUR_MAP if version >= 7 else 0)


def parse_header(data: bytes | memoryview) -> Header:
    """Read and check the header of a whole .tpsv file.

    Checks, in order: file size cap, magic, version, header length, header
    checksum, flags, size and count limits, declared file length. The payload
    checksum and the sections are checked by the caller.

    Raises
    ------
    TpsvFormatError
        What is wrong, in one line.
    """
    n = len(data)
    if n > MAX_FILE_BYTES:
        raise TpsvFormatError(f"file too large: {n} bytes (limit {MAX_FILE_BYTES})")
    if n == 0:
        raise TpsvFormatError("empty file: not a .tpsv file")
    head = bytes(data[: len(MAGIC)])
    if head != MAGIC[: len(head)]:
        if head[:4] == MAGIC[:4]:
            raise TpsvFormatError(
                "bad magic: bytes 4-7 are altered (was the file sent in text mode?)"
            )
        raise TpsvFormatError("bad magic: not a .tpsv file")
    if n >= len(MAGIC) + 2:
        # Read the version before demanding a whole v1 header: a future
        # version may have a different header, and deserves the clear message.
        (version,) = struct.unpack_from("<H", data, len(MAGIC))
        if not 1 <= version <= VERSION:
            raise TpsvFormatError(
                f"unsupported format version {version} (this tpsv reads up to {VERSION})"
            )
    if n < HEADER_SIZE:
        raise TpsvFormatError(
            f"truncated file: header needs {HEADER_SIZE} bytes, got {n}"
        )
    fields = HEADER.unpack_from(data, 0)
    (_, version, flags, width, height, regions, polygons, vertices, ctrl_points,
     features, c0, r0, c1, r1, c2, r2, _payload_crc, header_crc) = fields
    if zlib.crc32(data[:HEADER_CRC_OFFSET]) != header_crc:
        raise TpsvFormatError("corrupt header: header checksum mismatch")
    known = known_flags(version)
    if flags & ~known:
        raise TpsvFormatError(f"unsupported flags 0x{flags:04x} (version {version} defines 0x{known:04x})")
    h = Header(version, flags, width, height, regions, polygons, vertices,
               ctrl_points, features, (c0, c1, c2), (r0, r1, r2))
    check_header_limits(h)
    if h.has_detail:
        at = h.detail_offset
        if n < at + DETAIL_SIZES.size:
            raise TpsvFormatError(f"truncated file: the detail section's sizes need {at + DETAIL_SIZES.size} bytes, got {n}")
        dc, dr = DETAIL_SIZES.unpack_from(data, at)
        if dc == 0:
            raise TpsvFormatError("section detail: empty (a zstd frame is required)")
        bound = detail_raw_bound(h)
        if dr > bound:
            raise TpsvFormatError(f"section detail: declared size {dr} exceeds the bound {bound} for the header counts")
        h = Header(version, flags, width, height, regions, polygons, vertices,
                   ctrl_points, features, (c0, c1, c2), (r0, r1, r2), (dc, dr))
    if n < h.file_size:
        raise TpsvFormatError(
            f"truncated file: header declares {h.file_size} bytes, got {n}"
        )
    if n > h.file_size:
        raise TpsvFormatError(
            f"trailing data: header declares {h.file_size} bytes, got {n}"
        )
    return h


def check_size_limits(h: Header, error=TpsvFormatError, prefix: str = "bad header: ") -> None:
    """Raise ``error`` when the canvas or a count in ``h`` is beyond the limits (not below them)."""
    for name, value in (("width", h.width), ("height", h.height)):
        if value > MAX_SIDE:
            raise error(f"{prefix}{name} {value} not in 1..{MAX_SIDE}")
    if h.width * h.height > MAX_PIXELS:
        raise error(f"{prefix}{h.width}x{h.height} exceeds {MAX_PIXELS} pixels")
    limits = (
        ("regions", h.regions, MAX_REGIONS),
        ("polygons", h.polygons, MAX_POLYGONS),
        ("vertices", h.vertices, MAX_VERTICES),
        ("control points", h.ctrl_points, MAX_CTRL_POINTS),
        ("features", h.features, MAX_FEATURES),
    )
    for name, value, limit in limits:
        if value > limit:
            raise error(f"{prefix}{value} {name} exceed the limit {limit}")


def check_header_limits(h: Header) -> None:
    """Raise TpsvFormatError when a size or count in ``h`` is out of range."""
    for name, value in (("width", h.width), ("height", h.height)):
        if not 1 <= value <= MAX_SIDE:
            raise TpsvFormatError(f"bad header: {name} {value} not in 1..{MAX_SIDE}")
    check_size_limits(h)
    # Cross-count rules that hold for every valid model; checking them here
    # keeps the raw-size bounds tight.
    if h.polygons < h.regions:
        raise TpsvFormatError(
            f"bad header: {h.polygons} polygons for {h.regions} regions (each needs one)"
        )
    if h.vertices < 3 * h.polygons:
        raise TpsvFormatError(
            f"bad header: {h.vertices} vertices for {h.polygons} polygons (each needs 3)"
        )
    if h.ctrl_points < MIN_GRID**2 * h.regions or h.ctrl_points > MAX_GRID**2 * h.regions:
        raise TpsvFormatError(
            f"bad header: {h.ctrl_points} control points for {h.regions} regions"
        )
    if h.features and not h.regions:
        raise TpsvFormatError(f"bad header: {h.features} features but no regions")
    for name, raw, comp, bound in zip(SECTIONS, h.raw, h.compressed, raw_size_bounds(h)):
        if raw > bound:
            raise TpsvFormatError(
                f"section {name}: declared size {raw} exceeds the bound {bound} "
                "for the header counts"
            )
        if comp == 0:
            raise TpsvFormatError(f"section {name}: empty (a zstd frame is required)")
    # No compression-ratio rule: a smooth control grid compresses thousands of
    # times, and the count limits already bound what any file inflates to
    # (sum of raw_size_bounds at the limits: about 25 MiB).
