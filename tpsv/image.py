"""Reading and writing raster images and label maps, safely and with clear errors.

Reading has two steps. :func:`read_header` identifies the format by its magic
bytes and reads the size, bit depth, channels, frame count and (JPEG) EXIF
orientation in pure Python, so every budget is checked before OpenCV sees the
data: a 2 KB PNG declaring 60000x60000 pixels is refused at once instead of
after gigabytes of allocation. Only then OpenCV decodes, with its own log and
the C libraries' messages (libpng, libjpeg) kept off stderr for the call, so a
failure reaches the user as one line.

Formats read: PNG, JPEG, WebP, TIFF (classic and BigTIFF), BMP and PNM
(P1-P6). Others are refused by name even where OpenCV could decode them
(GIF, AVIF, JPEG 2000, ...): each extra decoder is attack surface, and the
budgets need a header this module can read. Multi-frame files (animated PNG or
WebP, multi-page TIFF) give their first frame. Photos are 8-bit, or 16-bit PNG
and TIFF (read without losing precision: :func:`read_image`).

Formats written (:func:`output_format`, :func:`encode_image`): PNG (8- or
16-bit), JPEG, WebP and TIFF (8- or 16-bit), chosen by the file's extension.

Budgets
-------
``MAX_PIXELS`` (40 Mpx)
    Admits a 24 Mpx (6000x4000) camera photo with margin; the pipeline's
    memory grows with pixels, so larger inputs are likely mistakes or attacks.
``MAX_SIDE`` (65535 px)
    The largest side a .tpsv file can store (and within OpenCV's own limit).
``MAX_FILE_BYTES`` (512 MiB)
    Bounds the read; every legitimate file within ``MAX_PIXELS`` (even an
    uncompressed 16-bit TIFF or a plain-text PNM) is smaller.
"""

from __future__ import annotations

import os
import re
import struct
import zlib
from dataclasses import dataclass

import cv2
import numpy as np

from .codec.layout import MAX_SIDE
from .errors import TpsvError
from .fileio import display, read_bytes, write_bytes_atomic
from .quiet import quiet_stderr

#: Largest raster we accept (pixels): a 24 Mpx camera photo fits with margin.
MAX_PIXELS = 40_000_000
#: Largest image file we read (bytes).
MAX_FILE_BYTES = 512 * 1024 * 1024
#: The formats :func:`read_header` understands, as named in messages.
FORMATS = ("PNG", "JPEG", "WebP", "TIFF", "BMP", "PNM")

# Header walks stop after this many chunks/markers/IFDs: real files need a few
# dozen, and a hostile file of millions of tiny chunks must not cost seconds.
_MAX_WALK = 1000


