"""Read CSM frame-camera image support data (ISD) into our camera, pose and sun position.

Two flavours of JSON are understood (both as the USGS tools write them):

``ale``
    The ALE/ISIS layout (``instrument_position``, ``instrument_pointing``,
    ``body_rotation``, ``sun_position``). Positions are J2000 kilometres relative to
    the target's centre; rotations are quaternions **(w, x, y, z)** (scalar first,
    SPICE/ISIS order) whose matrix ``q2m(q)`` rotates J2000 vectors **into** the
    named frame: ``v_frame = q2m(q) @ v_J2000``. ``body_rotation`` is J2000 ->
    body-fixed, ``instrument_pointing`` J2000 -> the first of its
    ``time_dependent_frames``, and ``constant_rotation`` (3 x 3, row-major) that frame
    -> the instrument frame. ``sun_position`` is the Sun relative to the target.
``usgscsm``
    The usgscsm layout (``sensor_position``, ``sensor_orientation``): position
    body-fixed, in the ``unit`` given (metres by default); the quaternion is
    **(x, y, z, w)** (scalar last) and rotates camera-frame vectors into the
    body-fixed frame; ``sun_position`` is body-fixed, Sun relative to the target.

These conventions were established on real MESSENGER MDIS data, not assumed:
see ``docs/design/isd-check.md`` (every other reading of the quaternions misses
the PDS label's pointing and sub-solar point by tens of degrees).

Pixels: CSM image coordinates put 0.5 at the centre of the first pixel; ours put 0
there (``mercury_dem.geometry.camera``). A CSM image pixel ``s_csm`` is detector
pixel ``s_csm * summing + starting_detector_sample``, and the focal plane is
``x = (detector_sample - detector_center.sample - a0) / a1`` with
``focal2pixel_samples = (a0, a1, a2)``; so the optical axis is at our sample
``(detector_center.sample + a0 - starting_detector_sample) / summing - 0.5``
(likewise for lines).

Light time and stellar aberration are not applied: the ISD's positions and
rotations are used as written (ALE has already applied its corrections, if any,
when it wrote them). Written here rather than taken from ``ale``/``usgscsm`` (C++
and SPICE dependencies) because we need only this small, fixed subset.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError, IsdError
from mercury_dem.geometry.camera import FramingCamera, detector_affine, minus_z_turn
from mercury_dem.geometry.distortion import CSM_DISTORTION_SIZES, CsmDistortion

#: Largest magnitude any ISD number may have (the Sun is ~1e11 m away; larger values are corrupt and
#: would overflow the geometry's squares).
MAX_MAGNITUDE = 1e20
#: Largest allowed | |q| - 1 | of a quaternion before it is called non-normalised.
QUATERNION_NORM_TOL = 1e-6
#: Largest allowed max|M M^T - I| of a rotation matrix given as nine numbers.
ROTATION_ORTHO_TOL = 1e-6
#: Heliocentric distance range that any ISD's sun position must lie in, metres: from inside Mercury's
#: perihelion (4.6e10 m) to beyond Pluto's aphelion (7.4e12 m). The reader does not know the body's orbit;
#: the range catches unit mistakes only (kilometres read as metres put the Earth–Moon system at 1.5e8 m,
#: metres read as kilometres put Mercury at 4.6e13 m), for every body ALE supports.
SUN_DISTANCE_RANGE_M = (3.0e10, 1.0e13)

#: Detector pixels per image pixel an ISD may state (usgscsm takes any number; beyond these, corrupt).
SUMMING_RANGE = (1e-6, 1e6)
#: Distortion models of ALE/usgscsm ISDs that are refused, and why.
REFUSED_DISTORTION = {
    "lunarorbiter": "usgscsm's frame sensor applies no distortion for it (Distortion.cpp has no case), so an "
                    "ISD with it does not say what its images need; ISIS's LoHighDistortionMap is not implemented here",
    "kplo_shadowcam": "the KPLO ShadowCam model belongs to a line-scan camera, not a frame camera",
    "cahvore": "the CAHVORE fish-eye model has no usgscsm frame-sensor implementation",
}

#: Metres per unit of the ISD's length units (its "unit" strings, lower-case).
UNIT_TO_M = {"m": 1.0, "meters": 1.0, "metres": 1.0, "km": 1000.0, "kilometers": 1000.0}


@dataclass(frozen=True, eq=False)
class IsdGeometry:
    """What an ISD says about one image, in our frames and units.

    Attributes
    ----------
    source : file name the ISD came from (used in messages)
    flavour : ``"ale"`` or ``"usgscsm"``
    camera : interior orientation (our 0-based pixel convention)
    position : ndarray of shape (3,), body-fixed metres, camera centre
    rotation : ndarray of shape (3, 3), body-fixed -> camera frame (``v_cam = R @ (X - C)``)
    sun_position : ndarray of shape (3,), body-fixed metres, Sun relative to the body centre;
        ``None`` only when read with ``require_sun=False`` from an ISD without a usable one
    radius_m : the ISD's body radius (``radii.semimajor``), metres
    ephemeris_time : ``center_ephemeris_time``, seconds TDB past J2000 (NaN when absent)
    j2000_to_body : ndarray of shape (3, 3) (J2000 -> body-fixed) for the ``ale`` flavour, else ``None``
    warnings : what was assumed because the ISD did not say it (no distortion model,
        no usable sun position with ``require_sun=False``); callers show these
    sensor_to_camera : ndarray of shape (3, 3), the ISD's sensor frame -> our camera frame
        (``rotation = sensor_to_camera @ R_body->sensor``): a 180° turn for a negative focal
        length (a -Z look), None (identity) otherwise
    """

    source: str
    flavour: str
    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]
    sun_position: NDArray[np.float64] | None
    radius_m: float
    ephemeris_time: float
    j2000_to_body: NDArray[np.float64] | None = None
    warnings: tuple[str, ...] = ()
    sensor_to_camera: NDArray[np.float64] | None = None


# -- rotations ------------------------------------------------------------------

def quaternion_to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of a unit quaternion given scalar first, (w, x, y, z).

    The matrix is the active rotation ``v -> q v q*`` (SPICE ``q2m``); shape (..., 3, 3).
    The quaternion is normalised first (callers check the norm).
    """
    qa = np.asarray(q, dtype=np.float64)
    qa = qa / np.linalg.norm(qa, axis=-1, keepdims=True)
    w, x, y, z = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quaternion(m: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (3, 3); inverse of :func:`quaternion_to_matrix`.

    Shepperd's method: the largest of the four squared components is taken from the
    diagonal, the others from off-diagonal sums, so it is stable for every angle.
    """
    m = np.asarray(m, dtype=np.float64)
    t = np.trace(m)
    cands = np.array([t, m[0, 0], m[1, 1], m[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        w = math.sqrt(1.0 + t) / 2.0
        q = [w, (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)]
    elif k == 1:
        x = math.sqrt(1.0 + 2 * m[0, 0] - t) / 2.0
        q = [(m[2, 1] - m[1, 2]) / (4 * x), x, (m[0, 1] + m[1, 0]) / (4 * x), (m[0, 2] + m[2, 0]) / (4 * x)]
    elif k == 2:
        y = math.sqrt(1.0 + 2 * m[1, 1] - t) / 2.0
        q = [(m[0, 2] - m[2, 0]) / (4 * y), (m[0, 1] + m[1, 0]) / (4 * y), y, (m[1, 2] + m[2, 1]) / (4 * y)]
    else:
        z = math.sqrt(1.0 + 2 * m[2, 2] - t) / 2.0
        q = [(m[1, 0] - m[0, 1]) / (4 * z), (m[0, 2] + m[2, 0]) / (4 * z), (m[1, 2] + m[2, 1]) / (4 * z), z]
    out = np.array(q)
    out /= np.linalg.norm(out)
    return -out if out[0] < 0 else out


def iau_body_rotation(
    ephemeris_time: float,
    pole_ra: Sequence[float],
    pole_dec: Sequence[float],
    pm: Sequence[float],
    nut_prec_pm: Sequence[float] = (),
    nut_prec_angles: Sequence[tuple[float, float]] = (),
) -> NDArray[np.float64]:
    """J2000 -> body-fixed rotation (3, 3) of an IAU rotation model (the PCK formulas).

    ``pole_ra``/``pole_dec`` are (deg, deg/century), ``pm`` (deg, deg/day);
    ``nut_prec_pm`` the amplitudes (deg) of ``sin(M_i)`` terms added to the prime
    meridian, with ``M_i = a_i + b_i T`` from ``nut_prec_angles`` (deg, deg/century).
    Used to check an ISD's ``body_rotation`` and to explain label differences made
    with another model; Mercury's right ascension/declination have no periodic terms.
    """
    d = ephemeris_time / 86400.0
    t = d / 36525.0
    ra = math.radians(pole_ra[0] + pole_ra[1] * t)
    dec = math.radians(pole_dec[0] + pole_dec[1] * t)
    w = pm[0] + pm[1] * d
    for amp, (a, b) in zip(nut_prec_pm, nut_prec_angles):
        w += amp * math.sin(math.radians(a + b * t))

    def rz(a: float) -> NDArray[np.float64]:
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])

    def rx(a: float) -> NDArray[np.float64]:
        c, s = math.cos(a), math.sin(a)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])

    return rz(math.radians(w)) @ rx(math.pi / 2 - dec) @ rz(math.pi / 2 + ra)


# -- reading helpers ------------------------------------------------------------

class _Reader:
    """Key access into an ISD dict with errors that name the file and the key."""

    def __init__(self, isd: Mapping[str, Any], source: str) -> None:
        self.isd = isd
        self.source = source

    def error(self, key: str, what: str) -> IsdError:
        return IsdError(f"ISD {self.source}: key '{key}' {what}")

    def has(self, key: str) -> bool:
        node: Any = self.isd
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                return False
            node = node[part]
        return True

    def get(self, key: str) -> Any:
        node: Any = self.isd
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise self.error(key, "is missing; re-export the ISD (e.g. with ALE's isd_generate) "
                                      "or add the key")
            node = node[part]
        return node

    def number(self, key: str, positive: bool = False) -> float:
        value = self.get(key)
        try:
            x = float(value)
        except (TypeError, ValueError, OverflowError):
            raise self.error(key, f"must be a number, got {value!r}") from None
        if not math.isfinite(x) or (positive and x <= 0):
            raise self.error(key, f"must be a finite{' positive' if positive else ''} number, got {x}")
        if abs(x) > MAX_MAGNITUDE:
            raise self.error(key, f"is {x:g}, beyond any physical value here (|x| <= {MAX_MAGNITUDE:g})")
        return x

    def integer(self, key: str, minimum: int) -> int:
        x = self.number(key)
        if x != int(x) or x < minimum:
            raise self.error(key, f"must be an integer >= {minimum}, got {x}")
        return int(x)

    def array(self, key: str, shape: tuple[int, ...]) -> NDArray[np.float64]:
        """A finite float array of exactly ``shape`` (a leading -1 accepts any length >= 1)."""
        raw = self.get(key)
        try:
            a = np.asarray(raw, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise self.error(key, f"must hold numbers of shape {shape}, got {str(raw)[:80]}") from None
        want = tuple(a.shape[0] if (i == 0 and n == -1 and a.ndim) else n for i, n in enumerate(shape))
        if a.shape != want or a.size == 0:
            what = (f"a list of rows of {shape[1]} numbers" if len(shape) == 2 and shape[0] == -1
                    else f"{shape[0]} numbers" if len(shape) == 1 and shape[0] > 0 else f"shape {shape}")
            raise self.error(key, f"must be {what}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise self.error(key, f"holds NaN or infinite values: {a.tolist()}")
        if np.any(np.abs(a) > MAX_MAGNITUDE):
            raise self.error(key, f"holds a value beyond any physical value here (|x| <= {MAX_MAGNITUDE:g})")
        return a

    def unit_scale(self, key: str, default: str) -> float:
        unit = self.get(key) if self.has(key) else default
        scale = UNIT_TO_M.get(str(unit).strip().lower())
        if scale is None:
            raise self.error(key, f"unit {unit!r} is not understood; use 'm' or 'km'")
        return scale


def _at_time(r: _Reader, table: str, column: str, width: int, et: float) -> NDArray[np.float64]:
    """One row of a time table at ``et`` (linear interpolation between rows; one row is used as is)."""
    rows = r.array(f"{table}.{column}", (-1, width))
    if width == 4:
        for q in rows:
            _unit_quaternion(r, f"{table}.{column}", q)
    if rows.shape[0] == 1:
        first: NDArray[np.float64] = rows[0]
        return first
    if not math.isfinite(et):
        raise r.error(f"{table}.{column}", f"has {rows.shape[0]} rows but 'center_ephemeris_time' is missing: "
                                           "it is needed to pick the image's row")
    times = r.array(f"{table}.ephemeris_times", (rows.shape[0],))
    if np.any(np.diff(times) <= 0):
        raise r.error(f"{table}.ephemeris_times", "must increase strictly")
    if not times[0] <= et <= times[-1]:
        raise r.error(f"{table}.ephemeris_times",
                      f"spans {times[0]:.6f}..{times[-1]:.6f} s, not center_ephemeris_time {et:.6f} s")
    i = int(np.clip(np.searchsorted(times, et) - 1, 0, len(times) - 2))
    f = (et - times[i]) / (times[i + 1] - times[i])
    a, b = rows[i], rows[i + 1]
    if width == 4 and np.dot(a, b) < 0:  # q and -q are the same rotation
        b = -b
    out: NDArray[np.float64] = (1 - f) * a + f * b
    return out / np.linalg.norm(out) if width == 4 else out


def _unit_quaternion(r: _Reader, key: str, q: NDArray[np.float64]) -> NDArray[np.float64]:
    # a component beyond 1 cannot be part of a unit quaternion (and would overflow the norm when huge)
    norm = float(np.linalg.norm(q)) if np.all(np.abs(q) <= 1.0 + QUATERNION_NORM_TOL) else math.inf
    if abs(norm - 1.0) > QUATERNION_NORM_TOL:
        raise r.error(key, f"is not a unit quaternion (norm {norm:.9f}, tolerance {QUATERNION_NORM_TOL:g}); "
                           "the ISD is corrupt or hand-edited: regenerate it")
    return q / norm


def _rotation(r: _Reader, key: str) -> NDArray[np.float64]:
    m = r.array(key, (9,)).reshape(3, 3)
    err = float(np.abs(m @ m.T - np.eye(3)).max())
    if err > ROTATION_ORTHO_TOL or np.linalg.det(m) < 0:
        raise r.error(key, f"is not a proper rotation (max |M M^T - I| = {err:.2e}, det = {np.linalg.det(m):.6f})")
    return m


def _check_sun(r: _Reader, key: str, sun: NDArray[np.float64]) -> NDArray[np.float64]:
    dist = float(np.linalg.norm(sun))
    lo, hi = SUN_DISTANCE_RANGE_M
    if not lo <= dist <= hi:
        raise r.error(key, f"puts the Sun {dist:.4g} m from the body; every solar-system body "
                           f"ALE supports is {SUN_DISTANCE_RANGE_M[0]:.1e}-{SUN_DISTANCE_RANGE_M[1]:.1e} m "
                           "from the Sun: check the position's unit")
    return sun


# -- camera -----------------------------------------------------------------------

def _distortion(r: _Reader, f_mm: float, axes: tuple[float, float],
                warnings: list[str]) -> tuple[tuple[float, ...], tuple[float, ...], CsmDistortion | None]:
    """``optical_distortion`` as usgscsm reads it: (transverse x, transverse y, other model)."""
    if not r.has("optical_distortion"):
        warnings.append("no 'optical_distortion' key: an ideal pinhole camera is assumed (MDIS-NAC's "
                        "distortion moves its corner pixels by about 0.5 px)")
        return (), (), None
    model = r.get("optical_distortion")
    known = ["transverse", *CSM_DISTORTION_SIZES]
    if not isinstance(model, Mapping) or len(model) != 1:
        got = sorted(map(str, model)) if isinstance(model, Mapping) else repr(model)[:60]
        raise r.error("optical_distortion", f"must name exactly one distortion model (one of {known}), got {got}")
    name = str(next(iter(model)))
    if name in REFUSED_DISTORTION:
        raise r.error(f"optical_distortion.{name}", f"model is not supported: {REFUSED_DISTORTION[name]}")
    if name not in known:
        raise r.error("optical_distortion", f"model {name!r} is not supported; supported are {known}")
    if name == "transverse":
        # ALE pads short lists with zeros; ten terms at most
        cx = r.array("optical_distortion.transverse.x", (-1,))
        cy = r.array("optical_distortion.transverse.y", (-1,))
        for key, c in (("x", cx), ("y", cy)):
            if c.size > 10:
                raise r.error(f"optical_distortion.transverse.{key}", f"has {c.size} terms; the model has 10")
        px, py = np.zeros(10), np.zeros(10)
        px[: cx.size], py[: cy.size] = cx, cy
        if axes != (1.0, 1.0):  # our x = sx x_isd: term x^i y^j of x_d' = sx P(sx x, sy y) scales by sx sx^i sy^j
            sx, sy = axes
            powers = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3)]
            px = np.array([sx * sx**i * sy**j * c for (i, j), c in zip(powers, px)])
            py = np.array([sy * sx**i * sy**j * c for (i, j), c in zip(powers, py)])
        if not np.any(px) and not np.any(py):
            return (), (), None
        return tuple(px.tolist()), tuple(py.tolist()), None
    if name == "kaguyalism":
        ax = r.array("optical_distortion.kaguyalism.x", (-1,))
        ay = r.array("optical_distortion.kaguyalism.y", (-1,))
        if ax.size > 4 or ay.size > 4:
            raise r.error("optical_distortion.kaguyalism", "x and y have at most 4 terms each")
        px, py = np.zeros(4), np.zeros(4)
        px[: ax.size], py[: ay.size] = ax, ay
        coeffs = (r.number("optical_distortion.kaguyalism.boresight_x"), *px.tolist(),
                  r.number("optical_distortion.kaguyalism.boresight_y"), *py.tolist())
    else:
        n = CSM_DISTORTION_SIZES[name]
        coeffs = tuple(r.array(f"optical_distortion.{name}.coefficients", (n,)).tolist())
    if name in ("radial", "dawnfc", "lrolrocnac", "radtan") and not any(coeffs):
        return (), (), None  # all-zero coefficients: no distortion
    return (), (), CsmDistortion(name, coeffs, abs(f_mm), axes)


def _check_distortion(r: _Reader, camera: FramingCamera) -> None:
    """Refuse a distortion that folds the image.

    On a 9 x 9 grid over the image (edges included) the model must invert consistently
    (distort(undistort(p)) = p to 1e-9 mm) with a Jacobian that stays orientation-keeping
    (determinant > 1e-6). usgscsm instead returns the distorted point where its Newton step meets a
    singular Jacobian, and may converge to another branch of a folding model.
    """
    if not camera.has_distortion:
        return
    s, ln = np.meshgrid(np.linspace(-0.5, camera.samples - 0.5, 9), np.linspace(-0.5, camera.lines - 0.5, 9))
    px = np.stack([s.ravel(), ln.ravel()], axis=-1)
    with np.errstate(all="ignore"):
        lin = camera.pixel_to_focal_matrix()
        xd, yd = np.einsum("ij,nj->in", lin, px - [camera.boresight_sample, camera.boresight_line])
        xu, yu = camera.undistort(xd, yd)
        xr, yr = camera.distort(xu, yu)
        jac = camera.distortion_jacobian(xu, yu)
        det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
        back = np.maximum(np.abs(xr - xd), np.abs(yr - yd))
    ok = np.isfinite(xu) & np.isfinite(yu) & (back <= 1e-9) & np.isfinite(det) & (det > 1e-6)
    if not np.all(ok):
        worst = float(np.nanmin(det)) if np.any(np.isfinite(det)) else math.nan
        raise r.error("optical_distortion", f"'{camera.distortion_model}' folds or degenerates inside the image "
                      f"(over a 9 x 9 grid of its pixels the model does not invert consistently or its Jacobian "
                      f"determinant, least {worst:.3g}, is not > 0): the coefficients are wrong")


def _camera(r: _Reader, warnings: list[str]) -> tuple[FramingCamera, NDArray[np.float64]]:
    """The camera and the rotation from the ISD's sensor frame to our camera frame (identity unless the
    focal length is negative: usgscsm's -Z look, turned as :func:`~mercury_dem.geometry.camera.minus_z_turn`).
    """
    f_mm = r.number("focal_length_model.focal_length")
    if f_mm == 0:
        raise r.error("focal_length_model.focal_length", "is 0; a frame camera needs a non-zero focal length")
    ts = r.array("focal2pixel_samples", (3,))
    tl = r.array("focal2pixel_lines", (3,))
    # focal2pixel: centred detector (sample, line) = m @ (x, y) + (a0, b0); its inverse maps detector -> focal
    m = np.array([[ts[1], ts[2]], [tl[1], tl[2]]])
    det = float(m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0])
    scale_m = float(np.abs(m).max())
    if not (math.isfinite(det) and scale_m > 0 and abs(det) > 1e-12 * scale_m * scale_m):
        raise r.error("focal2pixel_samples", f"/ focal2pixel_lines ({ts.tolist()}, {tl.tolist()}) are singular "
                      f"(determinant {det:.3g}): no pixel -> focal plane map exists")
    t = np.array([[m[1, 1], -m[0, 1]], [-m[1, 0], m[0, 0]]]) / det
    s_sum = r.number("detector_sample_summing", positive=True)
    l_sum = r.number("detector_line_summing", positive=True)
    for key, value in (("detector_sample_summing", s_sum), ("detector_line_summing", l_sum)):
        if not SUMMING_RANGE[0] <= value <= SUMMING_RANGE[1]:
            raise r.error(key, f"is {value:g}: detector pixels per image pixel must be within {SUMMING_RANGE}")
    c_s = r.number("detector_center.sample")
    c_l = r.number("detector_center.line")
    start_s = r.number("starting_detector_sample")
    start_l = r.number("starting_detector_line")
    samples = r.integer("image_samples", 1)
    lines = r.integer("image_lines", 1)
    if r.has("jitter") and _has_jitter(r.get("jitter")):
        raise r.error("jitter", "(rolling-shutter jitter) is not supported: its line/sample offsets vary along "
                      "the image, which a frame camera's single affine cannot describe")
    turn = minus_z_turn(t) if f_mm < 0 else np.eye(3)
    axes = (float(turn[0, 0]), float(turn[1, 1]))
    dist_x, dist_y, csm = _distortion(r, f_mm, axes, warnings)
    # usgscsm: detector = csm pixel * summing + starting detector; csm pixel = ours + 0.5
    diagonal = ts[2] == 0 and tl[1] == 0 and ts[1] == tl[2] and ts[1] > 0 and s_sum == l_sum and s_sum == int(s_sum)
    summing = int(s_sum) if diagonal else 1
    pitch = 1.0 / ts[1] if diagonal else 1.0 / math.sqrt(abs(det))
    name = str(r.isd.get("instrument_id") or r.isd.get("name_sensor") or "unknown")
    names = f"{r.isd.get('instrument_id', '')} {r.isd.get('name_sensor', '')}".upper()
    if "NARROW ANGLE" in names or "MDIS_NAC" in names:
        name = "MDIS-NAC"
    elif "WIDE ANGLE" in names or "MDIS_WAC" in names:
        name = "MDIS-WAC"
    try:
        bore_s, bore_l, fmap = detector_affine(
            turn[:2, :2] @ t, (ts[0], tl[0]), (s_sum, l_sum),
            (0.5 * s_sum + start_s - c_s, 0.5 * l_sum + start_l - c_l),
            square_mm=pitch * summing if diagonal else None)
        camera = FramingCamera(
            name=name,
            focal_length_mm=abs(f_mm),
            pixel_pitch_mm=pitch,
            summing=summing,
            samples=samples,
            lines=lines,
            boresight_sample=bore_s,
            boresight_line=bore_l,
            distortion_x=dist_x,
            distortion_y=dist_y,
            focal_plane_map=fmap,
            csm_distortion=csm,
        )
    except GeometryError as exc:
        raise IsdError(f"ISD {r.source}: camera keys give an invalid camera: {exc}") from None
    _check_distortion(r, camera)
    return camera, turn


def _has_jitter(node: Any) -> bool:
    """True when a ``jitter`` entry asks for any non-zero offset (or cannot be read)."""
    if not isinstance(node, Mapping):
        return True
    try:
        return any(float(c) != 0.0 for key in ("lineJitterCoefficients", "sampleJitterCoefficients")
                   for c in (node.get(key) or ()))
    except (TypeError, ValueError, OverflowError):
        return True


# -- the two flavours ---------------------------------------------------------------

def _frames_check(r: _Reader, keys: Sequence[str]) -> None:
    refs = {k: r.get(f"{k}.reference_frame") for k in keys if r.has(f"{k}.reference_frame")}
    if len(set(map(str, refs.values()))) > 1:
        raise r.error("reference_frame", f"differs between tables {refs}; all must share one inertial frame")


def _optional_sun(r: _Reader, require_sun: bool, warnings: list[str], read: Any) -> Any:
    """``read()`` the sun position; without ``require_sun`` a failure becomes a warning and None."""
    try:
        return read()
    except IsdError as exc:
        if require_sun:
            raise
        warnings.append(f"sun position unusable, illumination angles left undefined: {exc}")
        return None


def _ale_pose(r: _Reader, et: float, require_sun: bool, warnings: list[str]) -> tuple[Any, ...]:
    tables = ["instrument_position", "instrument_pointing", "body_rotation"]
    _frames_check(r, tables + (["sun_position"] if r.has("sun_position") else []))
    qb = _at_time(r, "body_rotation", "quaternions", 4, et)  # rows checked to be unit quaternions
    qi = _at_time(r, "instrument_pointing", "quaternions", 4, et)
    j2000_to_body = quaternion_to_matrix(qb)
    j2000_to_frame = quaternion_to_matrix(qi)
    if r.has("instrument_pointing.constant_rotation"):
        const = _rotation(r, "instrument_pointing.constant_rotation")
    elif not r.has("instrument_pointing.time_dependent_frames"):
        const = np.eye(3)  # ALE's default when the table names no frame chain
    else:
        raise r.error("instrument_pointing.constant_rotation",
                      "is missing; it rotates the pointing frame into the instrument frame (9 numbers, row-major)")
    rotation = const @ j2000_to_frame @ j2000_to_body.T
    scale = r.unit_scale("instrument_position.unit", "km")
    position = j2000_to_body @ (_at_time(r, "instrument_position", "positions", 3, et) * scale)

    def sun() -> NDArray[np.float64]:
        s = _at_time(r, "sun_position", "positions", 3, et) * r.unit_scale("sun_position.unit", "km")
        return j2000_to_body @ _check_sun(r, "sun_position.positions", s)

    return position, rotation, _optional_sun(r, require_sun, warnings, sun), j2000_to_body


def _single_row(r: _Reader, key: str, width: int) -> NDArray[np.float64]:
    rows = r.array(key, (-1, width))
    if rows.shape[0] != 1:
        raise r.error(key, f"has {rows.shape[0]} rows; a frame-camera ISD of this layout has exactly one")
    row: NDArray[np.float64] = rows[0]
    return row


def _csm_pose(r: _Reader, require_sun: bool, warnings: list[str]) -> tuple[Any, ...]:
    scale = r.unit_scale("sensor_position.unit", "m")
    position = _single_row(r, "sensor_position.positions", 3) * scale
    q = _single_row(r, "sensor_orientation.quaternions", 4)
    q = _unit_quaternion(r, "sensor_orientation.quaternions", q)
    camera_to_body = quaternion_to_matrix(np.r_[q[3], q[:3]])  # stored (x, y, z, w)

    def sun() -> NDArray[np.float64]:
        if _knoten_sun_quirk(r):
            return _knoten_sun(r, warnings)
        s = _single_row(r, "sun_position.positions", 3) * r.unit_scale("sun_position.unit", "m")
        return _check_sun(r, "sun_position.positions", s)

    return position, camera_to_body.T, _optional_sun(r, require_sun, warnings, sun), None


def _knoten_sun_quirk(r: _Reader) -> bool:
    """Whether ``sun_position`` has the known layout of the older knoten/ALE CSM exports: one row of 4 numbers
    whose 4th repeats the first velocity component (``sun_position.velocities[0][0]``) exactly. Seen in the USGS
    knoten MDIS stereo examples (tests/data/real/SOURCE.md), whose Sun is in kilometres though ``unit`` says "m".
    Any other row width stays an error (:func:`_single_row`).
    """
    try:
        rows = np.asarray(r.get("sun_position.positions"), dtype=np.float64)
        vel = np.asarray(r.get("sun_position.velocities"), dtype=np.float64) if r.has("sun_position.velocities") \
            else None
    except (TypeError, ValueError, OverflowError, IsdError):
        return False
    return (vel is not None and rows.shape == (1, 4) and vel.shape == (1, 3) and bool(np.all(np.isfinite(rows)))
            and bool(rows[0, 3] == vel[0, 0]))


def _knoten_sun(r: _Reader, warnings: list[str]) -> NDArray[np.float64]:
    """The Sun of a :func:`_knoten_sun_quirk` ISD: the row's first 3 numbers, in the labelled unit when that puts
    the Sun at a plausible distance (:data:`SUN_DISTANCE_RANGE_M`), else in kilometres when those do; each
    reinterpretation is a warning naming the file and the key. Neither plausible: the usual unit error.
    """
    key = "sun_position.positions"
    row = r.array(key, (1, 4))[0, :3]
    warnings.append(f"ISD {r.source}: key '{key}' has rows of 4 numbers, the 4th repeating "
                    "'sun_position.velocities'[0][0] (a known quirk of older knoten/ALE exports): the first 3 are "
                    "the position")
    labelled = row * r.unit_scale("sun_position.unit", "m")
    lo, hi = SUN_DISTANCE_RANGE_M
    if not lo <= float(np.linalg.norm(labelled)) <= hi and lo <= float(np.linalg.norm(row * 1000.0)) <= hi:
        warnings.append(f"ISD {r.source}: key '{key}' in the labelled unit puts the Sun "
                        f"{float(np.linalg.norm(labelled)):.4g} m from the body, outside {lo:.1e}-{hi:.1e} m; "
                        f"read as kilometres it is {float(np.linalg.norm(row)) * 1000.0:.4g} m: kilometres used")
        return _check_sun(r, key, row * 1000.0)
    return _check_sun(r, key, labelled)


def isd_from_dict(isd: Mapping[str, Any], source: str = "<dict>", require_sun: bool = True) -> IsdGeometry:
    """Camera, pose and sun of an ISD already parsed from JSON.

    Parameters
    ----------
    isd : the parsed JSON object
    source : name used in error messages (the file name)
    require_sun : when False, a missing or unusable ``sun_position`` gives
        ``sun_position=None`` instead of an :class:`IsdError`

    Raises
    ------
    IsdError
        naming ``source`` and the key, for a missing key, a non-finite or
        mis-shaped value, a non-unit quaternion, a non-orthonormal matrix, a
        spacecraft inside the body or a sun position with an implausible distance.
    """
    if not isinstance(isd, Mapping):
        raise IsdError(f"ISD {source}: top level must be a JSON object, got {type(isd).__name__}")
    r = _Reader(isd, source)
    if r.has("instrument_pointing") or r.has("instrument_position"):
        flavour = "ale"
    elif r.has("sensor_orientation") or r.has("sensor_position"):
        flavour = "usgscsm"
    else:
        raise IsdError(f"ISD {source}: neither 'instrument_pointing'/'instrument_position' (ALE) nor "
                       "'sensor_orientation'/'sensor_position' (usgscsm) is present: not a frame-camera ISD")
    radius_m = r.number("radii.semimajor", positive=True) * r.unit_scale("radii.unit", "km")
    et = r.number("center_ephemeris_time") if r.has("center_ephemeris_time") else math.nan
    warnings: list[str] = []
    if r.has("radii.semiminor"):
        minor = r.number("radii.semiminor", positive=True) * r.unit_scale("radii.unit", "km")
        if abs(minor - radius_m) > 1e-9 * radius_m:
            warnings.append(f"radii: an ellipsoid ({radius_m:.1f} m x {minor:.1f} m); the sphere of the "
                            "semimajor radius is used")
    camera, turn = _camera(r, warnings)
    if flavour == "ale":
        position, rotation, sun, j2b = _ale_pose(r, et, require_sun, warnings)
        pos_key = "instrument_position.positions"
    else:
        position, rotation, sun, j2b = _csm_pose(r, require_sun, warnings)
        pos_key = "sensor_position.positions"
    if float(np.linalg.norm(position)) < radius_m:
        raise r.error(pos_key, f"puts the camera {np.linalg.norm(position):.1f} m from the body centre, inside "
                               f"the {radius_m:.1f} m sphere: check its unit and frame")
    turned = bool(np.any(turn != np.eye(3)))
    return IsdGeometry(source=source, flavour=flavour, camera=camera, position=position,
                       rotation=turn @ rotation if turned else rotation, sun_position=sun, radius_m=radius_m,
                       ephemeris_time=et, j2000_to_body=j2b, warnings=tuple(warnings),
                       sensor_to_camera=turn if turned else None)


#: Bytes read from the start of a file to recognise an ISD by its content.
SNIFF_BYTES = 4096


def is_isd_file(path: str | Path) -> bool:
    """True when ``path`` holds a JSON object (its first non-blank byte is ``{``): a CSM ISD candidate.

    ISDs are recognised by content, whatever their extension (``.json``, ``.isd`` or none):
    the reader (:func:`read_isd`) then says precisely what is wrong with one that is not a
    usable frame ISD. A file that cannot be opened is not an ISD (False).
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(SNIFF_BYTES)
    except OSError:
        return False
    return head.removeprefix(b"\xef\xbb\xbf").lstrip().startswith(b"{")


def read_isd(path: str | Path, require_sun: bool = True) -> IsdGeometry:
    """Read a CSM frame-camera ISD file (ALE or usgscsm flavour); see :func:`isd_from_dict`.

    Raises :class:`IsdError` naming the file for an unreadable file or invalid JSON.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise IsdError(f"ISD {p}: cannot be read ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise IsdError(f"ISD {p}: not UTF-8 text, so not a JSON ISD (byte {exc.start}: {exc.reason})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise IsdError(f"ISD {p}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    return isd_from_dict(data, source=str(p), require_sun=require_sun)
