"""The map extent of a point cloud when the DEM bounds are left unset (mercury_dem.dem.extent)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.extent import config_with_extent, points_extent, whole_pixel_step
from mercury_dem.dem.grid import GridSpec
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import DATUM_RADIUS_M, MERCURY, latlon_to_xyz

MARGIN = 50_000.0
MARGIN_DEG = math.degrees(MARGIN / DATUM_RADIUS_M)


def _cloud(lat_range, lon_range, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    lat = rng.uniform(*lat_range, n)
    lon = rng.uniform(*lon_range, n)
    return latlon_to_xyz(lat, np.mod(lon, 360.0), rng.normal(0, 500, n), datum_radius_m=DATUM_RADIUS_M), lat, lon


def _covers(ext, lat, lon):
    lat_min, lat_max, lon_min, lon_max = ext
    lon_in = np.mod(lon - lon_min, 360.0) <= (lon_max - lon_min)
    return np.all((lat >= lat_min) & (lat <= lat_max) & lon_in)


def test_a_regional_cloud_gets_its_footprint_plus_the_margin_in_whole_degrees() -> None:
    pts, lat, lon = _cloud((-12.3, 7.8), (100.4, 131.2))
    ext = points_extent(pts, MARGIN, 64.0, datum_radius_m=DATUM_RADIUS_M)
    assert all(float(v).is_integer() for v in ext)
    assert ext[0] <= lat.min() - MARGIN_DEG and ext[1] >= lat.max() + MARGIN_DEG
    assert ext[0] > lat.min() - MARGIN_DEG - 1 and ext[1] < lat.max() + MARGIN_DEG + 1
    assert ext[2] < lon.min() and ext[3] > lon.max() and ext[3] - ext[2] < 35
    GridSpec(64.0, *ext, datum_radius_m=DATUM_RADIUS_M)  # whole pixels


def test_a_cloud_across_the_seam_is_not_the_whole_globe() -> None:
    pts, lat, lon = _cloud((20, 30), (-15, 25))
    ext = points_extent(pts, MARGIN, 8.0, datum_radius_m=DATUM_RADIUS_M)
    assert ext[3] - ext[2] < 50, ext
    assert _covers(ext, lat, lon)
    g = GridSpec(8.0, *ext, datum_radius_m=DATUM_RADIUS_M)
    assert not g.is_global_lon


def test_a_polar_or_global_cloud_gets_every_longitude() -> None:
    pts, _, _ = _cloud((80, 89.5), (0, 360))
    assert points_extent(pts, MARGIN, 8.0, datum_radius_m=DATUM_RADIUS_M)[1:] == (90.0, 0.0, 360.0)
    pts, _, _ = _cloud((-60, 60), (0, 360), n=20000)
    ext = points_extent(pts, MARGIN, 8.0, datum_radius_m=DATUM_RADIUS_M)
    assert ext[2:] == (0.0, 360.0) and ext[0] <= -60 - MARGIN_DEG and ext[1] >= 60 + MARGIN_DEG


def test_fractional_resolutions_snap_to_whole_pixels() -> None:
    assert whole_pixel_step(64.0) == 1 and whole_pixel_step(0.5) == 2 and whole_pixel_step(2.5) == 2
    pts, lat, lon = _cloud((3.3, 9.1), (40.2, 47.9))
    ext = points_extent(pts, MARGIN, 0.5, datum_radius_m=DATUM_RADIUS_M)
    assert all(v % 2 == 0 for v in ext)
    GridSpec(0.5, *ext, datum_radius_m=DATUM_RADIUS_M)
    assert _covers(ext, lat, lon)


def test_empty_cloud_is_a_named_error() -> None:
    with pytest.raises(GridError, match="empty"):
        points_extent(np.zeros((0, 3)), MARGIN, 8.0, datum_radius_m=DATUM_RADIUS_M)


def test_config_bounds_that_are_set_are_kept() -> None:
    pts, _, _ = _cloud((-12.3, 7.8), (100.4, 131.2))
    assert DemConfig().bounds() == (-90.0, 90.0, 0.0, 360.0)
    fixed = DemConfig(lat_min=-30.0, lat_max=30.0, lon_min=90.0, lon_max=150.0)
    assert not fixed.extent_from_points and config_with_extent(fixed, pts, datum_radius_m=DATUM_RADIUS_M) is fixed
    part = config_with_extent(DemConfig(lat_min=-40.0), pts, datum_radius_m=DATUM_RADIUS_M)
    assert part.lat_min == -40.0 and part.lat_max == 9.0 and part.lon_min == 99.0 and part.lon_max == 133.0


def test_grid_dem_with_unset_bounds_maps_the_cloud_not_the_globe(tmp_path) -> None:
    from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

    pts, lat, lon = _cloud((-5.5, 4.5), (10.2, 20.7), n=20000)
    summary = grid_dem(pts, DemConfig(pixels_per_degree=8.0, chunk_size=64), tmp_path / "dem.zarr", coverage=False, body=MERCURY)
    assert summary["grid_bounds_deg"] == [-7.0, 6.0, 9.0, 22.0]
    ds = open_dem(tmp_path / "dem.zarr")
    assert ds["elevation"].shape == (13 * 8, 13 * 8)
    inside = ds["elevation"].sel(lat=slice(4.0, -5.0), lon=slice(11.0, 20.0)).values
    assert np.isfinite(inside).all()


def test_coverage_of_a_regional_map_is_the_global_coverage_cut_to_its_area() -> None:
    from mercury_dem.dem.coverage import point_coverage
    from mercury_dem.dem.grid import build_point_index

    pts, lat, lon = _cloud((-5.5, 4.5), (-8.0, 6.0), n=5000)  # across the seam
    index = build_point_index(pts, datum_radius_m=DATUM_RADIUS_M)
    ext = points_extent(pts, MARGIN, 8.0, datum_radius_m=DATUM_RADIUS_M)
    whole = point_coverage(index, 20.0)
    part = point_coverage(index, 20.0, bounds=ext)
    s_whole, s_part = whole.summary(), part.summary()
    assert s_part["occupied_pixels"] == s_whole["occupied_pixels"]
    assert s_part["map_pixels"] < 0.05 * s_whole["map_pixels"]
    # the same pixels get the same counts and nearest distances
    rows = np.flatnonzero(np.isin(whole.y_km, part.y_km))
    on = part.count >= 0
    assert np.array_equal(whole.count[rows][on], part.count[on])
    assert np.array_equal(whole.nearest_km[rows][on], part.nearest_km[on])
    # every map pixel lies inside the bounds
    rk = DATUM_RADIUS_M / 1000.0
    la = np.degrees(part.y_km / rk)[:, None] * np.ones_like(part.x_km)[None, :]
    lo = np.degrees(part.x_km[None, :] / (rk * np.cos(np.radians(la))))
    assert np.all((la[on] >= ext[0]) & (la[on] <= ext[1]))
    assert np.all(np.mod(lo[on] - ext[2], 360.0) <= ext[3] - ext[2])
