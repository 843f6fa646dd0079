"""The one catalog builder: what an image label says, from a camera and an a-priori pose.

Used by ``synth`` (from the perturbed poses), by ``ingest`` (from the cubes' and
ISDs' SPICE) and by ``info --json`` (footprint statistics), so the three never
disagree on what "centre latitude" or "pixel scale" means:

* centre: the ray of the image centre pixel ((samples-1)/2, (lines-1)/2) on the datum
  sphere (the PDS labels' convention); pixel scale = slant distance x IFOV (ISIS's
  ``DetectorResolution``: no incidence/emission foreshortening);
* angles on the sphere normal (incidence, emission, phase), degrees;
* footprint: the latitude/longitude extent of the image border on the datum sphere;
* tile: the 10-degree tile of the centre (:class:`~mercury_dem.geometry.tiling.TileGrid`).

:func:`footprint_statistics` evaluates the camera at every ``step``-th pixel, the way
ISIS's ``camstats`` makes a cube's ``CameraStatistics`` (minimum, maximum, average and
standard deviation of latitude, longitude, resolution and the three angles over the
pixels that see the body).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import Body, xyz_to_latlon
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.caminfo import centre_geometry
from mercury_dem.geometry.footprints import image_footprints
from mercury_dem.geometry.pose import illumination_angles, intersect_sphere
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.mission.radiometry import RADIOMETRY_COLUMNS, Radiometry

if TYPE_CHECKING:
    import pandas as pd  # imported where a table is built: 'mercury-dem info' reads catalogs without pandas

ROTATION_COLUMNS = [f"rotation_{i}{j}" for i in range(3) for j in range(3)]
POSITION_COLUMNS = [f"position_{a}" for a in "xyz"]
SUN_COLUMNS = [f"sun_{a}" for a in "xyz"]
GEOMETRY_COLUMNS = ["pixel_scale_m", "center_lat", "center_lon", "incidence_deg", "emission_deg", "phase_deg"]
FOOTPRINT_COLUMNS = ["footprint_lat_min", "footprint_lat_max", "footprint_lon_min", "footprint_lon_max"]
CATALOG_COLUMNS = (
    ["image_id", "instrument", "camera_id", "samples", "lines", "summing", "time"]
    + POSITION_COLUMNS + ROTATION_COLUMNS + SUN_COLUMNS + GEOMETRY_COLUMNS + ["tile_id"]
    + FOOTPRINT_COLUMNS + RADIOMETRY_COLUMNS
)
#: Columns a version-1 (synthetic-only) catalog has; the reader fills the rest.
CATALOG_COLUMNS_V1 = (
    ["image_id", "instrument", "samples", "lines", "summing", "time"]
    + POSITION_COLUMNS + ROTATION_COLUMNS + SUN_COLUMNS + GEOMETRY_COLUMNS + ["tile_id"]
)


def footprint_extent(
    camera: FramingCamera, positions: NDArray[np.float64], rotations: NDArray[np.float64], radius_m: float
) -> dict[str, NDArray[np.float64]]:
    """Latitude and longitude extent (degrees) of N images' borders on the sphere.

    Longitudes are unwrapped about the border's circular mean, so an image across
    the 0/360 seam has ``lon_min`` < 0 or ``lon_max`` >= 360; an image over a pole
    gets the whole longitude range and its latitude extended to the pole.
    """
    fp = image_footprints(camera, positions, rotations, per_side=8, radius_m=radius_m)  # (N, K, 3) unit
    lat, lon, _ = xyz_to_latlon(fp, 1.0)
    mean = np.degrees(np.arctan2(np.sin(np.radians(lon)).mean(-1), np.cos(np.radians(lon)).mean(-1)))
    rel = (lon - mean[:, None] + 180.0) % 360.0 - 180.0
    lo, hi = mean + rel.min(-1), mean + rel.max(-1)
    shift = np.floor(lo / 360.0) * 360.0
    lo, hi = lo - shift, hi - shift
    la0, la1 = lat.min(-1), lat.max(-1)
    # A pole inside the footprint: the border's longitudes wind once around it.
    wind = np.abs(np.sum((np.diff(np.concatenate([lon, lon[:, :1]], -1), axis=-1) + 180.0) % 360.0 - 180.0, -1))
    polar = wind > 180.0
    la1 = np.where(polar & (la1 > 0), 90.0, la1)
    la0 = np.where(polar & (la0 < 0) & ~(la1 == 90.0), -90.0, la0)
    lo, hi = np.where(polar, 0.0, lo), np.where(polar, 360.0, hi)
    return {"footprint_lat_min": la0, "footprint_lat_max": la1, "footprint_lon_min": lo, "footprint_lon_max": hi}


def build_catalog(
    image_ids: Sequence[str],
    instruments: Sequence[str],
    cameras: dict[str, FramingCamera],
    camera_ids: Sequence[str],
    times: NDArray[np.float64],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    suns: NDArray[np.float64],
    body: Body,
    tile_size_deg: float,
    radiometry: Sequence[Radiometry],
    extra: dict[str, Any] | None = None,
) -> pd.DataFrame:
    """The image catalog (:data:`CATALOG_COLUMNS`, then ``extra``) from a-priori poses.

    Parameters
    ----------
    cameras : camera id -> camera; camera_ids : (N,) the camera of each image
    times : (N,) seconds (TDB past J2000 for real images; the synthetic clock otherwise)
    positions : (N, 3) body-fixed metres; rotations : (N, 3, 3) body -> camera; suns : (N, 3) metres
    body : the target (centres and footprints on its datum sphere)
    radiometry : (N,) the pixel facts of each image
    """
    n = len(image_ids)
    positions = np.asarray(positions, np.float64).reshape(n, 3)
    rotations = np.asarray(rotations, np.float64).reshape(n, 3, 3)
    suns = np.asarray(suns, np.float64).reshape(n, 3)
    cam_ids = np.asarray(camera_ids, dtype=str)
    missing = sorted(set(cam_ids.tolist()) - set(cameras))
    if missing:
        raise ValueError(f"build_catalog: camera ids {missing} are not in the camera table")
    cols = GEOMETRY_COLUMNS + FOOTPRINT_COLUMNS
    geo = {k: np.full(n, np.nan) for k in cols}
    samples, lines, summing = (np.zeros(n, np.int64) for _ in range(3))
    for cid in np.unique(cam_ids):
        idx = np.flatnonzero(cam_ids == cid)
        cam = cameras[str(cid)]
        samples[idx], lines[idx], summing[idx] = cam.samples, cam.lines, cam.summing
        g = centre_geometry(cam, positions[idx], rotations[idx], suns[idx], body.datum_radius_m)
        g.update(footprint_extent(cam, positions[idx], rotations[idx], body.datum_radius_m))
        for k in cols:
            geo[k][idx] = g[k]
    import pandas as pd

    cat = pd.DataFrame({
        "image_id": np.asarray(image_ids, dtype=str),
        "instrument": np.asarray(instruments, dtype=str),
        "camera_id": cam_ids,
        "samples": samples, "lines": lines, "summing": summing,
        "time": np.asarray(times, np.float64).reshape(n),
    })
    for cols3, arr in ((POSITION_COLUMNS, positions), (ROTATION_COLUMNS, rotations.reshape(n, 9)), (SUN_COLUMNS, suns)):
        for k, c in enumerate(cols3):
            cat[c] = arr[:, k]
    for k in GEOMETRY_COLUMNS:
        cat[k] = geo[k]
    ok = np.isfinite(geo["center_lat"])
    tile = np.full(n, -1, np.int64)
    tile[ok] = TileGrid(tile_size_deg).tile_of(geo["center_lat"][ok], geo["center_lon"][ok])
    cat["tile_id"] = tile
    for k in FOOTPRINT_COLUMNS:
        cat[k] = geo[k]
    cat["pixel_kind"] = [r.pixel_kind for r in radiometry]
    cat["saturation"] = np.array([r.saturation for r in radiometry], np.float64)
    cat["dn_scale"] = np.array([r.dn_scale for r in radiometry], np.float64)
    for k, v in (extra or {}).items():
        cat[k] = v
    return cat


STAT_QUANTITIES = ("latitude", "longitude", "resolution", "incidence", "emission", "phase")


def footprint_statistics(
    camera: FramingCamera,
    position: NDArray[np.float64],
    rotation: NDArray[np.float64],
    sun: NDArray[np.float64] | None,
    radius_m: float,
    step: int = 1,
) -> dict[str, dict[str, float]]:
    """Per quantity (latitude, longitude, resolution m, incidence, emission, phase) its
    ``minimum``, ``maximum``, ``average`` and ``standard_deviation`` over the image's
    pixels (every ``step``-th pixel centre in both directions) that see the sphere.

    The same quantities as ISIS's ``CameraStatistics``; longitudes east, unwrapped about
    their circular mean (min may be < 0 or max >= 360 across the seam). Resolution is
    slant distance x IFOV at each pixel (ISIS's ``PixelResolution`` of a framing camera).
    Returns an empty dict when no pixel sees the sphere.
    """
    s = np.arange(0, camera.samples, max(1, int(step)), dtype=np.float64)
    l_ = np.arange(0, camera.lines, max(1, int(step)), dtype=np.float64)
    ss, ll = np.meshgrid(s, l_)
    px = np.stack([ss.ravel(), ll.ravel()], -1)
    c = np.asarray(position, np.float64)
    v = camera.pixel_to_camera(px) @ np.asarray(rotation, np.float64)
    ground, hit = intersect_sphere(np.broadcast_to(c, v.shape), v, radius_m)
    if not hit.any():
        return {}
    g = ground[hit]
    lat, lon, _ = xyz_to_latlon(g, radius_m)
    mean_lon = np.degrees(np.arctan2(np.sin(np.radians(lon)).mean(), np.cos(np.radians(lon)).mean()))
    lon = mean_lon + (lon - mean_lon + 180.0) % 360.0 - 180.0
    if np.mean(lon) < 0:
        lon = lon + 360.0
    slant = np.linalg.norm(g - c, axis=-1)
    values: dict[str, NDArray[np.float64]] = {"latitude": lat, "longitude": lon,
                                              "resolution": slant * camera.ifov_rad}
    if sun is not None:
        inc, emi, pha = illumination_angles(g, c, np.asarray(sun, np.float64))
        values.update(incidence=inc, emission=emi, phase=pha)
    else:
        _, emi, _ = illumination_angles(g, c, 1e3 * c)
        values["emission"] = emi
    return {k: {"minimum": float(v.min()), "maximum": float(v.max()), "average": float(v.mean()),
                "standard_deviation": float(v.std())} for k, v in values.items()}
