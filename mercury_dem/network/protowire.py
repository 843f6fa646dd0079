"""Protocol-buffer wire format of ISIS control-point messages, compiled with Numba.

Why our own codec rather than the ``protobuf`` package: a network of 10^5-10^7
points is 10^6-10^8 small nested messages; decoding them one Python message
object at a time (what ``protobuf`` offers from Python) and then copying every
field into columns costs minutes and gigabytes, while a single compiled pass
that reads the wire format straight into preallocated numpy columns costs well
under a second per 10^6 measures and no objects at all. The wire format is
small and stable (varints, 64-bit doubles, length-delimited strings, packed
and embedded messages), so a few hundred lines cover it, and the project
avoids a dependency plus a schema compiler. Only the fields the network model
holds are decoded; every other field is skipped by wire type (forward
compatible), groups (wire types 3/4, never used by ISIS) are an error.

Message layouts (field numbers, from ``../shared/data/README.md``):

* ``ControlPointFileEntry``: 1 id, 2 type, 6 ignore, 7 jigsawRejected,
  16-18 aprioriX/Y/Z, 19 aprioriCovar (packed doubles), 20-22 adjustedX/Y/Z,
  23 adjustedCovar, 25 measures (embedded, repeated);
* ``ControlMeasure``: 1 serialnumber, 2 type, 3 sample, 4 line, 5/6
  sample/line residual, 10 ignore, 11 jigsawRejected, 13/14 apriori
  sample/line, 15/16 sample/line sigma.

Pixel values are written and read as they are (ISIS 1-based); the caller
converts. Decoders return ``(bad_point, bad_offset)``, both -1 when the data
were well formed, else the point index and the absolute byte offset at fault.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

WT_VARINT, WT_I64, WT_LEN, WT_I32 = 0, 1, 2, 5

# The kernels' column types (numba compiles them for exactly these dtypes).
U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
B = NDArray[np.bool_]


@njit(cache=True, inline="always")
def _varint(buf: NDArray[np.uint8], i: int, end: int) -> tuple[int, int]:
    result = np.int64(0)
    shift = 0
    while i < end:
        b = np.int64(buf[i])
        i += 1
        result |= (b & 0x7F) << shift
        if b < 0x80:
            return int(result), i
        shift += 7
        if shift > 63:
            return 0, -1
    return 0, -1


@njit(cache=True, inline="always")
def _skip(buf: NDArray[np.uint8], i: int, end: int, wt: int) -> int:
    if wt == WT_VARINT:
        _, j = _varint(buf, i, end)
        return j
    if wt == WT_I64:
        return i + 8 if i + 8 <= end else -1
    if wt == WT_I32:
        return i + 4 if i + 4 <= end else -1
    if wt == WT_LEN:
        n, j = _varint(buf, i, end)
        if j < 0 or n < 0 or j + n > end:
            return -1
        return j + n
    return -1


@njit(cache=True, inline="always")
def _f64(buf: NDArray[np.uint8], i: int) -> float:
    out: float = buf[i : i + 8].view(np.float64)[0]
    return out


@njit(cache=True)
def decode_varints(buf: NDArray[np.uint8], start: int, end: int) -> tuple[NDArray[np.int64], int]:
    """Packed varints in ``buf[start:end]``; returns (values, error offset or -1)."""
    out = np.empty(end - start, np.int64)
    n = 0
    i = start
    while i < end:
        v, j = _varint(buf, i, end)
        if j < 0:
            return out[:n], i
        out[n] = v
        n += 1
        i = j
    return out[:n], -1


@njit(cache=True)
def split_length_prefixed(buf: NDArray[np.uint8], start: int, end: int, n_max: int) -> tuple[NDArray[np.int64], NDArray[np.int64], int]:
    """Messages each preceded by a little-endian uint32 length (ISIS version 5).

    Returns starts, ends and the offset of a truncated/overrunning message (or -1).
    """
    starts = np.empty(n_max, np.int64)
    ends = np.empty(n_max, np.int64)
    n = 0
    i = start
    while i < end:
        if i + 4 > end or n >= n_max:
            return starts[:n], ends[:n], i
        size = int(np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8) | (np.int64(buf[i + 2]) << 16) | (np.int64(buf[i + 3]) << 24))
        if i + 4 + size > end:
            return starts[:n], ends[:n], i
        starts[n] = i + 4
        ends[n] = i + 4 + size
        n += 1
        i += 4 + size
    return starts[:n], ends[:n], -1


@njit(cache=True)
def count_measures(buf: NDArray[np.uint8], starts: NDArray[np.int64], ends: NDArray[np.int64], counts: NDArray[np.int64]) -> tuple[int, int]:
    """Number of measure sub-messages (field 25) of each point, into ``counts``."""
    for p in range(starts.size):
        i = starts[p]
        end = ends[p]
        c = 0
        while i < end:
            at = i
            key, i = _varint(buf, i, end)
            if i < 0:
                return p, at
            f = key >> 3
            wt = key & 7
            if f == 25 and wt == WT_LEN:
                c += 1
            j = _skip(buf, i, end, wt)
            if j < 0:
                return p, at
            i = j
        counts[p] = c
    return -1, -1


@njit(cache=True)
def decode_points(
    buf: U8, starts: I64, ends: I64, first_measure: I64,
    pid_off: I64, pid_len: I64, ptype: I64, pign: B, prej: B, apriori: F64, adjusted: F64, apcov: F64, adcov: F64,
    has_apcov: B, has_adcov: B,
    m_ser_off: I64, m_ser_len: I64, mtype: I64, sample: F64, line: F64, residuals: F64, mign: B, mrej: B,
    appix: F64, sigma: F64,
) -> tuple[int, int]:  # pragma: no cover - compiled
    """Decode point messages into preallocated columns (see module docstring)."""
    for p in range(starts.size):
        i = starts[p]
        end = ends[p]
        m = first_measure[p]
        while i < end:
            at = i
            key, i = _varint(buf, i, end)
            if i < 0:
                return p, at
            f = key >> 3
            wt = key & 7
            if wt == WT_I64 and i + 8 > end:
                return p, at
            if f == 1 and wt == WT_LEN:
                n, i = _varint(buf, i, end)
                if i < 0 or i + n > end:
                    return p, at
                pid_off[p] = i
                pid_len[p] = n
                i += n
            elif (f == 2 or f == 6 or f == 7) and wt == WT_VARINT:
                v, i = _varint(buf, i, end)
                if i < 0:
                    return p, at
                if f == 2:
                    ptype[p] = v
                elif f == 6:
                    pign[p] = v != 0
                else:
                    prej[p] = v != 0
            elif 16 <= f <= 18 and wt == WT_I64:
                apriori[p, f - 16] = _f64(buf, i)
                i += 8
            elif 20 <= f <= 22 and wt == WT_I64:
                adjusted[p, f - 20] = _f64(buf, i)
                i += 8
            elif (f == 19 or f == 23) and wt == WT_LEN:
                n, i = _varint(buf, i, end)
                if i < 0 or i + n > end:
                    return p, at
                k = min(n // 8, 6)
                for q in range(k):
                    if f == 19:
                        apcov[p, q] = _f64(buf, i + 8 * q)
                    else:
                        adcov[p, q] = _f64(buf, i + 8 * q)
                if f == 19:
                    has_apcov[p] = k > 0
                else:
                    has_adcov[p] = k > 0
                i += n
            elif f == 25 and wt == WT_LEN:
                n, i = _varint(buf, i, end)
                if i < 0 or i + n > end:
                    return p, at
                mend = i + n
                while i < mend:
                    mat = i
                    mkey, i = _varint(buf, i, mend)
                    if i < 0:
                        return p, mat
                    g = mkey >> 3
                    mwt = mkey & 7
                    if mwt == WT_I64:
                        if i + 8 > mend:
                            return p, mat
                        x = _f64(buf, i)
                        if g == 3:
                            sample[m] = x
                        elif g == 4:
                            line[m] = x
                        elif g == 5 or g == 6:
                            residuals[m, g - 5] = x
                        elif g == 13 or g == 14:
                            appix[m, g - 13] = x
                        elif g == 15 or g == 16:
                            sigma[m, g - 15] = x
                        i += 8
                    elif g == 1 and mwt == WT_LEN:
                        sl, i = _varint(buf, i, mend)
                        if i < 0 or i + sl > mend:
                            return p, mat
                        m_ser_off[m] = i
                        m_ser_len[m] = sl
                        i += sl
                    elif (g == 2 or g == 10 or g == 11) and mwt == WT_VARINT:
                        v, i = _varint(buf, i, mend)
                        if i < 0:
                            return p, mat
                        if g == 2:
                            mtype[m] = v
                        elif g == 10:
                            mign[m] = v != 0
                        else:
                            mrej[m] = v != 0
                    else:
                        j = _skip(buf, i, mend, mwt)
                        if j < 0:
                            return p, mat
                        i = j
                m += 1
            else:
                j = _skip(buf, i, end, wt)
                if j < 0:
                    return p, at
                i = j
    return -1, -1


# -- encoding -------------------------------------------------------------------


@njit(cache=True, inline="always")
def _vlen(v: int) -> int:
    n = 1
    while v >= 0x80:
        v >>= 7
        n += 1
    return n


@njit(cache=True, inline="always")
def _put_varint(out: NDArray[np.uint8], i: int, v: int) -> int:
    while v >= 0x80:
        out[i] = (v & 0x7F) | 0x80
        v >>= 7
        i += 1
    out[i] = v
    return i + 1


@njit(cache=True, inline="always")
def _put_f64(out: NDArray[np.uint8], i: int, field: int, x: float, scratch_f: F64, scratch_b: U8) -> int:
    i = _put_varint(out, i, (field << 3) | WT_I64)
    scratch_f[0] = x
    for q in range(8):
        out[i + q] = scratch_b[q]
    return i + 8


@njit(cache=True, inline="always")
def _f64_size(field: int, x: float) -> int:
    return _vlen((field << 3) | WT_I64) + 8 if np.isfinite(x) else 0


@njit(cache=True)
def measure_sizes(ser_len: I64, mimage: I64, mtype: I64, sample: F64, line: F64, residuals: F64,  # pragma: no cover
                  mign: B, mrej: B, appix: F64, sigma: F64) -> I64:
    """Encoded size of each measure message (without its tag and length)."""
    out = np.empty(mimage.size, np.int64)
    for m in range(mimage.size):
        sl = ser_len[mimage[m]]
        s = 1 + _vlen(sl) + sl + 1 + _vlen(mtype[m])
        s += _f64_size(3, sample[m]) + _f64_size(4, line[m])
        s += _f64_size(5, residuals[m, 0]) + _f64_size(6, residuals[m, 1])
        s += 2 * mign[m] + 2 * mrej[m]
        s += _f64_size(13, appix[m, 0]) + _f64_size(14, appix[m, 1])
        s += _f64_size(15, sigma[m, 0]) + _f64_size(16, sigma[m, 1])
        out[m] = s
    return out


@njit(cache=True)
def point_sizes(pid_len: I64, ptype: I64, pign: B, prej: B, apriori: F64, adjusted: F64,  # pragma: no cover
                apcov_ok: B, adcov_ok: B, first_measure: I64, msize: I64) -> I64:
    """Encoded size of each point message (without any length prefix)."""
    out = np.empty(pid_len.size, np.int64)
    for p in range(pid_len.size):
        s = 1 + _vlen(pid_len[p]) + pid_len[p] + 1 + _vlen(ptype[p]) + 2 * pign[p] + 2 * prej[p]
        for q in range(3):
            s += _f64_size(16 + q, apriori[p, q]) + _f64_size(20 + q, adjusted[p, q])
        if apcov_ok[p]:
            s += 2 + 1 + 48
        if adcov_ok[p]:
            s += 2 + 1 + 48
        for m in range(first_measure[p], first_measure[p + 1]):
            s += 2 + _vlen(msize[m]) + msize[m]
        out[p] = s
    return out


@njit(cache=True)
def encode_points(
    out: U8, starts: I64, prefix_u32: bool,
    pid_data: U8, pid_off: I64, ptype: I64, pign: B, prej: B, apriori: F64, adjusted: F64, apcov: F64, adcov: F64,
    apcov_ok: B, adcov_ok: B,
    first_measure: I64, psize: I64, msize: I64,
    ser_data: U8, ser_off: I64, mimage: I64, mtype: I64, sample: F64, line: F64, residuals: F64, mign: B, mrej: B,
    appix: F64, sigma: F64,
    scratch_f: F64, scratch_b: U8,
) -> int:  # pragma: no cover - compiled
    """Write every point message at ``starts[p]`` (after a uint32 length when ``prefix_u32``)."""
    for p in range(starts.size):
        i = starts[p]
        if prefix_u32:
            size = psize[p]
            out[i] = size & 0xFF
            out[i + 1] = (size >> 8) & 0xFF
            out[i + 2] = (size >> 16) & 0xFF
            out[i + 3] = (size >> 24) & 0xFF
            i += 4
        n = pid_off[p + 1] - pid_off[p]
        i = _put_varint(out, i, (1 << 3) | WT_LEN)
        i = _put_varint(out, i, n)
        out[i : i + n] = pid_data[pid_off[p] : pid_off[p + 1]]
        i += n
        i = _put_varint(out, i, (2 << 3) | WT_VARINT)
        i = _put_varint(out, i, ptype[p])
        if pign[p]:
            i = _put_varint(out, i, (6 << 3) | WT_VARINT)
            i = _put_varint(out, i, 1)
        if prej[p]:
            i = _put_varint(out, i, (7 << 3) | WT_VARINT)
            i = _put_varint(out, i, 1)
        for q in range(3):
            if np.isfinite(apriori[p, q]):
                i = _put_f64(out, i, 16 + q, apriori[p, q], scratch_f, scratch_b)
        if apcov_ok[p]:
            i = _put_varint(out, i, (19 << 3) | WT_LEN)
            i = _put_varint(out, i, 48)
            for q in range(6):
                scratch_f[0] = apcov[p, q]
                for r in range(8):
                    out[i + r] = scratch_b[r]
                i += 8
        for q in range(3):
            if np.isfinite(adjusted[p, q]):
                i = _put_f64(out, i, 20 + q, adjusted[p, q], scratch_f, scratch_b)
        if adcov_ok[p]:
            i = _put_varint(out, i, (23 << 3) | WT_LEN)
            i = _put_varint(out, i, 48)
            for q in range(6):
                scratch_f[0] = adcov[p, q]
                for r in range(8):
                    out[i + r] = scratch_b[r]
                i += 8
        for m in range(first_measure[p], first_measure[p + 1]):
            i = _put_varint(out, i, (25 << 3) | WT_LEN)
            i = _put_varint(out, i, msize[m])
            k = mimage[m]
            sl = ser_off[k + 1] - ser_off[k]
            i = _put_varint(out, i, (1 << 3) | WT_LEN)
            i = _put_varint(out, i, sl)
            out[i : i + sl] = ser_data[ser_off[k] : ser_off[k + 1]]
            i += sl
            i = _put_varint(out, i, (2 << 3) | WT_VARINT)
            i = _put_varint(out, i, mtype[m])
            if np.isfinite(sample[m]):
                i = _put_f64(out, i, 3, sample[m], scratch_f, scratch_b)
            if np.isfinite(line[m]):
                i = _put_f64(out, i, 4, line[m], scratch_f, scratch_b)
            for q in range(2):
                if np.isfinite(residuals[m, q]):
                    i = _put_f64(out, i, 5 + q, residuals[m, q], scratch_f, scratch_b)
            if mign[m]:
                i = _put_varint(out, i, (10 << 3) | WT_VARINT)
                i = _put_varint(out, i, 1)
            if mrej[m]:
                i = _put_varint(out, i, (11 << 3) | WT_VARINT)
                i = _put_varint(out, i, 1)
            for q in range(2):
                if np.isfinite(appix[m, q]):
                    i = _put_f64(out, i, 13 + q, appix[m, q], scratch_f, scratch_b)
            for q in range(2):
                if np.isfinite(sigma[m, q]):
                    i = _put_f64(out, i, 15 + q, sigma[m, q], scratch_f, scratch_b)
    return 0


# -- small messages (headers) in plain Python ----------------------------------


def encode_varint(v: int) -> bytes:
    """A non-negative integer as a protobuf varint."""
    out = bytearray()
    v = int(v)
    if v < 0:
        v &= (1 << 64) - 1
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def encode_field_bytes(field: int, payload: bytes) -> bytes:
    """One length-delimited protobuf field: its key, the payload's length and the payload."""
    return encode_varint((field << 3) | WT_LEN) + encode_varint(len(payload)) + payload


