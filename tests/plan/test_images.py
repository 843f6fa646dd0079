"""The plan of a run's images (:func:`mercury_dem.plan.images.plan_images`): tiles, regions, exclusions, pairs."""

from __future__ import annotations

import numpy as np

from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.camera import mdis_nac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.plan.images import plan_images


def _nadir(lat: float, lon: float, alt_m: float = 500e3) -> tuple[np.ndarray, np.ndarray]:
    la, lo = np.radians(lat), np.radians(lon)
    u = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    c = u * (DATUM_RADIUS_M + alt_m)
    return c, look_at_rotation(c, u * DATUM_RADIUS_M)


def test_images_are_tiled_by_their_centres_and_overlapping_usable_ones_paired() -> None:
    """Tiles and regions by centre; a missing centre excluded with its reason; only usable overlapping images paired."""
    lat = np.array([1.0, 1.05, 40.0, np.nan, 1.02])
    lon = np.array([2.0, 2.05, 100.0, 3.0, 2.01])
    ids = np.array(["a", "b", "c", "no_centre", "bad_pose"])
    poses = [_nadir(la if np.isfinite(la) else 0.0, lo) for la, lo in zip(lat, lon)]
    excluded = np.array(["", "", "", "", "image bad_pose: rotation is not orthonormal"], dtype=object)
    before = excluded.copy()
    plan = plan_images(ids, lat, lon, [mdis_nac(256)], np.zeros(5, np.int64), np.array([p[0] for p in poses]),
                       np.array([p[1] for p in poses]), excluded, tile_size_deg=10.0, min_overlap_fraction=0.05,
                       datum_radius_m=DATUM_RADIUS_M)
    grid = TileGrid(10.0)
    ok = np.array([True, True, True, False, False])
    assert np.array_equal(plan.ok, ok)
    assert np.array_equal(plan.tile[ok], grid.tile_of(lat[ok], lon[ok])) and np.all(plan.tile[~ok] == -1)
    assert np.array_equal(plan.region[ok], grid.region_of_tile(plan.tile[ok])) and np.all(plan.region[~ok] == -1)
    assert plan.excluded[3] == "image no_centre: centre latitude/longitude missing; fix the catalog"
    assert plan.excluded[4] == before[4] and np.array_equal(excluded, before)  # input not modified
    # a and b are 0.07 deg apart (their NAC footprints overlap); c is far; the excluded take no part
    assert list(zip(plan.i.tolist(), plan.j.tolist())) == [(0, 1)] and plan.fraction[0] > 0.05
    assert plan.non_empty_tiles() == sorted(set(grid.tile_of(lat[ok], lon[ok]).tolist()))
    assert (plan.tile_size_deg, plan.tiles_total) == (10.0, grid.n_tiles)
