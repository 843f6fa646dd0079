"""Synthetic MLA: the simulation's statistics recover what was injected (range noise, per-profile orbit
errors, bad-return fraction, shot spacing, north/south density), deterministically from the seed."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mercury_dem.altimetry.simulate import (
    MERCURY_GM,
    MERCURY_ROTATION_S,
    AltimetryDesign,
    screen_shots,
    simulate_altimetry,
)
from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit

R = 2_439_400.0


def _relief(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """A smooth known surface (km-scale relief) standing in for the synthetic truth."""
    return 1500.0 * np.sin(np.radians(3 * lat)) * np.cos(np.radians(2 * lon)) - 800.0 * np.sin(np.radians(lat)) ** 2


@pytest.fixture(scope="module")
def north() -> object:
    """A MESSENGER-like global design, few orbits (seed 2024, not tuned)."""
    d = AltimetryDesign(n_orbits=24, max_range_m=1_200e3, range_noise_m=1.0, bad_fraction=0.04)
    return simulate_altimetry(d, _relief, np.random.default_rng(2024), datum_radius_m=DATUM_RADIUS_M, gm=MERCURY_GM, rotation_period_s=MERCURY_ROTATION_S)


def test_range_noise_and_bad_returns(north) -> None:
    s, t = north.shots, north.truth
    good = t["bad"].to_numpy() == 0
    resid = (s["range_m"] - t["true_range_m"]).to_numpy()[good]
    n = good.sum()
    # std of the range noise within 5 standard errors of the injected 1 m
    assert abs(resid.std() - 1.0) < 5 * 1.0 / np.sqrt(2 * n)
    assert abs(resid.mean()) < 5 / np.sqrt(n)
    # bad returns: 4 % injected, half flagged (binomial tolerance, 5 sigma)
    frac = 1 - good.mean()
    assert abs(frac - 0.04) < 5 * np.sqrt(0.04 * 0.96 / len(s))
    flagged = (s["flag"] == 1).to_numpy()
    assert np.array_equal(flagged, t["bad"].to_numpy() == 1)
    assert abs(flagged.mean() - 0.02) < 5 * np.sqrt(0.02 * 0.98 / len(s))
    wild = np.abs(s["range_m"] - t["true_range_m"]).to_numpy()[t["bad"].to_numpy() == 2]
    assert np.median(wild) > 300.0  # wild ranges are far off (sigma 2 km), unflagged
    kept, dropped = screen_shots(s, R)
    assert dropped["flagged"] == flagged.sum() and len(kept) == len(s) - sum(dropped.values())


def test_per_profile_orbit_errors_are_in_the_shots_and_in_truth(north) -> None:
    s, t, prof = north.shots, north.truth, north.profiles
    assert len(prof) == s["profile_id"].nunique() == 24
    # injected magnitudes: tens-hundreds of metres horizontally, metres vertically
    assert 60 < prof["along_m"].std() < 300 and 40 < prof["cross_m"].std() < 200 and prof["radial_m"].std() < 8
    horiz = np.hypot(prof["east_m"], prof["north_m"])
    assert np.allclose(horiz, np.hypot(prof["along_m"], prof["cross_m"]), rtol=1e-6)
    assert np.allclose(prof["up_m"], prof["radial_m"], atol=1e-6)
    # every good shot = true point + the profile's offset - noise along the radial
    good = t["bad"].to_numpy() == 0
    rec = latlon_to_unit(s["lat"].to_numpy(), s["lon"].to_numpy()) * s["radius_m"].to_numpy()[:, None]
    tru = latlon_to_unit(t["true_lat"].to_numpy(), t["true_lon"].to_numpy()) * t["true_radius_m"].to_numpy()[:, None]
    off = t[["offset_x_m", "offset_y_m", "offset_z_m"]].to_numpy()
    miss = np.linalg.norm(rec - tru - off, axis=1)[good]
    assert np.percentile(miss, 99) < 4.0  # range noise (1 m) only
    # the mean displacement per profile recovers its injected error (east/north/up at the middle shot)
    disp = pd.DataFrame(rec - tru, columns=list("xyz")).assign(profile_id=s["profile_id"].to_numpy())[good]
    mean = disp.groupby("profile_id")[list("xyz")].mean()
    mid = prof.set_index("profile_id")
    up = latlon_to_unit(mid["lat_mid"].to_numpy(), mid["lon_mid"].to_numpy())
    # the orbit frame turns along a profile, so the mean is compared by magnitude and radial part
    assert np.corrcoef(np.linalg.norm(mean.to_numpy(), axis=1), np.hypot(horiz, mid["up_m"]))[0, 1] > 0.8
    assert np.all(np.abs(np.sum(mean.to_numpy() * up, axis=1) - mid["up_m"].to_numpy()) < 30.0)


def test_geometry_dense_north_none_south_400m_spacing(north) -> None:
    s = north.shots
    cap = lambda a, b: (np.sin(np.radians(b)) - np.sin(np.radians(a)))  # noqa: E731 (area of a latitude band / 2 pi)
    density_n = np.sum(s["lat"] > 60) / cap(60, 90)
    density_mid = np.sum((s["lat"] > 0) & (s["lat"] < 30)) / cap(0, 30)
    assert density_n > 5 * density_mid and np.sum(s["lat"] < -10) == 0
    one = s[s["profile_id"] == s["profile_id"].iloc[0]]
    xyz = latlon_to_unit(one["lat"].to_numpy(), one["lon"].to_numpy()) * R
    step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    near_periapsis = step[np.argsort(one["range_m"].to_numpy()[1:])[: len(step) // 10]]
    assert 330 < np.median(near_periapsis) < 460  # 8 Hz: ~400 m apart near periapsis
    assert (one["range_m"] <= 1_200e3 + 30e3).all()


def test_deterministic_and_regional(north) -> None:
    d = AltimetryDesign(n_orbits=24, max_range_m=1_200e3, range_noise_m=1.0, bad_fraction=0.04)
    again = simulate_altimetry(d, _relief, np.random.default_rng(2024), datum_radius_m=DATUM_RADIUS_M, gm=MERCURY_GM, rotation_period_s=MERCURY_ROTATION_S)
    pd.testing.assert_frame_equal(again.shots, north.shots)
    other = simulate_altimetry(d, _relief, np.random.default_rng(2025), datum_radius_m=DATUM_RADIUS_M, gm=MERCURY_GM, rotation_period_s=MERCURY_ROTATION_S)
    assert not np.allclose(other.profiles["along_m"], north.profiles["along_m"])
    area = (-10.0, 20.0, -15.0, 15.0)
    reg = simulate_altimetry(AltimetryDesign(n_orbits=12, lon_range_deg=(-16, 16), periapsis_lat_deg=20.0),
                             _relief, np.random.default_rng(3), area_deg=area, datum_radius_m=DATUM_RADIUS_M, gm=MERCURY_GM, rotation_period_s=MERCURY_ROTATION_S)
    lat, lon = reg.shots["lat"], (reg.shots["lon"] + 180) % 360 - 180
    assert lat.between(-11.5, 21.5).all() and lon.between(-16.5, 16.5).all() and reg.profiles.shape[0] == 12
    with pytest.raises(ConfigError, match="periapsis_lat"):
        AltimetryDesign(n_orbits=1, periapsis_lat_deg=85.0)
