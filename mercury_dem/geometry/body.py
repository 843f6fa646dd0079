"""The target body: Mercury as a sphere, and latitude/longitude/height <-> body-fixed XYZ.

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

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Datum radius of the MESSENGER global DEM (Becker et al. 2016), metres.
DATUM_RADIUS_M: float = 2_439_400.0
#: Radius of the IAU 2015 Mercury sphere (the CRS `IAU_2015:19900`), metres.
IAU_SPHERE_RADIUS_M: float = 2_440_530.0

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
    height_m: ArrayLike = 0.0,
    datum_radius_m: float = DATUM_RADIUS_M,
) -> NDArray[np.float64]:
    """Body-fixed XYZ (metres, shape (..., 3)) of points at a height above the datum."""
    radius = datum_radius_m + np.asarray(height_m, dtype=np.float64)
    return latlon_to_unit(lat_deg, lon_deg) * radius[..., None]


def xyz_to_latlon(
    xyz: ArrayLike, datum_radius_m: float = DATUM_RADIUS_M
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
    return np.degrees(np.arctan2(cross, dot))
