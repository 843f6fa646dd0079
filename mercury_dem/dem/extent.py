"""The map a point cloud needs: its bounding box plus a margin of a few pixels, snapped to the pixel grid.

A DEM configured without bounds (``dem.lat_min`` ... ``dem.lon_max`` left unset) is
gridded over this canvas instead of the whole globe: the grid of a block covers the
block. The canvas is the points' latitude/longitude bounding box widened by
``dem.canvas_margin_pixels`` pixels on each side and snapped outward to the global pixel
grid (edges at ``-90 + i / ppd`` and ``j / ppd`` degrees), so two grids at the same
resolution share their pixels wherever they overlap. Every pixel added beyond the data
costs its search for the nearest points and ends up without a value: a user's 0.8 deg x
0.75 deg block of LOLA shots once got a 6 deg x 5 deg canvas (the margin was the 50 km
no-value distance, then whole degrees), 30 times the data's area, 48 % of it no value.

Longitudes are handled on the circle: the box is the complement of the largest empty
longitude gap, so a block across 0/360 gives e.g. -0.4..0.5 (the grid's columns may
start west of 0, ``GridSpec`` handles any start) and one across 180 gives 179.6..180.5.
A canvas that would reach a pole, or span more than :data:`GLOBAL_LON_SPAN_DEG` (270)
degrees, gets every longitude (a pole meets them all; a nearly global cloud gets a map
that wraps); its latitudes stay the points' plus the margin, so a global cloud reaching
the poles gets the globe and a cloud between 60 S and 60 N the band between them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.dem import DemConfig
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import xyz_to_lat_lon

#: A canvas wider than this (degrees of longitude) takes every longitude: at most a third more pixels, and
#: the map then wraps at 0/360 without an edge (a global cloud, whose widest gap is small, keeps the globe).
GLOBAL_LON_SPAN_DEG = 270.0

#: Tolerance (in pixels) of the outward snapping: a box edge within it of a pixel edge stays on that edge.
SNAP_TOLERANCE_PX = 1e-6


def whole_pixel_step(pixels_per_degree: float, max_step: int = 360) -> int:
    """Smallest whole number of degrees that is a whole number of pixels (1 for integral resolutions)."""
    for d in range(1, max_step + 1):
        n = d * pixels_per_degree
        if abs(n - round(n)) <= 1e-9 * max(1.0, n):
            return d
    raise GridError(f"no whole number of degrees up to {max_step} is a whole number of pixels at "
                    f"{pixels_per_degree} pixel/deg; choose a resolution like 4, 8, 0.5 or 64")


def _finite_directions(points_xyz: NDArray[np.floating]) -> NDArray[np.float64]:
    p = np.asarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1) & (np.einsum("ij,ij->i", p, p) > 0)]
    if p.shape[0] == 0:
        raise GridError("the point cloud is empty: no extent to grid (did the adjustment keep any points?)")
    out: NDArray[np.float64] = p
    return out


def lonlat_box(lat_deg: NDArray[np.floating], lon_deg: NDArray[np.floating]) -> tuple[float, float, float, float]:
    """(lat_min, lat_max, west, east) in degrees of points given by latitude and east longitude.

    The longitudes are taken on the circle: ``[west, east]`` is the complement of the
    largest empty longitude gap, ``west`` in [0, 360), ``east`` in [west, west + 360)
    (above 360 for a box across the 0/360 seam). Non-empty input only.
    """
    lat = np.asarray(lat_deg, dtype=np.float64).ravel()
    lons = np.sort(np.mod(np.asarray(lon_deg, dtype=np.float64).ravel(), 360.0))
    gaps = np.diff(np.concatenate([lons, lons[:1] + 360.0]))
    k = int(np.argmax(gaps))
    west = float(lons[(k + 1) % lons.size])  # the largest gap ends where the cloud starts
    east = float(lons[k])
    if east < west:
        east += 360.0
    return float(lat.min()), float(lat.max()), west, east


def points_box(points_xyz: NDArray[np.floating]) -> tuple[float, float, float, float]:
    """:func:`lonlat_box` of a point cloud (N, 3) in body-fixed metres (non-finite and zero points ignored).

    Only directions matter: no datum or body is needed. An empty cloud raises :class:`GridError`.
    """
    lat, lon = xyz_to_lat_lon(_finite_directions(points_xyz))
    return lonlat_box(lat, lon)


def box_area_ratio(outer: tuple[float, float, float, float], inner: tuple[float, float, float, float]) -> float:
    """Area of the latitude/longitude box ``outer`` over that of ``inner`` (both (lat_min, lat_max, west, east),
    degrees) on a sphere: ``(east - west) * (sin lat_max - sin lat_min)`` each.
    """
    def area(b: tuple[float, float, float, float]) -> float:
        return (b[3] - b[2]) * (math.sin(math.radians(b[1])) - math.sin(math.radians(b[0])))

    return area(outer) / area(inner)


def points_extent(points_xyz: NDArray[np.floating], pixels_per_degree: float, *,
                  margin_pixels: float) -> tuple[float, float, float, float]:
    """(lat_min, lat_max, lon_min, lon_max) in degrees: the canvas of a point cloud (see the module docstring).

    Parameters
    ----------
    points_xyz : ndarray of shape (N, 3), body-fixed metres (non-finite and zero points ignored)
    pixels_per_degree : the grid's resolution; bounds are whole pixels of the global grid
        (edges at ``-90 + i / ppd`` degrees of latitude, ``j / ppd`` of longitude)
    margin_pixels : pixels added beyond the points' bounding box on each side, before snapping outward

    Raises
    ------
    GridError : empty cloud (there is nothing to size the map by)
    """
    ppd = float(pixels_per_degree)
    lat_lo, lat_hi, west, east = points_box(points_xyz)
    m = float(margin_pixels)
    eps = SNAP_TOLERANCE_PX
    n_lat = math.floor(180.0 * ppd + eps)  # pixel rows of the globe
    i0 = max(0, math.floor((lat_lo + 90.0) * ppd - m + eps))
    i1 = min(n_lat, math.ceil((lat_hi + 90.0) * ppd + m - eps))
    if i1 <= i0:
        i1 = min(n_lat, i0 + 1)
        i0 = i1 - 1
    lat_min, lat_max = -90.0 + i0 / ppd, -90.0 + i1 / ppd
    j0 = math.floor(west * ppd - m + eps)
    j1 = math.ceil(east * ppd + m - eps)
    if j1 <= j0:
        j1 = j0 + 1
    if i0 == 0 or i1 == n_lat or (j1 - j0) / ppd > GLOBAL_LON_SPAN_DEG:
        # a pole on the canvas meets every longitude; a box wider than 3/4 of the circle is the circle
        return lat_min, lat_max, 0.0, 360.0
    lon_min, lon_max = j0 / ppd, j1 / ppd
    if lon_max > 360.0:  # across the 0/360 seam: start west of 0 (e.g. -0.4..0.5, not 359.6..360.5)
        lon_min, lon_max = lon_min - 360.0, lon_max - 360.0
    return float(lat_min), float(lat_max), float(lon_min), float(lon_max)


def config_with_extent(cfg: DemConfig, points_xyz: NDArray[np.floating]) -> DemConfig:
    """``cfg`` with its unset bounds taken from a point cloud (:func:`points_extent` with the margin
    ``cfg.canvas_margin_pixels``); set bounds are kept, and ``cfg`` itself is returned when all four are set.

    Here and not a method of :class:`~mercury_dem.config.dem.DemConfig`: ``dem/`` depends on
    ``config/``, never the reverse.
    """
    if not cfg.extent_from_points:
        return cfg
    auto = points_extent(points_xyz, cfg.pixels_per_degree, margin_pixels=cfg.canvas_margin_pixels)
    lat_min, lat_max, lon_min, lon_max = auto
    return dataclasses.replace(
        cfg,
        lat_min=lat_min if cfg.lat_min is None else cfg.lat_min,
        lat_max=lat_max if cfg.lat_max is None else cfg.lat_max,
        lon_min=lon_min if cfg.lon_min is None else cfg.lon_min,
        lon_max=lon_max if cfg.lon_max is None else cfg.lon_max,
    )
