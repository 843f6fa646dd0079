"""The dense cloud's registration (issue 31): points moved by ``register_points`` lie on the map ``register_dem``
moved by the same tile transforms and mean level, so the dense DEM lands in the registered DEM's frame.
"""

from __future__ import annotations

import numpy as np

from mercury_dem.altimetry.merge import blended_scalar, register_dem, register_points, transform_table
from mercury_dem.altimetry.register import TileTransform
from mercury_dem.geometry.body import latlon_to_xyz
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.reference.sampling import sample_grid
from tests.altimetry.synthetic import R_DATUM, Surface

TILES = TileGrid(10.0)


def test_points_moved_lie_on_the_map_moved_by_the_same_transform() -> None:
    """Two tiles (one shifted 1.5 km / 0.8 km / 250 m, one lifted) and a mean level: the moved points sit on the
    moved map.
    """
    rng = np.random.default_rng(5)
    surf = Surface(rng)
    lat = np.arange(41.0, 28.99, -0.02)
    lon = np.arange(99.0, 111.01, 0.02)
    dem = surf.height(*np.meshgrid(lat, lon, indexing="ij"))
    # two tiles: a shift of 1.5 km east, 0.8 km north, 250 m up, and a neighbour only lifted; a mean level on top
    ts = [TileTransform(int(TILES.tile_of(35.0, 105.0)), 35.0, 105.0, R_DATUM, model="translation",
                        translation_enu_m=(1500.0, -800.0, 250.0), ok=True),
          TileTransform(int(TILES.tile_of(35.0, 115.0)), 35.0, 115.0, R_DATUM, model="translation",
                        translation_enu_m=(0.0, 0.0, -120.0), ok=True)]
    table, _ = transform_table(ts, TILES)
    level = np.zeros(TILES.n_tiles)
    level[int(TILES.tile_of(35.0, 105.0))] = 30.0
    reg = register_dem(dem, lat, lon, R_DATUM, ts, TILES)
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    reg = reg + blended_scalar(level, TILES, LA.ravel(), LO.ravel()).reshape(reg.shape)  # as the stage levels
    # points on the unregistered surface (a dense cloud without noise), inside the map
    pla = rng.uniform(31.0, 39.0, 5000)
    plo = rng.uniform(101.0, 109.0, 5000)
    ph = sample_grid(dem, lat, lon, pla, plo)  # exactly on the map as gridded
    xyz = latlon_to_xyz(pla, plo, height_m=ph, datum_radius_m=R_DATUM)
    qla, qlo, qh = register_points(xyz, pla, plo, R_DATUM, table, TILES, level)
    on_map = sample_grid(reg, lat, lon, qla, qlo)
    d = qh - on_map
    moved = qh - ph
    print(f"moved median {np.nanmedian(np.abs(moved)):.0f} m; against the map: mean {np.nanmean(d):.2f} m, rms "
          f"{np.sqrt(np.nanmean(d * d)):.2f} m")
    assert np.nanmedian(np.abs(moved)) > 100.0  # the transform does move them (250 m up, the shift over slopes)
    # agree to the map's bilinear resampling (2 km grid, ~1 km relief of >= 25 km waves): measured mean 0.00 m,
    # RMS 0.17 m
    assert abs(float(np.nanmean(d))) < 0.5, np.nanmean(d)
    assert float(np.sqrt(np.nanmean(d * d))) < 2.0


def test_no_level_and_identity_table_leave_the_points() -> None:
    """No tile registered and no level: the points stay where they are."""
    lat = np.array([10.0, -20.0])
    lon = np.array([30.0, 200.0])
    h = np.array([100.0, -2000.0])
    xyz = latlon_to_xyz(lat, lon, height_m=h, datum_radius_m=R_DATUM)
    qla, qlo, qh = register_points(xyz, lat, lon, R_DATUM, np.zeros((TILES.n_tiles, 12)), TILES)
    np.testing.assert_allclose(qh, h, atol=1e-6)
    np.testing.assert_allclose(qla, lat, atol=1e-9)
    np.testing.assert_allclose(np.mod(qlo, 360.0), np.mod(lon, 360.0), atol=1e-9)


def test_level_on_shots_removes_the_mean_bias_of_a_skewed_map() -> None:
    """A map whose error is skewed (crater floors missed: a positive tail) and median-aligned has a mean bias;
    levelled on shots of the truth (5 m noise, 4000 in the tile), the mean error where the map has values is
    within a few times the noise's standard error plus the skewed error's (its mean over 4000 shots).
    """
    from mercury_dem.altimetry.merge import level_on_shots

    rng = np.random.default_rng(17)
    lat = np.arange(39.95, 30.0, -0.1)
    lon = np.arange(100.05, 110.0, 0.1)
    truth = np.zeros((lat.size, lon.size))
    err = rng.exponential(150.0, truth.shape)
    err -= np.median(err)  # median-aligned, mean +150 x (1 - ln 2) = +46 m
    dem = truth + err
    dem[:10] = np.nan  # no values in the north: shots there are left out
    slat, slon = rng.uniform(30.5, 39.5, 4000), rng.uniform(100.5, 109.5, 4000)
    levelled, offset, own, n = level_on_shots(dem, lat, lon, slat, slon, rng.normal(0.0, 5.0, 4000), TILES)
    before, after = float(np.nanmean(dem - truth)), float(np.nanmean(levelled - truth))
    print(f"mean error before {before:+.1f} m, after {after:+.1f} m; {n.sum()} shots, offset {offset[own]}")
    assert before > 35.0
    # the offset is measured at the shots (bilinear: it averages 4 posts of the skewed error), so it estimates the
    # map's mean error to about its std / sqrt(shots) ~ 150 / 2 / sqrt(3500) ~ 1.3 m, plus the 5 m noise / 60
    assert abs(after) < 5.0
    assert own.sum() == 1 and 3000 < n.sum() < 4000
    assert np.array_equal(np.isnan(levelled), np.isnan(dem))
