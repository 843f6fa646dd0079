"""ISIS3 cubes read without ISIS: the label (pixels in :mod:`~mercury_dem.sources.isis_pixels`).

Why here: ISIS is a large C++ install with its own data area; GDAL's ISIS3 driver reads
pixels but not the attached SPICE tables, and ``ale`` needs SPICE kernels. A cube that
``spiceinit attach=true`` has processed carries everything we need (pixels, SPICE
tables, NAIF keywords), so a small reader of the documented layout is enough.

Layout facts used (``../shared/data/README.md``, "Real pixels", and the ISIS3 sources:
``Cube/CubeTileHandler.cpp``, ``Cube/CubeIoHandler.cpp``, ``SpecialPixel/SpecialPixel.h``):

* The label is PVL text at byte 0 ending at a line ``End`` (then zero padding up to
  ``Object = Label``'s ``Bytes``). ``Object = IsisCube`` / ``Object = Core`` holds
  ``StartByte`` (1-based), ``Format`` (``Tile`` or ``BandSequential``), ``TileSamples``/
  ``TileLines``, ``Group = Dimensions`` (``Samples``, ``Lines``, ``Bands``) and
  ``Group = Pixels`` (``Type``, ``ByteOrder`` Lsb/Msb, ``Base``, ``Multiplier``).
* The core holds Samples x Lines x Bands pixels of the type's size from ``StartByte``
  (Tile: whole tiles, edge tiles padded); its end must lie within the file.

Every fault is a :class:`~mercury_dem.exceptions.CubeError` naming the file; sizes are
checked against the file size before anything is allocated.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

with warnings.catch_warnings():
    # pvl 1.3 warns on import: ImportWarning when the optional 'multidict' package is absent (we do
    # not use it) and PendingDeprecationWarning for its own pvl.collections.Units class.
    warnings.simplefilter("ignore", ImportWarning)
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import pvl
    from pvl.decoder import OmniDecoder
    from pvl.grammar import OmniGrammar

from mercury_dem.exceptions import CubeError

#: Bytes of one stored pixel, by ISIS pixel type.
PIXEL_BYTES = {"Real": 4, "SignedWord": 2, "UnsignedWord": 2, "UnsignedByte": 1}
#: Largest label we look for the ``End`` line in (labels are a few tens of kB).
MAX_LABEL_BYTES = 16 * 2**20

_END_LINE = re.compile(rb"(?m)^End[ \t]*\r?$")


class _StringTimeDecoder(OmniDecoder):
    """PVL decoder that keeps date-times as the strings written (serial numbers need them)."""

    def decode_datetime(self, value: str) -> Any:
        raise ValueError(value)


@dataclass(frozen=True, eq=False)
class IsisCube:
    """An ISIS3 cube's label and the facts needed to read it.

    Attributes
    ----------
    path : the cube file
    label : the whole PVL label (a mapping; ``label["IsisCube"]["Core"]`` ...)
    samples, lines, bands : image size
    pixel_type : ``"Real"``, ``"SignedWord"``, ``"UnsignedWord"`` or ``"UnsignedByte"``
    byte_order : ``"Lsb"`` or ``"Msb"``
    base, multiplier : physical value = base + multiplier * stored (integer types)
    core_start_byte : 1-based byte of the first pixel (ISIS ``StartByte``)
    core_format : ``"Tile"`` or ``"BandSequential"``
    tile_samples, tile_lines : tile size; for BandSequential the band size (one tile a band)
    file_size : bytes of the file when it was opened
    spacecraft_name, instrument_id, target_name, start_time : from ``Group = Instrument``
        (``start_time`` the string as written, UTC)
    spacecraft_clock_count : ``SpacecraftClockCount`` when present
    exposure_duration_s : ``ExposureDuration`` in seconds (label unit ms) when present
    summing : detector summing when the label says it (MDIS: PixelBinningMode x 2 when
        FpuBinningMode = 1, as ISIS's MdisCamera; else ``Summing``/``SummingMode``)
    filter : ``BandBin`` ``Name`` or ``FilterName`` when present
    """

    path: Path
    label: Mapping[str, Any]
    samples: int
    lines: int
    bands: int
    pixel_type: str
    byte_order: str
    base: float
    multiplier: float
    core_start_byte: int
    core_format: str
    tile_samples: int
    tile_lines: int
    file_size: int
    spacecraft_name: str | None = None
    instrument_id: str | None = None
    target_name: str | None = None
    start_time: str | None = None
    spacecraft_clock_count: str | None = None
    exposure_duration_s: float | None = None
    summing: int | None = None
    filter: str | None = None

    @property
    def band_bytes(self) -> int:
        """Stored bytes of one band, padding of the edge tiles included."""
        nts = -(-self.samples // self.tile_samples)
        ntl = -(-self.lines // self.tile_lines)
        return nts * ntl * self.tile_samples * self.tile_lines * PIXEL_BYTES[self.pixel_type]


# -- label access with errors that name the file -------------------------------------

def cube_fault(path: Path, what: str, todo: str = "the file is damaged or not an ISIS3 cube; "
           "re-export it with ISIS (e.g. cubeatt) or fetch it again") -> CubeError:
    """The :class:`CubeError` of a damaged or unexpected cube: ``ISIS cube PATH: FAULT; ADVICE`` (the fault, then what the user can do)."""
    return CubeError(f"ISIS cube {path}: {what}; {todo}")


def _group(path: Path, node: Any, name: str, where: str) -> Mapping[str, Any]:
    value = node.get(name) if isinstance(node, Mapping) else None
    if not isinstance(value, Mapping):
        raise cube_fault(path, f"label has no {where}{name}")
    return value


def pvl_scalar(value: Any) -> Any:
    """The value of a PVL quantity (``1 <MS>``) or the value itself."""
    return value.value if hasattr(value, "units") and hasattr(value, "value") else value


def label_int(path: Path, node: Mapping[str, Any], key: str, where: str, minimum: int = 0) -> int:
    """An integer keyword >= ``minimum``; CubeError naming the file otherwise."""
    value = pvl_scalar(node.get(key)) if isinstance(node, Mapping) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value != int(value) or value < minimum:
        raise cube_fault(path, f"{where}{key} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def label_float(path: Path, node: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    """A finite number keyword (``default`` when absent and a default is given)."""
    if default is not None and (not isinstance(node, Mapping) or key not in node):
        return default
    value = pvl_scalar(node.get(key)) if isinstance(node, Mapping) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise cube_fault(path, f"{where}{key} must be a finite number, got {value!r}")
    return float(value)


def _opt_str(node: Any, key: str) -> str | None:
    if not isinstance(node, Mapping) or key not in node:
        return None
    value = pvl_scalar(node[key])
    if isinstance(value, (list, tuple)):
        return ", ".join(str(v) for v in value)
    return None if value is None else str(value)


def _opt_number(node: Any, key: str) -> float | None:
    value = pvl_scalar(node.get(key)) if isinstance(node, Mapping) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


# -- opening ------------------------------------------------------------------------

def read_label_text(path: Path, file_size: int) -> str:
    """The label text from byte 0 through its ``End`` line."""
    limit = min(file_size, MAX_LABEL_BYTES)
    try:
        with open(path, "rb") as fh:
            head = b""
            size = 65536
            while True:
                head = fh.read(min(size, limit))
                m = _END_LINE.search(head)
                if m or len(head) >= limit:
                    break
                fh.seek(0)
                size *= 4
    except OSError as exc:
        raise CubeError(f"ISIS cube {path}: cannot be read ({exc.strerror or exc}); check the path") from None
    if not head.startswith(b"Object") and b"IsisCube" not in head[:4096]:
        raise cube_fault(path, "no PVL label at byte 0 (not an ISIS3 cube)", "give the path of a .cub file")
    if m is None:
        raise cube_fault(path, f"label has no 'End' line in its first {limit} bytes (truncated or not a cube)")
    raw = head[: m.end()]
    if b"\0" in raw:
        raw = raw.split(b"\0", 1)[0]
    return raw.decode("utf-8", errors="replace")


_AGGREGATE = re.compile(r"(?i)^\s*(Object|Group)\s*=\s*(.*?)\s*$")
_END_AGGREGATE = re.compile(r"(?i)^\s*End_(Object|Group)\b\s*(?:=\s*(.*?)\s*)?$")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_:]*")


def check_label_structure(path: Path, text: str) -> None:
    """Check, in one pass over the lines, that every ``Object``/``Group`` has a name and a matching end.

    Why our own pass before :mod:`pvl`: pvl 1.3's permissive parser (the one the real MDIS
    labels need, for their ``-`` line continuations) does not return on some malformed
    labels (an ``Object =`` with no name made it loop for hours inside a fuzz test; found by
    ``tests/sources/test_fuzz.py``). ISIS itself refuses such labels, so refusing them here
    first costs nothing and bounds the time pvl can take. Lines inside double-quoted
    strings and ``/* */`` comments are skipped.
    """
    stack: list[tuple[str, str, int]] = []
    in_string = in_comment = False
    for number, line in enumerate(text.splitlines(), start=1):
        if in_comment:
            if "*/" not in line:
                continue
            line, in_comment = line.split("*/", 1)[1], False
        starts_in_string = in_string
        if line.count('"') % 2:
            in_string = not in_string
        if starts_in_string:
            continue
        if "/*" in line and "*/" not in line.split("/*", 1)[1]:
            in_comment = True
        m = _AGGREGATE.match(line)
        if m:
            kind, name = m.group(1).capitalize(), m.group(2).strip('"')
            if not _NAME.fullmatch(name):
                raise cube_fault(path, f"label line {number}: {kind} has no valid name ({m.group(2)!r})",
                             "the label is damaged; fetch or copy the cube again")
            stack.append((kind, name, number))
            continue
        m = _END_AGGREGATE.match(line)
        if m:
            kind = m.group(1).capitalize()
            if not stack or stack[-1][0] != kind:
                opened = f"the open {stack[-1][0]} {stack[-1][1]} (line {stack[-1][2]})" if stack else "nothing open"
                raise cube_fault(path, f"label line {number}: End_{kind} does not close {opened}",
                             "the label is damaged; fetch or copy the cube again")
            stack.pop()
    if stack:
        kind, name, number = stack[-1]
        raise cube_fault(path, f"label: {kind} {name} (line {number}) has no End_{kind}",
                     "the label is damaged; fetch or copy the cube again")


def parse_label(path: Path, text: str) -> Mapping[str, Any]:
    """The PVL label as a mapping; CubeError for text pvl cannot parse (or that would not return from it)."""
    check_label_structure(path, text)
    try:
        grammar = OmniGrammar()
        return pvl.loads(text, grammar=grammar, decoder=_StringTimeDecoder(grammar=grammar))
    except Exception as exc:  # pvl raises many types (LexerError, ParseError, ValueError ...)
        first = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise cube_fault(path, f"label is not valid PVL ({first})") from None


def _summing(inst: Mapping[str, Any] | None) -> int | None:
    if not isinstance(inst, Mapping):
        return None
    fpu, pix = _opt_number(inst, "FpuBinningMode"), _opt_number(inst, "PixelBinningMode")
    if fpu is not None and pix is not None:  # MDIS, as ISIS's MdisCamera
        s = 1 if pix == 0 else int(pix)
        return s * 2 if fpu == 1 else s
    for key in ("Summing", "SummingMode", "SampleDetectorSumming"):
        v = _opt_number(inst, key)
        if v is not None and v >= 1 and v == int(v):
            return int(v)
    return None


def open_cube(path: str | Path) -> IsisCube:
    """Parse an ISIS3 cube's label and check that its pixels are all in the file.

    Parameters
    ----------
    path : the ``.cub`` file (attached label; detached labels are not supported)

    Returns
    -------
    IsisCube

    Raises
    ------
    CubeError
        naming the file, when it cannot be read, has no ``IsisCube`` object, an
        unparseable label, an unknown pixel type or format, sizes <= 0, or a core that
        runs past the end of the file (truncated).
    """
    p = Path(path)
    try:
        file_size = p.stat().st_size
    except OSError as exc:
        raise CubeError(f"ISIS cube {p}: cannot be read ({exc.strerror or exc}); check the path") from None
    label = parse_label(p, read_label_text(p, file_size))
    cube = _group(p, label, "IsisCube", "")
    core = _group(p, cube, "Core", "IsisCube/")
    if "^Core" in core or "^Core" in cube:
        raise cube_fault(p, "has a detached core (^Core)", "merge it into one file with ISIS cubeatt")
    dims = _group(p, core, "Dimensions", "IsisCube/Core/")
    pix = _group(p, core, "Pixels", "IsisCube/Core/")
    where = "IsisCube/Core/Dimensions/"
    samples = label_int(p, dims, "Samples", where, 1)
    lines = label_int(p, dims, "Lines", where, 1)
    bands = label_int(p, dims, "Bands", where, 1)
    ptype = _opt_str(pix, "Type")
    if ptype not in PIXEL_BYTES:
        raise cube_fault(p, f"pixel type {ptype!r} is not supported (only {', '.join(PIXEL_BYTES)})",
                     "convert it with ISIS cubeatt (e.g. to real)")
    order = (_opt_str(pix, "ByteOrder") or "Lsb").capitalize()
    if order not in ("Lsb", "Msb"):
        raise cube_fault(p, f"IsisCube/Core/Pixels/ByteOrder must be Lsb or Msb, got {order!r}")
    base = label_float(p, pix, "Base", "IsisCube/Core/Pixels/", 0.0)
    mult = label_float(p, pix, "Multiplier", "IsisCube/Core/Pixels/", 1.0)
    if ptype != "Real":
        top = abs(base) + abs(mult) * {"SignedWord": 32767, "UnsignedWord": 65522, "UnsignedByte": 254}[ptype]
        if not top < float(np.finfo(np.float32).max):
            raise cube_fault(p, f"Base {base} and Multiplier {mult} take {ptype} values beyond float32")
    start = label_int(p, core, "StartByte", "IsisCube/Core/", 1)
    fmt = _opt_str(core, "Format")
    if fmt == "Tile":
        ts = label_int(p, core, "TileSamples", "IsisCube/Core/", 1)
        tl = label_int(p, core, "TileLines", "IsisCube/Core/", 1)
    elif fmt == "BandSequential":
        ts, tl = samples, lines
    else:
        raise cube_fault(p, f"core format {fmt!r} is not supported (Tile or BandSequential)")
    out = IsisCube(path=p, label=label, samples=samples, lines=lines, bands=bands, pixel_type=ptype,
                   byte_order=order, base=base, multiplier=mult, core_start_byte=start, core_format=fmt,
                   tile_samples=ts, tile_lines=tl, file_size=file_size)
    end = start - 1 + out.band_bytes * bands
    if end > file_size:
        raise cube_fault(p, f"truncated: its {samples} x {lines} x {bands} {ptype} core ends at byte {end} "
                        f"but the file has {file_size} bytes", "fetch or copy the file again")
    inst = cube.get("Instrument")
    exp = _opt_number(inst, "ExposureDuration")
    bandbin = cube.get("BandBin")
    return replace(
        out,
        spacecraft_name=_opt_str(inst, "SpacecraftName"),
        instrument_id=_opt_str(inst, "InstrumentId"),
        target_name=_opt_str(inst, "TargetName"),
        start_time=_opt_str(inst, "StartTime"),
        spacecraft_clock_count=_opt_str(inst, "SpacecraftClockCount"),
        exposure_duration_s=None if exp is None else exp / 1000.0,
        summing=_summing(inst),
        filter=_opt_str(bandbin, "Name") or _opt_str(bandbin, "FilterName"),
    )


def read_cube_bytes(cube: IsisCube, offset: int, count: int) -> bytes:
    """``count`` bytes of ``cube``'s file from byte ``offset``; CubeError naming the file when unreadable or short."""
    try:
        with open(cube.path, "rb") as fh:
            fh.seek(offset)
            data = fh.read(count)
    except OSError as exc:
        raise CubeError(f"ISIS cube {cube.path}: cannot be read ({exc.strerror or exc}); check the path") from None
    if len(data) != count:
        raise cube_fault(cube.path, f"truncated: {count} bytes wanted at byte {offset}, {len(data)} there",
                     "fetch or copy the file again")
    return data
