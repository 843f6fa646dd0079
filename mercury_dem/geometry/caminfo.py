"""Image geometry summary, the equivalent of ISIS ``caminfo``, and comparison with a PDS3 label.

:func:`compute_caminfo` turns a camera and pose (and the Sun) into the quantities
a MESSENGER MDIS PDS3 label carries: image centre and corner latitude/longitude,
slant distance, pixel scale, incidence/emission/phase, sub-spacecraft and
sub-solar points, and the centre's right ascension/declination when the J2000
orientation is known. All on a sphere of a given radius, with the sphere normal
(the labels' convention), planetocentric east longitudes in [0, 360).

:func:`parse_pds3_label` reads the top-level ``KEY = value`` pairs of a PDS3 label
(a small reader, written here because only numeric geometry keywords are needed
and ``pvl`` would be one more dependency for it); :func:`label_values` maps them
to our quantity names and units; :func:`compare_with_label` makes the table of
differences with the tolerances of the real-geometry check.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.body import xyz_to_latlon
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import illumination_angles, image_to_ground, intersect_sphere, pixel_rays


@dataclass(frozen=True)
class CamInfo:
    """Geometry of one image (angles in degrees, distances in metres; NaN when undefined).

    ``corner_*`` are ordered like ``corner_pixels``: (0, 0), (samples-1, 0),
    (0, lines-1), (samples-1, lines-1) in our 0-based pixel-centre convention,
    which is the order of the MDIS labels' RETICLE_POINT_* (see docs/design/isd-check.md).
    """

    radius_m: float
    centre_sample: float
    centre_line: float
    centre_lat: float
    centre_lon: float
    corner_pixels: tuple[tuple[float, float], ...]
    corner_lat: tuple[float, ...]
    corner_lon: tuple[float, ...]
    slant_distance_m: float
    pixel_scale_m: float
    incidence_deg: float
    emission_deg: float
    phase_deg: float
    sub_spacecraft_lat: float
    sub_spacecraft_lon: float
    spacecraft_altitude_m: float
    target_center_distance_m: float
    sub_solar_lat: float
    sub_solar_lon: float
    solar_distance_m: float
    centre_ra_deg: float
    centre_dec_deg: float

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (NaN becomes None)."""
        def clean(v: Any) -> Any:
            if isinstance(v, (tuple, list)):
                return [clean(x) for x in v]
            if isinstance(v, float) and not math.isfinite(v):
                return None
            return v
        return {k: clean(v) for k, v in asdict(self).items()}


def _latlon(v: NDArray[np.float64]) -> tuple[float, float]:
    if not np.all(np.isfinite(v)):
        return math.nan, math.nan
    lat, lon, _ = xyz_to_latlon(v, 0.0)
    return float(lat), float(lon)


def centre_geometry(
    camera: FramingCamera,
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    suns: NDArray[np.float64],
    radius_m: float,
    centre_pixel: tuple[float, float] | None = None,
) -> dict[str, NDArray[np.float64]]:
    """Centre lat/lon, pixel scale and angles of N images sharing one camera (the labels' convention).

    The one definition of these label quantities: the mission catalog builder
    (:func:`mercury_dem.mission.catalog.build_catalog`) and :func:`compute_caminfo` both use it.

    Parameters
    ----------
    positions : (N, 3) body-fixed metres; rotations : (N, 3, 3) body -> camera;
    suns : (N, 3) body-fixed metres; radius_m : the sphere the centre ray meets;
    centre_pixel : (sample, line), 0-based; default the image centre ((samples-1)/2, (lines-1)/2).
    Also returns the centre ``ground`` points (N, 3) and ``slant_distance_m``.
    NaN where the centre ray misses the sphere.
    """
    n = positions.shape[0]
    centre_px = np.array(centre_pixel if centre_pixel is not None
                         else ((camera.samples - 1) / 2.0, (camera.lines - 1) / 2.0), dtype=np.float64)
    look = camera.pixel_to_camera(centre_px)
    d = np.einsum("nji,j->ni", rotations, look)  # R^T v
    ground, _ = intersect_sphere(positions, d, np.full(n, radius_m))
    lat, lon, _ = xyz_to_latlon(ground, radius_m)
    slant = np.linalg.norm(ground - positions, axis=-1)
    inc, emi, phase = illumination_angles(ground, positions, suns)
    return {
        "center_lat": lat,
        "center_lon": lon,
        "pixel_scale_m": slant * camera.ifov_rad,
        "incidence_deg": inc,
        "emission_deg": emi,
        "phase_deg": phase,
        "ground": ground,
        "slant_distance_m": slant,
    }


