"""Radius constraints from altimetry shots: recovered heights and honest sigmas on a known surface."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.altimetry.constraints import altimetry_radius_priors, unit_vectors

R = 2_439_400.0


def terrain(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """Heights (m) with 3-30 km wavelengths, a few hundred metres high."""
    x, y = np.radians(lon) * R * np.cos(np.radians(lat)), np.radians(lat) * R
    return (300 * np.sin(x / 9000.0) * np.cos(y / 13000.0) + 120 * np.sin((x + 2 * y) / 4000.0)
            + 40 * np.cos((x - y) / 2500.0))


def shots(rng: np.random.Generator, n_profiles: int, noise_m: float) -> tuple[np.ndarray, ...]:
    """Near-polar profiles across a 1 x 1 degree box, a shot every ~400 m."""
    lats, lons = [], []
    for k in range(n_profiles):
        lon0 = 10.0 + rng.uniform(0, 1)
        lat = np.arange(20.0, 21.0, 400.0 / R * 180 / np.pi)
        lats.append(lat)
        lons.append(lon0 + (lat - 20.0) * rng.uniform(-0.05, 0.05))
    lat, lon = np.concatenate(lats), np.concatenate(lons)
    return lat, lon, R + terrain(lat, lon) + rng.normal(0, noise_m, lat.size)


@pytest.mark.parametrize("seed", [3, 11])
def test_heights_recovered_with_calibrated_sigmas(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lat_s, lon_s, r_s = shots(rng, 120, noise_m=1.0)
    lat_p, lon_p = rng.uniform(20.1, 20.9, 3000), rng.uniform(10.1, 10.9, 3000)
    # The points' own radii are wrong by kilometres: only their directions may matter.
    pts = unit_vectors(lat_p, lon_p) * (R + rng.normal(0, 3000, 3000))[:, None]
    pri = altimetry_radius_priors(pts, lat_s, lon_s, r_s, shot_sigma_m=1.0, search_radius_m=1500.0)
    c = pri.constrained
    assert c.mean() > 0.8, c.mean()
    err = pri.radius_m[c] - (R + terrain(lat_p[c], lon_p[c]))
    z = err / pri.sigma_m[c]
    print(f"seed {seed}: {c.sum()} constrained, error RMS {np.sqrt(np.mean(err**2)):.1f} m, "
          f"median sigma {np.median(pri.sigma_m[c]):.1f} m, |z|<2 {np.mean(np.abs(z) < 2):.3f}")
    # Far better than the datum prior's kilometres; sigmas neither optimistic nor useless.
    assert np.sqrt(np.mean(err**2)) < 40.0
    assert abs(np.mean(err)) < 3.0
    assert np.mean(np.abs(z) < 2.0) > 0.9
    assert np.median(pri.sigma_m[c]) < 3 * np.sqrt(np.mean(err**2))


def test_points_near_one_profile_get_a_profile_fit_whose_sigma_grows_across_it() -> None:
    """Away from crossovers a point sees one profile (MLA's tracks are km apart, shots 400 m apart): the
    along-track fit at its nearest place, the sigma widened by the cross-track distance; still honest."""
    rng = np.random.default_rng(8)
    step = 400.0 / R * 180 / np.pi
    lat_s = np.arange(20.0, 21.0, step)
    tracks = [10.2 + 0.15 * k for k in range(5)]  # ~7 km apart: never two within the search radius
    lat_all = np.concatenate([lat_s] * len(tracks))
    lon_all = np.concatenate([np.full_like(lat_s, t) for t in tracks])
    r_all = R + terrain(lat_all, lon_all) + rng.normal(0, 1.0, lat_all.size)
    k = rng.integers(0, len(tracks), 4000)
    cross_m = rng.uniform(-900, 900, 4000)
    lat_p = rng.uniform(20.1, 20.9, 4000)
    lon_p = np.asarray(tracks)[k] + cross_m / (R * np.cos(np.radians(lat_p))) * 180 / np.pi
    pri = altimetry_radius_priors(unit_vectors(lat_p, lon_p) * R, lat_all, lon_all, r_all, search_radius_m=1000.0,
                                  cross_track_slope=0.05)
    c = pri.constrained
    assert c.mean() > 0.95
    err = pri.radius_m[c] - (R + terrain(lat_p[c], lon_p[c]))
    z = err / pri.sigma_m[c]
    near, far = np.abs(cross_m[c]) < 150, np.abs(cross_m[c]) > 700
    print(f"profile fits: |z|<2 {np.mean(np.abs(z) < 2):.3f}; median sigma near {np.median(pri.sigma_m[c][near]):.1f} m, "
          f"far {np.median(pri.sigma_m[c][far]):.1f} m; error RMS near {np.sqrt(np.mean(err[near]**2)):.1f} m")
    assert np.mean(np.abs(z) < 2.0) > 0.85
    assert np.median(pri.sigma_m[c][far]) > 2 * np.median(pri.sigma_m[c][near])
    # A point far from every shot stays free; fewer than 3 shots give nothing.
    lone = altimetry_radius_priors(unit_vectors([40.0], [10.5]) * R, lat_all, lon_all, r_all)
    assert not lone.constrained.any() and lone.n_shots[0] == 0
    two = altimetry_radius_priors(unit_vectors([20.5], [10.2]) * R, lat_s[:2] * 0 + 20.5, [10.2, 10.2 + 1e-3],
                                  [R, R])
    assert not two.constrained.any()
    with pytest.raises(ValueError, match="min_shots"):
        altimetry_radius_priors(unit_vectors([20.5], [10.2]) * R, lat_all, lon_all, r_all, min_shots=2)


def test_no_shots_or_no_points() -> None:
    pri = altimetry_radius_priors(np.zeros((0, 3)), [], [], [])
    assert len(pri.radius_m) == 0
    pri = altimetry_radius_priors(unit_vectors([1.0], [2.0]) * R, [], [], [])
    assert not pri.constrained.any()
    assert pri.summary()["constrained_points"] == 0
