"""The canvas of a point cloud when the DEM bounds are left unset (mercury_dem.dem.extent)."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.extent import (
    box_area_ratio,
    config_with_extent,
    points_box,
    points_extent,
    whole_pixel_step,
)
from mercury_dem.dem.grid import GridSpec
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import DATUM_RADIUS_M, MOON, latlon_to_xyz


def _cloud(lat_range, lon_range, n=2000, seed=0, radius=DATUM_RADIUS_M):
    rng = np.random.default_rng(seed)
    lat = rng.uniform(*lat_range, n)
    lon = rng.uniform(*lon_range, n)
    return latlon_to_xyz(lat, np.mod(lon, 360.0), rng.normal(0, 500, n), radius), lat, lon


def _covers(ext, lat, lon):
    lat_min, lat_max, lon_min, lon_max = ext
    lon_in = np.mod(lon - lon_min, 360.0) <= (lon_max - lon_min)
    return np.all((lat >= lat_min) & (lat <= lat_max) & lon_in)


def _on_pixel_grid(ext, ppd):
    """Every edge is a pixel edge of the global grid (-90 + i / ppd, j / ppd)."""
    idx = np.array([ext[0] + 90.0, ext[1] + 90.0, ext[2], ext[3]]) * ppd
    return np.allclose(idx, np.round(idx), atol=1e-9)


@pytest.mark.parametrize("ppd", [64.0, 256.0])
def test_a_small_block_gets_its_box_plus_a_pixel_snapped_to_the_pixel_grid(ppd) -> None:
    # the user's case: 0.8 x 0.75 deg of the Moon near 25 N, 3 E (was a 6 x 5 deg canvas at 64 ppd)
    pts, lat, lon = _cloud((24.6, 25.35), (2.6, 3.4), n=20000, radius=MOON.datum_radius_m)
    ext = points_extent(pts, ppd, margin_pixels=1)
    box = points_box(pts)
    assert _covers(ext, lat, lon) and _on_pixel_grid(ext, ppd)
    assert box_area_ratio(ext, box) < 1.2
    # at most the margin plus one pixel of snapping beyond the box on each side
    assert box[0] - ext[0] <= 2 / ppd and ext[1] - box[1] <= 2 / ppd
    assert box[2] - ext[2] <= 2 / ppd and ext[3] - box[3] <= 2 / ppd
    assert box[0] - ext[0] >= 1 / ppd and ext[3] - box[3] >= 1 / ppd
    GridSpec(ppd, *ext, datum_radius_m=DATUM_RADIUS_M)  # whole pixels


def test_grids_of_the_same_resolution_align() -> None:
    a, _, _ = _cloud((10.1, 10.9), (40.3, 41.2), seed=1)
    b, _, _ = _cloud((10.5, 11.6), (40.9, 42.0), seed=2)
    ea, eb = points_extent(a, 64.0, margin_pixels=1), points_extent(b, 64.0, margin_pixels=1)
    ga, gb = GridSpec(64.0, *ea, datum_radius_m=DATUM_RADIUS_M), GridSpec(64.0, *eb, datum_radius_m=DATUM_RADIUS_M)
    # the pixel centres of one grid, where the grids overlap, are pixel centres of the other
    lat_a, lat_b = ga.lat_centres(), gb.lat_centres()
    common = lat_a[(lat_a > eb[0]) & (lat_a < eb[1])]
    assert common.size and np.all(np.isclose(common[:, None], lat_b[None, :], atol=1e-9).any(axis=1))
    lon_a, lon_b = ga.lon_centres(), gb.lon_centres()
    common = lon_a[(lon_a > eb[2]) & (lon_a < eb[3])]
    assert common.size and np.all(np.isclose(common[:, None], lon_b[None, :], atol=1e-9).any(axis=1))


@pytest.mark.parametrize("lon_range", [(-0.45, 0.35), (179.6, 180.4), (-180.4, -179.6)])
def test_a_block_across_0_or_180_degrees_is_not_the_whole_globe(lon_range) -> None:
    pts, lat, lon = _cloud((-12.0, -11.25), lon_range, n=5000, radius=MOON.datum_radius_m)
    ext = points_extent(pts, 64.0, margin_pixels=1)
    assert _covers(ext, lat, lon) and _on_pixel_grid(ext, 64.0)
    assert ext[3] - ext[2] < 0.8 + 3 / 64, ext
    assert box_area_ratio(ext, points_box(pts)) < 1.2
    g = GridSpec(64.0, *ext, datum_radius_m=DATUM_RADIUS_M)
    assert not g.is_global_lon
    if lon_range[0] < 0 < lon_range[1]:
        assert ext[2] < 0 < ext[3]  # across the 0/360 seam: starts west of 0


def test_a_polar_or_global_cloud_gets_every_longitude() -> None:
    pts, _, _ = _cloud((80, 89.5), (0, 360))
    ext = points_extent(pts, 8.0, margin_pixels=1)
    assert ext[2:] == (0.0, 360.0) and 89.5 <= ext[1] <= 90.0 and 79.75 <= ext[0] < 80.0
    pts, _, _ = _cloud((84, 89.95), (10, 30))  # a block whose margin reaches the pole
    assert points_extent(pts, 8.0, margin_pixels=1)[1:] == (90.0, 0.0, 360.0)
    pts, _, _ = _cloud((-60, 60), (0, 360), n=20000)
    ext = points_extent(pts, 8.0, margin_pixels=1)
    assert ext[2:] == (0.0, 360.0) and -60.25 <= ext[0] < -60 and 60 < ext[1] <= 60.25
    pts, _, _ = _cloud((-90, 90), (0, 360), n=20000)
    assert points_extent(pts, 8.0, margin_pixels=1) == (-90.0, 90.0, 0.0, 360.0)


def test_fractional_resolutions_snap_to_whole_pixels() -> None:
    assert whole_pixel_step(64.0) == 1 and whole_pixel_step(0.5) == 2 and whole_pixel_step(2.5) == 2
    pts, lat, lon = _cloud((3.3, 9.1), (40.2, 47.9))
    ext = points_extent(pts, 0.5, margin_pixels=1)
    assert all(v % 2 == 0 for v in ext)
    GridSpec(0.5, *ext, datum_radius_m=DATUM_RADIUS_M)
    assert _covers(ext, lat, lon)
    ext = points_extent(pts, 3.0, margin_pixels=1)
    GridSpec(3.0, *ext, datum_radius_m=DATUM_RADIUS_M)
    assert _covers(ext, lat, lon)


def test_empty_cloud_is_a_named_error() -> None:
    with pytest.raises(GridError, match="empty"):
        points_extent(np.zeros((0, 3)), 8.0, margin_pixels=1)


def test_config_bounds_that_are_set_are_kept() -> None:
    pts, lat, lon = _cloud((-12.3, 7.8), (100.4, 131.2))
    assert DemConfig().bounds() == (-90.0, 90.0, 0.0, 360.0)
    fixed = DemConfig(lat_min=-30.0, lat_max=30.0, lon_min=90.0, lon_max=150.0)
    assert not fixed.extent_from_points and config_with_extent(fixed, pts) is fixed
    part = config_with_extent(DemConfig(lat_min=-40.0), pts)
    auto = points_extent(pts, 64.0, margin_pixels=1)
    assert (part.lat_min, part.lat_max, part.lon_min, part.lon_max) == (-40.0, *auto[1:])
    wide = config_with_extent(DemConfig(canvas_margin_pixels=10), pts)
    assert wide.lat_max == pytest.approx(auto[1] + 9 / 64, abs=1.01 / 64)


def test_grid_dem_with_unset_bounds_maps_the_cloud_not_the_globe(tmp_path) -> None:
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

    pts, lat, lon = _cloud((-5.5, 4.5), (10.2, 20.7), n=20000)
    summary = grid_dem(pts, DemConfig(pixels_per_degree=8.0, chunk_size=64), tmp_path / "dem.zarr", coverage=False,
                       body=MERCURY)
    assert summary["grid_bounds_deg"] == [-5.625, 4.625, 10.0, 20.875]
    ds = open_dem(tmp_path / "dem.zarr")
    assert ds["elevation"].shape == (82, 87)
    inside = ds["elevation"].sel(lat=slice(4.0, -5.0), lon=slice(11.0, 20.0)).values
    assert np.isfinite(inside).all()


def test_coverage_of_a_regional_map_is_the_global_coverage_cut_to_its_area() -> None:
    from mercury_dem.dem.coverage import point_coverage
    from mercury_dem.dem.grid import build_point_index

    pts, lat, lon = _cloud((-5.5, 4.5), (-8.0, 6.0), n=5000)  # across the seam
    index = build_point_index(pts, DATUM_RADIUS_M)
    ext = points_extent(pts, 8.0, margin_pixels=1)
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
