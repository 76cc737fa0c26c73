"""The .tpsv container: a versioned, checksummed, compact binary model file.

The byte layout is specified in ``docs/FORMAT.md``. In short: a 72-byte
little-endian header (magic, version, flags, image size, counts, section
sizes, CRC-32s), then three zstd frames of msgpack (params, regions,
features) holding quantised, delta-coded columns.

Functions
---------
encode(model) -> bytes
decode(data) -> Model
quantize(model) -> Model        the model as decode(encode(model)) returns it
section_sizes(data) -> dict     stored bytes per part, header included
load(path) -> Model             read a file or stdin ('-') and decode
save(model, path) -> int        encode and write atomically

The limits (``MAX_*``, ``SUPPORTED_KERNEL_SIZES``) are budgets every command
can meet (``docs/FORMAT.md``, Limits); the renderer and the CLI take their
kernel sizes from ``SUPPORTED_KERNEL_SIZES``. A model beyond them is refused by
the encoder with ``FormatLimitError`` (a ``ValueError`` and a ``TpsvError``).
"""

from .container import decode, encode, load, quantize, save, section_sizes
from .layout import (
    HEADER_SIZE,
    FormatLimitError,
    MAGIC,
    MAX_CTRL_POINTS,
    MAX_FEATURES,
    MAX_FILE_BYTES,
    MAX_GRID,
    MAX_PIXELS,
    MAX_POLYGON_VERTICES,
    MAX_POLYGONS,
    MAX_REGIONS,
    MAX_SIDE,
    MAX_VERTICES,
    MIN_GRID,
    SECTIONS,
    SUPPORTED_KERNEL_SIZES,
    VERSION,
)

__all__ = [
    "encode", "decode", "quantize", "section_sizes", "load", "save", "FormatLimitError",
    "MAGIC", "VERSION", "HEADER_SIZE", "SECTIONS", "MAX_FILE_BYTES", "MAX_SIDE",
    "MAX_PIXELS", "MAX_REGIONS", "MAX_POLYGONS", "MAX_VERTICES", "MAX_CTRL_POINTS",
    "MAX_FEATURES", "MAX_POLYGON_VERTICES", "MIN_GRID", "MAX_GRID", "SUPPORTED_KERNEL_SIZES",
]