def compute_caminfo(
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    sun_position: ArrayLike | None = None,
    *,
    radius_m: float,
    j2000_to_body: ArrayLike | None = None,
    centre_pixel: tuple[float, float] | None = None,
) -> CamInfo:
    """Centre/corner ground points and viewing/lighting geometry of one image.

    Parameters
    ----------
    camera : the framing camera
    position : ndarray of shape (3,), body-fixed metres
    rotation : ndarray of shape (3, 3), body-fixed -> camera
    sun_position : ndarray of shape (3,), body-fixed metres (Sun relative to the body
        centre); ``None`` gives NaN illumination angles and sub-solar point
    radius_m : radius of the sphere the rays are intersected with, metres
    j2000_to_body : ndarray of shape (3, 3) or None; when given, the centre pixel's
        look direction is also expressed as J2000 right ascension/declination
    centre_pixel : (sample, line) of the "centre" in our 0-based convention; default
        the image centre ((samples-1)/2, (lines-1)/2)

    Notes
    -----
    The centre is the image centre ((samples-1)/2, (lines-1)/2), where the labels'
    RA_DEC_REF_PIXEL points. Slant distance is camera -> centre ground point; pixel
    scale is slant distance x IFOV (the label's HORIZONTAL_PIXEL_SCALE). Light time and
    aberration are ignored. A centre off the body gives NaN centre quantities.
    """
    c = np.asarray(position, dtype=np.float64)
    r = np.asarray(rotation, dtype=np.float64)
    if c.shape != (3,) or r.shape != (3, 3) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
        raise GeometryError("compute_caminfo: position must be 3 finite numbers and rotation a finite 3x3 matrix")
    cs, cl = ((camera.samples - 1) / 2.0, (camera.lines - 1) / 2.0) if centre_pixel is None else centre_pixel
    s1, l1 = camera.samples - 1.0, camera.lines - 1.0
    corners = ((0.0, 0.0), (s1, 0.0), (0.0, l1), (s1, l1))
    pixels = np.array([(cs, cl), *corners])
    ground, _ = image_to_ground(camera, c, r, pixels, datum_radius_m=radius_m)
    corner_ll = [_latlon(g) for g in ground[1:]]
    sun = None if sun_position is None else np.asarray(sun_position, dtype=np.float64)
    # Without a Sun, any far point stands in for it: only the emission is kept.
    g = centre_geometry(camera, c[None], r[None], (sun if sun is not None else 1e3 * c)[None], radius_m, (cs, cl))
    centre = g["ground"][0]
    clat, clon = _latlon(centre)
    slant = float(g["slant_distance_m"][0])  # NaN when off the body
    inc, emi, pha = (float(g[k][0]) for k in ("incidence_deg", "emission_deg", "phase_deg"))
    if sun is None:
        inc = pha = math.nan
    sc_lat, sc_lon = _latlon(c)
    sun_lat, sun_lon = _latlon(sun) if sun is not None else (math.nan, math.nan)
    ra = dec = math.nan
    if j2000_to_body is not None:
        _, d = pixel_rays(camera, c, r, pixels[:1])
        d_j2000 = np.asarray(j2000_to_body, dtype=np.float64).T @ d[0]
        dec, ra = _latlon(d_j2000)
    dist = float(np.linalg.norm(c))
    return CamInfo(
        radius_m=float(radius_m),
        centre_sample=cs,
        centre_line=cl,
        centre_lat=clat,
        centre_lon=clon,
        corner_pixels=corners,
        corner_lat=tuple(p[0] for p in corner_ll),
        corner_lon=tuple(p[1] for p in corner_ll),
        slant_distance_m=slant,
        pixel_scale_m=float(g["pixel_scale_m"][0]),
        incidence_deg=inc,
        emission_deg=emi,
        phase_deg=pha,
        sub_spacecraft_lat=sc_lat,
        sub_spacecraft_lon=sc_lon,
        spacecraft_altitude_m=dist - float(radius_m),
        target_center_distance_m=dist,
        sub_solar_lat=sun_lat,
        sub_solar_lon=sun_lon,
        solar_distance_m=float(np.linalg.norm(sun)) if sun is not None else math.nan,
        centre_ra_deg=ra,
        centre_dec_deg=dec,
    )


