"""The AVIF container of a detail image, kept apart from its AV1 bitstream (format version 9).

Every AVIF file tpsv's encoder writes for a detail image (a 10-bit
monochrome still picture, OpenCV's libavif) is the same 269 bytes of
ISO-BMFF boxes around the AV1 bitstream, but for three fields: the image's
width and height (``ispe``), the bitstream's length (``iloc``, ``mdat``) and
its level (``av1C``). The bitstream's sequence header holds the level and the
size too, and the size must be the texture's.
About 176 bytes of that survive the section's zstd: a small file's tenth.
Version 9 stores the bitstream alone (the detail section's codec ``"av1"``)
and the decoder wraps it in exactly these boxes (docs/FORMAT.md, detail)
before libavif reads it. A file that is not exactly such a wrapping (another
libavif's layout) is stored whole, as before (codec ``"avif"``).
"""

from __future__ import annotations

import struct

from ..errors import TpsvFormatError


def _box(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", 8 + len(body)) + kind + body


def _full(kind: bytes, body: bytes, version: int = 0, flags: int = 0) -> bytes:
    return _box(kind, struct.pack(">I", (version << 24) | flags) + body)


def _meta(width: int, height: int, length: int, level: int, offset: int) -> bytes:
    hdlr = _full(b"hdlr", b"\0" * 4 + b"pict" + b"\0" * 12 + b"\0")
    pitm = _full(b"pitm", struct.pack(">H", 1))
    # offset and length of 4 bytes, no base offset; item 1, data in this file, one extent
    iloc = _full(b"iloc", bytes([0x44, 0x00]) + struct.pack(">HHHHII", 1, 1, 0, 1, offset, length))
    iinf = _full(b"iinf", struct.pack(">H", 1) + _full(b"infe", struct.pack(">HH", 1, 0) + b"av01Color\0", version=2))
    ispe = _full(b"ispe", struct.pack(">II", width, height))
    pixi = _full(b"pixi", bytes([1, 10]))  # one channel of 10 bits
    # AV1 codec configuration: marker and version, profile 0 and the level, main tier,
    # high bit depth (10 bits), monochrome, 4:2:0 siting unknown; no presentation delay
    av1c = _box(b"av1C", bytes([0x81, level, 0x5C, 0x00]))
    colr = _box(b"colr", b"nclx" + struct.pack(">HHHB", 2, 2, 2, 0x80))  # unspecified, full range
    ipma = _full(b"ipma", struct.pack(">IH", 1, 1) + bytes([4, 0x01, 0x02, 0x83, 0x04]))
    iprp = _box(b"iprp", _box(b"ipco", ispe + pixi + av1c + colr) + ipma)
    return _full(b"meta", hdlr + pitm + iloc + iinf + iprp)


_FTYP = _box(b"ftyp", b"avif" + b"\0" * 4 + b"avif" + b"mif1" + b"miaf")
#: Bytes of the boxes before the bitstream: ``ftyp``, ``meta`` and ``mdat``'s header.
HEAD = len(_FTYP) + len(_meta(0, 0, 0, 0, 0)) + 8


def sequence_header(bitstream: bytes) -> tuple[int, int, int] | None:
    """``(profile and level, width, height)`` from the sequence header of an AV1 still picture with
    a reduced header (``av1C``'s second byte and the largest frame it declares), or None when the
    bitstream has no such header."""
    pos, n = 0, len(bitstream)
    for _ in range(16):  # the sequence header comes first, after a temporal delimiter
        if pos >= n:
            return None
        head = bitstream[pos]
        kind, ext, has_size = (head >> 3) & 15, (head >> 2) & 1, (head >> 1) & 1
        pos += 1 + ext
        if not has_size:
            return None
        size, shift = 0, 0
        while True:  # leb128
            if pos >= n or shift > 56:
                return None
            b = bitstream[pos]
            pos += 1
            size |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                break
        if kind == 1:
            if pos + size > n or size < 3:
                return None
            # what is read here lies in the first 50 bits
            bits = int.from_bytes(bitstream[pos:pos + min(size, 8)], "big")
            at = 8 * min(size, 8)

            def take(k: int) -> int:
                nonlocal at
                at -= k
                return (bits >> at) & ((1 << k) - 1) if at >= 0 else -1

            # profile, still picture, reduced still-picture header, level, then the frame size's
            # bit counts and the largest frame (AV1 specification 5.5.1)
            profile, _, reduced, lvl = take(3), take(1), take(1), take(5)
            if reduced != 1:
                return None
            wbits, hbits = take(4) + 1, take(4) + 1
            w, h = take(wbits) + 1, take(hbits) + 1
            return ((profile << 5) | lvl, w, h) if at >= 0 else None
        pos += size
    return None


def wrap(bitstream: bytes, width: int, height: int) -> bytes:
    """The AVIF file of an AV1 bitstream of a ``width x height`` picture (the boxes of the module doc).

    Raises
    ------
    TpsvFormatError
        The bitstream has no reduced still-picture sequence header.
    """
    seq = sequence_header(bitstream)
    if seq is None:
        raise TpsvFormatError("section detail: image is not an AV1 still picture")
    lvl, w, h = seq
    if (w, h) != (width, height):
        raise TpsvFormatError(f"section detail: image is {w}x{h}, the texture's is {width}x{height}")
    n = len(bitstream)
    return _FTYP + _meta(width, height, n, lvl, HEAD) + struct.pack(">I", 8 + n) + b"mdat" + bytes(bitstream)


def unwrap(data: bytes, width: int, height: int) -> bytes | None:
    """The AV1 bitstream of an AVIF file that is exactly :func:`wrap` of it, else None."""
    if len(data) <= HEAD:
        return None
    body = bytes(data[HEAD:])
    try:
        return body if wrap(body, width, height) == bytes(data) else None
    except TpsvFormatError:  # no sequence header of a still picture of this size
        return None


__all__ = ["HEAD", "sequence_header", "unwrap", "wrap"]
