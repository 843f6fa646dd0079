"""The target body (a sphere with a datum), and latitude/longitude/height <-> body-fixed XYZ.

:class:`Body` is what a mission says about its target: name, NAIF id, the IAU
sphere radius, the datum radius heights refer to, and the IAU 2015 CRS codes of
its products. :data:`MERCURY` and :data:`MOON`; no body is a default below the mission.
Stage code takes the body from the mission (``mission.body``); the module
constants below are Mercury's (for the synthetic presets, the command line and tests).

Conventions (see docs/conventions.md):

* body-fixed frame: IAU_MERCURY, origin at the centre of mass, +Z the north pole,
  +X through longitude 0, metres;
* latitude planetocentric, longitude east-positive in [0, 360), both in degrees;
* height: metres above the datum sphere of radius :data:`DATUM_RADIUS_M`
  (2439.4 km, the datum of the MESSENGER global DEM). The IAU 2015 Mercury sphere
  (:data:`IAU_SPHERE_RADIUS_M`, 2440.53 km) is a different radius: products state
  which one their heights refer to and never mix them.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Datum radius of the MESSENGER global DEM (Becker et al. 2016), metres.
DATUM_RADIUS_M: float = 2_439_400.0
#: Radius of the IAU 2015 Mercury sphere (the CRS `IAU_2015:19900`), metres.
IAU_SPHERE_RADIUS_M: float = 2_440_530.0
#: Radius of the IAU 2015 lunar sphere, which is also the datum of LOLA's products, metres.
MOON_RADIUS_M: float = 1_737_400.0

#: CRS codes the products use (pyproj knows them). Geographic sphere, planetocentric.
CRS_GEOGRAPHIC = "IAU_2015:19900"
#: Equirectangular, central meridian 0 (global products and |lat| < 65 deg).
CRS_EQUIRECTANGULAR = "IAU_2015:19910"
#: Equirectangular, central meridian 180.
CRS_EQUIRECTANGULAR_180 = "IAU_2015:19915"
#: Polar stereographic, north and south (PDS convention beyond +-65 deg).
CRS_NORTH_POLAR_STEREOGRAPHIC = "IAU_2015:19930"
CRS_SOUTH_POLAR_STEREOGRAPHIC = "IAU_2015:19935"
#: Sphere with the DEM datum radius 2439.4 km (pyproj knows it as ESRI:104974).
CRS_DATUM_GEOGRAPHIC = "ESRI:104974"


@dataclass(frozen=True)
class Body:
    """A target body as the pipeline sees it: a sphere for geometry, a datum for heights.

    Parameters
    ----------
    name : upper-case body name as SPICE/ISIS spell it (``MERCURY``, ``MOON``)
    naif_id : NAIF body id (199, 301)
    radius_m : radius of the body's IAU 2015 sphere, metres (the sphere of its IAU CRS codes)
    datum_radius_m : radius of the sphere heights are measured from, metres
    iau_code : the IAU 2015 code of its geographic sphere CRS (``naif_id * 100``); the other
        products' codes follow the IAU 2015 scheme (``+10`` equirectangular clon 0, ``+15``
        clon 180, ``+30``/``+35`` north/south polar stereographic, ``+55`` Robinson clon 180)
    datum_crs : a geographic CRS whose sphere has the datum radius, when one is catalogued
    """

    name: str
    naif_id: int
    radius_m: float
    datum_radius_m: float
    iau_code: int
    datum_crs: str | None = None

    def __post_init__(self) -> None:
        if not (self.radius_m > 0 and self.datum_radius_m > 0):
            raise ValueError(f"body {self.name}: radii must be > 0 (got {self.radius_m}, {self.datum_radius_m})")

    def crs(self, kind: str = "geographic") -> str:
        """The IAU 2015 CRS code of a product kind: geographic, equirectangular, equirectangular_180,
        north_polar, south_polar, robinson_180.
        """
        offsets = {"geographic": 0, "equirectangular": 10, "equirectangular_180": 15, "north_polar": 30,
                   "south_polar": 35, "robinson_180": 55}
        if kind not in offsets:
            raise ValueError(f"unknown CRS kind {kind!r}; choose one of {sorted(offsets)}")
        return f"IAU_2015:{self.iau_code + offsets[kind]}"

    @property
    def datum_is_iau_sphere(self) -> bool:
        """True when heights are above the IAU 2015 sphere itself (the Moon; not Mercury)."""
        return self.datum_radius_m == self.radius_m

    def datum_geographic_crs(self) -> str:
        """The geographic CRS of the datum sphere, as a CRS code or a WKT2 string (pyproj/GDAL input).

        The grid mapping of a height map: its sphere is the one heights are measured from,
        so a CF/GIS reader sees heights above the ellipsoid of the file's own CRS. Where the
        datum is the IAU 2015 sphere this is the IAU code itself; otherwise the IAU 2015
        geographic CRS with the sphere's radius replaced by the datum radius (same
        planetocentric, east-positive latitude/longitude, same reference meridian; no
        authority code: the IAU code of :meth:`crs` stays the horizontal reference).
        """
        return _datum_geographic_crs(self)

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "naif_id": self.naif_id, "radius_m": self.radius_m,
                "datum_radius_m": self.datum_radius_m, "iau_code": self.iau_code, "datum_crs": self.datum_crs}

    @staticmethod
    def from_dict(d: dict[str, object]) -> Body:
        """A body from :meth:`to_dict`'s mapping; a known name alone gives the catalogued body."""
        if not isinstance(d, dict):
            raise ValueError(f"a body is an object of name, naif_id, radius_m, ...; got {type(d).__name__}")
        name = str(d.get("name", "")).upper()
        if set(d) <= {"name"}:
            return body_by_name(name)
        try:
            body = Body(name=name, naif_id=_json_int(d["naif_id"]), radius_m=_json_float(d["radius_m"]),
                        datum_radius_m=_json_float(d["datum_radius_m"]), iau_code=_json_int(d["iau_code"]),
                        datum_crs=None if d.get("datum_crs") is None else str(d["datum_crs"]))
            if not (math.isfinite(body.radius_m) and math.isfinite(body.datum_radius_m)):
                raise ValueError("radii must be finite")
            return body
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f"body {name or '?'}: bad or missing field ({exc})") from None