@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header says, read without decoding pixels.

    Attributes
    ----------
    format : str
        One of :data:`FORMATS`.
    width, height : int
        Stored size in pixels (before EXIF orientation).
    bit_depth : int
        Bits per sample (PNG bit depth, JPEG precision, largest TIFF
        BitsPerSample, 8 or 16 for PNM by its maximum value, 8 for BMP and WebP).
    channels : int or None
        Samples per pixel after palette expansion, where the header says it.
    sample_format : str
        ``"uint"``, ``"int"`` or ``"float"`` (TIFF SampleFormat; ``"uint"`` elsewhere).
    palette : bool
        Pixels are palette indices (PNG colour type 3, BMP of <= 8 bits).
    frames : int
        Frame or page count where cheap to find (APNG acTL, animated WebP ANMF
        chunks, TIFF IFD chain); 1 otherwise.
    orientation : int
        EXIF orientation 1..8 of a JPEG (1, upright, elsewhere or when absent).
    truncated : bool
        The data visibly ends early (a JPEG with no end marker after its scan).
    """

    format: str
    width: int
    height: int
    bit_depth: int = 8
    channels: int | None = None
    sample_format: str = "uint"
    palette: bool = False
    frames: int = 1
    orientation: int = 1
    truncated: bool = False

    @property
    def upright_size(self) -> tuple[int, int]:
        """``(width, height)`` as displayed, after EXIF orientation."""
        if self.orientation >= 5:  # orientations 5..8 swap the axes
            return self.height, self.width
        return self.width, self.height


class _Corrupt(Exception):
    """A truncated or inconsistent header; :func:`read_header` adds path and format."""


def _unpack(fmt: str, data: bytes, offset: int) -> tuple:
    # struct.error (short data) and negative offsets both mean a broken header.
    if offset < 0:
        raise _Corrupt
    try:
        return struct.unpack_from(fmt, data, offset)
    except struct.error:
        raise _Corrupt from None


# --------------------------------------------------------------------------- PNG

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Allowed bit depths and channels (after palette expansion) of each colour type.
_PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}


def _png_header(data: bytes) -> ImageHeader:
    length, kind = _unpack(">I4s", data, 8)
    if kind != b"IHDR" or length != 13:
        raise _Corrupt
    width, height, depth, colour, compression, filtering, interlace = _unpack(">IIBBBBB", data, 16)
    (crc,) = _unpack(">I", data, 29)
    if crc != zlib.crc32(data[12:29]):
        raise _Corrupt
    if depth not in _PNG_DEPTHS.get(colour, ()) or compression or filtering or interlace > 1:
        raise _Corrupt
    if not (0 < width < 2**31 and 0 < height < 2**31):
        raise _Corrupt
    return ImageHeader("PNG", width, height, depth, _PNG_CHANNELS[colour], palette=colour == 3,
                       frames=_png_frames(data))


def _png_frames(data: bytes) -> int:
    """Frame count of an APNG (acTL comes before the first IDAT), else 1."""
    pos = 33
    for _ in range(_MAX_WALK):
        if pos + 8 > len(data):
            break
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind == b"acTL" and length >= 4 and pos + 12 <= len(data):
            return max(1, struct.unpack_from(">I", data, pos + 8)[0])
        if kind in (b"IDAT", b"IEND"):
            break
        pos += 12 + length
    return 1


# --------------------------------------------------------------------------- JPEG

# Start-of-frame markers (all coding processes); C4 DHT, C8 JPG and CC DAC are not.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# Markers without a length field.
_JPEG_STANDALONE = frozenset([0x01, *range(0xD0, 0xD8)])


def _jpeg_segments(data: bytes, pos: int):
    """Yield ``(marker, payload offset, payload length)`` from ``pos`` up to SOS."""
    for _ in range(_MAX_WALK):
        if data[pos] != 0xFF:
            raise _Corrupt
        while data[pos] == 0xFF:  # fill bytes may precede a marker
            pos += 1
        marker = data[pos]
        pos += 1
        if marker in _JPEG_STANDALONE:
            continue
        if marker in (0xD8, 0xD9):  # SOI or EOI before the scan
            raise _Corrupt
        (length,) = _unpack(">H", data, pos)
        if length < 2 or pos + length > len(data):
            raise _Corrupt
        yield marker, pos + 2, length - 2
        if marker == 0xDA:
            return
        pos += length
    raise _Corrupt


def _jpeg_header(data: bytes) -> ImageHeader:
    orientation, frame = 1, None
    try:
        for marker, at, size in _jpeg_segments(data, 2):
            if marker == 0xE1 and frame is None and data[at:at + 6] == b"Exif\0\0":
                orientation = _exif_orientation(data[at + 6:at + size])
            elif marker in _JPEG_SOF and frame is None:
                if size < 6:
                    raise _Corrupt
                frame = _unpack(">BHHB", data, at)
            elif marker == 0xDA:
                if frame is None:  # a scan before any frame header
                    raise _Corrupt
                # Entropy-coded data never holds FF D9 (FF is stuffed), so a
                # missing end marker after the scan means a truncated file.
                truncated = data.find(b"\xff\xd9", at + size) < 0
                break
        else:
            raise _Corrupt  # no scan at all
    except IndexError:
        raise _Corrupt from None
    precision, height, width, components = frame
    if width == 0 or height == 0 or components not in (1, 3, 4) or precision not in (8, 12, 16):
        raise _Corrupt  # height 0 (size given later by DNL) is not supported by the decoder either
    return ImageHeader("JPEG", width, height, precision, 3 if components > 1 else 1,
                       orientation=orientation, truncated=truncated)


def _exif_orientation(tiff: bytes) -> int:
    """Orientation tag of EXIF IFD0; 1 when absent or unreadable.

    A broken EXIF block is common in real photos and does not stop decoding,
    so it never makes the image unreadable here either.
    """
    try:
        order, ifd0, big = _tiff_start(tiff)
        tags, _ = _tiff_ifd(tiff, order, ifd0, big)
    except _Corrupt:
        return 1
    value = tags.get(0x0112, (1,))[0]
    return value if 1 <= value <= 8 else 1


# --------------------------------------------------------------------------- TIFF

_TIFF_MAGIC = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")
# struct codes of the integer field types (BYTE, SHORT, LONG, LONG8 and signed).
_TIFF_INT = {1: "B", 3: "H", 4: "I", 16: "Q", 6: "b", 8: "h", 9: "i", 17: "q"}
# Tags read: size, BitsPerSample, SamplesPerPixel, SampleFormat, Orientation, tile size.
_TIFF_TAGS = frozenset([256, 257, 258, 277, 339, 0x0112, 322, 323])


def _tiff_start(data: bytes) -> tuple[str, int, bool]:
    """Byte order, offset of IFD0 and whether the file is a BigTIFF."""
    order = {b"II": "<", b"MM": ">"}.get(data[:2])
    if order is None:
        raise _Corrupt
    (version,) = _unpack(order + "H", data, 2)
    if version == 42:
        return order, _unpack(order + "I", data, 4)[0], False
    if version == 43 and _unpack(order + "HH", data, 4) == (8, 0):
        return order, _unpack(order + "Q", data, 8)[0], True
    raise _Corrupt


def _tiff_ifd(data: bytes, order: str, offset: int, big: bool) -> tuple[dict[int, tuple[int, ...]], int]:
    """Integer values of the wanted tags of the IFD at ``offset``, and the next IFD's offset."""
    count_fmt, long_fmt, entry_size, inline = ("Q", "Q", 20, 8) if big else ("H", "I", 12, 4)
    (n,) = _unpack(order + count_fmt, data, offset)
    if n == 0 or n > 4096:
        raise _Corrupt
    first = offset + (8 if big else 2)
    tags = {}
    for e in range(first, first + n * entry_size, entry_size):
        tag, kind = _unpack(order + "HH", data, e)
        (count,) = _unpack(order + long_fmt, data, e + 4)
        code = _TIFF_INT.get(kind)
        if tag not in _TIFF_TAGS or code is None:
            continue
        if not 1 <= count <= 64:  # per-sample tags; more samples than this is hostile
            raise _Corrupt
        at = e + 4 + inline
        if count * struct.calcsize(code) > inline:  # values stored elsewhere
            (at,) = _unpack(order + long_fmt, data, at)
        tags[tag] = _unpack(f"{order}{count}{code}", data, at)
    (next_ifd,) = _unpack(order + long_fmt, data, first + n * entry_size)
    return tags, next_ifd


