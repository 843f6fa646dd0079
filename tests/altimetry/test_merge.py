"""The registered DEM recovers the truth; the blend across tiles and the merge have no steps."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.altimetry.merge import MergeOptions, merge_dem, register_dem
from mercury_dem.altimetry.register import TileTransform, register_tile
from mercury_dem.geometry.tiling import TileGrid
from tests.altimetry.synthetic import R_DATUM, Rigid, Surface, moved_dem, profiles

TILES = TileGrid(10.0)


def test_registered_dem_recovers_truth():
    rng = np.random.default_rng(11)
    surf = Surface(rng)
    lat = np.arange(41.0, 28.99, -0.05)
    lon = np.arange(99.0, 111.01, 0.05)
    D = Rigid((35.0, 105.0), np.array([1500.0, -800.0, 250.0]), angle_up_deg=0.01)
    dem = moved_dem(surf, D, lat, lon)
    prof = profiles(surf, rng, (30.0, 40.0, 100.0, 110.0), n_profiles=120, spacing_deg=0.03, sigma_h_m=0.0,
                    sigma_v_m=0.0)
    from mercury_dem.altimetry.register import DemWindow

    tid = int(TILES.tile_of(35.0, 105.0))
    res = register_tile(DemWindow(dem, lat, lon, R_DATUM), prof.lat, prof.lon, prof.radius, prof.profile_id,
                        tile_id=tid, centre=(35.0, 105.0))
    assert res.transform.ok
    reg = register_dem(dem, lat, lon, R_DATUM, [res.transform], TILES)
    truth = surf.height(*np.meshgrid(lat, lon, indexing="ij"))
    core = np.ix_((lat > 30.5) & (lat < 39.5), (lon > 100.5) & (lon < 109.5))
    before = np.sqrt(np.nanmean((dem - truth)[core] ** 2))
    after = np.sqrt(np.nanmean((reg - truth)[core] ** 2))
    assert before > 200.0
    assert after < 15.0, after  # bilinear resampling of a 2 km grid of ~1 km relief, twice


def test_blend_has_no_step_at_tile_borders():
    """Flat DEM, neighbouring tiles moved 300 m apart vertically and 1 km horizontally: a ramp, not a step."""
    lat = np.arange(29.95, 10.0, -0.1)
    lon = np.arange(0.05, 40.0, 0.1)
    h = np.zeros((lat.size, lon.size))
    ts = []
    for k, (la, lo) in enumerate([(15, 5), (15, 15), (15, 25), (15, 35), (25, 5), (25, 15), (25, 25), (25, 35)]):
        up = 300.0 if lo == 15 else 0.0
        ts.append(TileTransform(int(TILES.tile_of(la, lo)), float(la), float(lo), R_DATUM, model="translation",
                                translation_enu_m=(1000.0 * (k % 2), 0.0, up), ok=True))
    reg = register_dem(h, lat, lon, R_DATUM, ts, TILES)
    step_px = np.nanmax(np.abs(np.diff(reg, axis=1)))
    # 300 m over 10 deg = 100 pixels is 3 m per pixel, plus the radial part of a 1 km tangent-plane shift
    # on the sphere (~1 km x sin(10 deg) over 100 pixels); a step would be 300 m
    assert step_px < 10.0
    at_centre = reg[np.argmin(np.abs(lat - 15.05)), np.argmin(np.abs(lon - 15.05))]
    assert abs(at_centre - 300.0) < 5.0  # the tile's own transform at its centre
    assert np.isfinite(reg).all()


def test_merge_uses_altimetry_where_dense_and_has_no_step():
    lat = np.arange(9.975, -10.0, -0.05)
    lon = np.arange(0.025, 20.0, 0.05)
    reg = np.zeros((lat.size, lon.size))
    rng = np.random.default_rng(2)
    # dense altimetry in a block 4-8 N, 5-12 E, 25 m above the DEM; a few lone shots elsewhere
    sl = rng.uniform(4.0, 8.0, 60000)
    so = rng.uniform(5.0, 12.0, 60000)
    sl = np.r_[sl, rng.uniform(-9, -5, 50)]
    so = np.r_[so, rng.uniform(14, 19, 50)]
    sr = R_DATUM + 25.0 + rng.normal(0, 0.3, sl.size)
    m = merge_dem(reg, lat, lon, R_DATUM, sl, so, sr, MergeOptions(min_shots_per_pixel=3, feather_px=8))
    inner = np.ix_((lat > 5) & (lat < 7), (lon > 6.5) & (lon < 10.5))
    assert np.all(np.abs(m.height[inner] - 25.0) < 5 * 0.3 / np.sqrt(3)) and np.all(m.altimetry_weight[inner] == 1)
    assert np.all(m.height[lat < 0] == 0.0)  # lone shots do not make an altimetry area
    jump = max(np.max(np.abs(np.diff(m.height, axis=0))), np.max(np.abs(np.diff(m.height, axis=1))))
    assert jump < 25.0 / 8 * 1.6  # feathered over 8 pixels; a seam would jump 25 m


def test_merge_without_shots_is_the_registered_dem():
    reg = np.ones((10, 12))
    m = merge_dem(reg, np.linspace(1, 0, 10), np.linspace(0, 1.1, 12), R_DATUM, [], [], [])
    assert np.array_equal(m.height, reg) and m.n_dense_pixels == 0
    with pytest.raises(ValueError):
        MergeOptions(feather_px=0)


def test_mean_level_removes_a_skewed_error_mean_that_a_median_fit_leaves():
    """A DEM whose error is skewed (it misses crater bottoms: positive tail) and median-aligned has a positive
    mean bias; levelling on the shots' mean per tile brings the mean error to ~0, continuously, and tiles
    without shots take the nearest tile's offset."""
    from mercury_dem.altimetry.merge import mean_level

    rng = np.random.default_rng(23)
    lat = np.arange(29.95, -30.0, -0.1)
    lon = np.arange(0.05, 40.0, 0.1)
    truth = 300.0 * np.sin(np.radians(lat))[:, None] * np.cos(np.radians(3 * lon))[None, :]
    skew = rng.exponential(120.0, truth.shape)  # mean 120, median 83: mean − median ≈ 37 m
    dem = truth + skew - np.median(skew)  # median error 0, mean error ≈ +37 m
    # Shots on the truth (1 m noise), everywhere but the southernmost 10° rows.
    n = 200_000
    slat, slon = rng.uniform(-20.0, 30.0, n), rng.uniform(0.0, 40.0, n)
    tr = 300.0 * np.sin(np.radians(slat)) * np.cos(np.radians(3 * slon))
    srad = R_DATUM + tr + rng.normal(0.0, 1.0, n)
    lev = mean_level(dem, lat, lon, R_DATUM, slat, slon, srad, TileGrid(10.0), min_shots=500)
    before = float(np.mean(dem - truth))
    after = float(np.mean(lev.height - truth))
    assert before == pytest.approx(37.0, abs=5.0)
    # each tile's mean over ~5000 shots of a 120 m-scale error: a few metres
    assert abs(after) < 5.0
    assert lev.own.sum() == 4 * 5 and lev.shots[lev.own].min() >= 500
    south = lat < -20.0
    assert abs(float(np.mean((lev.height - truth)[south]))) < 8.0  # the nearest tiles' offsets
    step = np.abs(np.diff(lev.height - dem, axis=1)).max()
    assert step < 2.0  # tent-blended: no step at tile borders (offsets differ by a few metres)
    # A tile not allowed its own offset (its transform undetermined) takes its nearest allowed neighbour's.
    allowed = np.ones(TileGrid(10.0).n_tiles, bool)
    first = int(np.flatnonzero(lev.own)[0])
    allowed[first] = False
    part = mean_level(dem, lat, lon, R_DATUM, slat, slon, srad, TileGrid(10.0), allowed=allowed)
    assert not part.own[first] and part.own.sum() == lev.own.sum() - 1
    # No shot on the DEM: nothing changes.
    none = mean_level(dem, lat, lon, R_DATUM, slat + 100.0, slon, srad)
    assert np.array_equal(none.height, dem) and not none.own.any()
