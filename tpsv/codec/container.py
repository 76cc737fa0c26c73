"""Whole-file encode and decode: header, checksums, zstd, sections."""

from __future__ import annotations

import os
import zlib

import numpy as np
import zstandard

from ..errors import TpsvError, TpsvFormatError
from ..fileio import read_bytes, write_bytes_atomic
from ..model import Model
from . import detail as detail_codec
from . import layout, quant, sections

#: zstd level for every section. Measured on the samples' features (mostly
#: entropy-coded bytes, few long matches), levels 16-17 are as small as 19 and
#: 22 (within 0.5%) and 2-4 times faster; vectorize's search encodes ~20 times.
ZSTD_LEVEL = 16
#: Every section starts with the zstd frame magic number (RFC 8878).
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def _quantized(model: Model) -> tuple[quant.Quantized, np.ndarray | None]:
    """``model`` as stored, checked, and its blur map's cells (``quant.validate``); ValueError when
    it cannot be encoded (FormatLimitError, also a TpsvError, when it is too large for the format)."""
    q = quant.from_model(model)
    quant.check_limits(q)
    try:
        return q, quant.validate(q)
    except TpsvFormatError as exc:
        raise ValueError(f"model cannot be encoded: {exc}") from None


def quantize(model: Model) -> Model:
    """The model exactly as ``decode(encode(model))`` returns it.

    Parameters
    ----------
    model : Model

    Returns
    -------
    Model
        A new model; arrays are bit-identical to the decoded ones. Idempotent:
        ``quantize(quantize(m))`` equals ``quantize(m)``.

    Raises
    ------
    ValueError
        The model cannot be encoded (see :func:`encode`).
    """
    out = quant.to_model(*_quantized(model))
    out.detail = detail_codec.quantize(model.detail, len(model.regions))
    return out