def _tiff_header(data: bytes) -> ImageHeader:
    order, ifd0, big = _tiff_start(data)
    tags, next_ifd = _tiff_ifd(data, order, ifd0, big)
    if 256 not in tags or 257 not in tags:
        raise _Corrupt
    width, height = tags[256][0], tags[257][0]
    bits = max(tags.get(258, (1,)))
    samples = tags.get(277, (1,))[0]
    formats = set(tags.get(339, (1,)))
    tile = tags.get(322, (0,))[0] * tags.get(323, (0,))[0]
    if width <= 0 or height <= 0 or bits <= 0 or samples <= 0 or tile < 0 or tile > MAX_PIXELS:
        raise _Corrupt
    sample_format = "float" if 3 in formats else "int" if 2 in formats else "uint"
    return ImageHeader("TIFF", width, height, bits, samples, sample_format,
                       frames=_tiff_frames(data, order, next_ifd, big))


def _tiff_frames(data: bytes, order: str, offset: int, big: bool) -> int:
    """Pages counted along the IFD chain (cycles and broken links end the count)."""
    seen, frames = set(), 1
    while offset and offset not in seen and len(seen) < _MAX_WALK:
        seen.add(offset)
        try:
            _, offset = _tiff_ifd(data, order, offset, big)
        except _Corrupt:
            break  # only page 1 is decoded; a broken later page does not matter
        frames += 1
    return frames


# --------------------------------------------------------------------------- WebP


