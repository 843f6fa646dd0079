"""ISIS3 binary control networks (``.net``), versions 2 and 5: the codec, bytes in and out.

:func:`decode_isis_network` turns a file's bytes into a :class:`ControlNetwork`, :func:`encode_isis_network`
a network into a file's bytes; opening and writing the files is :mod:`mercury_dem.io.isis_net`'s job
(``read_isis_network``, ``write_isis_network``, ``isis_network_info``).

File layout (``../shared/data/README.md``): a zero-padded PVL text label at byte
0 (``HeaderStartByte``, ``HeaderBytes``, ``PointsStartByte``, ``PointsBytes``,
``Version``, counts); a protobuf header message; then the point messages —
back to back with their sizes listed in the header (version 2), or each after
a little-endian uint32 length (version 5). The protobuf wire format is decoded
and encoded by our own compiled codec, :mod:`mercury_dem.network.protowire`
(the module docstring says why).

Conventions converted here and only here:

* pixels: ISIS is 1-based at the first pixel's centre; ours 0-based:
  ``ours = isis - 1`` for sample, line and a-priori sample/line (residuals and
  sigmas are differences and are unchanged);
* images: ISIS names them by serial number; an optional mapping gives our
  image id of each serial number (and back when writing);
* point types Tie (0) and Ground (1) of old files read as Free and Fixed.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import mercury_dem.network.protowire as pw
from mercury_dem.exceptions import NetworkError
from mercury_dem.network.model import ControlNetwork, PointType, as_string_array, take_measure_columns
from mercury_dem.network.strings import encode_strings

#: Where the protobuf header starts in files we write (as ISIS does).
HEADER_START_BYTE = 65536
_LABEL_KEYS = ("HeaderStartByte", "HeaderBytes", "PointsStartByte", "PointsBytes")
def _timestamp() -> str:
    """The UTC time written as a new network's ``Created``/``LastModified``.

    ``SOURCE_DATE_EPOCH`` (the reproducible-builds convention, seconds since 1970) fixes it, so that two
    exports of the same network are byte-identical; otherwise the clock's time.
    """
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    when = datetime.now(UTC)
    if epoch.isdigit():
        when = datetime.fromtimestamp(int(epoch), UTC)
    return when.strftime("%Y-%m-%dT%H:%M:%S")


_HEADER_TEXT_FIELDS = {1: "network_id", 2: "target_name", 3: "created", 4: "last_modified", 5: "description", 6: "user_name"}


def _parse_label(path: Path, data: bytes) -> dict[str, Any]:
    head = data[: min(len(data), HEADER_START_BYTE)]
    text = head.split(b"\0", 1)[0].decode("latin-1")
    if "Object = ProtoBuffer" not in text and "Object=ProtoBuffer" not in text.replace(" ", ""):
        raise NetworkError(
            f"{path}: not an ISIS binary control network (no 'Object = ProtoBuffer' label at byte 0); "
            f"convert PVL networks with ISIS cnetbin2pvl/cnetpvl2bin first"
        )
    label: dict[str, Any] = {}
    for key in (*_LABEL_KEYS, "Version", "NumberOfPoints", "NumberOfMeasures"):
        m = re.search(rf"^\s*{key}\s*=\s*(\d+)\s*$", text, re.MULTILINE)
        if m:
            label[key] = int(m.group(1))
    for key in _LABEL_KEYS:
        if key not in label:
            raise NetworkError(f"{path}: ISIS label lacks the keyword {key}; the file is damaged")
    label.setdefault("Version", 2)
    return label


def _header_fields(path: Path, data: bytes, start: int, size: int) -> list[tuple[int, int, int | bytes, int]]:
    try:
        return pw.decode_message(data[start : start + size], base_offset=start)
    except ValueError as exc:
        raise NetworkError(f"{path}: corrupt protobuf header: {exc}") from exc


def decode_isis_network(
    data: bytes,
    path: str | Path,
    serial_to_image: Mapping[str, str] | None = None,
    image_ids: Sequence[str] | NDArray[np.str_] | None = None,
    drop_unknown: bool = False,
    int_point_ids: bool = True,
) -> ControlNetwork:
    """Decode the bytes of an ISIS3 binary control network (version 2 or 5).

    Parameters
    ----------
    data : the bytes of a ``.net`` file
    path : the file they came from, for the messages (nothing is opened)
    serial_to_image : optional mapping ISIS serial number -> our image id; serial
        numbers not in it are kept as they are.
    image_ids : optional catalog of image ids; when given it becomes the images
        table (in this order) and every measure's image must be in it.
    drop_unknown : with ``image_ids``, drop measures of images not in the catalog
        instead of raising (the count is in ``metadata['dropped_measures']``).
    int_point_ids : when every point id is a canonical decimal integer, return
        int64 point ids (so networks we wrote read back identically).

    Returns
    -------
    ControlNetwork with 0-based pixels; ``metadata`` holds the header texts and
    ``isis_version``.

    Raises
    ------
    NetworkError naming the file: not a control network, truncated (with the byte
    offset where the data stop or the message that overruns), corrupt messages,
    serial numbers that match no catalog image.
    """
    path = Path(path)
    label = _parse_label(path, data)
    version = label["Version"]
    if version not in (2, 5):
        raise NetworkError(f"{path}: ISIS control network version {version} is not supported (only 2 and 5)")
    hs, hb, ps, pbytes = (label[k] for k in _LABEL_KEYS)
    if len(data) < hs + hb:
        raise NetworkError(
            f"{path}: truncated at byte offset {len(data)}: the header needs bytes {hs}..{hs + hb}"
        )
    if len(data) < ps + pbytes:
        raise NetworkError(
            f"{path}: truncated at byte offset {len(data)}: its label says the points end at byte {ps + pbytes}"
        )
    header = _header_fields(path, data, hs, hb)
    meta = {"isis_version": str(version)}
    header_serials: list[str] = []
    for f, wt, value, _ in header:
        if f in _HEADER_TEXT_FIELDS and wt == pw.WT_LEN:
            meta[_HEADER_TEXT_FIELDS[f]] = bytes(value).decode("utf-8", "replace")
        elif version == 5 and f == 8 and wt == pw.WT_LEN:
            try:
                header_serials.append(bytes(value).decode("utf-8"))
            except UnicodeDecodeError:
                raise NetworkError(f"{path}: a serial number in the header is not UTF-8 text; the file is "
                                   "damaged") from None
    buf = np.frombuffer(data, np.uint8)
    end = ps + pbytes
    if version == 2:
        sizes_parts = [(v, off) for f, wt, v, off in header if f == 7]
        chunks = []
        for value, off in sizes_parts:
            if isinstance(value, bytes):  # packed
                arr = np.frombuffer(value, np.uint8)
                vals, err = pw.decode_varints(arr, 0, arr.size)
                if err >= 0:
                    raise NetworkError(f"{path}: corrupt pointMessageSizes in the header near byte offset {hs + off}")
                chunks.append(vals)
            else:
                chunks.append(np.array([value], np.int64))
        sizes = np.concatenate(chunks) if chunks else np.zeros(0, np.int64)
        if np.any(sizes < 0):
            raise NetworkError(f"{path}: a point message size in the header is negative; the file is damaged")
        if sizes.size and int(sizes.sum()) < pbytes:  # more than that runs past the end (checked below)
            raise NetworkError(
                f"{path}: the header's point message sizes add up to {int(sizes.sum())} bytes but the label says "
                f"PointsBytes = {pbytes}; the file is damaged"
            )
        starts = ps + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)[: sizes.size]
        ends = starts + sizes
        if sizes.size and ends[-1] > end:
            bad = int(np.argmax(ends > end))
            raise NetworkError(
                f"{path}: truncated: point message {bad} at byte offset {starts[bad]} runs past the end "
                f"of the points ({end} bytes)"
            )
    else:
        starts, ends, err = pw.split_length_prefixed(buf, ps, end, max(1, pbytes // 4 + 1))
        if err >= 0:
            raise NetworkError(f"{path}: truncated or corrupt point message at byte offset {err}")
    n = starts.size
    if "NumberOfPoints" in label and label["NumberOfPoints"] != n:
        raise NetworkError(
            f"{path}: the label says {label['NumberOfPoints']} points but the data hold {n}; the file is damaged"
        )
    counts = np.zeros(n, np.int64)
    bad_p, bad_off = pw.count_measures(buf, starts, ends, counts)
    _raise_corrupt(path, bad_p, bad_off)
    first = np.zeros(n + 1, np.int64)
    np.cumsum(counts, out=first[1:])
    m = int(first[-1])
    if "NumberOfMeasures" in label and label["NumberOfMeasures"] != m:
        raise NetworkError(
            f"{path}: the label says {label['NumberOfMeasures']} measures but the data hold {m}; the file is damaged"
        )
    cols = _empty_columns(n, m)
    bad_p, bad_off = pw.decode_points(
        buf, starts, ends, first,
        cols["pid_off"], cols["pid_len"], cols["ptype"], cols["pign"], cols["prej"], cols["apriori"],
        cols["adjusted"], cols["apcov"], cols["adcov"], cols["has_apcov"], cols["has_adcov"],
        cols["ser_off"], cols["ser_len"], cols["mtype"], cols["sample"], cols["line"], cols["res"],
        cols["mign"], cols["mrej"], cols["appix"], cols["sigma"],
    )
    _raise_corrupt(path, bad_p, bad_off)
    if np.any(cols["pid_len"] < 0):
        raise NetworkError(f"{path}: point {int(np.argmax(cols['pid_len'] < 0))} has no id; the file is damaged")
    if np.any(cols["ser_len"] < 0):
        raise NetworkError(f"{path}: a measure has no serial number; the file is damaged")
    point_ids: NDArray[Any] | None = None
    if int_point_ids and n:
        values, canonical = pw.parse_int_spans(buf, cols["pid_off"], cols["pid_len"])
        point_ids = values if canonical else None
    what = "a point id"
    try:
        if point_ids is None:
            point_ids = _strings_at(buf, cols["pid_off"], cols["pid_len"])
        what = "a measure's serial number"
        serial_codes, serials = _unique_strings_at(buf, cols["ser_off"], cols["ser_len"])
    except UnicodeDecodeError:  # protobuf strings are UTF-8: another byte sequence is a damaged message
        raise NetworkError(f"{path}: {what} is not UTF-8 text; the file is damaged") from None
    ptype = cols["ptype"]
    ptype = np.where(ptype == 0, PointType.FREE, np.where(ptype == 1, PointType.FIXED, ptype)).astype(np.int8)
    measure_point = np.repeat(np.arange(n, dtype=np.int64), counts)
    table, measure_image, keep = _image_table(path, serials, serial_codes, header_serials, serial_to_image, image_ids, drop_unknown)
    net = ControlNetwork(
        image_ids=table,
        point_ids=point_ids,
        point_type=ptype,
        apriori_xyz=cols["apriori"],
        adjusted_xyz=cols["adjusted"],
        point_ignored=cols["pign"],
        point_rejected=cols["prej"],
        measure_point=measure_point,
        measure_image=measure_image,
        sample=cols["sample"] - 1.0,
        line=cols["line"] - 1.0,
        sigma=cols["sigma"],
        measure_type=cols["mtype"].astype(np.int8),
        measure_ignored=cols["mign"],
        measure_rejected=cols["mrej"],
        residuals=cols["res"],
        apriori_pixels=cols["appix"] - 1.0,
        apriori_covariance=_covariance(cols["apcov"], cols["has_apcov"]),
        adjusted_covariance=_covariance(cols["adcov"], cols["has_adcov"]),
        metadata=meta,
    )
    if keep is not None:
        net = net.select_measures(keep, min_measures=0)
        net = net.replace(metadata={**net.metadata, "dropped_measures": str(int((~keep).sum()))})
    return net


def _raise_corrupt(path: Path, bad_p: int, bad_off: int) -> None:
    if bad_p >= 0:
        raise NetworkError(
            f"{path}: corrupt or truncated point message {bad_p}: bad field at byte offset {bad_off}"
        )


def _empty_columns(n: int, m: int) -> dict[str, NDArray[Any]]:
    return {
        "pid_off": np.zeros(n, np.int64), "pid_len": np.full(n, -1, np.int64),
        "ptype": np.full(n, PointType.FREE, np.int64), "pign": np.zeros(n, bool), "prej": np.zeros(n, bool),
        "apriori": np.full((n, 3), np.nan), "adjusted": np.full((n, 3), np.nan),
        "apcov": np.full((n, 6), np.nan), "adcov": np.full((n, 6), np.nan),
        "has_apcov": np.zeros(n, bool), "has_adcov": np.zeros(n, bool),
        "ser_off": np.zeros(m, np.int64), "ser_len": np.full(m, -1, np.int64),
        "mtype": np.zeros(m, np.int64), "sample": np.full(m, np.nan), "line": np.full(m, np.nan),
        "res": np.full((m, 2), np.nan), "mign": np.zeros(m, bool), "mrej": np.zeros(m, bool),
        "appix": np.full((m, 2), np.nan), "sigma": np.full((m, 2), np.nan),
    }


def _covariance(values: NDArray[np.float64], present: NDArray[np.bool_]) -> NDArray[np.float64] | None:
    return values if present.any() else None


def _strings_at(buf: NDArray[np.uint8], off: NDArray[np.int64], length: NDArray[np.int64]) -> NDArray[np.str_]:
    """The spans as a numpy unicode array (gathered by a compiled loop, decoded as ASCII when possible)."""
    if off.size == 0:
        return np.zeros(0, "U1")
    width = max(int(length.max()), 1)
    raw = pw.gather_padded(buf, off, length, width).view(f"S{width}").ravel()
    try:
        out: NDArray[np.str_] = raw.astype(f"U{width}")
        return out
    except UnicodeDecodeError:
        return np.char.decode(raw, "utf-8")


def _unique_strings_at(buf: NDArray[np.uint8], off: NDArray[np.int64], length: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.str_]]:
    """Codes (M,) into the distinct spans, and those strings in order of first appearance.

    Spans are told apart by a 64-bit hash (one compiled pass, then a sort of
    integers, not of strings); every span is then compared byte for byte with
    its group's first span, and a hash collision falls back to sorting the
    strings themselves.
    """
    if off.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, "U1")
    h = pw.hash_spans(buf, off, length)
    _, first, inv = np.unique(h, return_index=True, return_inverse=True)
    inv = inv.ravel()
    rep = first[inv]
    if not np.all(pw.spans_equal(buf, off, length, off[rep], length[rep])):  # pragma: no cover - 2^-64 odds
        raw = _strings_at(buf, off, length)
        _, first, inv = np.unique(raw, return_index=True, return_inverse=True)
        inv = inv.ravel()
    order = np.argsort(first)  # first-appearance order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    strings = _strings_at(buf, off[first[order]], length[first[order]])
    return rank[inv].astype(np.int64), strings


def _image_table(
    path: Path,
    serials: NDArray[np.str_],
    codes: NDArray[np.int64],
    header_serials: list[str],
    serial_to_image: Mapping[str, str] | None,
    image_ids: Sequence[str] | NDArray[np.str_] | None,
    drop_unknown: bool,
) -> tuple[NDArray[np.str_], NDArray[np.int64], NDArray[np.bool_] | None]:
    """The images table, each measure's image index, and the measures to keep (None: all)."""
    names = list(dict.fromkeys([*header_serials, *serials.tolist()]))
    mapped = np.array([serial_to_image.get(s, s) for s in names] if serial_to_image else names, dtype=str)
    pos_of_name = {s: i for i, s in enumerate(names)}
    serial_pos = np.array([pos_of_name[s] for s in serials.tolist()], np.int64)
    if image_ids is None:
        table, inv = np.unique(mapped, return_inverse=True) if mapped.size else (mapped, np.zeros(0, np.int64))
        # keep first-appearance order rather than sorted order
        first = np.full(table.size, mapped.size, np.int64)
        np.minimum.at(first, inv, np.arange(mapped.size))
        order = np.argsort(first)
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        return table[order], rank[inv][serial_pos][codes], None
    catalog = as_string_array(np.asarray(image_ids), "image_ids")
    lookup = {s: i for i, s in enumerate(catalog.tolist())}
    name_index = np.array([lookup.get(s, -1) for s in mapped.tolist()], np.int64)
    measure_image = name_index[serial_pos][codes] if codes.size else np.zeros(0, np.int64)
    unknown = measure_image < 0
    if serials.size and np.all(name_index[serial_pos] < 0):
        raise NetworkError(
            f"{path}: none of its {serials.size} serial numbers (e.g. {serials[0]!r}) matches an image of the "
            f"catalog ({catalog.size} images, e.g. {catalog[0] if catalog.size else 'none'!r}); give the "
            f"serial-number -> image-id mapping of this mission"
        )
    if unknown.any():
        missing = sorted({str(mapped[i]) for i in np.unique(serial_pos[codes[unknown]])})
        if not drop_unknown:
            raise NetworkError(
                f"{path}: {unknown.sum()} measures in {len(missing)} images not in the catalog, e.g. "
                f"{missing[0]!r}; add them to the mapping or pass drop_unknown=True"
            )
        measure_image = np.where(unknown, 0, measure_image)
        return catalog, measure_image, ~unknown
    return catalog, measure_image, None