def encode(model: Model) -> bytes:
    """Encode a model as a .tpsv file (``docs/FORMAT.md``).

    Parameters
    ----------
    model : Model
        Any valid model; values are rounded as :func:`quantize` describes.

    Returns
    -------
    bytes
        The whole file. The same model always gives the same bytes.

    Raises
    ------
    FormatLimitError
        A ``ValueError`` and a ``TpsvError``: the canvas, a count or a polygon
        is beyond the format's limits, or ``kernel_size`` is not one of
        ``SUPPORTED_KERNEL_SIZES`` (the user's data or options, shown as one
        line by the CLI).
    ValueError
        The model breaks another rule of the format: wrong shapes, non-finite
        values, features not sorted by region, asymmetric pairs.
    """
    q, _ = _quantized(model)
    detail = detail_codec.quantize(model.detail, len(q.labels))
    raws = (sections.pack_params(q), sections.pack_regions(q), sections.pack_features(q))
    # No zstd checksum (the header's CRC-32 covers the payload) and no dict id.
    cctx = zstandard.ZstdCompressor(
        level=ZSTD_LEVEL, write_content_size=True, write_checksum=False, write_dict_id=False
    )
    comps = tuple(cctx.compress(raw) for raw in raws)
    tail = b""
    if detail is not None:
        raw = detail_codec.pack_section(detail, len(q.labels))
        comp = cctx.compress(raw)
        tail = layout.DETAIL_SIZES.pack(len(comp), len(raw)) + comp
    header = layout.Header(
        version=layout.VERSION, flags=(layout.FLAG_DETAIL if detail is not None else 0)
        | (layout.FLAG_ALPHA if q.transparent is not None and q.transparent.any() else 0)
        | (layout.FLAG_CURVES if q.curves else 0)
        | (layout.FLAG_BLUR_MAP if q.map_values is not None else 0),
        width=q.width, height=q.height,
        regions=len(q.labels), polygons=int(q.vert_counts.size),
        vertices=int(q.xy.shape[0]), ctrl_points=int(q.ctrl.size // 8),
        features=int(q.st.shape[0]),
        compressed=tuple(len(c) for c in comps), raw=tuple(len(r) for r in raws),
        detail=(len(tail) - layout.DETAIL_SIZES.size, len(raw)) if detail is not None else (0, 0),
    )
    try:
        layout.check_header_limits(header)
    except TpsvFormatError as exc:
        raise ValueError(f"model cannot be encoded: {exc}") from None
    if detail is not None and header.detail[1] > layout.detail_raw_bound(header):
        raise ValueError("model cannot be encoded: the detail layer is larger than the format allows")
    payload = b"".join(comps) + tail
    data = layout.pack_header(header, zlib.crc32(payload)) + payload
    if len(data) > layout.MAX_FILE_BYTES:
        raise ValueError(f"model cannot be encoded: {len(data)} bytes exceed {layout.MAX_FILE_BYTES}")
    return data


def decode(data: bytes) -> Model:
    """Decode and validate a .tpsv file.

    Parameters
    ----------
    data : bytes-like
        The whole file.

    Returns
    -------
    Model
        Equal, field by field, to ``quantize`` of the model that was encoded.

    Raises
    ------
    TpsvFormatError
        The file is truncated, corrupt, hostile or of an unknown version; the
        message says what is wrong in one line. No other exception escapes for
        any input bytes.
    """
    view = memoryview(data).cast("B")
    h = layout.parse_header(view)
    payload = view[layout.HEADER_SIZE:]
    (payload_crc,) = layout.HEADER.unpack_from(view, 0)[-2:-1]
    if zlib.crc32(payload) != payload_crc:
        raise TpsvFormatError("checksum mismatch: the payload is corrupt")
    raws, start = [], 0
    for name, comp_size, raw_size in zip(layout.SECTIONS, h.compressed, h.raw):
        raws.append(_decompress(payload[start:start + comp_size], raw_size, name))
        start += comp_size
    q = quant.Quantized(
        width=h.width, height=h.height, params=sections.unpack_params(raws[0]),
        **sections.unpack_regions(raws[1], h), **sections.unpack_features(raws[2], h),
        curves=h.has_curves,
    )
    if h.version < layout.SIMPLE_OUTLINES_SINCE:
        # older encoders could write an outline folded over itself; read it as today's would write it
        try:
            q.xy, q.vert_counts = quant.mend_outlines(q.xy, q.vert_counts)
        except TpsvError as exc:
            raise TpsvFormatError(str(exc)) from None
    model = quant.to_model(q, quant.validate(q))
    if h.has_detail:
        start += layout.DETAIL_SIZES.size
        raw = _decompress(payload[start:start + h.detail[0]], h.detail[1], "detail")
        model.detail = detail_codec.unpack_section(raw, h)
    return model


def _decompress(frame: memoryview, size: int, name: str) -> bytes:
    """One zstd frame that must inflate to exactly ``size`` bytes.

    The frame's own content size is checked against ``size`` (already bounded
    by the header counts) before anything is allocated, so a bomb is refused
    without being inflated.
    """
    # Skippable frames and magicless frames parse as frames too; refuse them.
    if bytes(frame[:4]) != ZSTD_MAGIC:
        raise TpsvFormatError(f"section {name}: not a zstd frame")
    try:
        fp = zstandard.get_frame_parameters(frame)
    except zstandard.ZstdError:
        raise TpsvFormatError(f"section {name}: not a zstd frame") from None
    if fp.content_size == zstandard.CONTENTSIZE_UNKNOWN:
        raise TpsvFormatError(f"section {name}: zstd frame does not state its size")
    if fp.content_size != size:
        raise TpsvFormatError(
            f"section {name}: zstd frame holds {fp.content_size} bytes, header declares {size}"
        )
    if fp.dict_id != 0:
        raise TpsvFormatError(f"section {name}: zstd frame needs a dictionary")
    if fp.window_size > layout.MAX_WINDOW:
        raise TpsvFormatError(
            f"section {name}: zstd window {fp.window_size} exceeds {layout.MAX_WINDOW}"
        )
    try:
        dctx = zstandard.ZstdDecompressor(max_window_size=layout.MAX_WINDOW)
        raw = dctx.decompress(frame, max_output_size=size, allow_extra_data=False)
    except zstandard.ZstdError as exc:
        raise TpsvFormatError(f"section {name}: bad zstd data ({exc})") from None
    if len(raw) != size:
        raise TpsvFormatError(f"section {name}: inflates to {len(raw)} bytes, expected {size}")
    return raw


def section_sizes(data: bytes) -> dict[str, int]:
    """Bytes each part of a .tpsv file takes (compressed, as stored).

    Parameters
    ----------
    data : bytes-like
        The whole file; its header is checked (not its payload).

    Returns
    -------
    dict
        ``{"header": 72, "params": ..., "regions": ..., "features": ...}``,
        and ``"detail"`` (its sizes included) when the file has a detail
        layer; the values sum to ``len(data)``.
    """
    h = layout.parse_header(memoryview(data).cast("B"))
    out = {"header": layout.HEADER_SIZE, **dict(zip(layout.SECTIONS, h.compressed))}
    if h.has_detail:
        out["detail"] = layout.DETAIL_SIZES.size + h.detail[0]
    return out


def _display(path) -> str:
    return "<stdin>" if str(path) == "-" else os.fspath(path)


def load(path: str | os.PathLike) -> Model:
    """Read and decode a .tpsv file (``-`` reads stdin).

    Raises
    ------
    TpsvError
        The file cannot be read or exceeds ``MAX_FILE_BYTES``.
    TpsvFormatError
        The content is not a valid .tpsv file; the message starts with the path.
    """
    name = _display(path)
    data = read_bytes(path, limit=layout.MAX_FILE_BYTES)  # TpsvError naming the file
    try:
        return decode(data)
    except TpsvFormatError as exc:
        raise TpsvFormatError(f"{name}: {exc}") from None


def save(model: Model, path: str | os.PathLike) -> int:
    """Encode ``model`` and write it atomically (``-`` writes stdout).

    Returns
    -------
    int
        Bytes written.

    Raises
    ------
    TpsvError
        The file cannot be written.
    ValueError
        The model cannot be encoded.
    """
    data = encode(model)
    write_bytes_atomic(path, data)  # TpsvError naming the file
    return len(data)
