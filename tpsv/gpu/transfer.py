"""Host arrays to a Warp device in few copies.

Each copy from host memory to a Warp array has a fixed cost (tens of
microseconds on a CUDA device, whose driver stages pageable memory, and
Python overhead on any device), and preparing a frame uploads dozens of
small arrays (outline edges, the border pieces' tables, patches, kernels).
:func:`upload` packs the small arrays of one step into one host buffer,
copies it once and returns views into the device buffer; each view keeps
the buffer alive. A large array (a detail texture) goes on its own: packing
it would only add a host copy of its bytes.
"""

from __future__ import annotations

import numpy as np
import warp as wp

#: Alignment of each array in the shared buffer, bytes (the widest element, a vec4d, needs 8).
ALIGN = 16
#: Arrays of more bytes than this are copied on their own.
PACK_BYTES = 1 << 16


def _prepare(a, dtype) -> tuple[np.ndarray, tuple]:
    """``a`` as a C-contiguous array of ``dtype``'s scalars, and the Warp shape it takes."""
    host = np.ascontiguousarray(a, dtype=wp.dtype_to_numpy(getattr(dtype, "_wp_scalar_type_", dtype)))
    n = int(getattr(dtype, "_length_", 1))
    if n == 1:
        return host, host.shape
    if host.ndim >= 2 and host.shape[-1] == n:
        return host, host.shape[:-1]
    if host.size % n:
        raise ValueError(f"{host.size} scalars do not make whole {dtype.__name__} elements")
    return host.reshape(-1, n), (host.size // n,)


def upload(device: str, *items, pack_bytes: int = PACK_BYTES) -> list:
    """Copy host arrays to ``device``, the small ones in one transfer.

    Parameters
    ----------
    device : str
        Warp device (``cpu``, ``cuda``, ``cuda:N``).
    *items : (array_like, Warp dtype)
        Each array with the element type it takes on the device. A vector
        type's components are the array's last axis (``(n, 2)`` float64 ->
        ``n`` ``wp.vec2d``), or consecutive scalars of a flat array.
    pack_bytes : int
        Arrays of at most this many bytes share one transfer (0: each
        array is copied on its own, as ``wp.array`` copies it).

    Returns
    -------
    list of wp.array
        One per item, in order, with the shapes ``wp.array(a, dtype=...)``
        would give them.
    """
    prepared = [(*_prepare(a, dtype), dtype) for a, dtype in items]
    small = [i for i, (host, _, _) in enumerate(prepared) if 0 < host.nbytes <= pack_bytes]
    if len(small) < 2:
        small = []
    out = [None] * len(prepared)
    for i, (host, shape, dtype) in enumerate(prepared):
        if i not in small:
            out[i] = (wp.array(host, dtype=dtype, device=device) if host.size
                      else wp.empty(shape, dtype=dtype, device=device))
    if not small:
        return out
    offsets, size = [], 0
    for i in small:
        offsets.append(size)
        size += -(-prepared[i][0].nbytes // ALIGN) * ALIGN
    packed = np.empty(size, np.uint8)
    for i, off in zip(small, offsets):
        host = prepared[i][0]
        packed[off:off + host.nbytes] = host.reshape(-1).view(np.uint8)
    base = wp.array(packed, dtype=wp.uint8, device=device)
    for i, off in zip(small, offsets):
        _, shape, dtype = prepared[i]
        view = wp.array(ptr=base.ptr + off, dtype=dtype, shape=shape, device=device)
        view._ref = base  # (as Warp's own views hold their parent)
        out[i] = view
    return out


__all__ = ["ALIGN", "PACK_BYTES", "upload"]
