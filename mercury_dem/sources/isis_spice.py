"""Exterior orientation of a framing-camera image from the SPICE tables spiceinit attached to its cube.

Table conventions (``../shared/data/README.md``; ISIS3 ``Spice/Spice.cpp``,
``SpiceRotation``, ``SpicePosition``; checked on the real cubes in ``tests/sources``):

* ``InstrumentPointing`` and ``BodyRotation``: columns ``J2000Q0..Q3`` are SPICE quaternions
  (w, x, y, z) whose matrix ``q2m(q)`` rotates J2000 vectors into ``TimeDependentFrames[0]``;
  when the table has ``ConstantFrames``/``ConstantRotation`` (9 numbers, row-major), that
  matrix rotates ``TimeDependentFrames[0]`` (= ``ConstantFrames[-1]``) into
  ``ConstantFrames[0]``, the frame wanted (the NAIF instrument frame, e.g. MSGR_MDIS_NAC
  -236820; the body frame, e.g. the Moon's 310001). So J2000 -> frame = C . q2m(q), for both.
  ``ET`` is TDB seconds past J2000; ``AV1..3`` angular velocity (unused).
* ``InstrumentPosition``: ``J2000X/Y/Z`` the spacecraft relative to the target's centre, J2000,
  km; ``J2000XV..ZV`` its velocity, km/s. ``SunPosition``: the Sun relative to the target, same layout.
* Tables stored as polynomials (jigsaw's ``CacheType = PolyFunction``, columns ``J2000Ang1..``)
  are not read: run spiceinit again or use the ISD.

Exposure time: ISIS's MdisCamera takes the shutter-open time from ``SpacecraftClockCount``
and uses open + ExposureDuration/2; spiceinit stores the clock's ET as the NAIF keyword
``CLOCK_ET_<sc>_<clock>_COMPUTED`` (a double written as 16 hex digits, little-endian), so
that rule needs no clock kernel. For other framing cameras (Apollo Metric: ``StartTime`` is
the shutter centre) converting UTC needs a leapseconds kernel; instead the midpoint of the
pointing table's ``CkTableStartTime``/``CkTableEndTime`` is used: spiceinit caches a framing
image's tables over its exposure time, padded symmetrically, so the midpoint is that time.
Between records, quaternions are slerped (sign made continuous) and positions Hermite-
interpolated with the velocities (linearly without them). Light time and aberration are
whatever spiceinit applied; nothing is added here.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import CubeError
from mercury_dem.geometry.isd import QUATERNION_NORM_TOL, ROTATION_ORTHO_TOL, quaternion_to_matrix
from mercury_dem.sources.isis_cube import IsisCube, cube_fault
from mercury_dem.sources.isis_tables import CubeTable, naif_keywords, read_table

#: How far (s) the exposure time may lie outside the tables' time span.
TIME_TOLERANCE_S = 0.01
#: Bounds on table values before any arithmetic on them (a flipped exponent byte gives finite values near
#: 1e300 whose products overflow): ET within +-1e12 s of J2000 (~31,700 years), positions within 1e11 km
#: (~670 AU), velocities under 1e6 km/s (past light's 3e5). Found by the cube fuzz test at 2000 inputs
#: (quaternion components ~1e247 overflowed in the norm).
MAX_ABS_ET_S = 1e12
MAX_ABS_POSITION_KM = 1e11
MAX_ABS_VELOCITY_KM_S = 1e6
_RUN_SPICEINIT = "run spiceinit attach=true on it"


@dataclass(frozen=True, eq=False)
class CubeSpice:
    """Exterior orientation of a framing image at its exposure time, from the cube's SPICE tables.

    Attributes
    ----------
    source : the cube file (for messages)
    et : exposure centre, TDB seconds past J2000
    et_source : how ``et`` was found (see the module docstring)
    j2000_to_body : ndarray of shape (3, 3), rotates J2000 vectors into the body-fixed frame
    body_to_instrument : ndarray of shape (3, 3), body-fixed -> NAIF instrument frame (no axis
        flips: Apollo Metric looks along -Z of it, MDIS along +Z); a point X has instrument
        coordinates ``body_to_instrument @ (X - position)``
    position : ndarray of shape (3,), spacecraft, body-fixed metres
    sun_position : ndarray of shape (3,), Sun relative to the body centre, body-fixed metres
    ik_code : NAIF instrument code (Kernels ``NaifIkCode``/``NaifFrameCode``)
    instrument_frame_code, body_frame_code : NAIF frame codes the rotations end in
    radii_m : body radii (a, b, c) from the NaifKeywords, metres, or None
    serial_number : the ISIS serial number, or None for a mission without a rule here
    """

    source: str
    et: float
    et_source: str
    j2000_to_body: NDArray[np.float64]
    body_to_instrument: NDArray[np.float64]
    position: NDArray[np.float64]
    sun_position: NDArray[np.float64]
    ik_code: int
    instrument_frame_code: int
    body_frame_code: int
    radii_m: tuple[float, float, float] | None
    serial_number: str | None


# -- serial numbers ------------------------------------------------------------------

def isis_serial_number(label: Mapping[str, Any], source: str = "<label>") -> str:
    """The serial number ISIS gives an image (ISIS ``appdata/serialnumbers/*.trn``).

    MESSENGER MDIS: ``MeSSEnGeR/<InstrumentId>/<SpacecraftClockCount>`` — ISIS's
    MessengerMdisSerialNumber.trn really translates the spacecraft name to this mixed case
    (its own test networks carry e.g. ``MeSSEnGeR/MDIS-WAC/1/0211981114:916000``).
    Apollo 15/16/17 Metric: ``APOLLO15/METRIC/<Instrument StartTime as written>``.

    Raises CubeError naming ``source`` for another mission or a missing keyword.
    """
    cube = label.get("IsisCube") if isinstance(label, Mapping) else None
    inst = cube.get("Instrument") if isinstance(cube, Mapping) else None
    if not isinstance(inst, Mapping):
        raise CubeError(f"ISIS cube {source}: label has no IsisCube/Instrument group; cannot form a serial number")

    def key(name: str) -> str:
        value = inst.get(name)
        if value is None or isinstance(value, (Mapping, list, tuple)) or str(value) == "":
            raise CubeError(f"ISIS cube {source}: Instrument/{name} is missing or not a single value; "
                            "it is needed for the ISIS serial number")
        return str(value)

    craft = key("SpacecraftName").upper().replace(" ", "").replace("_", "")
    instrument = key("InstrumentId")
    if craft == "MESSENGER" and instrument.upper() in ("MDIS-NAC", "MDIS-WAC"):
        return f"MeSSEnGeR/{instrument}/{key('SpacecraftClockCount')}"
    if craft in ("APOLLO15", "APOLLO16", "APOLLO17") and instrument.upper() == "METRIC":
        return f"{craft}/{instrument}/{key('StartTime')}"
    raise CubeError(f"ISIS cube {source}: no serial-number rule for spacecraft {craft!r} instrument "
                    f"{instrument!r} (MESSENGER MDIS and Apollo Metric are known); add its ISIS rule here")


# -- tables ---------------------------------------------------------------------------

def _spice_table(cube: IsisCube, name: str) -> CubeTable:
    try:
        return read_table(cube, name)
    except CubeError as exc:
        if "has no table named" in str(exc):
            raise CubeError(f"ISIS cube {cube.path}: has no {name} table: {_RUN_SPICEINIT}") from None
        raise


def _columns(cube: IsisCube, table: CubeTable, names: tuple[str, ...]) -> NDArray[np.float64]:
    missing = [n for n in names if n not in table.columns or table.columns[n].ndim != 1]
    if missing:
        raise cube_fault(cube.path, f"table {table.name} lacks the columns {missing} (a polynomial table "
                                "written by jigsaw is not supported)", f"{_RUN_SPICEINIT} again, or use the ISD")
    out = np.stack([table.columns[n].astype(np.float64) for n in names], axis=-1)
    if out.shape[0] == 0 or not np.all(np.isfinite(out)):
        raise cube_fault(cube.path, f"table {table.name} has no records or non-finite values", f"{_RUN_SPICEINIT} again")
    return out


def _bounded(cube: IsisCube, table: CubeTable, values: NDArray[np.float64], bound: float, what: str) -> None:
    worst = float(np.abs(values).max())
    if worst > bound:
        raise cube_fault(cube.path, f"table {table.name} holds {what} of magnitude {worst:.3g} (more than {bound:g}): "
                                "the table is damaged", f"{_RUN_SPICEINIT} again")


def _times(cube: IsisCube, table: CubeTable) -> NDArray[np.float64]:
    t = _columns(cube, table, ("ET",))[:, 0]
    _bounded(cube, table, t, MAX_ABS_ET_S, "ET values (s)")
    if np.any(np.diff(t) <= 0):
        raise cube_fault(cube.path, f"table {table.name} ET values do not increase", f"{_RUN_SPICEINIT} again")
    return t


def _frames(table: CubeTable, key: str) -> tuple[int, ...]:
    value = table.keywords.get(key)
    value = value if isinstance(value, tuple) else (value,)
    return tuple(int(v) for v in value if isinstance(v, int) and not isinstance(v, bool))


def _constant_rotation(cube: IsisCube, table: CubeTable) -> NDArray[np.float64]:
    value = table.keywords.get("ConstantRotation")
    if value is None:
        return np.eye(3)
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (9,) or not np.all(np.isfinite(m)):
        raise cube_fault(cube.path, f"table {table.name} ConstantRotation must be 9 numbers, got {value!r}")
    m = m.reshape(3, 3)
    err = float(np.abs(m @ m.T - np.eye(3)).max())
    if err > ROTATION_ORTHO_TOL or np.linalg.det(m) < 0:
        raise cube_fault(cube.path, f"table {table.name} ConstantRotation is not a rotation (|M M^T - I| = {err:.2e})")
    return m


def _bracket(cube: IsisCube, table: CubeTable, times: NDArray[np.float64], et: float) -> tuple[int, float]:
    """Index i and fraction f with et = times[i] + f (times[i+1] - times[i]); one record gives (0, 0)."""
    if not times[0] - TIME_TOLERANCE_S <= et <= times[-1] + TIME_TOLERANCE_S:
        raise cube_fault(cube.path, f"table {table.name} covers ET {times[0]:.6f}..{times[-1]:.6f} s, not the "
                                f"exposure time {et:.6f} s", f"{_RUN_SPICEINIT} again")
    if times.size == 1:
        return 0, 0.0
    i = int(np.clip(np.searchsorted(times, et) - 1, 0, times.size - 2))
    return i, float(np.clip((et - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0))


def _rotation_at(cube: IsisCube, table: CubeTable, et: float) -> NDArray[np.float64]:
    """J2000 -> ConstantFrames[0] (or TimeDependentFrames[0]) rotation (3, 3) at ``et``."""
    q = _columns(cube, table, ("J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3"))
    # a unit quaternion's components are within [-1, 1]: larger ones are refused before the norm can overflow
    norms = np.where(np.all(np.abs(q) <= 1.0 + QUATERNION_NORM_TOL, axis=1),
                     np.linalg.norm(np.clip(q, -2.0, 2.0), axis=1), np.inf)
    if np.any(np.abs(norms - 1.0) > QUATERNION_NORM_TOL):
        raise cube_fault(cube.path, f"table {table.name} holds non-unit quaternions (norms {norms.min():.9f}.."
                                f"{norms.max():.9f})", f"{_RUN_SPICEINIT} again")
    i, f = _bracket(cube, table, _times(cube, table), et)
    q0 = q[i]
    if f > 0.0:
        q1 = q[i + 1] if np.dot(q0, q[i + 1]) >= 0 else -q[i + 1]
        theta = math.acos(min(1.0, float(np.dot(q0, q1)) / float(np.linalg.norm(q0) * np.linalg.norm(q1))))
        if theta < 1e-12:
            q0 = (1 - f) * q0 + f * q1
        else:
            q0 = (math.sin((1 - f) * theta) * q0 + math.sin(f * theta) * q1) / math.sin(theta)
    return _constant_rotation(cube, table) @ quaternion_to_matrix(q0)


def _position_at(cube: IsisCube, table: CubeTable, et: float) -> NDArray[np.float64]:
    """Position (3,) in J2000 km at ``et``: Hermite with the velocity columns, else linear."""
    p = _columns(cube, table, ("J2000X", "J2000Y", "J2000Z"))
    _bounded(cube, table, p, MAX_ABS_POSITION_KM, "positions (km)")
    i, f = _bracket(cube, table, _times(cube, table), et)
    if f == 0.0:
        return p[i]
    if all(c in table.columns for c in ("J2000XV", "J2000YV", "J2000ZV")):
        v = _columns(cube, table, ("J2000XV", "J2000YV", "J2000ZV"))
        _bounded(cube, table, v, MAX_ABS_VELOCITY_KM_S, "velocities (km/s)")
        t = table.columns["ET"]
        dt = float(t[i + 1] - t[i])
        h00, h10 = 2 * f**3 - 3 * f**2 + 1, f**3 - 2 * f**2 + f
        h01, h11 = -2 * f**3 + 3 * f**2, f**3 - f**2
        return h00 * p[i] + h10 * dt * v[i] + h01 * p[i + 1] + h11 * dt * v[i + 1]
    return (1 - f) * p[i] + f * p[i + 1]


# -- exposure time ------------------------------------------------------------------

def _clock_et(naif: Mapping[str, Any], clock: str) -> float | None:
    """ET of a spacecraft clock string from spiceinit's ``CLOCK_ET_<sc>_<clock>_COMPUTED`` keyword."""
    for k, v in naif.items():
        if k.startswith("CLOCK_ET_") and k.endswith(f"_{clock}_COMPUTED"):
            text = v if isinstance(v, str) else (str(v).zfill(16) if isinstance(v, int) else "")
            try:
                et = struct.unpack("<d", bytes.fromhex(text))[0]
            except (ValueError, struct.error):
                return None
            return et if math.isfinite(et) else None
    return None


def exposure_time(cube: IsisCube, pointing: CubeTable, naif: Mapping[str, Any]) -> tuple[float, str]:
    """Exposure centre (TDB s past J2000) and how it was found; see the module docstring."""
    if (cube.instrument_id or "").upper().startswith("MDIS") and cube.spacecraft_clock_count \
            and cube.exposure_duration_s is not None:
        et = _clock_et(naif, cube.spacecraft_clock_count)
        if et is not None:
            return et + cube.exposure_duration_s / 2, "MDIS: SpacecraftClockCount ET + ExposureDuration/2"
    lo, hi = pointing.keywords.get("CkTableStartTime"), pointing.keywords.get("CkTableEndTime")
    if all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in (lo, hi)):
        return (float(lo) + float(hi)) / 2, "midpoint of CkTableStartTime/CkTableEndTime"
    t = _times(cube, pointing)
    return float((t[0] + t[-1]) / 2), "midpoint of the InstrumentPointing ET column"


# -- the pose ------------------------------------------------------------------------

def _radii(naif: Mapping[str, Any]) -> tuple[float, float, float] | None:
    for k, v in naif.items():
        if (k.startswith("BODY") and k.endswith("_RADII") and isinstance(v, tuple) and len(v) == 3
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in v)):
            return (float(v[0]) * 1e3, float(v[1]) * 1e3, float(v[2]) * 1e3)
    return None


def _ik_code(cube: IsisCube, pointing: CubeTable) -> int:
    kernels = cube.label["IsisCube"].get("Kernels")
    for key in ("NaifIkCode", "NaifFrameCode"):
        v = kernels.get(key) if isinstance(kernels, Mapping) else None
        if isinstance(v, int) and not isinstance(v, bool):
            return v
    frames = _frames(pointing, "ConstantFrames") or _frames(pointing, "TimeDependentFrames")
    if not frames:
        raise cube_fault(cube.path, "neither Kernels/NaifIkCode nor the pointing table's frames give the "
                                "instrument code", f"{_RUN_SPICEINIT} again")
    return frames[0]


def cube_spice(cube: IsisCube) -> CubeSpice:
    """Position, rotations and Sun of a framing image at its exposure centre, from its attached SPICE.

    Parameters
    ----------
    cube : from :func:`~mercury_dem.sources.isis_cube.open_cube`, spiceinit'ed with attach=true

    Returns
    -------
    CubeSpice (body-fixed metres; rotations J2000 -> body and body -> NAIF instrument frame)

    Raises
    ------
    CubeError
        naming the file: a SPICE table is missing ("run spiceinit attach=true on it"), damaged,
        stored as a polynomial, or does not cover the exposure time.
    """
    pointing = _spice_table(cube, "InstrumentPointing")
    body = _spice_table(cube, "BodyRotation")
    position_t = _spice_table(cube, "InstrumentPosition")
    sun_t = _spice_table(cube, "SunPosition")
    try:
        naif = naif_keywords(cube)
    except CubeError:
        naif = {}
    et, how = exposure_time(cube, pointing, naif)
    j2b = _rotation_at(cube, body, et)
    j2i = _rotation_at(cube, pointing, et)
    position = j2b @ _position_at(cube, position_t, et) * 1e3
    sun = j2b @ _position_at(cube, sun_t, et) * 1e3
    try:
        serial: str | None = isis_serial_number(cube.label, str(cube.path))
    except CubeError:
        serial = None
    frame_i = (_frames(pointing, "ConstantFrames") or _frames(pointing, "TimeDependentFrames") or (0,))[0]
    frame_b = (_frames(body, "ConstantFrames") or _frames(body, "TimeDependentFrames") or (0,))[0]
    return CubeSpice(source=str(cube.path), et=et, et_source=how, j2000_to_body=j2b,
                     body_to_instrument=j2i @ j2b.T, position=position, sun_position=sun,
                     ik_code=_ik_code(cube, pointing), instrument_frame_code=frame_i, body_frame_code=frame_b,
                     radii_m=_radii(naif), serial_number=serial)