def encode_field_varint(field: int, value: int) -> bytes:
    """One varint protobuf field: its key and the value."""
    return encode_varint((field << 3) | WT_VARINT) + encode_varint(value)


def decode_message(data: bytes, base_offset: int = 0) -> list[tuple[int, int, int | bytes, int]]:
    """Top-level fields of a small message as (field, wire type, value, offset).

    Values: int for varints, bytes for length-delimited fields, raw 8/4 bytes
    for fixed-width ones. Raises ValueError naming the byte offset on bad data.
    """
    buf = np.frombuffer(data, np.uint8)
    out: list[tuple[int, int, int | bytes, int]] = []
    i, end = 0, len(data)
    while i < end:
        at = i
        key, i = _varint(buf, i, end)
        if i < 0:
            raise ValueError(f"bad field key at byte offset {base_offset + at}")
        f, wt = key >> 3, key & 7
        if wt == WT_VARINT:
            val, j = _varint(buf, i, end)
            value: int | bytes = val
        elif wt == WT_LEN:
            n, i = _varint(buf, i, end)
            j = i + n if i >= 0 and i + n <= end else -1
            value = bytes(data[i:j]) if j >= 0 else b""
        elif wt in (WT_I64, WT_I32):
            w = 8 if wt == WT_I64 else 4
            j = i + w if i + w <= end else -1
            value = bytes(data[i:j]) if j >= 0 else b""
        else:
            j = -1
        if j < 0:
            raise ValueError(f"truncated or malformed field {f} at byte offset {base_offset + at}")
        out.append((f, wt, value, at))
        i = j
    return out