def encode_isis_network(
    network: ControlNetwork,
    version: int = 5,
    image_to_serial: Mapping[str, str] | None = None,
    network_id: str | None = None,
    target_name: str | None = None,
    description: str | None = None,
    user_name: str | None = None,
    created: str | None = None,
    last_modified: str | None = None,
) -> bytes:
    """The bytes of an ISIS ``.net`` file holding ``network``.

    Parameters
    ----------
    network : the network (0-based pixels; written 1-based)
    version : 2 or 5
    image_to_serial : optional mapping our image id -> ISIS serial number
        (image ids not in it are written as they are)
    network_id, target_name, description, user_name, created, last_modified : the header texts
        (defaults: the network's metadata, then "mercury_dem", "Mercury", now). Point ids are written
        as text (int ids as decimals).
    """
    if version not in (2, 5):
        raise NetworkError(f"ISIS control network version {version} cannot be written (only 2 and 5)")
    net = network
    n, m = net.n_points, net.n_measures
    if m and (net.measure_point.min() < 0 or net.measure_point.max() >= n or net.measure_image.min() < 0 or net.measure_image.max() >= net.n_images):
        raise NetworkError("network has dangling point or image indices; run validate() and fix it before export")
    serial_names = net.image_ids
    if image_to_serial is not None:
        serial_names = np.array([image_to_serial.get(s, s) for s in net.image_ids.tolist()], dtype=str)
    ser_data, ser_off = encode_strings(serial_names)
    if net.point_ids.dtype.kind in "iu":
        pid_data, pid_off = pw.format_ints(net.point_ids.astype(np.int64))
    else:
        pid_data, pid_off = encode_strings(net.point_ids)
    first = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(net.measure_point, minlength=n), out=first[1:])
    if m and np.any(np.diff(net.measure_point) < 0):  # group measures by point (stable)
        net = net.replace(**take_measure_columns(net, np.argsort(net.measure_point, kind="stable")))
    mimage, sample, line = net.measure_image, net.sample + 1.0, net.line + 1.0
    mtype = net.measure_type.astype(np.int64)
    res, mign, mrej, sigma = net.residuals, net.measure_ignored, net.measure_rejected, net.sigma
    appix = net.apriori_pixels + 1.0
    ptype = net.point_type.astype(np.int64)
    apcov = net.apriori_covariance if net.apriori_covariance is not None else np.full((n, 6), np.nan)
    adcov = net.adjusted_covariance if net.adjusted_covariance is not None else np.full((n, 6), np.nan)
    apcov_ok = np.all(np.isfinite(apcov), axis=1)
    adcov_ok = np.all(np.isfinite(adcov), axis=1)
    ser_len = np.diff(ser_off)
    msize = pw.measure_sizes(ser_len, mimage, mtype, sample, line, res, mign, mrej, appix, sigma)
    psize = pw.point_sizes(np.diff(pid_off), ptype, net.point_ignored, net.point_rejected, net.apriori_xyz,
                           net.adjusted_xyz, apcov_ok, adcov_ok, first, msize)
    prefix = 4 if version == 5 else 0
    starts = np.zeros(n, np.int64)
    if n:
        np.cumsum(psize[:-1] + prefix, out=starts[1:])
    points_bytes = int(psize.sum() + prefix * n)
    body = np.zeros(points_bytes, np.uint8)
    scratch_f = np.zeros(1)
    pw.encode_points(
        body, starts, version == 5, pid_data, pid_off, ptype, net.point_ignored, net.point_rejected,
        net.apriori_xyz, net.adjusted_xyz, apcov, adcov, apcov_ok, adcov_ok, first, psize, msize,
        ser_data, ser_off, mimage, mtype, sample, line, res, mign, mrej, appix, sigma,
        scratch_f, scratch_f.view(np.uint8),
    )
    now = _timestamp()
    md = net.metadata
    texts = {
        1: network_id if network_id is not None else md.get("network_id", "mercury_dem"),
        2: target_name if target_name is not None else md.get("target_name", "Mercury"),
        3: created if created is not None else md.get("created", now),
        4: last_modified if last_modified is not None else now,
        5: description if description is not None else md.get("description", "written by mercury_dem"),
        6: user_name if user_name is not None else md.get("user_name", "mercury_dem"),
    }
    header = b"".join(pw.encode_field_bytes(f, str(v).encode("utf-8")) for f, v in texts.items())
    if version == 2:
        packed = b"".join(pw.encode_varint(int(s)) for s in psize) if n < 50_000 else _packed_varints(psize)
        header += pw.encode_field_bytes(7, packed)
    else:
        header += pw.encode_field_varint(7, n)
        header += b"".join(pw.encode_field_bytes(8, s.encode("utf-8")) for s in serial_names.tolist())
    label = _label(texts, len(header), points_bytes, n, m, version)
    return label + header + body.tobytes()


