"""Arrays of strings as UTF-8 bytes back to back plus offsets (pure: arrays in, arrays out).

The layout of every string column of a network store (:mod:`mercury_dem.io.network_store`) and the
serial numbers and point ids the ISIS codec (:mod:`mercury_dem.network.isis`) writes. It lives here, not
with the store, so that the codec and the store both import it without importing each other.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def encode_strings(values: NDArray[Any]) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """UTF-8 bytes of all strings back to back, and offsets of shape (n + 1,)."""
    if values.size == 0:
        return np.zeros(0, np.uint8), np.zeros(1, np.int64)
    values = values.astype(str, copy=False)
    try:
        encoded = values.astype("S")  # ASCII fast path
    except UnicodeEncodeError:
        encoded = np.char.encode(values, "utf-8")
    width = encoded.dtype.itemsize
    raw = encoded.view(np.uint8).reshape(values.size, width)
    keep = raw != 0  # strings hold no NUL: the padding is the zeros
    lengths = keep.sum(axis=1, dtype=np.int64)
    offsets = np.zeros(values.size + 1, np.int64)
    np.cumsum(lengths, out=offsets[1:])
    return raw[keep], offsets


def decode_strings(data: NDArray[np.uint8], offsets: NDArray[np.int64]) -> NDArray[np.str_]:
    """Inverse of :func:`encode_strings`: a numpy unicode array."""
    n = offsets.size - 1
    if n <= 0:
        return np.zeros(0, "U1")
    lengths = np.diff(offsets)
    width = max(int(lengths.max()), 1)
    col = np.arange(width)[None, :]
    idx = offsets[:-1, None] + col
    valid = col < lengths[:, None]
    buf = np.zeros((n, width), np.uint8)
    buf[valid] = data[idx[valid]]
    raw = buf.view(f"S{width}").ravel()
    try:
        return raw.astype(f"U{width}")  # ASCII fast path
    except UnicodeDecodeError:
        return np.char.decode(raw, "utf-8")
