"""Statistics (reference Table 1), accuracy against truth and the CLI, on analytic cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mercury_dem.cli import main
from mercury_dem.dem.accuracy import dem_accuracy
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.products.sampling import sample_bilinear
from mercury_dem.products.stats import block_mean, dem_statistics, slope_deg


def _global(ppd):
    lat = 90 - (np.arange(int(180 * ppd)) + 0.5) / ppd
    lon = (np.arange(int(360 * ppd)) + 0.5) / ppd
    return lat, lon


def test_area_weighted_statistics_of_latitude_field():
    lat, lon = _global(2)
    h = np.repeat(lat[:, None], lon.size, axis=1).astype(np.float32) * 10.0  # 10 m per degree
    s = dem_statistics(h, lat, lon, pixel_km=1.0, radius_m=DATUM_RADIUS_M)
    assert s["resample"]["factor"] == 1
    assert s["global"]["mean_m"] == pytest.approx(0.0, abs=1e-3)
    assert s["global"]["median_m"] == pytest.approx(0.0, abs=3.0)
    # Area-weighted mean latitude of the cap 65..90: int(lat cos) / int(cos).
    a, b = math.radians(65), math.radians(90)
    mean_cap = math.degrees(((b * math.sin(b) + math.cos(b)) - (a * math.sin(a) + math.cos(a)))
                            / (math.sin(b) - math.sin(a)))
    assert s["north_polar"]["mean_m"] == pytest.approx(10 * mean_cap, rel=2e-3)
    assert s["south_polar"]["min_m"] == pytest.approx(10 * -87.75, abs=1e-3)  # stops at 88 S
    assert s["equatorial"]["max_m"] == pytest.approx(10 * 64.75, abs=1e-3)
    # Uniform north-south gradient: slope = atan(10 m / km per degree) everywhere (away from the poles).
    expect = math.degrees(math.atan(10.0 / (DATUM_RADIUS_M * math.radians(1.0))))
    assert s["equatorial"]["slope_mean_deg"] == pytest.approx(expect, rel=1e-6)
    assert s["equatorial"]["slope_std_deg"] == pytest.approx(0.0, abs=1e-9)


def test_slope_of_east_west_ramp_uses_true_spacing():
    lat, lon = np.array([30.5, 30.0, 29.5]), np.arange(0.25, 10, 0.5)
    km_per_deg_lon = DATUM_RADIUS_M * math.radians(1.0) * np.cos(np.radians(30.0))
    h = np.tile(lon * 0.01 * km_per_deg_lon, (3, 1))  # 1 % grade along the parallel at 30 deg
    s = slope_deg(h, lat, 0.5, 0.5, wrap_lon=False, radius_m=DATUM_RADIUS_M)
    assert s[1, 5] == pytest.approx(math.degrees(math.atan(0.01)), rel=2e-3)
    assert np.isnan(s[0]).all() and np.isnan(s[:, 0]).all()


def test_block_mean_is_nan_aware():
    a = np.array([[1.0, np.nan, 3.0], [3.0, 5.0, np.nan]])
    out = block_mean(a, 2)
    np.testing.assert_allclose(out, [[3.0, 3.0]])
    assert np.isnan(block_mean(np.full((2, 2), np.nan), 2)).all()


def test_accuracy_recovers_injected_bias_and_noise():
    rng = np.random.default_rng(0)
    lat, lon = _global(1)
    truth = lambda la, lo: 100.0 * np.sin(np.radians(lo)) * np.cos(np.radians(la))  # noqa: E731
    la2, lo2 = np.meshgrid(lat, lon, indexing="ij")
    dem = truth(la2, lo2) + 5.0 + rng.normal(0, 10.0, la2.shape)
    dem[:10] = np.nan
    dist = np.where(lo2 < 180, 500.0, 15_000.0)
    dem[lo2 >= 180] += 30.0  # farther from points -> worse
    acc = dem_accuracy(dem, lat, lon, truth, dist)
    assert acc["n_no_value"] == 10 * 360
    assert acc["n_compared"] == 170 * 360
    near, far = acc["error_vs_distance"][1], acc["error_vs_distance"][5]
    assert near["distance_km_min"] == 0.5 and far["distance_km_min"] == 10.0
    assert near["bias_m"] == pytest.approx(5.0, abs=0.3) and near["std_m"] == pytest.approx(10.0, rel=0.05)
    assert far["bias_m"] == pytest.approx(35.0, abs=0.3)
    assert near["p5_m"] == pytest.approx(5.0 - 16.45, abs=1.0) and near["p95_m"] == pytest.approx(5 + 16.45, abs=1.0)
    assert acc["bias_m"] == pytest.approx(20.0, abs=0.5)
    assert acc["error_vs_distance"][0]["n"] == 0 and acc["error_vs_distance"][0]["rmse_m"] is None


def test_sampling_wraps_the_seam_and_skips_gaps():
    lat, lon = _global(1)
    g = np.tile(np.cos(np.radians(lon)), (lat.size, 1))
    v = sample_bilinear(g, lat, lon, np.array([0.0, 0.0]), np.array([0.0, 359.9]))
    # lon 0 lies between the centres 359.5 and 0.5: the seam is interpolated across.
    np.testing.assert_allclose(v, [np.cos(np.radians(0.5)), np.cos(np.radians(0.5))], atol=1e-4)
    g2 = g.copy()
    g2[:, 1] = np.nan
    # Column 1 (centre 1.5 E) is a gap: lon 0.7 keeps 80 % of its weight, lon 1.4 only 10 %.
    v2 = sample_bilinear(g2, lat, lon, np.array([0.0, 0.0]), np.array([0.7, 1.4]))
    assert v2[0] == pytest.approx(np.cos(np.radians(0.5)), abs=1e-6) and np.isnan(v2[1])


@pytest.mark.integration  # two whole commands (grid, products) end to end
def test_cli_grid_then_products(tmp_path, capsys):
    from products_synthetic import truth_height

    from mercury_dem.geometry.body import latlon_to_unit

    rng = np.random.default_rng(4)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, 8000)))
    lon = rng.uniform(0, 360, 8000)
    r = DATUM_RADIUS_M + truth_height(lat, lon)
    csv = tmp_path / "points.csv"
    np.savetxt(csv, np.column_stack([lat, lon, r]), delimiter=",", header="lat,lon,radius", comments="")
    np.save(tmp_path / "points.npy", latlon_to_unit(lat, lon) * r[:, None])
    cfg = tmp_path / "c.yaml"
    cfg.write_text("dem:\n  coverage_pixel_km: 200.0\n  stats_pixel_km: 100.0\n  browse_width: 360\n"
                   "  max_distance_m: 200000.0\n")
    assert main(["grid", str(csv), "--out", str(tmp_path / "a"), "--ppd", "1", "--config", str(cfg)]) == 0
    assert main(["grid", str(tmp_path / "points.npy"), "--out", str(tmp_path / "b"), "--ppd", "1",
                 "--config", str(cfg)]) == 0
    from mercury_dem.products.make import open_dem

    a, b = open_dem(tmp_path / "a/dem.zarr"), open_dem(tmp_path / "b/dem.zarr")
    np.testing.assert_allclose(a.elevation.values, b.elevation.values, atol=1e-3)
    assert main(["grid", str(csv), "--out", str(tmp_path / "a"), "--ppd", "1", "--config", str(cfg)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["products", str(tmp_path / "a"), "--profile", "0,10,20,60", "--config", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "north_polar" in out and "coverage (200 km/pixel" in out
    assert (tmp_path / "a/products/profile_1.csv").is_file()
    assert main(["products", str(tmp_path / "a"), "--config", str(cfg)]) == 2
    assert main(["products", str(tmp_path / "a"), "--profile", "0,10,20", "--overwrite", "--config", str(cfg)]) == 2
    assert main(["grid", str(tmp_path / "missing.npy"), "--out", str(tmp_path / "c")]) == 2


def test_crop_to_data_keeps_a_patch_across_the_seam_whole():
    from mercury_dem.products.browse import crop_to_data

    lat, lon = _global(1)
    h = np.full((lat.size, lon.size), np.nan)
    la2, lo2 = np.meshgrid(lat, lon, indexing="ij")
    patch = (np.abs(la2) < 10) & ((lo2 < 10) | (lo2 > 350))
    h[patch] = 1.0
    ch, cs, clat, clon = crop_to_data(h, h.copy(), lat, lon, margin=2)
    assert np.all(np.diff(clon) == pytest.approx(1.0))  # continuous across 0/360
    assert clon[0] == pytest.approx(-11.5) and clon[-1] == pytest.approx(11.5)
    assert clat[0] == pytest.approx(11.5) and clat[-1] == pytest.approx(-11.5)
    assert np.isfinite(ch).sum() == patch.sum()


def test_accuracy_finds_an_injected_bending_of_the_block():
    """Poles high, mid-latitudes low (a degree-2 zonal error of known size) plus noise: the latitude bands
    and the spherical-harmonic fit both recover it, and removing it leaves the noise."""
    rng = np.random.default_rng(1)
    lat, lon = _global(1)
    la2, lo2 = np.meshgrid(lat, lon, indexing="ij")
    x = np.sin(np.radians(la2))
    p2 = np.sqrt(5.0) * 0.5 * (3 * x**2 - 1)  # 4π-normalised zonal degree 2 (mean square 1)
    truth = lambda la, lo: np.zeros_like(la)  # noqa: E731
    dem = 300.0 * p2 + 40.0 + rng.normal(0, 20.0, la2.shape)
    acc = dem_accuracy(dem, lat, lon, truth, shape_lmax=4)
    low = acc["low_degree"]
    assert acc["sphere_fraction"] == pytest.approx(1.0, abs=0.01)
    assert low["zonal_m"][0] == pytest.approx(40.0, abs=2.0)
    assert abs(low["zonal_m"][2]) == pytest.approx(300.0, rel=0.02)
    assert low["degree_rms_m"][2] == pytest.approx(300.0, rel=0.02)
    assert max(low["degree_rms_m"][1], low["degree_rms_m"][3], low["degree_rms_m"][4]) < 5.0
    assert low["rmse_after_removal_m"] == pytest.approx(20.0, rel=0.05)
    bands = {(b["lat_min"], b["lat_max"]): b for b in acc["error_vs_latitude"]}
    # P2 at the poles is sqrt(5) = 2.24 times the amplitude; at the equator -sqrt(5)/2.
    assert bands[(60.0, 90.0)]["bias_m"] > 40.0 + 1.5 * 300.0
    assert bands[(-10.0, 10.0)]["bias_m"] == pytest.approx(40.0 - 300.0 * np.sqrt(5) / 2, abs=15.0)


def test_accuracy_of_a_regional_dem_has_no_harmonic_fit():
    lat = np.arange(-9.5, 10.0, 1.0)
    lon = np.arange(0.5, 20.0, 1.0)
    dem = np.zeros((lat.size, lon.size)) + 3.0
    acc = dem_accuracy(dem, lat, lon, lambda la, lo: np.zeros_like(la))
    assert acc["low_degree"] is None and acc["sphere_fraction"] < 0.02
    band = [b for b in acc["error_vs_latitude"] if b["n"]]
    assert [(b["lat_min"], b["lat_max"]) for b in band] == [(-10.0, 10.0)] and band[0]["bias_m"] == pytest.approx(3.0)
