"""Tile grid, regions, hemispheres, footprints and the overlap graph (seam, pole, disjoint)."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac, mdis_wac
from mercury_dem.geometry.footprints import (
    footprint_area_m2,
    footprint_latlon,
    image_footprint,
    image_footprints,
    overlap_graph,
)
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.geometry.tiling import N_REGIONS, TileGrid, region_name


def test_tile_counts_10_and_15_deg() -> None:
    g = TileGrid(10.0)
    assert (g.n_rows, g.n_cols, g.n_tiles) == (18, 36, 648)  # not the 720 of the reference text
    s = g.summary()
    assert sum(s["regions"].values()) == 648
    assert s["regions"]["N-cap"] == 3 * 36 and s["regions"]["N-000-060"] == 6 * 6
    assert s["hemispheres"] == {"north": 324, "south": 324}
    assert TileGrid(15.0).n_tiles == 288


def test_tile_of_edges_seam_and_poles() -> None:
    g = TileGrid(10.0)
    assert g.tile_of(-90.0, 0.0) == 0
    assert g.tile_of(90.0, 359.999) == g.n_tiles - 1
    assert g.tile_of(0.0, 360.0) == g.tile_of(0.0, 0.0)
    assert g.tile_of(0.0, -0.001) == g.tile_of(0.0, 359.999)
    lat0, lat1, lon0, lon1 = g.bounds(g.tile_of(45.3, 123.4))
    assert (lat0, lat1, lon0, lon1) == (40.0, 50.0, 120.0, 130.0)
    with pytest.raises(ConfigError):
        g.tile_of(91.0, 0.0)


def test_regions_are_whole_tiles_and_cover_the_globe() -> None:
    for size in (5.0, 10.0, 15.0, 30.0):
        g = TileGrid(size)
        tiles = np.arange(g.n_tiles)
        reg = g.region_of_tile(tiles)
        assert set(reg.tolist()) == set(range(N_REGIONS))
        lat_c, lon_c = g.centre(tiles)
        # every tile of a region lies inside the region's lat/lon box
        cap = np.abs(lat_c) >= 60
        assert np.all((reg % 7 == 0) == cap)
        assert np.all((reg < 7) == (lat_c > 0))
        sector = reg % 7 - 1
        band = ~cap
        assert np.all((lon_c[band] >= sector[band] * 60) & (lon_c[band] < sector[band] * 60 + 60))
        hem = g.hemisphere_of_region(reg)
        assert np.all(hem == (lat_c < 0))
    assert region_name(0) == "N-cap" and region_name(9) == "S-060-120"


def test_bad_tile_size_names_key_and_allowed_values() -> None:
    with pytest.raises(ConfigError, match="tiling.tile_size_deg.*divide 60"):
        TileGrid(7.0)


def _pose(lat: float, lon: float, alt: float = 300e3, dlat: float = 0.0, dlon: float = 0.0):
    c = latlon_to_xyz(lat + dlat, lon + dlon, alt, datum_radius_m=DATUM_RADIUS_M)
    return c, look_at_rotation(c, latlon_to_xyz(lat, lon, height_m=0.0, datum_radius_m=DATUM_RADIUS_M))


def test_footprint_contains_centre_and_is_counter_clockwise_sized() -> None:
    cam = mdis_wac(512)
    c, r = _pose(10.0, 20.0, 400e3)
    f = image_footprint(cam, c, r, 8, radius_m=DATUM_RADIUS_M)
    assert f.shape == (32, 3)
    lat, lon = footprint_latlon(f)
    # nadir WAC at 400 km: half-width = 400 km * tan(FOV/2), FOV = 512 * 2 * 14 um / 78.25 mm
    half_km = 400.0 * np.tan(512 * 0.028 / 78.25 / 2)
    half_deg = np.degrees(half_km / 2439.4)
    assert np.abs(lat - 10.0).max() == pytest.approx(half_deg, rel=0.02)
    area = footprint_area_m2(f[None], radius_m=DATUM_RADIUS_M)[0]
    assert area == pytest.approx((2 * half_km * 1e3) ** 2, rel=0.03)
    batched = image_footprints(cam, c[None], r[None], 8, radius_m=DATUM_RADIUS_M)[0]
    assert np.allclose(batched, f)


def _graph(poses, cam):
    c = np.stack([p[0] for p in poses])
    r = np.stack([p[1] for p in poses])
    return overlap_graph([cam], np.zeros(len(poses), int), c, r, radius_m=DATUM_RADIUS_M)


def test_overlap_across_the_seam() -> None:
    cam = mdis_wac(256)
    g = _graph([_pose(0.0, 359.5), _pose(0.0, 0.5), _pose(0.0, 180.0)], cam)
    assert list(zip(g.i.tolist(), g.j.tolist())) == [(0, 1)]
    # nadir WAC (10.5 deg FOV) at 300 km sees 1.30 deg; centres 1 deg apart overlap by 1 - 1/1.30
    width_deg = 2 * np.degrees(300.0 * np.tan(256 * 0.056 / 78.25 / 2) / 2439.4)
    assert g.fraction[0] == pytest.approx(1.0 - 1.0 / width_deg, abs=0.07)


def test_overlap_at_the_pole_finds_every_neighbour() -> None:
    cam = mdis_wac(256)
    poses = [_pose(90.0, 0.0)] + [_pose(89.0, lon) for lon in (0.0, 90.0, 180.0, 270.0)] + [_pose(80.0, 0.0)]
    g = _graph(poses, cam)
    pole = set(g.neighbours(0).tolist())
    assert pole == {1, 2, 3, 4}  # every image around the pole, none 10 deg away
    assert 5 not in set(g.i.tolist()) | set(g.j.tolist())


def test_disjoint_and_identical_images() -> None:
    cam = mdis_nac(256)
    g = _graph([_pose(0.0, 0.0), _pose(0.0, 0.0), _pose(30.0, 30.0)], cam)
    assert list(zip(g.i.tolist(), g.j.tolist())) == [(0, 1)]
    assert g.fraction[0] == pytest.approx(1.0)


def test_overlap_fraction_scales_with_offset() -> None:
    """Two nadir images offset by a known share of their width overlap by 1 - share."""
    cam = mdis_wac(256)
    half_deg = np.degrees(300.0 * np.tan(256 * 0.056 / 78.25 / 2) / 2439.4)
    for share in (0.25, 0.5, 0.75):
        g = _graph([_pose(0.0, 100.0), _pose(0.0, 100.0 + share * 2 * half_deg)], cam)
        assert g.fraction[0] == pytest.approx(1.0 - share, abs=0.08)