# -- byte spans (strings inside the buffer) ---------------------------------------


@njit(cache=True)
def gather_padded(buf: U8, off: I64, length: I64, width: int) -> U8:  # pragma: no cover - compiled
    """Rows (n, width) of the spans ``buf[off:off+length]``, zero-padded."""
    out = np.zeros((off.size, width), np.uint8)
    for i in range(off.size):
        for j in range(min(length[i], width)):
            out[i, j] = buf[off[i] + j]
    return out


@njit(cache=True)
def hash_spans(buf: U8, off: I64, length: I64) -> NDArray[np.uint64]:  # pragma: no cover - compiled
    """64-bit FNV-1a hash of each span (the length mixed in)."""
    out = np.empty(off.size, np.uint64)
    prime = np.uint64(1099511628211)
    for i in range(off.size):
        h = np.uint64(14695981039346656037)
        for j in range(length[i]):
            h = (h ^ np.uint64(buf[off[i] + j])) * prime
        out[i] = (h ^ np.uint64(length[i])) * prime
    return out


@njit(cache=True)
def spans_equal(buf: U8, off_a: I64, len_a: I64, off_b: I64, len_b: I64) -> B:  # pragma: no cover - compiled
    """True where span a equals span b, byte for byte."""
    out = np.empty(off_a.size, np.bool_)
    for i in range(off_a.size):
        same = len_a[i] == len_b[i]
        j = 0
        while same and j < len_a[i]:
            same = buf[off_a[i] + j] == buf[off_b[i] + j]
            j += 1
        out[i] = same
    return out


