"""Attached tables, NAIF keywords and the AlphaCube crop of an ISIS3 cube.

Layout facts (``../shared/data/README.md``; ISIS3 ``Table/Table.cpp``,
``TableRecord/TableRecord.cpp``, ``TableField/TableField.cpp``, ``AlphaCube/AlphaCube.cpp``):

* ``Object = Table`` at the label's top level: ``Name``, ``StartByte`` (1-based),
  ``Bytes``, ``Records``, ``ByteOrder``, then one ``Group = Field`` per column
  (``Name``, ``Type`` Double 8 / Integer 4 / Real 4 bytes / Text 1 byte per character,
  ``Size`` values). Records are packed back to back with no padding;
  ``Bytes = Records * record size``. Text fields are NUL-padded character arrays.
* ``Object = NaifKeywords``: the NAIF kernel-pool values spiceinit used (lists are tuples here).
* ``Group = AlphaCube`` (in ``IsisCube``): a crop/reduce of the original ("alpha") image
  to this ("beta") one. With ISIS 1-based pixel-centre coordinates,
  ``alpha = slope * (beta - 0.5) + AlphaStartingSample``,
  ``slope = (AlphaEndingSample - AlphaStartingSample) / BetaSamples`` (likewise lines): the
  starting/ending values are the alpha positions of the beta image's outer pixel edges.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import CubeError
from mercury_dem.geometry.naif_camera import AlphaCube
from mercury_dem.sources.isis_cube import IsisCube, cube_fault, label_float, label_int, pvl_scalar, read_cube_bytes

_FIELD_TYPES = {"Double": ("f8", 8), "Integer": ("i4", 4), "Real": ("f4", 4), "Text": ("S", 1)}
#: Largest ``Size`` of one field (values per record) accepted.
MAX_FIELD_SIZE = 2**20


@dataclass(frozen=True, eq=False)
class CubeTable:
    """One attached ISIS table.

    Attributes
    ----------
    name : the table's ``Name``
    records : number of records
    columns : field name -> ndarray of shape (records,) (``Size`` 1, or Text: str) or
        (records, size); numbers as float64 (Double), int32 (Integer), float32 (Real)
    keywords : the table object's keywords other than its fields (e.g.
        ``TimeDependentFrames``, ``CkTableStartTime``), lists as tuples
    """

    name: str
    records: int
    columns: dict[str, NDArray[Any]]
    keywords: dict[str, Any]


def _plain(value: Any) -> Any:
    """A PVL value as plain Python: quantities lose their unit, lists become tuples."""
    value = pvl_scalar(value)
    if isinstance(value, (list, tuple, set)):
        return tuple(_plain(v) for v in value)
    return value


def _find_table(cube: IsisCube, name: str) -> Mapping[str, Any] | None:
    items = cube.label.items() if isinstance(cube.label, Mapping) else ()
    for key, node in items:
        if key == "Table" and isinstance(node, Mapping) and str(pvl_scalar(node.get("Name"))) == name:
            return node
    return None


def table_names(cube: IsisCube) -> tuple[str, ...]:
    """Names of the tables attached to a cube, in label order."""
    return tuple(str(pvl_scalar(n.get("Name"))) for k, n in cube.label.items()
                 if k == "Table" and isinstance(n, Mapping))


def read_table(cube: IsisCube, name: str) -> CubeTable:
    """Read one attached table.

    Parameters
    ----------
    cube : from :func:`~mercury_dem.sources.isis_cube.open_cube`
    name : the table's ``Name`` (e.g. ``"InstrumentPointing"``, ``"CameraStatistics"``)

    Raises
    ------
    CubeError
        naming the file and the table when it is missing, its fields are invalid, its size
        disagrees with its records, or its bytes run past the end of the file.
    """
    node = _find_table(cube, name)
    if node is None:
        raise CubeError(f"ISIS cube {cube.path}: has no table named {name!r} (it has: "
                        f"{', '.join(table_names(cube)) or 'none'}); run the ISIS program that makes it "
                        "(e.g. spiceinit attach=true for the SPICE tables)")
    where = f"Table {name}: "
    records = label_int(cube.path, node, "Records", where, 0)
    start = label_int(cube.path, node, "StartByte", where, 1)
    nbytes = label_int(cube.path, node, "Bytes", where, 0)
    order = str(pvl_scalar(node.get("ByteOrder", "Lsb"))).capitalize()
    if order not in ("Lsb", "Msb"):
        raise cube_fault(cube.path, f"{where}ByteOrder must be Lsb or Msb, got {order!r}")
    fields: list[tuple[str, str, int]] = []
    for key, group in node.items():
        if key != "Field" or not isinstance(group, Mapping):
            continue
        fname = str(pvl_scalar(group.get("Name")))
        ftype = str(pvl_scalar(group.get("Type")))
        if ftype not in _FIELD_TYPES:
            raise cube_fault(cube.path, f"{where}field {fname!r} has unknown type {ftype!r}")
        size = label_int(cube.path, group, "Size", f"{where}field {fname!r} ", 1)
        if size > MAX_FIELD_SIZE:
            raise cube_fault(cube.path, f"{where}field {fname!r} Size {size} is absurd")
        if any(f[0] == fname for f in fields):
            raise cube_fault(cube.path, f"{where}field {fname!r} appears twice")
        fields.append((fname, ftype, size))
    if not fields:
        raise cube_fault(cube.path, f"{where}has no Field groups")
    record_bytes = sum(_FIELD_TYPES[t][1] * s for _, t, s in fields)
    if records * record_bytes != nbytes:
        raise cube_fault(cube.path, f"{where}Bytes = {nbytes} but {records} records of {record_bytes} bytes "
                                f"make {records * record_bytes}")
    if start - 1 + nbytes > cube.file_size:
        raise cube_fault(cube.path, f"truncated: table {name!r} ends at byte {start - 1 + nbytes}, the file has "
                                f"{cube.file_size}", "fetch or copy the file again")
    endian = "<" if order == "Lsb" else ">"
    # numpy field names are positional (c0, c1, ...): the label's names may be anything.
    dtype = np.dtype([(f"c{k}", (f"S{s}" if t == "Text" else endian + _FIELD_TYPES[t][0],
                                 () if (s == 1 or t == "Text") else (s,))) for k, (_, t, s) in enumerate(fields)])
    data = np.frombuffer(read_cube_bytes(cube, start - 1, nbytes), dtype=dtype, count=records)
    columns: dict[str, NDArray[Any]] = {}
    for k, (f, t, _) in enumerate(fields):
        col = data[f"c{k}"]
        if t == "Text":
            columns[f] = np.array([v.rstrip(b"\0 ").decode("utf-8", errors="replace") for v in col], dtype=str)
        else:
            columns[f] = col.astype(col.dtype.newbyteorder("="))
    keywords = {k: _plain(v) for k, v in node.items() if k != "Field"}
    return CubeTable(name=name, records=records, columns=columns, keywords=keywords)


def naif_keywords(cube: IsisCube) -> dict[str, Any]:
    """The ``NaifKeywords`` object: NAIF kernel-pool name -> value (float, int, str, bool or tuple).

    Raises CubeError naming the file when the cube has none (spiceinit writes it).
    """
    node = cube.label.get("NaifKeywords") if isinstance(cube.label, Mapping) else None
    if not isinstance(node, Mapping):
        raise CubeError(f"ISIS cube {cube.path}: has no NaifKeywords object; run spiceinit attach=true on it")
    return {str(k): _plain(v) for k, v in node.items()}


def alpha_cube(cube: IsisCube) -> AlphaCube | None:
    """The cube's AlphaCube group (the camera model's :class:`~mercury_dem.geometry.naif_camera.AlphaCube`),
    or None when it was never cropped or reduced.

    Raises CubeError naming the file when the group is inconsistent (non-positive sizes,
    ending <= starting, BetaSamples/BetaLines not the cube's size).
    """
    group = cube.label["IsisCube"].get("AlphaCube")
    if group is None:
        return None
    if not isinstance(group, Mapping):
        raise cube_fault(cube.path, "IsisCube/AlphaCube is not a group")
    w = "IsisCube/AlphaCube/"
    p = cube.path
    a_s, a_l = label_int(p, group, "AlphaSamples", w, 1), label_int(p, group, "AlphaLines", w, 1)
    s0, s1 = label_float(p, group, "AlphaStartingSample", w), label_float(p, group, "AlphaEndingSample", w)
    l0, l1 = label_float(p, group, "AlphaStartingLine", w), label_float(p, group, "AlphaEndingLine", w)
    bs, bl = label_int(p, group, "BetaSamples", w, 1), label_int(p, group, "BetaLines", w, 1)
    if not (s1 > s0 and l1 > l0):
        raise cube_fault(p, f"{w}ending sample/line must exceed the starting ones ({s0}..{s1}, {l0}..{l1})")
    if (bs, bl) != (cube.samples, cube.lines):
        raise cube_fault(p, f"{w}BetaSamples x BetaLines = {bs} x {bl} is not the cube's "
                        f"size {cube.samples} x {cube.lines}")
    # ISIS: alpha = slope (beta - 0.5) + AlphaStarting, 1-based; ours: start = AlphaStarting - 0.5
    return AlphaCube(a_s, a_l, s0 - 0.5, l0 - 0.5, (s1 - s0) / bs, (l1 - l0) / bl)