def _webp_header(data: bytes) -> ImageHeader:
    kind, size = _unpack("<4sI", data, 12)
    if kind == b"VP8 ":
        tag, start, width, height = _unpack("<3s3sHH", data, 20)
        if tag[0] & 1 or start != b"\x9d\x01\x2a":  # must be a key frame
            raise _Corrupt
        width, height, channels, frames = width & 0x3FFF, height & 0x3FFF, 3, 1
    elif kind == b"VP8L":
        signature, bits = _unpack("<BI", data, 20)
        if signature != 0x2F or bits >> 29:  # version must be 0
            raise _Corrupt
        width, height = (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
        channels, frames = 4 if bits >> 28 & 1 else 3, 1
    elif kind == b"VP8X":
        flags, w3, h3 = _unpack("<B3x3s3s", data, 20)
        if size < 10:
            raise _Corrupt
        width = 1 + int.from_bytes(w3, "little")
        height = 1 + int.from_bytes(h3, "little")
        channels = 4 if flags & 0x10 else 3
        frames = _webp_frames(data, 20 + size + (size & 1)) if flags & 0x02 else 1
    else:
        raise _Corrupt
    if width == 0 or height == 0:
        raise _Corrupt
    return ImageHeader("WebP", width, height, 8, channels, frames=frames)


def _webp_frames(data: bytes, pos: int) -> int:
    """ANMF chunks counted from ``pos`` (at least 1)."""
    frames = 0
    for _ in range(_MAX_WALK):
        if pos + 8 > len(data):
            break
        kind, size = struct.unpack_from("<4sI", data, pos)
        frames += kind == b"ANMF"
        pos += 8 + size + (size & 1)  # chunks are padded to even length
    return max(frames, 1)


# --------------------------------------------------------------------------- BMP and PNM


def _bmp_header(data: bytes) -> ImageHeader:
    (dib,) = _unpack("<I", data, 14)
    if dib == 12:  # OS/2 BITMAPCOREHEADER: 16-bit unsigned sizes
        width, height, planes, bpp = _unpack("<HHHH", data, 18)
    elif dib in (16, 40, 52, 56, 64, 108, 124):
        width, height, planes, bpp = _unpack("<iiHH", data, 18)
        height = abs(height)  # negative: rows stored top-down
    else:
        raise _Corrupt
    if width <= 0 or height == 0 or planes != 1 or bpp not in (1, 4, 8, 16, 24, 32):
        raise _Corrupt
    return ImageHeader("BMP", width, height, 8, 4 if bpp == 32 else 3, palette=bpp <= 8)


# Whitespace and comments, then one decimal number (PNM header fields).
_PNM_FIELD = re.compile(rb"(?:\s|#[^\r\n]*[\r\n])+(\d{1,10})")


def _pnm_header(data: bytes) -> ImageHeader:
    kind = data[1] - ord("0")
    bitmap = kind in (1, 4)
    fields, pos = [], 2
    for _ in range(2 if bitmap else 3):
        m = _PNM_FIELD.match(data, pos, pos + 4096)  # comments are short in real files
        if m is None:
            raise _Corrupt
        fields.append(int(m.group(1)))
        pos = m.end()
    if pos >= len(data) or not data[pos:pos + 1].isspace():
        raise _Corrupt  # one whitespace byte separates the header from the raster
    width, height = fields[:2]
    maxval = 1 if bitmap else fields[2]
    if width == 0 or height == 0 or not 0 < maxval < 65536:
        raise _Corrupt
    depth = 1 if bitmap else 8 if maxval < 256 else 16
    return ImageHeader("PNM", width, height, depth, 3 if kind in (3, 6) else 1)


# --------------------------------------------------------------------------- header entry point


def _sniff(data: bytes) -> str | None:
    """Format named by the magic bytes, or None."""
    if data.startswith(_PNG_SIGNATURE):
        return "PNG"
    if data.startswith(b"\xff\xd8"):
        return "JPEG"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "WebP"
    if data[:4] in _TIFF_MAGIC:
        return "TIFF"
    if data.startswith(b"BM"):
        return "BMP"
    if re.match(rb"P[1-6][\s#]", data[:3]):
        return "PNM"
    return None


_READERS = {"PNG": _png_header, "JPEG": _jpeg_header, "WebP": _webp_header,
            "TIFF": _tiff_header, "BMP": _bmp_header, "PNM": _pnm_header}


def read_header(data: bytes, path: str | os.PathLike = "-") -> ImageHeader:
    """Read an image file's header without decoding any pixel.

    Parameters
    ----------
    data : bytes
        The file's content (or at least its header).
    path : str or path-like
        Name used in error messages.

    Returns
    -------
    header : ImageHeader

    Raises
    ------
    TpsvError
        "PATH: unsupported image format; ..." for anything but PNG, JPEG, WebP,
        TIFF, BMP and PNM; "PATH: truncated or corrupt FORMAT header" for a
        header that ends early or contradicts itself (including zero sizes).
    """
    fmt = _sniff(data)
    if fmt is None:
        raise TpsvError(f"{path}: unsupported image format; tpsv reads PNG, JPEG, WebP, TIFF, BMP and PNM")
    try:
        return _READERS[fmt](data)
    except (_Corrupt, IndexError):
        raise TpsvError(f"{path}: truncated or corrupt {fmt} header") from None


# --------------------------------------------------------------------------- budgets and decoding


def _check_budget(header: ImageHeader, path) -> None:
    """Refuse, from the header alone, what is too large or of a sample type we do not read."""
    width, height = header.upright_size
    if width * height > MAX_PIXELS:
        raise TpsvError(f"{path} is {width}x{height} px; tpsv accepts at most {MAX_PIXELS} px")
    if max(width, height) > MAX_SIDE:
        raise TpsvError(f"{path} is {width}x{height} px; tpsv accepts at most {MAX_SIDE} px per side")
    if header.sample_format == "float":
        raise TpsvError(f"{path}: {header.bit_depth}-bit floating-point image; "
                        "tpsv reads 8- and 16-bit integer images only")
    if header.sample_format == "int":
        raise TpsvError(f"{path}: {header.bit_depth}-bit signed image; tpsv reads 8- and 16-bit unsigned images only")
    if header.bit_depth > 16:
        raise TpsvError(f"{path}: {header.bit_depth}-bit image; tpsv reads 8- and 16-bit images only")


def _upright(img: np.ndarray, orientation: int) -> np.ndarray:
    """Apply EXIF orientation 2..8 (flip and/or rotate) to a decoded array."""
    ops = {
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: a.swapaxes(0, 1),
        6: lambda a: np.rot90(a, -1),
        7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
        8: lambda a: np.rot90(a, 1),
    }
    if orientation not in ops:
        return img
    return np.ascontiguousarray(ops[orientation](img))


def _read_file(path: str | os.PathLike) -> bytes:
    try:
        data = read_bytes(path, limit=MAX_FILE_BYTES)
    except OSError as exc:
        raise TpsvError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise TpsvError(f"{path}: empty file")
    return data


def _open(path: str | os.PathLike) -> tuple[bytes, ImageHeader]:
    """The file's bytes and its header, checked against the budgets."""
    data = _read_file(path)
    header = read_header(data, path)
    _check_budget(header, path)
    return data, header


def _decode(data: bytes, header: ImageHeader, path, flags: int) -> np.ndarray:
    """Decode quietly with OpenCV and put upright; one line for any failure."""
    if header.truncated:
        raise TpsvError(f"{path}: truncated or corrupt {header.format} data")
    with quiet_stderr():
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
        except cv2.error:
            img = None
    # A decoder that disagrees with the header read something else than we checked.
    if img is None or img.shape[:2] != (header.height, header.width):
        raise TpsvError(f"{path}: truncated or corrupt {header.format} data")
    return _upright(img, header.orientation)


#: Formats whose 16-bit samples :func:`read_image` reads (OpenCV 5 swaps the
#: bytes of 16-bit PNM; 12-bit JPEG is rare and decodes to another range).
DEEP_FORMATS = ("PNG", "TIFF")


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an opaque grey or RGB photo: 8-bit, or 16-bit PNG and TIFF.

    The header is read first and checked (size at most :data:`MAX_PIXELS`,
    8 bits per sample, or 16 for PNG and TIFF) before any pixel is decoded.
    Palette and CMYK images come back as RGB, a JPEG's EXIF orientation is
    applied, and of a multi-frame file (animated PNG or WebP, multi-page TIFF)
    the first frame is read.

    Sample values ``v`` become ``v / 255`` (8-bit) or ``v / 65535`` (16-bit)
    in float32, so a 16-bit photo keeps its precision into the float image
    (``round(x * 65535)`` gives ``v`` back) and a 16-bit copy of an 8-bit one
    (``v * 257``) reads as the same floats.

    Parameters
    ----------
    path : str or path-like
        PNG, JPEG, WebP, TIFF, BMP or PNM file; ``-`` reads stdin.

    Returns
    -------
    rgb : ndarray, shape (H, W, 3), float32
        Colours in ``[0, 1]``.

    Raises
    ------
    TpsvError
        Unreadable, not a supported image, truncated or corrupt, too large,
        floating-point, signed, of another depth than 8 or 16 (16: PNG and
        TIFF only), with transparent pixels (:func:`read_image_alpha` reads
        those), or smaller than 2x2.
    """
    rgb, alpha = read_image_alpha(path)
    if alpha is not None:
        raise TpsvError(f"{path}: image has transparent pixels; this command reads opaque images "
                        "(vectorize keeps transparency): flatten it onto a background first")
    return rgb


def read_image_alpha(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a photo with its transparency: :func:`read_image`, plus the alpha channel.

    Parameters
    ----------
    path : str or path-like
        As :func:`read_image`; grey + alpha, RGBA and palette images with
        transparency give their alpha.

    Returns
    -------
    rgb : ndarray, shape (H, W, 3), float32
        Straight (not premultiplied) colours in ``[0, 1]``.
    alpha : ndarray, shape (H, W), float32, or None
        Opacity in ``[0, 1]`` (``v / 255`` or ``v / 65535``); None when every
        pixel is opaque.

    Raises
    ------
    TpsvError
        As :func:`read_image`, transparency aside.
    """
    data, header = _open(path)
    w, h = header.upright_size
    if header.bit_depth > 8 and not (header.bit_depth == 16 and header.format in DEEP_FORMATS):
        raise TpsvError(f"{path}: {header.bit_depth}-bit {header.format} image; "
                        "tpsv reads 8-bit images, and 16-bit PNG and TIFF")
    if h < 2 or w < 2:
        raise TpsvError(f"{path}: image of {w}x{h} is too small (at least 2x2)")
    img = _decode(data, header, path, cv2.IMREAD_UNCHANGED)
    del data  # the file's bytes are not needed while the float copy is made
    if img.dtype not in (np.uint8, np.uint16):  # the header said otherwise; the decoder's word is final
        raise TpsvError(f"{path}: {img.dtype.itemsize * 8}-bit image; tpsv reads 8- and 16-bit images only")
    top = np.iinfo(img.dtype).max
    alpha = None
    if img.ndim == 2:
        img = img[:, :, None]
    elif img.shape[2] == 4:
        if np.any(img[:, :, 3] != top):
            alpha = img[:, :, 3].astype(np.float32) / np.float32(top)
        img = img[:, :, :3]
    elif img.shape[2] != 3:
        raise TpsvError(f"{path}: image with {img.shape[2]} channels; expected grey or RGB")
    rgb = np.empty(img.shape[:2] + (3,), np.float32)
    rgb[...] = img[:, :, ::-1]  # BGR -> RGB (grey: broadcast to three channels)
    del img
    rgb /= np.float32(top)
    return rgb, alpha


def read_labels(path: str | os.PathLike, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a label map (8- or 16-bit single-channel image, one integer a pixel).

    The same header checks as :func:`read_image` apply, with 16 bits allowed.

    Parameters
    ----------
    path : str or path-like
    shape : (H, W), optional
        Required size; a map of another size is an error.

    Returns
    -------
    labels : ndarray, shape (H, W), int32
    """
    data, header = _open(path)
    img = _decode(data, header, path, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        if img.shape[2] >= 3 and np.array_equal(img[:, :, 0], img[:, :, 1]) and np.array_equal(img[:, :, 1], img[:, :, 2]):
            img = img[:, :, 0]
        else:
            raise TpsvError(f"{path}: label map must have one channel (got {img.shape[2]})")
    if img.dtype not in (np.uint8, np.uint16):
        raise TpsvError(f"{path}: label map must be 8- or 16-bit")
    if shape is not None and img.shape[:2] != tuple(shape):
        raise TpsvError(
            f"{path}: label map is {img.shape[1]}x{img.shape[0]} but the image is {shape[1]}x{shape[0]}"
        )
    return img.astype(np.int32)


def read_strokes(path: str | os.PathLike) -> np.ndarray:
    """Read a stroke image as 8-bit RGB (grey, palette and 16-bit are converted, alpha dropped).

    The same header checks as :func:`read_image` apply, with 16 bits allowed.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    rgb : ndarray, shape (H, W, 3), uint8
    """
    data, header = _open(path)
    # Orientation is applied by _decode, as for the other readers.
    img = _decode(data, header, path, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    return np.ascontiguousarray(img[:, :, ::-1])


#: Pixels converted to integers at a time (bounds the float64 scratch copy).
_U8_PIXELS = 1 << 18


def _to_uint(rgb: np.ndarray, dtype) -> np.ndarray:
    """``round(v * top)`` clipped to ``0..top`` (the dtype's largest value), a few rows at a time."""
    top = float(np.iinfo(dtype).max)
    out = np.empty(rgb.shape, dtype)
    flat_in = rgb.reshape(-1, rgb.shape[2]) if rgb.ndim == 3 else rgb.reshape(-1)
    flat_out = out.reshape(flat_in.shape)
    for i in range(0, flat_in.shape[0], _U8_PIXELS):
        part = np.asarray(flat_in[i:i + _U8_PIXELS], np.float64)
        flat_out[i:i + _U8_PIXELS] = np.clip(np.rint(part * top), 0, top).astype(dtype)
    return out


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """8-bit sRGB of float sRGB in ``[0, 1]`` (rounded, clipped); uint8 input is returned as is.

    The one rounding rule of every 8-bit raster tpsv writes (PNG, JPEG, WebP,
    TIFF, bands of a large render, stylize's strokes), applied a few rows at a
    time.
    """
    if rgb.dtype == np.uint8:
        return rgb
    return _to_uint(rgb, np.uint8)


def to_uint16(rgb: np.ndarray) -> np.ndarray:
    """16-bit sRGB of float sRGB in ``[0, 1]``: ``round(v * 65535)``, clipped.

    uint8 input becomes ``v * 257`` (the same value, 8-bit ``v / 255``
    rounded to 16 bits); uint16 input is returned as is.
    """
    if rgb.dtype == np.uint16:
        return rgb
    if rgb.dtype == np.uint8:
        return rgb.astype(np.uint16) * np.uint16(257)
    return _to_uint(rgb, np.uint16)


# --------------------------------------------------------------------------- writing

#: Raster formats written, by file extension (compared in lower case).
OUTPUT_EXTENSIONS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".webp": "WebP", ".tif": "TIFF",
                     ".tiff": "TIFF"}
#: Format names :func:`output_format` accepts (lower case) for a path without an extension (stdout).
OUTPUT_NAMES = {"png": "PNG", "jpeg": "JPEG", "jpg": "JPEG", "webp": "WebP", "tiff": "TIFF", "tif": "TIFF"}
#: Quality of a JPEG or WebP output when none is given, and of every preview:
#: high enough that a render's colour steps and borders show no artefacts.
OUTPUT_QUALITY = 95
#: JPEGs of at least this quality keep chroma at full resolution (4:4:4), as
#: sharp coloured region borders need; lower qualities halve it both ways (4:2:0).
FULL_CHROMA_QUALITY = 90
#: Formats that hold 16 bits a sample.
DEEP_OUTPUTS = ("PNG", "TIFF")
#: Largest side each format can store (WebP: 14 bits; JPEG: 16 bits).
OUTPUT_MAX_SIDE = {"PNG": 2**31 - 1, "JPEG": 65535, "WebP": 16383, "TIFF": 2**32 - 1}
_WRITTEN = ".png, .jpg/.jpeg, .webp or .tif/.tiff"


@dataclass(frozen=True)
class OutputFormat:
    """How a raster output is encoded (:func:`output_format` makes one from a path).

    Attributes
    ----------
    name : str
        ``"PNG"``, ``"JPEG"``, ``"WebP"`` or ``"TIFF"``.
    depth : int
        Bits a sample: 8, or 16 for PNG and TIFF.
    quality : int
        1-100, for JPEG and WebP (WebP at 100 is lossless); PNG and TIFF are
        always lossless (TIFF: LZW with the horizontal predictor).
    """

    name: str = "PNG"
    depth: int = 8
    quality: int = OUTPUT_QUALITY

    def check_size(self, width: int, height: int) -> None:
        """Refuse a size the format cannot store (a WebP over 16383 px a side).

        Raises
        ------
        TpsvError
        """
        side = OUTPUT_MAX_SIDE[self.name]
        if max(width, height) > side:
            others = [f for f, s in OUTPUT_MAX_SIDE.items() if f != self.name and max(width, height) <= s]
            raise TpsvError(f"a {self.name} image is at most {side} px a side, not {width}x{height} px; "
                            f"write {', '.join(others[:-1])} or {others[-1]}")


def output_format(path: str | os.PathLike = "-", name: str | None = None, depth: int = 8,
                  quality: int | None = None) -> OutputFormat:
    """The format a raster output is written in: its extension's, else ``name``'s, else PNG.

    ``.png``, ``.jpg``/``.jpeg``, ``.webp`` and ``.tif``/``.tiff`` (any case)
    name their format; a path without an extension (``-``, ``/dev/stdout``)
    gets ``name``, or PNG.

    Parameters
    ----------
    path : str or path-like
        The output path (``-``: stdout).
    name : str, optional
        A format name (:data:`OUTPUT_NAMES`); with an extension, it must agree.
    depth : int
        8, or 16 (PNG and TIFF).
    quality : int, optional
        1-100 for JPEG and WebP (default :data:`OUTPUT_QUALITY`); not for
        lossless formats.

    Returns
    -------
    OutputFormat

    Raises
    ------
    TpsvError
        An extension tpsv does not write, an unknown name, a name the extension
        contradicts, 16 bits for JPEG or WebP, a quality for PNG or TIFF, or a
        quality outside 1-100; one line each.
    """
    text = os.fspath(path)
    shown = display(text)
    ext = "" if text == "-" else os.path.splitext(text)[1]
    by_ext = OUTPUT_EXTENSIONS.get(ext.lower())
    if ext and by_ext is None:
        raise TpsvError(f"{shown}: tpsv does not write {display(ext)} images; name the file {_WRITTEN}")
    by_name = None
    if name is not None:
        by_name = OUTPUT_NAMES.get(str(name).lower())
        if by_name is None:
            raise TpsvError(f"unknown image format {display(str(name))!r}; tpsv writes png, jpeg, webp or tiff")
        if by_ext is not None and by_name != by_ext:
            raise TpsvError(f"{shown} names a {by_ext} file, but the format asked for is {by_name}")
    fmt = by_ext or by_name or "PNG"
    if depth not in (8, 16):
        raise TpsvError(f"image depth {depth} bits; tpsv writes 8 or 16 bits a sample")
    if depth == 16 and fmt not in DEEP_OUTPUTS:
        raise TpsvError(f"{fmt} holds 8 bits a sample; 16-bit output needs a PNG or TIFF file")
    if quality is not None:
        if fmt in DEEP_OUTPUTS:
            raise TpsvError(f"a quality applies to JPEG and WebP output; {fmt} is lossless")
        if not 1 <= quality <= 100:
            raise TpsvError(f"quality {quality} is not in 1-100")
    return OutputFormat(fmt, depth, OUTPUT_QUALITY if quality is None else int(quality))


def _encoder_params(fmt: OutputFormat) -> tuple[str, list[int]]:
    """OpenCV's extension and parameters for ``fmt``."""
    if fmt.name == "JPEG":
        sampling = (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444 if fmt.quality >= FULL_CHROMA_QUALITY
                    else cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420)
        return ".jpg", [cv2.IMWRITE_JPEG_QUALITY, fmt.quality, cv2.IMWRITE_JPEG_OPTIMIZE, 1,
                        cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling]
    if fmt.name == "WebP":  # OpenCV's quality above 100 selects lossless
        return ".webp", [cv2.IMWRITE_WEBP_QUALITY, 101 if fmt.quality >= 100 else fmt.quality]
    if fmt.name == "TIFF":  # OpenCV's default: LZW with the horizontal predictor, read everywhere
        return ".tiff", []
    return ".png", []


def encode_image(rgb: np.ndarray, fmt: OutputFormat = OutputFormat()) -> bytes:
    """The file bytes of an RGB (or grey) image in ``fmt``.

    Parameters
    ----------
    rgb : ndarray (H, W, 3), (H, W, 4) or (H, W)
        Float sRGB in ``[0, 1]`` (rounded by :func:`to_uint8` or
        :func:`to_uint16`), or uint8; four channels are RGBA with straight
        alpha, kept by PNG, WebP and TIFF, composited over white for JPEG.
    fmt : OutputFormat
        Default: 8-bit PNG.

    Returns
    -------
    bytes

    Raises
    ------
    TpsvError
        A size the format cannot store, or the encoder failed.
    """
    fmt.check_size(rgb.shape[1], rgb.shape[0])
    if rgb.ndim == 3 and rgb.shape[2] == 4 and fmt.name == "JPEG":
        rgb = over_white(rgb)
    img = to_uint16(rgb) if fmt.depth == 16 else to_uint8(rgb)
    if img.ndim == 3:
        img = np.ascontiguousarray(img[:, :, [2, 1, 0, 3][:img.shape[2]]])  # OpenCV's BGR(A)
    ext, params = _encoder_params(fmt)
    with quiet_stderr():  # libtiff and libwebp print their failures themselves
        try:
            ok, buf = cv2.imencode(ext, img, params)
        except cv2.error:
            ok = False
    if not ok:
        raise TpsvError(f"{fmt.name} encoding failed")
    return buf.tobytes()


def over_white(rgba: np.ndarray) -> np.ndarray:
    """An RGBA image (straight alpha) composited over white: what a JPEG, which has no alpha, holds of it."""
    rgba = rgba / np.float32(255) if rgba.dtype == np.uint8 else np.asarray(rgba, np.float32)
    a = rgba[..., 3:4]
    return rgba[..., :3] * a + (1.0 - a)


def encode_png(rgb: np.ndarray) -> bytes:
    """8-bit PNG bytes of an RGB image given as float in ``[0, 1]`` or uint8."""
    return encode_image(rgb, OutputFormat())


def write_image(path: str | os.PathLike, rgb: np.ndarray, quality: int | None = None, depth: int = 8,
                format: str | None = None) -> None:
    """Write an RGB image atomically, in the format its extension names (``-``: stdout).

    Parameters
    ----------
    path : str or path-like
        ``.png``, ``.jpg``/``.jpeg``, ``.webp``, ``.tif``/``.tiff``; no
        extension (or ``-``): ``format``, else PNG (:func:`output_format`).
    rgb : ndarray
        As :func:`encode_image` takes it.
    quality : int, optional
        JPEG and WebP: 1-100 (default :data:`OUTPUT_QUALITY`; WebP 100 is lossless).
    depth : int
        8, or 16 for PNG and TIFF.
    format : str, optional
        For a path without an extension.
    """
    fmt = output_format(path, format, depth, quality)
    write_bytes_atomic(path, encode_image(rgb, fmt))


def encode_labels(labels: np.ndarray) -> bytes:
    """PNG bytes of a label map: 8-bit, or 16-bit when there are over 256 labels."""
    if labels.min(initial=0) < 0 or labels.max(initial=0) > 65535:
        raise TpsvError("label values must lie in 0..65535")
    dtype = np.uint8 if labels.max(initial=0) < 256 else np.uint16
    ok, buf = cv2.imencode(".png", labels.astype(dtype))
    if not ok:
        raise TpsvError("PNG encoding failed")
    return buf.tobytes()

