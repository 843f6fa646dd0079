"""Corrected pointing as ISDs: an input ISD with its orientation replaced, or a usgscsm
frame ISD written from one of our cameras.

Pure functions: a parsed ISD (dict) and our pose in, a new dict out. Conventions are
those of :mod:`mercury_dem.geometry.isd` (read its docstring), and every ISD made here
reads back through :func:`~mercury_dem.geometry.isd.isd_from_dict` to the pose given.

* ``usgscsm`` layout: ``sensor_orientation.quaternions`` rows are (x, y, z, w) of the
  camera -> body-fixed rotation, i.e. of ``R.T`` for our body -> camera ``R``;
  ``sensor_position.positions`` body-fixed in the ISD's ``unit``.
* ``ale`` layout: our rotation is ``R = C @ q2m(q_i(t)) @ q2m(q_b(t)).T`` (C the
  ``constant_rotation``). The correction ``D = R_new @ R_old.T`` (camera frame) is applied
  to every pointing row as ``q_i' = q(C.T @ D @ C @ q2m(q_i))``, so the whole table moves
  by the same small rotation, as jigsaw's constant pointing offset does; a position
  correction ``dC`` (body-fixed) is added to every row as ``q2m(q_b(t)).T @ dC``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import IsdError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.isd import UNIT_TO_M, isd_from_dict, matrix_to_quaternion, quaternion_to_matrix


def _scale(isd: Mapping[str, Any], key: str, default: str) -> float:
    unit = (isd.get(key) or {}).get("unit", default) if isinstance(isd.get(key), Mapping) else default
    s = UNIT_TO_M.get(str(unit).strip().lower())
    if s is None:
        raise IsdError(f"ISD: {key}.unit {unit!r} is not understood")
    return s


def _continuous(q_new: NDArray[np.float64], q_old: NDArray[np.float64]) -> NDArray[np.float64]:
    return -q_new if float(np.dot(q_new, q_old)) < 0 else q_new


def updated_isd(isd: Mapping[str, Any], rotation: ArrayLike, position: ArrayLike, source: str = "<isd>") -> dict[str, Any]:
    """A copy of ``isd`` (either layout) whose pose reads back as ``rotation``/``position``.

    Parameters
    ----------
    isd : the parsed input ISD
    rotation : (3, 3) the corrected body-fixed -> camera rotation
    position : (3,) the corrected camera position, body-fixed metres
    source : for messages
    """
    old = isd_from_dict(isd, source=source, require_sun=False)
    r_new = np.asarray(rotation, np.float64)
    r_old = old.rotation
    if old.sensor_to_camera is not None:  # a -Z-looking ISD: back from our camera frame to its sensor frame
        r_new = old.sensor_to_camera.T @ r_new
        r_old = old.sensor_to_camera.T @ r_old
    c_new = np.asarray(position, np.float64)
    out = copy.deepcopy(dict(isd))
    if old.flavour == "usgscsm":
        q = matrix_to_quaternion(r_new.T)  # (w, x, y, z) of camera -> body
        rows = np.asarray(out["sensor_orientation"]["quaternions"], np.float64)
        q_xyzw = _continuous(np.r_[q[1:], q[0]], rows[0])
        out["sensor_orientation"]["quaternions"] = [q_xyzw.tolist()]
        dc = c_new - old.position
        if np.any(dc != 0):
            pos = np.asarray(out["sensor_position"]["positions"], np.float64)
            out["sensor_position"]["positions"] = (pos + dc / _scale(isd, "sensor_position", "m")).tolist()
        return out
    const = np.asarray(isd["instrument_pointing"]["constant_rotation"], np.float64).reshape(3, 3)
    d = r_new @ r_old.T
    turn = const.T @ d @ const
    rows = np.asarray(isd["instrument_pointing"]["quaternions"], np.float64)
    new_rows = [_continuous(matrix_to_quaternion(turn @ quaternion_to_matrix(q)), q) for q in rows]
    out["instrument_pointing"]["quaternions"] = [q.tolist() for q in new_rows]
    dc = c_new - old.position
    if np.any(dc != 0):
        j2b = old.j2000_to_body
        pos = np.asarray(isd["instrument_position"]["positions"], np.float64)
        shift = (j2b.T @ dc) / _scale(isd, "instrument_position", "km")  # type: ignore[union-attr]
        out["instrument_position"]["positions"] = (pos + shift).tolist()
    return out


def usgscsm_frame_isd(
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    *,
    sun_position: ArrayLike | None,
    radius_m: float,
    ephemeris_time: float,
    target_name: str,
    platform: str,
    sensor: str,
    serial_number: str | None = None,
) -> dict[str, Any]:
    """A usgscsm frame-camera ISD of one of our cameras at a pose.

    ``apollo_metric`` distortion has no usgscsm model (:class:`IsdError`); usgscsm's other
    models are written as read (a camera turned from a -Z-looking ISD's frame is refused
    unless its model is rotationally symmetric: ``radial`` or ``dawnfc``). The detector is described in image pixels when the camera
    has a general ``focal_plane_map`` (summing 1, ``focal2pixel`` = ``L^-1``), in detector
    pixels otherwise (pitch and summing as the camera states them).
    """
    model = camera.distortion_model
    if model == "apollo_metric":
        raise IsdError(f"camera {camera.name}: the Apollo Metric distortion has no usgscsm model; "
                       "no frame ISD can describe this camera")
    if camera.focal_plane_map:
        summing = 1
        m = camera.focal_to_pixel_matrix()
    else:
        summing = camera.summing
        m = np.eye(2) / camera.pixel_pitch_mm
    distortion: dict[str, Any]
    csm = camera.csm_distortion
    if model == "transverse":
        distortion = {"transverse": {"x": list(camera.distortion_x), "y": list(camera.distortion_y)}}
    elif csm is not None:
        if csm.axes != (1.0, 1.0) and csm.model not in ("radial", "dawnfc"):
            raise IsdError(f"camera {camera.name}: its '{csm.model}' distortion is in a turned sensor frame "
                           "(a -Z-looking ISD); no frame ISD of our camera frame is written for it")
        c = list(csm.coefficients)
        if csm.model == "kaguyalism":
            distortion = {"kaguyalism": {"x": c[1:5], "y": c[6:10], "boresight_x": c[0], "boresight_y": c[5]}}
        else:
            distortion = {csm.model: {"coefficients": c}}
    else:
        distortion = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
    q = matrix_to_quaternion(np.asarray(rotation, np.float64).T)
    isd: dict[str, Any] = {
        "name_model": "USGS_ASTRO_FRAME_SENSOR_MODEL",
        "name_platform": platform,
        "name_sensor": sensor,
        "target_name": target_name,
        "center_ephemeris_time": float(ephemeris_time),
        "starting_ephemeris_time": float(ephemeris_time),
        "image_samples": int(camera.samples),
        "image_lines": int(camera.lines),
        "detector_sample_summing": summing,
        "detector_line_summing": summing,
        "starting_detector_sample": 0.0,
        "starting_detector_line": 0.0,
        "detector_center": {"sample": (camera.boresight_sample + 0.5) * summing,
                            "line": (camera.boresight_line + 0.5) * summing},
        "focal2pixel_samples": [0.0, float(m[0, 0]), float(m[0, 1])],
        "focal2pixel_lines": [0.0, float(m[1, 0]), float(m[1, 1])],
        "focal_length_model": {"focal_length": float(camera.focal_length_mm)},
        "optical_distortion": distortion,
        "radii": {"semimajor": radius_m / 1000.0, "semiminor": radius_m / 1000.0, "unit": "km"},
        "reference_height": {"maxheight": 10000, "minheight": -10000, "unit": "m"},
        "sensor_position": {"positions": [np.asarray(position, np.float64).tolist()], "unit": "m"},
        "sensor_orientation": {"quaternions": [[float(q[1]), float(q[2]), float(q[3]), float(q[0])]]},
    }
    if sun_position is not None and np.all(np.isfinite(sun_position)):
        isd["sun_position"] = {"positions": [np.asarray(sun_position, np.float64).tolist()], "unit": "m"}
    if serial_number:
        isd["isis_serial_number"] = serial_number
    return isd


__all__ = ["updated_isd", "usgscsm_frame_isd"]