@njit(cache=True)
def parse_int_spans(buf: U8, off: I64, length: I64) -> tuple[I64, bool]:  # pragma: no cover - compiled
    """Spans that are canonical decimal integers ("0", "17", "-5"; no '+', no leading zeros) as int64.

    Returns (values, all_canonical); values are meaningless when not all are canonical.
    """
    out = np.empty(off.size, np.int64)
    for i in range(off.size):
        n = length[i]
        j = off[i]
        neg = n > 0 and buf[j] == 45  # '-'
        start = j + (1 if neg else 0)
        digits = n - (1 if neg else 0)
        if digits < 1 or digits > 18:
            return out, False
        if digits > 1 and buf[start] == 48:  # leading zero
            return out, False
        if neg and digits == 1 and buf[start] == 48:  # "-0"
            return out, False
        v = 0
        for q in range(digits):
            c = buf[start + q]
            if c < 48 or c > 57:
                return out, False
            v = v * 10 + (c - 48)
        out[i] = -v if neg else v
    return out, True


@njit(cache=True)
def format_ints(values: I64) -> tuple[U8, I64]:  # pragma: no cover - compiled
    """Decimal text of int64 values: (bytes back to back, offsets (n + 1,))."""
    n = values.size
    offsets = np.zeros(n + 1, np.int64)
    tmp = np.empty(20, np.uint8)
    data = np.empty(n * 20, np.uint8)
    pos = 0
    for i in range(n):
        v = values[i]
        neg = v < 0
        u = -v if neg else v
        k = 0
        while True:
            tmp[k] = 48 + u % 10
            u //= 10
            k += 1
            if u == 0:
                break
        if neg:
            data[pos] = 45
            pos += 1
        for q in range(k):
            data[pos + q] = tmp[k - 1 - q]
        pos += k
        offsets[i + 1] = pos
    return data[:pos].copy(), offsets