def _packed_varints(values: NDArray[np.int64]) -> bytes:
    """Packed varints of non-negative values, vectorized."""
    v = values.astype(np.uint64)
    nbytes = np.ones(v.size, np.int64)
    for k in range(1, 10):
        nbytes += v >= (np.uint64(1) << np.uint64(7 * k))
    out = np.zeros(int(nbytes.sum()), np.uint8)
    start = np.concatenate([[0], np.cumsum(nbytes)[:-1]])
    for k in range(int(nbytes.max())):
        sel = nbytes > k
        byte = (v[sel] >> np.uint64(7 * k)) & np.uint64(0x7F)
        more = nbytes[sel] > k + 1
        out[start[sel] + k] = (byte | (more.astype(np.uint64) << np.uint64(7))).astype(np.uint8)
    return out.tobytes()


def _label(texts: Mapping[int, str], header_bytes: int, points_bytes: int, n: int, m: int, version: int) -> bytes:
    text = (
        "Object = ProtoBuffer\n"
        "  Object = Core\n"
        f"    HeaderStartByte = {HEADER_START_BYTE}\n"
        f"    HeaderBytes     = {header_bytes}\n"
        f"    PointsStartByte = {HEADER_START_BYTE + header_bytes}\n"
        f"    PointsBytes     = {points_bytes}\n"
        "  End_Object\n\n"
        "  # This group is for informational purposes only\n"
        "  Group = ControlNetworkInfo\n"
        f"    NetworkId        = {_pvl_value(texts[1])}\n"
        f"    TargetName       = {_pvl_value(texts[2])}\n"
        f"    UserName         = {_pvl_value(texts[6])}\n"
        f"    Created          = {_pvl_value(texts[3])}\n"
        f"    LastModified     = {_pvl_value(texts[4])}\n"
        f"    Description      = {_pvl_value(texts[5])}\n"
        f"    NumberOfPoints   = {n}\n"
        f"    NumberOfMeasures = {m}\n"
        f"    Version          = {version}\n"
        "  End_Group\n"
        "End_Object\n"
        "End\n"
    ).encode()
    if len(text) > HEADER_START_BYTE:
        raise NetworkError("ISIS label longer than 65536 bytes; shorten the network description")
    return text + b"\0" * (HEADER_START_BYTE - len(text))


def _pvl_value(v: str) -> str:
    s = str(v).replace("\n", " ")
    return s if s and re.fullmatch(r"[A-Za-z0-9_.:+\-/]+", s) else '"' + s.replace('"', "'") + '"'


def label_fields(path: str | Path, data: bytes) -> dict[str, Any]:
    """The label keywords of a ``.net`` file from its first bytes (``path`` names it in messages)."""
    return dict(_parse_label(Path(path), data))


__all__ = ["decode_isis_network", "encode_isis_network", "label_fields", "HEADER_START_BYTE"]
