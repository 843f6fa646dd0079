"""Levelling of the dense cloud (issue 31, done-when 1; docs/design/dense.md step 5): each stereo pair's points put
on the sparse DEM's level (``dem.dense_grid.pair_level_offsets``), and the dense values alone moved with the
delivered DEM's level on the altimetry (``pipeline.dense_dem.level_dense_pixels``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from mercury_dem.dem.dense_grid import pair_level_offsets


def test_each_pairs_offset_is_recovered_within_its_noise_and_gross_points_do_not_move_it() -> None:
    """Synthetic pairs with known offsets, 300 m noise and 5 % gross points: each offset within 4 standard errors."""
    rng = np.random.default_rng(3)
    n, sigma = 4000, 300.0  # points per pair; each point's own error (m)
    truth_offset = {0: -8.0, 1: 49.0, 2: 94.0, 3: 261.0, 7: -150.0}  # a pair's heights above the prior's level
    pair = np.repeat(np.array(list(truth_offset)), n)
    point_error = rng.normal(0.0, sigma, pair.size) + np.array([truth_offset[int(p)] for p in pair])
    point_error[rng.random(pair.size) < 0.05] += 20_000.0  # 5 % gross points (SGBM's outliers)
    diff = -point_error  # prior - point
    diff[rng.random(pair.size) < 0.1] = np.nan  # points where the prior has no value
    shift, offsets = pair_level_offsets(diff, pair, clip_nmad=3.0, min_points=500)
    tol = 4 * sigma / np.sqrt(0.85 * n)  # 4 standard errors of a pair's mean over its kept points
    for k, v in truth_offset.items():
        assert offsets[k] == pytest.approx(-v, abs=tol)
        assert np.all(shift[pair == k] == offsets[k])  # every point of the pair, those without a prior too
    levelled = point_error + shift
    for k in truth_offset:
        kept = (pair == k) & (np.abs(levelled) < 5 * sigma)
        assert abs(np.mean(levelled[kept])) <= tol


def test_a_pair_with_too_few_points_on_the_prior_is_not_moved() -> None:
    """Below ``min_points`` on the prior a pair keeps its level (offset 0, not in the offsets)."""
    pair = np.r_[np.zeros(600, int), np.ones(600, int)]
    diff = np.full(1200, 100.0)
    diff[600:1000] = np.nan  # pair 1: 200 points on the prior
    shift, offsets = pair_level_offsets(diff, pair, clip_nmad=3.0, min_points=500)
    assert offsets == {0: pytest.approx(100.0)}
    assert np.all(shift[:600] == 100.0) and np.all(shift[600:] == 0.0)


def test_the_dense_values_alone_move_with_the_delivered_dems_level() -> None:
    """Both layers get the offsets fitted on ``elevation`` (the shots sit 40 m below it), the sparse pixels none."""
    from mercury_dem.config import load_config
    from mercury_dem.pipeline.dense_dem import SOURCE_DENSE, SOURCE_SPARSE, level_dense_pixels
    from mercury_dem.reference.sampling import sample_grid

    radius = 1000e3  # any body: the datum is a parameter
    lat, lon = np.linspace(-4.75, 4.75, 20), np.linspace(0.25, 9.75, 20)
    rng = np.random.default_rng(5)
    elev = rng.normal(0.0, 100.0, (20, 20))
    alone = elev + rng.normal(150.0, 50.0, (20, 20))
    source = np.full((20, 20), SOURCE_DENSE, np.uint8)
    source[:, :3] = SOURCE_SPARSE
    ds = xr.Dataset({"elevation": (("lat", "lon"), elev.astype(np.float32)),
                     "elevation_dense": (("lat", "lon"), alone.astype(np.float32)),
                     "source": (("lat", "lon"), source)}, coords={"lat": lat, "lon": lon})
    slat, slon = rng.uniform(-4.5, 4.5, 2000), rng.uniform(2.0, 9.5, 2000)
    shots = pd.DataFrame({"lat": slat, "lon": slon,
                          "radius_m": radius + sample_grid(elev, lat, lon, slat, slon) - 40.0})
    level = level_dense_pixels(ds, shots, radius, load_config())
    assert level is not None and level["tiles"] >= 1
    d = source == SOURCE_DENSE
    got_e = ds["elevation"].values.astype(np.float64)
    got_a = ds["elevation_dense"].values.astype(np.float64)
    assert np.allclose((got_e - elev)[d], -40.0, atol=1.0)
    assert np.allclose((got_a - alone)[d], (got_e - elev)[d], atol=1e-2)  # the same offsets
    assert np.array_equal(got_e[~d], elev[~d].astype(np.float32))
    assert np.array_equal(got_a[~d], alone[~d].astype(np.float32))
