"""DEM - reference statistics: known bias and noise recovered, one datum, NaN and the seam."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from mercury_dem.reference.compare import (
    compare_dem_with_harmonics,
    compare_dem_with_shots,
    compare_heights,
    difference_statistics,
    residuals_at_shots,
)
from mercury_dem.reference.sha import evaluate_grid

DATUM_M = 2_439_400.0
BIAS_M, SIGMA_M = 30.0, 5.0


def _assert_recovers(stats, n, bias=BIAS_M, sigma=SIGMA_M):
    assert stats["n"] == n
    assert abs(stats["bias_m"] - bias) < 3 * sigma / math.sqrt(n)
    assert abs(stats["median_m"] - bias) < 4 * sigma / math.sqrt(n)
    assert stats["std_m"] == pytest.approx(sigma, rel=0.10)
    assert stats["nmad_m"] == pytest.approx(sigma, rel=0.10)
    assert stats["rmse_m"] == pytest.approx(math.hypot(bias, sigma), rel=0.02)
    assert stats["p5_m"] == pytest.approx(bias - 1.645 * sigma, abs=0.5)
    assert stats["p95_m"] == pytest.approx(bias + 1.645 * sigma, abs=0.5)


def test_known_bias_and_noise_against_radii():
    rng = np.random.default_rng(7)
    n = 20_000
    ref_radius = DATUM_M + rng.uniform(-5000, 4000, n)
    dem = (ref_radius - DATUM_M) + BIAS_M + rng.normal(0, SIGMA_M, n)
    stats = compare_heights(dem, datum_radius_m=DATUM_M, reference_radius_m=ref_radius)
    _assert_recovers(stats, n)
    assert stats["datum_radius_m"] == DATUM_M and stats["n_excluded"] == 0


def test_reference_heights_on_another_datum_are_converted():
    """LOLA-style heights above 1737.4 km against a DEM on a 1737.0 km datum: 400 m apart."""
    rng = np.random.default_rng(8)
    n = 5000
    ref_h = rng.uniform(-3000, 3000, n)  # above 1 737 400 m
    dem_h = ref_h + 400.0 + BIAS_M + rng.normal(0, SIGMA_M, n)  # above 1 737 000 m
    stats = compare_heights(
        dem_h, datum_radius_m=1_737_000.0, reference_heights_m=ref_h, reference_datum_radius_m=1_737_400.0
    )
    _assert_recovers(stats, n)
    with pytest.raises(ValueError, match="reference_datum_radius_m"):
        compare_heights(dem_h, datum_radius_m=1_737_000.0, reference_heights_m=ref_h)
    with pytest.raises(ValueError, match="exactly one"):
        compare_heights(dem_h, datum_radius_m=1_737_000.0)


def test_nan_excluded_and_counted():
    dem = np.array([1.0, np.nan, 3.0, 5.0, np.inf])
    ref = DATUM_M + np.array([0.0, 0.0, np.nan, 1.0, 0.0])
    stats = compare_heights(dem, datum_radius_m=DATUM_M, reference_radius_m=ref)
    assert (stats["n"], stats["n_excluded"]) == (2, 3)
    assert stats["bias_m"] == pytest.approx(2.5)
    empty = difference_statistics([np.nan, np.nan])
    assert empty["n"] == 0 and math.isnan(empty["bias_m"]) and math.isnan(empty["nmad_m"])
    with pytest.raises(ValueError, match="shape"):
        compare_heights(np.zeros(3), datum_radius_m=DATUM_M, reference_radius_m=np.zeros(4))


def _smooth_surface(lat, lon):
    """Heights (m) smooth enough that bilinear sampling of a 0.25-degree grid is exact to ~0.1 m."""
    return 1500.0 * np.sin(np.radians(lat) * 2) * np.cos(np.radians(lon)) + 300.0 * np.sin(np.radians(lon) * 3)


def _dem(lat, lon, attrs=None):
    h = _smooth_surface(lat[:, None], lon[None, :])
    return xr.DataArray(h, dims=("lat", "lon"), coords={"lat": lat, "lon": lon},
                        attrs=attrs if attrs is not None else {"datum_radius_m": DATUM_M})


def test_dem_with_shots_global_grid_across_the_seam():
    lat = np.arange(89.875, -90, -0.25)  # descending, like the project's DEMs
    lon = np.arange(0.125, 360, 0.25)
    dem = _dem(lat, lon)
    rng = np.random.default_rng(9)
    n = 4000
    s_lat = rng.uniform(-60, 60, n)
    s_lon = np.where(np.arange(n) % 2 == 0, rng.uniform(-0.2, 0.2, n) % 360, rng.uniform(0, 360, n))  # half on the seam
    # Shots are absolute radii BIAS_M below the DEM's surface, with N(0, SIGMA_M) noise.
    radius = DATUM_M + _smooth_surface(s_lat, s_lon) - BIAS_M + rng.normal(0, SIGMA_M, n)
    shots = pd.DataFrame({"lat": s_lat, "lon": s_lon, "radius_m": radius, "profile_id": np.arange(n) // 100})
    stats = compare_dem_with_shots(dem, shots, DATUM_M)
    _assert_recovers(stats, n)
    assert stats["n_profiles"] == 40
    r = residuals_at_shots(dem, shots, DATUM_M)
    assert r.shape == (n,) and np.all(np.isfinite(r))


def test_dem_with_shots_outside_and_gaps():
    lat = np.arange(10.0, 20.01, 0.25)
    lon = np.arange(-5.0, 5.01, 0.25)  # a regional DEM across the seam
    dem = _dem(lat, lon)
    dem[10, 10] = np.nan
    shots = pd.DataFrame({
        "lat": [15.0, 15.0, 15.0, 30.0, lat[10]],
        "lon": [359.0, 1.0, 100.0, 0.0, lon[10]],
    })
    shots["radius_m"] = DATUM_M + _smooth_surface(shots["lat"].to_numpy(), shots["lon"].to_numpy())
    stats = compare_dem_with_shots(dem, shots, DATUM_M)
    assert (stats["n"], stats["n_excluded"]) == (2, 3)
    assert abs(stats["bias_m"]) < 0.5


def test_datums_are_never_mixed():
    dem = _dem(np.array([0.0, 1.0]), np.array([0.0, 1.0]), attrs={"datum_radius_m": 2_440_530.0})
    shots = pd.DataFrame({"lat": [0.5], "lon": [0.5], "radius_m": [DATUM_M]})
    with pytest.raises(ValueError, match="never compared"):
        compare_dem_with_shots(dem, shots, DATUM_M)


def test_dem_with_harmonics(gtmes):
    lat = np.arange(87.0, -88.0, -2.0)
    lon = np.arange(1.0, 360.0, 2.0)
    truth = evaluate_grid(gtmes, lat, lon, lmax=148) - DATUM_M
    rng = np.random.default_rng(10)
    h = truth + BIAS_M + rng.normal(0, SIGMA_M, truth.shape)
    h[:3, :] = np.nan
    dem = xr.DataArray(h, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}, attrs={"datum_radius_m": DATUM_M})
    stats = compare_dem_with_harmonics(dem, gtmes, DATUM_M, lmax=148)
    _assert_recovers(stats, h.size - 3 * lon.size)
    assert stats["n_excluded"] == 3 * lon.size and stats["lmax"] == 148


def test_dem_with_harmonics_long_wavelengths(gtmes):
    """A DEM bent like the demo's block (a zonal degree-2 error) and offset: the long-wavelength report
    of DEM − shape gives the offset as degree 0, the bend as degree 2, nothing at the other degrees."""
    lat = np.arange(87.0, -88.0, -2.0)
    lon = np.arange(1.0, 360.0, 2.0)
    truth = evaluate_grid(gtmes, lat, lon, lmax=148) - DATUM_M
    la = np.radians(lat)[:, None] * np.ones(lon.size)
    c2 = 120.0  # m, the 4π-normalised zonal degree-2 coefficient (its RMS over the sphere)
    bend = c2 * math.sqrt(5.0) * (3 * np.sin(la) ** 2 - 1) / 2
    h = truth + BIAS_M + bend + np.random.default_rng(11).normal(0, SIGMA_M, truth.shape)
    dem = xr.DataArray(h, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}, attrs={"datum_radius_m": DATUM_M})
    lw = compare_dem_with_harmonics(dem, gtmes, DATUM_M, lmax=148, long_lmax=6)["long_wavelength"]
    deg = lw["low_degree"]["degree_rms_m"]
    # Noise of 5 m over ~16,000 pixels moves each coefficient by well under 1 m; the 2° grid's quadrature a bit more.
    assert deg[0] == pytest.approx(BIAS_M, abs=2.0) and deg[2] == pytest.approx(c2, abs=2.0)
    assert max(deg[1], *deg[3:]) < 2.0
    assert lw["low_degree"]["zonal_m"][2] == pytest.approx(c2, abs=2.0)
    bands = {(b["lat_min"], b["lat_max"]): b["bias_m"] for b in lw["error_vs_latitude"]}
    assert bands[(60.0, 90.0)] > BIAS_M + 100 and bands[(-10.0, 10.0)] < BIAS_M - 100
    assert compare_dem_with_harmonics(dem, gtmes, DATUM_M, lmax=148, long_lmax=0)["long_wavelength"] is None


def test_reference_table_prints_the_long_wavelengths(gtmes):
    from mercury_dem.pipeline.reference_check import reference_table

    lat = np.arange(87.0, -88.0, -6.0)
    lon = np.arange(3.0, 360.0, 6.0)
    h = evaluate_grid(gtmes, lat, lon, lmax=20) - DATUM_M + 40.0
    dem = xr.DataArray(h, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}, attrs={"datum_radius_m": DATUM_M})
    text = reference_table({"shape:GTMES": compare_dem_with_harmonics(dem, gtmes, DATUM_M, lmax=20, long_lmax=4)})
    assert "long wavelengths (area-weighted): bias +40.0 m" in text
    assert "RMS per degree 0..4: 40 0 0 0 0 m" in text
