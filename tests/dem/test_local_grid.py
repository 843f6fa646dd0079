"""The grid of a block covers the block (issue 30 item 5): canvas, no-value distance, --bounds, wrap, accuracy.

The block is the user's case scaled down: altimeter shots along near-polar tracks over
0.8 deg x 0.75 deg of the Moon near 25 N, 3 E (mercury_dem.synth.altimeter_block), ~490 m between
tracks, gridded at 256 pixel/deg (118 m pixels).
"""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.cli import main
from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.extent import box_area_ratio, points_box
from mercury_dem.dem.grid import build_point_index, config_with_no_value_distance, typical_gap_m
from mercury_dem.geometry.body import MOON
from mercury_dem.pipeline.dem_stage import grid_dem, open_dem
from mercury_dem.synth.altimeter_block import BlockSurface, altimeter_block

R = MOON.datum_radius_m
LAT = (24.6, 25.35)
LON = (2.6, 3.4)
N_PROFILES = 45
PPD = 256.0
NOISE_M = 5.0
#: A gentle surface: across-track interpolation (up to 250 m, slopes < 0.6 %) stays below the noise.
GENTLE = BlockSurface(25.0, 3.0, R, slope=0.002, wave_m=4.0, n_craters=0)


def _block(lon=LON, drop=(), spacing_jitter=0.0, n_shots=20_000, surface=GENTLE, seed=3, tilt_deg=1.5):
    lat0 = 0.5 * (LAT[0] + LAT[1])
    surf = BlockSurface(lat0, 0.5 * (lon[0] + lon[1]), R, slope=surface.slope, wave_m=surface.wave_m,
                        n_craters=surface.n_craters)
    b = altimeter_block(np.random.default_rng(seed), R, surf, lat_range=LAT, lon_range=lon, n_profiles=N_PROFILES,
                        n_shots=n_shots, noise_m=NOISE_M, spacing_jitter=spacing_jitter, drop_profiles=drop,
                        tilt_deg=tilt_deg)
    return b, surf


def _track_spacing_m(lon=LON):
    return (lon[1] - lon[0]) / N_PROFILES * np.pi / 180 * R * np.cos(np.radians(np.mean(LAT)))


def _grid(tmp_path, pts, **cfg):
    summary = grid_dem(pts, DemConfig(pixels_per_degree=PPD, **cfg), tmp_path / "dem.zarr", coverage=False, body=MOON)
    return summary, open_dem(tmp_path / "dem.zarr")


def _error(ds, surf):
    la, lo = np.meshgrid(ds.lat.values, ds.lon.values, indexing="ij")
    return ds["elevation"].values - surf(la, lo)


def test_typical_gap_of_tracks_is_a_quarter_of_their_spacing() -> None:
    b, _ = _block()
    g = typical_gap_m(build_point_index(b.xyz, R), DemConfig(pixels_per_degree=PPD))
    assert g == pytest.approx(_track_spacing_m() / 4, rel=0.15)
    # the rule: 5 x the typical gap, never below a pixel (here the pixel is coarser than the gap)
    coarse = config_with_no_value_distance(DemConfig(pixels_per_degree=8.0), build_point_index(b.xyz, R))
    assert coarse.max_distance_m == pytest.approx(2 * np.pi * R / 360 / 8.0)
    fixed = DemConfig(pixels_per_degree=PPD, max_distance_m=1234.0)
    assert config_with_no_value_distance(fixed, build_point_index(b.xyz, R)) is fixed


def test_grid_of_a_block_covers_the_block_and_recovers_its_surface(tmp_path) -> None:
    b, surf = _block(spacing_jitter=0.3)
    summary, ds = _grid(tmp_path, b.xyz)
    bounds = summary["grid_bounds_deg"]
    assert box_area_ratio(tuple(bounds), points_box(b.xyz)) < 1.2
    idx = np.array([bounds[0] + 90, bounds[1] + 90, bounds[2], bounds[3]]) * PPD
    assert np.allclose(idx, np.round(idx))  # snapped to the pixel grid
    assert summary["no_value_fraction"] < 0.02  # only the canvas's rim beyond the outermost tracks
    err = _error(ds, surf)
    # median of ~11 shots of noise sigma then a 3 x 3 mean: well under the noise; nowhere several sigma off
    assert float(np.sqrt(np.nanmean(err**2))) < 0.5 * NOISE_M
    assert float(np.nanmax(np.abs(err))) < 3 * NOISE_M


