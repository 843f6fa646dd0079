"""The map extent a point cloud needs: its footprint plus a margin, snapped to whole pixels.

A DEM configured without bounds (``dem.lat_min`` ... ``dem.lon_max`` left unset) is
gridded over this extent instead of the whole globe: a regional mission (the
``tiny`` synthetic one, a single campaign) then gets a map of its own area at the
full resolution, while a global cloud still gets the global map. Gridding the globe
at 64 pixel/deg from a cloud that covers 2 % of it spends nearly all its time on
pixels that end up without a value (each needs its exact distance to the nearest
point, hundreds of kilometres away).

Longitudes are handled on the circle: the extent is the complement of the largest
empty longitude gap, so a cloud straddling the 0/360 seam gives e.g. -20..40 (the
grid's columns may start west of 0, ``GridSpec`` handles any start); a cloud that
reaches a pole within the margin, or leaves no gap wider than twice the margin, gets
all longitudes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.dem import DemConfig
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import xyz_to_latlon


def whole_pixel_step(pixels_per_degree: float, max_step: int = 360) -> int:
    """Smallest whole number of degrees that is a whole number of pixels (1 for integral resolutions)."""
    for d in range(1, max_step + 1):
        n = d * pixels_per_degree
        if abs(n - round(n)) <= 1e-9 * max(1.0, n):
            return d
    raise GridError(f"no whole number of degrees up to {max_step} is a whole number of pixels at "
                    f"{pixels_per_degree} pixel/deg; choose a resolution like 4, 8, 0.5 or 64")


def points_extent(points_xyz: NDArray[np.floating], margin_m: float,
                  pixels_per_degree: float, datum_radius_m: float) -> tuple[float, float, float, float]:
    """(lat_min, lat_max, lon_min, lon_max) in degrees covering the points plus ``margin_m``.

    Bounds are snapped outward to multiples of :func:`whole_pixel_step` degrees (whole
    degrees for integral resolutions), so the grid spans whole pixels and two clouds
    over the same area give the same grid. Non-finite points are ignored; an empty
    cloud raises :class:`GridError` (there is nothing to size the map by).
    """
    p = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1) & (np.einsum("ij,ij->i", p, p) > 0)]
    if p.shape[0] == 0:
        raise GridError("the point cloud is empty: no extent to grid (did the adjustment keep any points?)")
    d = whole_pixel_step(pixels_per_degree)
    lat, lon = xyz_to_latlon(p, datum_radius_m)[:2]
    margin_deg = math.degrees(margin_m / datum_radius_m)
    lo = max(-90.0, float(lat.min()) - margin_deg)
    hi = min(90.0, float(lat.max()) + margin_deg)
    lat_min = max(-90.0, -90.0 + math.floor((lo + 90.0) / d + 1e-9) * d)
    lat_max = min(90.0, -90.0 + math.ceil((hi + 90.0) / d - 1e-9) * d)
    if lat_max <= lat_min:
        lat_max = min(90.0, lat_min + d)
    if lat_min <= -90.0 or lat_max >= 90.0:  # a pole inside the map: every longitude meets it
        return lat_min, lat_max, 0.0, 360.0
    # longitude margin at the map's highest |latitude| (where a degree of longitude is shortest)
    coslat = math.cos(math.radians(max(abs(lat_min), abs(lat_max))))
    lon_margin = margin_deg / max(coslat, 1e-6)
    lons = np.sort(np.mod(lon, 360.0))
    gaps = np.diff(np.concatenate([lons, lons[:1] + 360.0]))
    k = int(np.argmax(gaps))
    if gaps[k] - 2.0 * lon_margin <= d:
        return lat_min, lat_max, 0.0, 360.0
    west = float(lons[(k + 1) % lons.size]) - lon_margin  # the gap ends where the cloud starts
    east = float(lons[k]) + lon_margin
    if east < west:
        east += 360.0
    lon_min = math.floor(west / d + 1e-9) * d
    lon_max = math.ceil(east / d - 1e-9) * d
    if lon_max - lon_min >= 360.0:
        return lat_min, lat_max, 0.0, 360.0
    if lon_min >= 360.0 or lon_min < -180.0:
        shift = 360.0 * math.floor(lon_min / 360.0)
        lon_min, lon_max = lon_min - shift, lon_max - shift
    return float(lat_min), float(lat_max), float(lon_min), float(lon_max)


def config_with_extent(cfg: DemConfig, points_xyz: NDArray[np.floating],
                       datum_radius_m: float) -> DemConfig:
    """``cfg`` with its unset bounds taken from a point cloud (:func:`points_extent` with the margin
    ``cfg.max_distance_m``); set bounds are kept, and ``cfg`` itself is returned when all four are set.

    Here and not a method of :class:`~mercury_dem.config.dem.DemConfig`: ``dem/`` depends on
    ``config/``, never the reverse.
    """
    if not cfg.extent_from_points:
        return cfg
    auto = points_extent(points_xyz, cfg.max_distance_m, cfg.pixels_per_degree, datum_radius_m)
    names = ("lat_min", "lat_max", "lon_min", "lon_max")
    return dataclasses.replace(cfg, **{n: a for n, a in zip(names, auto) if getattr(cfg, n) is None})