# -- PDS3 labels ------------------------------------------------------------------

_COMMENT = re.compile(r"/\*.*?\*/", re.S)
_UNIT = re.compile(r"<[^>]*>")


def _pds3_value(text: str, in_tuple: bool = False) -> Any:
    text = _UNIT.sub("", text).strip()
    if text.startswith("(") and text.endswith(")") and not in_tuple:
        # one level: elements are scalars (a nested sequence would not split on commas anyway)
        return tuple(_pds3_value(x, True) for x in text[1:-1].split(","))
    if text.startswith('"') and text.endswith('"'):
        return " ".join(text[1:-1].split())
    if text.upper() in ("N/A", "UNK", "NULL"):
        return None
    try:
        return float(text)
    except ValueError:
        return text


def parse_pds3_label(text: str) -> dict[str, Any]:
    """Top-level keywords of a PDS3 label: ``{KEY: value}``.

    Values: floats, strings, tuples (parenthesised lists, which may span lines);
    units ``<KM>`` are dropped (see :func:`label_values` for them); ``N/A`` is None.
    Keywords inside ``OBJECT``/``GROUP`` blocks are skipped (the MDIS labels repeat
    RETICLE_POINT_* per subframe there).
    """
    text = _COMMENT.sub("", text)
    out: dict[str, Any] = {}
    depth = 0
    pending = ""
    for raw in text.splitlines():
        line = (pending + " " + raw.strip()) if pending else raw.strip()
        if not line:
            continue
        if line.count("(") > line.count(")") or line.count('"') % 2:
            pending = line  # value continues on the next line
            continue
        pending = ""
        if line.upper() == "END":
            break
        if "=" not in line:
            continue
        key, value = (s.strip() for s in line.split("=", 1))
        ukey = key.upper()
        if ukey in ("OBJECT", "GROUP"):
            depth += 1
        elif ukey in ("END_OBJECT", "END_GROUP"):
            depth = max(depth - 1, 0)
        elif depth == 0:
            out[ukey] = _pds3_value(value)
    return out


#: Our CamInfo field -> (label keyword, index in a tuple or None, scale to our unit).
_LABEL_KEYS: dict[str, tuple[str, int | None, float]] = {
    "centre_lat": ("CENTER_LATITUDE", None, 1.0),
    "centre_lon": ("CENTER_LONGITUDE", None, 1.0),
    "slant_distance_m": ("SLANT_DISTANCE", None, 1000.0),
    "pixel_scale_m": ("HORIZONTAL_PIXEL_SCALE", None, 1.0),
    "incidence_deg": ("INCIDENCE_ANGLE", None, 1.0),
    "emission_deg": ("EMISSION_ANGLE", None, 1.0),
    "phase_deg": ("PHASE_ANGLE", None, 1.0),
    **{f"corner_lat[{i}]": ("RETICLE_POINT_LATITUDE", i, 1.0) for i in range(4)},
    **{f"corner_lon[{i}]": ("RETICLE_POINT_LONGITUDE", i, 1.0) for i in range(4)},
    "sub_spacecraft_lat": ("SUB_SPACECRAFT_LATITUDE", None, 1.0),
    "sub_spacecraft_lon": ("SUB_SPACECRAFT_LONGITUDE", None, 1.0),
    "spacecraft_altitude_m": ("SPACECRAFT_ALTITUDE", None, 1000.0),
    "target_center_distance_m": ("TARGET_CENTER_DISTANCE", None, 1000.0),
    "sub_solar_lat": ("SUB_SOLAR_LATITUDE", None, 1.0),
    "sub_solar_lon": ("SUB_SOLAR_LONGITUDE", None, 1.0),
    "centre_ra_deg": ("RIGHT_ASCENSION", None, 1.0),
    "centre_dec_deg": ("DECLINATION", None, 1.0),
}