def test_the_no_value_mask_follows_the_track_spacing(tmp_path) -> None:
    # one missing track (a gap of 2 spacings: narrower than the rule's 2.5) and three missing (4: wider)
    b, _ = _block(drop=(10, 30, 31, 32), tilt_deg=0.0)  # meridian tracks: a gap's middle is one column
    summary, ds = _grid(tmp_path, b.xyz)
    s = _track_spacing_m()
    assert summary["no_value_distance_m"] == pytest.approx(5 * s / 4, rel=0.2)
    elev = ds["elevation"].values
    rows = slice(8, elev.shape[0] - 8)  # away from the block's northern and southern ends
    lon = ds.lon.values
    t = np.sort(b.profile_lon)

    def middle_column(west, east):
        return int(np.argmin(np.abs(lon - 0.5 * (west + east))))

    narrow = middle_column(t[9], t[10])  # track 10 of the 45 dropped: kept tracks 9 and 10 are 2 spacings apart
    wide = middle_column(t[28], t[29])  # tracks 30-32 dropped: kept 28 and 29 are 4 spacings apart
    assert (t[10] - t[9]) == pytest.approx(2 * (t[1] - t[0]), rel=0.05)
    assert (t[29] - t[28]) == pytest.approx(4 * (t[1] - t[0]), rel=0.05)
    assert np.isfinite(elev[rows, narrow]).all()
    assert np.isnan(elev[rows, wide]).all()
    ordinary = [middle_column(t[i], t[i + 1]) for i in range(20, 27)]
    assert np.isfinite(elev[rows][:, ordinary]).all()
    # configurable: a fixed distance fills the wide gap too
    _, ds_fixed = _grid(tmp_path / "fixed", b.xyz, max_distance_m=2 * s + 1)
    assert np.isfinite(ds_fixed["elevation"].values[rows, wide]).all()


@pytest.mark.parametrize("lon", [(-0.4, 0.4), (179.6, 180.4)])
def test_a_block_across_0_or_180_degrees_is_gridded_as_one_block(tmp_path, lon) -> None:
    b, surf = _block(lon=lon, spacing_jitter=0.3, seed=5)
    summary, ds = _grid(tmp_path, b.xyz)
    lat_min, lat_max, lon_min, lon_max = summary["grid_bounds_deg"]
    assert lon_max - lon_min < 0.85 and box_area_ratio((lat_min, lat_max, lon_min, lon_max), points_box(b.xyz)) < 1.2
    if lon[0] < 0:
        assert lon_min < 0 < lon_max
    else:
        assert lon_min < 180 < lon_max
    # the meridian inside the block is gridded like any other column
    seam = int(np.argmin(np.abs(np.mod(ds.lon.values - lon[0], 360.0) - 0.4)))
    assert np.isfinite(ds["elevation"].values[8:-8, seam]).all()
    err = _error(ds, surf)
    assert float(np.sqrt(np.nanmean(err**2))) < 0.5 * NOISE_M


def test_grid_bounds_override_the_canvas(tmp_path, capsys) -> None:
    b, _ = _block(n_shots=5000)
    np.save(tmp_path / "pts.npy", b.xyz)
    assert main(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path / "a"), "--ppd", "64", "--no-coverage",
                 "--body", "moon", "--bounds", "2", "4", "24", "26"]) == 0
    out = capsys.readouterr().out
    assert "map lat 24..26, lon 2..4" in out and "from every point" in out
    ds = open_dem(tmp_path / "a" / "dem.zarr")
    assert ds["elevation"].shape == (128, 128)
    assert ds.lat.values[0] == 26 - 0.5 / 64 and ds.lon.values[0] == 2 + 0.5 / 64
    elev = ds["elevation"].values
    assert np.isnan(elev[:, :20]).all() and np.isfinite(elev[70, 45:85]).all()  # far west of the data: no value
    # without --bounds: the block's own canvas
    assert main(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path / "b"), "--ppd", "64", "--no-coverage",
                 "--body", "moon"]) == 0
    assert open_dem(tmp_path / "b" / "dem.zarr")["elevation"].shape == (51, 54)
    # a box that is not one: a named error, not a traceback
    assert main(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path / "c"), "--body", "moon",
                 "--bounds", "4", "2", "24", "26"]) == 2
    assert "--bounds" in capsys.readouterr().err
