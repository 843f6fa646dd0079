"""Registration recovers injected transforms and per-profile offsets (synthetic truth)."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.altimetry.register import DemWindow, RegisterOptions, register_tile, tile_window
from tests.altimetry.synthetic import R_DATUM, Rigid, Surface, moved_dem, profiles

BOUNDS = (30.0, 40.0, 100.0, 110.0)
CENTRE = (35.0, 105.0)


def _case(seed: int, t_enu=(2000.0, 1000.0, 300.0), angle=0.02, n_profiles=200, spacing_deg=0.03,
          sigma_h_m=10.0, sigma_v_m=3.0, **kw):
    rng = np.random.default_rng(seed)
    surf = Surface(rng)
    lat = np.arange(42.0, 27.99, -0.05)  # north first, as dem.zarr
    lon = np.arange(98.0, 112.01, 0.05)
    D = Rigid(CENTRE, np.asarray(t_enu), angle_up_deg=angle)
    dem = moved_dem(surf, D, lat, lon)
    # 200 profiles: their mean error (sigma_h / sqrt(200)) is what the tile translation cannot tell apart.
    prof = profiles(surf, rng, BOUNDS, n_profiles=n_profiles, spacing_deg=spacing_deg, sigma_h_m=sigma_h_m,
                    sigma_v_m=sigma_v_m, **kw)
    return DemWindow(dem, lat, lon, R_DATUM), prof


# Seeds: 1 used while writing. With 30 m profile errors the plain two-step fit missed 10 % of the
# rotation on 2 of 7 seeds (7, 7, 13, 12, 3, 3, 3.5 % on seeds 1, 7, 13, 21-24): constant per-profile
# errors that line up with a rotation bias it. With the profile nuisance in the tile fit (the default)
# seeds 1, 7, 13, 21, 22 are within 5 %; 41 was first run after that. With the offsets kept out of the
# directions they mimic (session 11): 3.8, 3.6, 5.0, 3.9, 2.4 % and 2.0 % (seed 41).
# The fast loop (-m "not integration") keeps seed 41, the one not used while writing; make test runs all three.
@pytest.mark.parametrize("seed", [pytest.param(1, marks=pytest.mark.integration),
                                  pytest.param(13, marks=pytest.mark.integration), 41])
def test_injected_transform_recovered(seed):
    win, prof = _case(seed, sigma_h_m=30.0)
    res = register_tile(win, prof.lat, prof.lon, prof.radius, prof.profile_id, tile_id=0, centre=CENTRE)
    t = res.transform
    assert t.ok and t.model in ("affine", "similarity"), t.reason
    # T maps the DEM back onto the altimetry: the inverse of the injected move
    inj = np.array([2000.0, 1000.0, 300.0])
    got = -np.asarray(t.translation_enu_m)
    mean_off = prof.offset_enu.mean(axis=0)  # the tile transform absorbs the profiles' mean error
    assert np.all(np.abs(got - (inj - mean_off)) <= 0.1 * np.abs(inj)), (got, inj)
    assert abs(-t.rotation_deg[2] - 0.02) <= 0.002, t.rotation_deg
    # the reported sigma of the translation includes the profiles' unknown mean error
    assert 30.0 / np.sqrt(200) < t.sigma_m[-2] < 3 * 100.0 / np.sqrt(200)
    # scale and tilts: nothing injected; within 3 sigma of the fit (10 m at ~115 km is 0.005 deg)
    assert abs(t.scale - 1) < 1e-4 and max(abs(v) for v in t.rotation_deg[:2]) < 0.005
    assert res.rms_after_m < res.rms_registered_m < res.rms_before_m
    assert res.rms_after_m < 5.0  # 1 m noise + interpolation of a 2 km DEM


# Profile errors of 100 m / 5 m: large against their precision (a few metres horizontally, from the
# slopes; < 1 m vertically), so the per-profile offsets are measurable; seed 13 first run with this test.
@pytest.mark.parametrize("seed", [pytest.param(1, marks=pytest.mark.integration), 13])  # fast loop: 13 (unseen)
def test_injected_profile_offsets_recovered(seed):
    win, prof = _case(seed, sigma_h_m=100.0, sigma_v_m=5.0)
    res = register_tile(win, prof.lat, prof.lon, prof.radius, prof.profile_id, tile_id=0, centre=CENTRE)
    t = res.transform
    mean_off = prof.offset_enu.mean(axis=0)
    got = -np.asarray(t.translation_enu_m)
    assert np.all(np.abs(got - ([2000.0, 1000.0, 300.0] - mean_off)) <= [200.0, 100.0, 30.0])
    # the correction is minus the injected error (less its mean)
    p = res.profiles
    assert p.fitted.mean() > 0.95  # tracks clipped at the tile corner may be short
    f = p.fitted
    inj_corr = -(prof.offset_enu[p.profile_id] - mean_off)[f]
    for k in range(3):
        assert np.corrcoef(p.offset_enu_m[f, k], inj_corr[:, k])[0, 1] > 0.9, k
    # vertical: ~1 m noise over ~300 shots + the DEM's bilinear error
    assert np.sqrt(np.mean((p.offset_enu_m[f, 2] - inj_corr[:, 2]) ** 2)) < 1.0
    assert np.all(p.rms_after_m[f] <= p.rms_before_m[f] + 0.05)
    assert res.rms_after_m < res.rms_registered_m < res.rms_before_m


@pytest.mark.integration  # the option off: 2.3 s; the default path is in the fast loop
def test_plain_two_step_without_nuisance_still_runs():
    """The plain seed-004 step 1 (profile errors as shot noise) stays available and recovers the shift."""
    win, prof = _case(1, sigma_h_m=30.0)
    res = register_tile(win, prof.lat, prof.lon, prof.radius, prof.profile_id, tile_id=0, centre=CENTRE,
                        options=RegisterOptions(profile_nuisance=False))
    got = -np.asarray(res.transform.translation_enu_m)
    assert np.all(np.abs(got - [2000.0, 1000.0, 300.0]) <= [200.0, 100.0, 30.0])
    assert res.transform.sigma_m[-2] < 30.0 / np.sqrt(200)  # it does not know the profiles' mean error


def test_no_shift_gives_identity():
    win, prof = _case(3, t_enu=(0.0, 0.0, 0.0), angle=0.0, n_profiles=60, sigma_h_m=0.0, sigma_v_m=0.0)
    res = register_tile(win, prof.lat, prof.lon, prof.radius, prof.profile_id, tile_id=0, centre=CENTRE)
    t = res.transform
    assert np.all(np.abs(t.translation_enu_m[:2]) < 30.0) and abs(t.translation_enu_m[2]) < 2.0
    assert np.all(np.abs(res.profiles.offset_enu_m[:, 2]) < 2.0)


def test_bad_shots_counted_not_fatal():
    win, prof = _case(5, n_profiles=60)
    lat, lon, rad, track = prof.lat.copy(), prof.lon.copy(), prof.radius.copy(), prof.profile_id.copy()
    lat[:7] = np.nan
    rad[10:13] = np.inf
    rad[20:22] = R_DATUM + 2e6  # off the body
    # a profile of 2 shots and 30 shots off the DEM
    lat = np.r_[lat, 35.0, 35.01, np.full(30, 60.0)]
    lon = np.r_[lon, 105.0, 105.0, np.full(30, 105.0)]
    rad = np.r_[rad, R_DATUM, R_DATUM, np.full(30, R_DATUM)]
    track = np.r_[track, 999, 999, np.full(30, 1000)]
    # 3 % wild returns (clouds of the simulation: bad returns kilometres off)
    rng = np.random.default_rng(0)
    bad = rng.choice(lat.size - 32, size=int(0.03 * lat.size), replace=False)
    rad[bad] += rng.choice([-1, 1], bad.size) * rng.uniform(2e3, 8e3, bad.size)
    res = register_tile(win, lat, lon, rad, track, tile_id=0, centre=CENTRE)
    c = res.counts
    assert c["invalid"] == 12 and c["off_dem"] == 30
    assert c["rejected"] >= bad.size
    assert c["profiles_too_few_shots"] >= 1
    assert res.transform.ok
    got = -np.asarray(res.transform.translation_enu_m) + prof.offset_enu.mean(axis=0)
    assert np.all(np.abs(got - [2000, 1000, 300]) <= [200, 100, 30])
    row = res.profiles.to_frame().set_index("profile_id").loc[999]
    assert not row["fitted"] and row["offset_e_m"] == 0.0


def test_tile_without_shots_and_too_few():
    win, _ = _case(2, n_profiles=1)
    res = register_tile(win, [], [], [], [], tile_id=3, centre=CENTRE)
    assert not res.transform.ok and "usable shots" in res.transform.reason and res.counts["shots"] == 0
    res = register_tile(win, [35.0] * 5, [105.0] * 5, [R_DATUM] * 5, [0] * 5, tile_id=3, centre=CENTRE)
    assert not res.transform.ok and res.counts["used"] == 0


def test_single_line_falls_back():
    """All shots on one profile (a line): shear and rotation about the line are not determined, so the tile
    falls back to a model the line carries (a translation, or at least the vertical shift) and is registered
    with it: the injected shift comes back and the shots fit the DEM to the noise-free interpolation error."""
    win, prof = _case(4, n_profiles=1, sigma_h_m=0.0, sigma_v_m=0.0)
    res = register_tile(win, prof.lat, prof.lon, prof.radius, prof.profile_id, tile_id=0, centre=CENTRE)
    t = res.transform
    # registered, not given up: a tile left unregistered would pass a test that only names the models
    assert t.ok and t.model in ("translation", "vertical"), (t.model, t.reason)
    assert "affine" in t.reason and "similarity" in t.reason  # why the richer models were refused
    assert res.counts["used"] == res.counts["shots"] > 300 and res.counts["not_registered"] == 0
    # the fall-back estimates no rotation nor scale
    assert t.rotation_deg == (0.0, 0.0, 0.0) and t.scale == 1.0
    # T maps the DEM back onto the altimetry: minus the injected (2000, 1000, 300) m, within 3 sigma (no noise
    # injected; sigma is the fit's: ~9 m vertically, ~90 m across the line)
    got = -np.asarray(t.translation_enu_m)
    inj = np.array([2000.0, 1000.0, 300.0])
    sigma = np.asarray(t.sigma_m)
    if t.model == "translation":
        assert np.all(np.abs(got - inj) <= 3 * sigma[-3:]), (got, t.sigma_m)
    else:
        assert abs(got[2] - inj[2]) <= 3 * sigma[-1], (got, t.sigma_m)
    assert abs(got[2] - 300.0) < 30.0
    # 300 m off before; after, the misfit of a noise-free line on an interpolated 2 km DEM (measured 1.9 m)
    assert res.rms_before_m > 250.0 and res.rms_after_m < 5.0, (res.rms_before_m, res.rms_after_m)


def test_tile_window_wraps_the_seam():
    lat = np.arange(89.75, -90, -0.5)
    lon = np.arange(0.25, 360, 0.5)
    h = np.tile(lon, (lat.size, 1))
    w = tile_window(h, lat, lon, (0.0, 10.0, 350.0, 360.0), R_DATUM, margin_deg=1.0)
    assert w is not None and np.all(np.diff(w.lon) > 0) and w.lon[0] < 350 and w.lon[-1] > 360
    np.testing.assert_allclose(w.height[0], w.lon % 360)
    polar = tile_window(h, lat, lon, (80.0, 90.0, 0.0, 10.0), R_DATUM)
    assert polar.lon.size == lon.size + 1


def test_options_validated():
    with pytest.raises(ValueError, match="models"):
        RegisterOptions(models=("shear",))
    with pytest.raises(ValueError, match="nuisance_min_within_share"):
        RegisterOptions(nuisance_min_within_share=1.5)


# Few near-parallel profiles (the 10^7-shot benchmark's tiles have 9-22): the profiles' offsets can mimic
# the translation and the rotation about north exactly, and with the nuisance free in those directions the
# transform alone fitted the shots much worse (seed 1: 5.5 m vs 3.2 m plain; the benchmark's registered
# DEM 3.6 -> 9.6 m RMSE). The nuisance is now kept out of the directions it can mimic: the transform fits
# as well as the plain fit's, and the rotation about up keeps the nuisance's benefit (plain: 20 / 10 / 12 %
# off on seeds 1-3; these seeds were first run with the chosen threshold).
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_few_profiles_nuisance_does_not_loosen_the_transform(seed):
    win, prof = _case(seed, n_profiles=12, spacing_deg=0.01, sigma_h_m=30.0)
    args = (win, prof.lat, prof.lon, prof.radius, prof.profile_id)
    res = register_tile(*args, tile_id=0, centre=CENTRE)
    plain = register_tile(*args, tile_id=0, centre=CENTRE, options=RegisterOptions(profile_nuisance=False))
    assert res.transform.ok and plain.transform.ok
    assert res.rms_registered_m <= 1.1 * plain.rms_registered_m, (res.rms_registered_m, plain.rms_registered_m)
    assert abs(-res.transform.rotation_deg[2] - 0.02) <= 0.002, res.transform.rotation_deg
    got = -np.asarray(res.transform.translation_enu_m)
    mean_off = prof.offset_enu.mean(axis=0)
    # vertical: 3 m profile errors over 12 profiles -> ~1 m; 3 m allows 3 sigma
    assert abs(got[2] - (300.0 - mean_off[2])) < 3.0, got
    assert res.rms_after_m < res.rms_registered_m
