"""The whole-map registration and merge, block by block (mercury_dem.altimetry.register_map), on numpy arrays."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mercury_dem.altimetry.merge import MergedDem, MergeOptions
from mercury_dem.altimetry.register import ProfileOffsets, TileTransform
from mercury_dem.altimetry.register_map import (
    ShotPositions,
    corrected_shots,
    level_allowed_tiles,
    register_and_merge_blockwise,
    row_blocks,
    row_of,
    rows_per_block,
    transform_margin_rows,
)
from mercury_dem.geometry.body import latlon_to_unit, xyz_to_latlon
from mercury_dem.geometry.tiling import TileGrid

R = 2_439_400.0
LAT = np.linspace(13.95, 10.05, 40)  # 0.1° rows, north first (the DEM's order), inside one 10° tile
LON = np.linspace(10.05, 13.95, 40)


def _truth(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    return 800.0 * np.sin(np.radians(lat) * 90.0) * np.cos(np.radians(lon) * 70.0)


def _case(seed: int, bias_m: float, noise_m: float):
    """A DEM = truth + bias, and shots on the truth (+ noise) over it."""
    rng = np.random.default_rng(seed)
    dem = _truth(*np.meshgrid(LAT, LON, indexing="ij")) + bias_m
    slat, slon = rng.uniform(10.2, 13.8, 6000), rng.uniform(10.2, 13.8, 6000)
    shots = ShotPositions(slat, slon, R + _truth(slat, slon) + rng.normal(0.0, noise_m, slat.size))
    return dem, shots


def _run(dem: np.ndarray, shots: ShotPositions, block_rows: int, level: bool):
    tiles = TileGrid(10.0)
    written: dict[str, np.ndarray] = {"registered": np.full(dem.shape, np.nan), "merged": np.full(dem.shape, np.nan),
                                      "count": np.zeros(dem.shape, np.int32)}

    def write(r0: int, r1: int, registered: np.ndarray, merged: MergedDem) -> None:
        written["registered"][r0:r1] = registered
        written["merged"][r0:r1] = merged.height
        written["count"][r0:r1] = merged.shot_count

    maps = register_and_merge_blockwise(
        lambda i0, i1: dem[i0:i1].copy(), LAT, LON, R, [], tiles, shots, scratch=np.full(dem.shape, np.nan),
        write=write, block_rows=block_rows, merge_options=MergeOptions(),
        level_allowed=np.ones(tiles.n_tiles, bool) if level else None, surface_height_m=50_000.0,
        level_min_shots=500, level_clip_nmad=10.0)
    return maps, written


def test_the_mean_level_recovers_a_dem_bias():
    """A DEM 120 m above the truth, shots on the truth with 5 m noise: levelled on the shots' mean, the registered
    map is the truth within a few noise means (6000 shots: the mean's error ~0.07 m), and the offset is -120 m."""
    dem, shots = _case(31, bias_m=120.0, noise_m=5.0)
    maps, out = _run(dem, shots, block_rows=9, level=True)
    assert maps.level is not None and maps.level.own.sum() == 1
    assert maps.level.offset_m[maps.level.own][0] == pytest.approx(-120.0, abs=0.5)
    truth = _truth(*np.meshgrid(LAT, LON, indexing="ij"))
    assert np.nanmax(np.abs(out["registered"] - truth)) < 0.5
    assert np.nanmedian(np.abs(maps.samples["as_given"] - (shots.radius_m - R))) > 100.0  # the bias was there
    # the merge: dense pixels (>= 2 shots) follow the shots, so the merged map is the truth within the noise
    dense = out["count"] >= 2
    assert dense.sum() > 500 and maps.n_dense_pixels == int(dense.sum())
    assert np.nanmedian(np.abs(out["merged"] - truth)[dense]) < 5.0


def test_without_level_the_registered_map_is_the_dem():
    """No transform and no mean level: the registered map is the DEM, exactly."""
    dem, shots = _case(32, bias_m=120.0, noise_m=5.0)
    maps, out = _run(dem, shots, block_rows=40, level=False)
    assert maps.level is None
    np.testing.assert_array_equal(out["registered"], dem)


@pytest.mark.parametrize("block_rows", [1, 5, 13])
def test_blocks_equal_the_whole_map(block_rows):
    """Any block height (down to one row, far less than the merge's margin) gives the whole-map arrays (the same
    pixels valued, the shot counts exactly; heights to rounding: a block's sums run over other neighbours)."""
    dem, shots = _case(33, bias_m=-40.0, noise_m=3.0)
    whole_maps, whole = _run(dem, shots, block_rows=40, level=True)
    maps, out = _run(dem, shots, block_rows=block_rows, level=True)
    np.testing.assert_array_equal(out["count"], whole["count"])
    for k in ("registered", "merged"):
        np.testing.assert_allclose(out[k], whole[k], rtol=0, atol=1e-9)
    for k, v in whole_maps.samples.items():
        np.testing.assert_allclose(maps.samples[k], v, rtol=0, atol=1e-9)


def test_corrected_shots_apply_the_fitted_profile_offsets():
    """A profile offset of +30 m up moves its shots 30 m out; an unfitted profile's shots stay."""
    lat, lon = np.array([12.0, 12.5, 11.0]), np.array([11.0, 11.5, 12.0])
    rad = np.full(3, R + 100.0)
    shots = pd.DataFrame({"lat": lat, "lon": lon, "radius_m": rad, "profile_id": [1, 1, 2], "tile_id": [0, 0, 0]})
    prof = ProfileOffsets(np.array([1, 2]), np.array([0, 0]), np.array([[0.0, 0.0, 30.0], [0.0, 0.0, 500.0]]),
                          np.ones((2, 3)), np.array([12.25, 11.0]), np.array([11.25, 12.0]), np.array([2, 1]),
                          np.array([2, 1]), np.ones(2), np.ones(2), np.array([True, False]))
    out = corrected_shots(shots, prof, R)
    # "up" is the profile centre's: at 0.35° from it the radius grows by 30 cos(0.35°) and the shot slides ~0.18 m
    assert out.radius_m[:2] == pytest.approx(R + 100.0 + 30.0, abs=0.01)
    assert out.radius_m[2] == pytest.approx(R + 100.0, abs=1e-6) and out.lat[2] == pytest.approx(11.0, abs=1e-9)
    x = latlon_to_unit(lat, lon) * rad[:, None]
    assert xyz_to_latlon(x, R)[0] == pytest.approx(lat)


def test_only_tiles_with_a_transform_level_themselves():
    tr = [TileTransform(3, 0, 0, R, ok=True), TileTransform(5, 0, 0, R, ok=False), TileTransform(7, 0, 0, R, ok=True)]
    assert np.flatnonzero(level_allowed_tiles(tr, 10)).tolist() == [3, 7]


def test_rows_and_margins():
    assert row_blocks(10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert row_of(np.array([13.95, 13.84, 10.0, 99.0, np.nan]), LAT).tolist() == [0, 1, 39, 0, 0]
    assert rows_per_block(1000, 100, 4e3, 16) == 40 and rows_per_block(1000, 1000, 4e3, 16) == 16
    assert rows_per_block(10, 100, 4e6, 16) == 16  # a short map: one block
    # a pure 2 km translation: 2 km on the datum is deg(2000/R) ≈ 0.047°, under one 0.1° row, + 2 rows
    t = TileTransform(0, 12.0, 12.0, R, translation_enu_m=(2000.0, 0.0, 0.0), ok=True)
    assert transform_margin_rows([t], R, LAT, 50_000.0) == math.ceil(math.degrees(2000.0 / R) / 0.1) + 2 == 3
    assert transform_margin_rows([], R, LAT, 50_000.0) == 2