#: Required agreement with the label (issue #2): (kind, tolerance); kind "abs" in the
#: quantity's unit, "lon" absolute after wrapping, "rel" a fraction.
TOLERANCES: dict[str, tuple[str, float]] = {
    "centre_lat": ("abs", 0.02),
    "centre_lon": ("lon", 0.15),
    "slant_distance_m": ("rel", 0.005),
    "pixel_scale_m": ("rel", 0.01),
    "incidence_deg": ("abs", 0.2),
    "emission_deg": ("abs", 0.2),
    "phase_deg": ("abs", 0.2),
}


def label_values(label: Mapping[str, Any]) -> dict[str, float]:
    """The label's geometry under our quantity names and units (metres, degrees).

    Keywords absent, N/A or not finite in the label are left out. Also gives ``radius_m``, the
    sphere the label was computed on (TARGET_CENTER_DISTANCE - SPACECRAFT_ALTITUDE), when positive.
    """
    out: dict[str, float] = {}
    for name, (key, index, scale) in _LABEL_KEYS.items():
        v = label.get(key)
        if isinstance(v, tuple):
            v = v[index] if index is not None and index < len(v) else None
        if isinstance(v, float) and math.isfinite(v * scale):  # NaN/1e400 in a label are no values
            out[name] = v * scale
    if "target_center_distance_m" in out and "spacecraft_altitude_m" in out:
        radius = out["target_center_distance_m"] - out["spacecraft_altitude_m"]
        if math.isfinite(radius) and radius > 0:
            out["radius_m"] = radius
    return out


@dataclass(frozen=True)
class Comparison:
    """One row of ours-vs-label: ``difference`` is ours - label (wrapped for longitudes;
    a fraction for ``kind == "rel"``); ``ok`` is None when no tolerance applies.
    """

    quantity: str
    ours: float
    label: float
    difference: float
    kind: str
    tolerance: float | None
    ok: bool | None


def _ours(info: CamInfo, name: str) -> float:
    if name.endswith("]"):
        field, index = name[:-1].split("[")
        return float(getattr(info, field)[int(index)])
    return float(getattr(info, name))


def compare_with_label(info: CamInfo, label: Mapping[str, float]) -> list[Comparison]:
    """Ours vs a label (as from :func:`label_values`), one row per quantity the label has.

    Only the quantities of :data:`TOLERANCES` get an ``ok``; the others (corners,
    sub-points, RA/Dec, altitude) are reported for information.
    """
    rows = []
    for name in _LABEL_KEYS:
        if name not in label:
            continue
        ours, lab = _ours(info, name), float(label[name])
        kind, tol = TOLERANCES.get(name, ("lon" if name.endswith("lon") or "lon[" in name
                                          or name == "centre_ra_deg" else "abs", None))
        if kind == "lon":
            diff = (ours - lab + 180.0) % 360.0 - 180.0
        elif kind == "rel":
            diff = (ours - lab) / lab if lab != 0 else (0.0 if ours == 0 else math.inf)  # a label's 0 km
        else:
            diff = ours - lab
        ok = None if tol is None else bool(abs(diff) <= tol)
        rows.append(Comparison(name, ours, lab, diff, kind, tol, ok))
    return rows
