"""An sRGB ICC profile (version 2, matrix/TRC display profile), built from the IEC 61966-2-1 numbers.

The PDF's colours are sRGB; tagging them ICCBased with this profile (rather
than DeviceRGB, which a colour-managed viewer or printer may read as its own
RGB) states what they are. No ICC library is needed: a matrix/TRC profile is
a 128-byte header, a tag table and nine small tags:

* ``rXYZ``, ``gXYZ``, ``bXYZ``: the sRGB primaries adapted to the D50 PCS
  (Bradford), ``wtpt`` D50 (the adapted white);
* ``rTRC``, ``gTRC``, ``bTRC``: one shared 1024-entry curve of the sRGB
  transfer function;
* ``desc`` and ``cprt``.
"""

from __future__ import annotations

import struct

import numpy as np

#: sRGB primaries in XYZ, Bradford-adapted from D65 to D50 (columns R, G, B), and the D50 white.
_PRIMARIES_D50 = np.array([[0.4360747, 0.3850649, 0.1430804],
                           [0.2225045, 0.7168786, 0.0606169],
                           [0.0139322, 0.0971045, 0.7141733]])
_D50 = (0.9642, 1.0, 0.8249)
#: Entries of the tone curve.
_CURVE_POINTS = 1024


def _s15f16(values) -> bytes:
    return b"".join(struct.pack(">i", int(round(v * 65536.0))) for v in values)


def _xyz(values) -> bytes:
    return b"XYZ " + b"\0" * 4 + _s15f16(values)


def _curve() -> bytes:
    x = np.linspace(0.0, 1.0, _CURVE_POINTS)
    y = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    table = np.round(y * 65535.0).astype(">u2").tobytes()
    return b"curv" + b"\0" * 4 + struct.pack(">I", _CURVE_POINTS) + table


def _desc(text: str) -> bytes:
    ascii_ = text.encode("ascii") + b"\0"
    # textDescriptionType: ASCII, then empty Unicode and ScriptCode parts (67 bytes of Mac string)
    return (b"desc" + b"\0" * 4 + struct.pack(">I", len(ascii_)) + ascii_ + struct.pack(">II", 0, 0)
            + struct.pack(">HB", 0, 0) + b"\0" * 67)


def _text(text: str) -> bytes:
    return b"text" + b"\0" * 4 + text.encode("ascii") + b"\0"


def srgb_profile() -> bytes:
    """The bytes of an sRGB ICC profile (v2.1, display class, RGB -> XYZ PCS).

    Returns
    -------
    bytes
    """
    curve = _curve()
    tags = [
        (b"desc", _desc("sRGB IEC61966-2.1 (tpsv)")),
        (b"cprt", _text("No copyright, use freely")),
        (b"wtpt", _xyz(_D50)),
        (b"rXYZ", _xyz(_PRIMARIES_D50[:, 0])),
        (b"gXYZ", _xyz(_PRIMARIES_D50[:, 1])),
        (b"bXYZ", _xyz(_PRIMARIES_D50[:, 2])),
        (b"rTRC", curve),
        (b"gTRC", None),  # share rTRC's data
        (b"bTRC", None),
    ]
    table_size = 4 + 12 * len(tags)
    offset = 128 + table_size
    entries, blobs = [], []
    shared = None
    for sig, data in tags:
        if data is None:
            entries.append((sig,) + shared)
            continue
        pad = (-offset) % 4
        if pad:
            blobs.append(b"\0" * pad)
            offset += pad
        entries.append((sig, offset, len(data)))
        if sig == b"rTRC":
            shared = (offset, len(data))
        blobs.append(data)
        offset += len(data)
    body = struct.pack(">I", len(tags)) + b"".join(struct.pack(">4sII", *e) for e in entries) + b"".join(blobs)
    size = 128 + len(body)
    header = (struct.pack(">I", size) + b"\0" * 4 + struct.pack(">I", 0x02100000) + b"mntr" + b"RGB " + b"XYZ "
              + struct.pack(">6H", 2024, 1, 1, 0, 0, 0) + b"acsp" + b"\0" * 4 + struct.pack(">I", 0) + b"\0" * 8
              + b"\0" * 8 + struct.pack(">I", 0) + _s15f16(_D50) + b"\0" * 4 + b"\0" * 16 + b"\0" * 28)
    assert len(header) == 128
    return header + body


__all__ = ["srgb_profile"]