def _json_int(v: object) -> int:
    """``int(v)`` of a value read from JSON/YAML; TypeError for a value ``int()`` does not take."""
    if isinstance(v, int | float | str | bytes):
        return int(v)
    raise TypeError(f"expected a number, got {type(v).__name__}")


def _json_float(v: object) -> float:
    """``float(v)`` of a value read from JSON/YAML; TypeError for a value ``float()`` does not take."""
    if isinstance(v, int | float | str | bytes):
        return float(v)
    raise TypeError(f"expected a number, got {type(v).__name__}")


#: Mercury: the IAU 2015 sphere and the 2439.4 km datum of the MESSENGER global DEM.
MERCURY = Body("MERCURY", 199, IAU_SPHERE_RADIUS_M, DATUM_RADIUS_M, 19900, CRS_DATUM_GEOGRAPHIC)
#: The Moon: the IAU 2015 sphere (1737.4 km), which is also the LOLA datum.
MOON = Body("MOON", 301, MOON_RADIUS_M, MOON_RADIUS_M, 30100, "IAU_2015:30100")
BODIES = {b.name: b for b in (MERCURY, MOON)}


@functools.lru_cache(maxsize=8)
def _datum_geographic_crs(body: Body) -> str:
    code = body.crs("geographic")
    if body.datum_is_iau_sphere:
        return code
    import pyproj

    j = pyproj.CRS.from_user_input(code).to_json_dict()
    sphere = f"{body.name.title()} datum sphere (R = {body.datum_radius_m:.0f} m)"
    j["name"] = f"{sphere} / Ocentric"
    j["datum"]["name"] = sphere
    j["datum"]["ellipsoid"] = {"name": sphere, "radius": body.datum_radius_m}
    j.pop("id", None)
    j["remarks"] = (f"Sphere of the height datum. Latitude/longitude are those of {code} (planetocentric, "
                    f"east-positive); only the radius differs ({body.radius_m:.0f} m there).")
    return pyproj.CRS.from_json_dict(j).to_wkt("WKT2_2019")


def body_by_name(name: str) -> Body:
    """A catalogued body by name (case-insensitive): MERCURY or MOON."""
    try:
        return BODIES[str(name).strip().upper()]
    except KeyError:
        raise ValueError(f"unknown body {name!r}; known bodies: {sorted(BODIES)}") from None


def wrap_longitude(lon_deg: ArrayLike) -> NDArray[np.float64]:
    """Longitude folded into [0, 360) degrees."""
    lon = np.mod(np.asarray(lon_deg, dtype=np.float64), 360.0)
    # np.mod(-1e-17, 360) == 360.0 in floating point; fold that back to 0.
    return np.where(lon >= 360.0, 0.0, lon)


def latlon_to_unit(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """Unit vectors of shape (..., 3) for planetocentric latitude/longitude in degrees."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


def latlon_to_xyz(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    height_m: ArrayLike,
    datum_radius_m: float,
) -> NDArray[np.float64]:
    """Body-fixed XYZ (metres, shape (..., 3)) of points at a height above the datum."""
    radius = datum_radius_m + np.asarray(height_m, dtype=np.float64)
    return latlon_to_unit(lat_deg, lon_deg) * radius[..., None]


def xyz_to_lat_lon(xyz: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Latitude and east longitude in [0, 360) (degrees) of body-fixed vectors of any length (no datum needed).

    Parameters
    ----------
    xyz : array of shape (..., 3), body-fixed (metres, or unit vectors)
    """
    p = np.asarray(xyz, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return np.degrees(np.arctan2(z, np.hypot(x, y))), wrap_longitude(np.degrees(np.arctan2(y, x)))


def xyz_to_latlon(
    xyz: ArrayLike, datum_radius_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Latitude, east longitude in [0, 360) (degrees) and height above the datum (m).

    Parameters
    ----------
    xyz : array of shape (..., 3), body-fixed metres
    """
    p = np.asarray(xyz, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    r = np.sqrt(x * x + y * y + z * z)
    lat = np.degrees(np.arctan2(z, np.hypot(x, y)))
    lon = wrap_longitude(np.degrees(np.arctan2(y, x)))
    return lat, lon, r - datum_radius_m


def angular_distance_deg(
    lat1: ArrayLike, lon1: ArrayLike, lat2: ArrayLike, lon2: ArrayLike
) -> NDArray[np.float64]:
    """Great-circle angle between two points, degrees (stable at small angles)."""
    a = latlon_to_unit(lat1, lon1)
    b = latlon_to_unit(lat2, lon2)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    out: NDArray[np.float64] = np.degrees(np.arctan2(cross, dot))
    return out
