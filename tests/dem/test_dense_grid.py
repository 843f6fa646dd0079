"""The dense DEM's grid rules on exact inputs: resolution, bounds, the precision layer, the control distance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mercury_dem.dem.dense_grid import (
    control_distance,
    dense_grid_ppd,
    fuse_with_prior,
    pixel_precision,
    snapped_bounds,
)
from mercury_dem.geometry.body import MERCURY, latlon_to_xyz


def test_the_grid_rule_is_three_pixel_scales_in_half_pixels_per_degree() -> None:
    r = MERCURY.datum_radius_m
    deg_m = 2 * math.pi * r / 360
    # median 2 km x 3 = 6 km -> 7.1 pixel/deg -> 7.0
    assert dense_grid_ppd(np.array([1000.0, 2000.0, 9000.0]), 3.0, r) == round(deg_m / 6000 * 2) / 2 == 7.0
    assert dense_grid_ppd(np.array([1e6]), 3.0, r) == 0.5  # never below half a pixel per degree


def test_bounds_are_snapped_outward_to_whole_pixels() -> None:
    assert snapped_bounds((-20.0, 30.0, -25.0, 25.0), 5.5) == pytest.approx(
        (-20.0, 30.0, -25.0909090909, 25.0909090909))
    a0, a1, o0, o1 = snapped_bounds((-90.0, 90.0, 0.0, 360.0), 7.5)
    assert (a0, a1, o0, o1) == (-90.0, 90.0, 0.0, 360.0)
    for lo, hi in ((a0, a1), (o0, o1)):
        n = (hi - lo) * 7.5
        assert abs(n - round(n)) < 1e-9


def test_the_precision_layer_is_the_median_sigma_over_the_root_of_the_points() -> None:
    ppd = 1.0
    lat = np.array([0.5, -0.5])  # rows: pixel centres, north to south
    lon = np.array([10.5, 11.5])
    cloud = {"lat": np.array([0.2, 0.7, 0.9, 0.1, -0.4]), "lon": np.array([10.2, 10.8, 10.1, 10.6, 11.9]),
             "sigma_h_m": np.array([100.0, 300.0, 200.0, 400.0, 50.0], np.float32)}
    p = pixel_precision(cloud, lat, lon, ppd, k=64)
    assert p[0, 0] == pytest.approx(1.2533 * 250.0 / 2.0)  # 4 points, median of 100, 200, 300, 400
    assert p[1, 1] == pytest.approx(1.2533 * 50.0)
    assert np.isnan(p[0, 1]) and np.isnan(p[1, 0])
    assert pixel_precision(cloud, lat, lon, ppd, k=1)[0, 0] == pytest.approx(1.2533 * 250.0)


def test_the_precision_layer_counts_pairs_not_points() -> None:
    """Pixels whose points come from 1-4 pairs, each pair's points sharing one error (their common window) plus a
    little of their own; the pixel's value is the median of its points. The layer states that error honestly; the
    rule counting every point as independent states it 2.5x too small.
    """
    rng = np.random.default_rng(5)
    n_pix, per_pair, sigma = 3000, 9, 400.0
    ppd = 10.0  # 3000 pixels along 300 degrees of one row
    lat = np.array([0.05])
    lon = (np.arange(n_pix) + 0.5) / ppd
    rows: dict[str, list[np.ndarray]] = {"lat": [], "lon": [], "sigma_h_m": [], "pair": [], "err": []}
    values = np.empty(n_pix)
    for px in range(n_pix):
        m = int(rng.integers(1, 5))
        errs = []
        for pr in range(m):
            e = rng.normal(0.0, sigma) + rng.normal(0.0, 0.1 * sigma, per_pair)
            errs.append(e)
            rows["lat"].append(np.full(per_pair, 0.03))
            rows["lon"].append(np.full(per_pair, (px + 0.5) / ppd))
            rows["sigma_h_m"].append(np.full(per_pair, sigma))
            rows["pair"].append(np.full(per_pair, pr))
        values[px] = np.median(np.concatenate(errs))
    cloud = {k: np.concatenate(v) for k, v in rows.items() if k != "err"}
    p = pixel_precision(cloud, lat, lon, ppd, k=64)[0]
    ratio = np.sqrt(np.mean(values**2) / np.mean(p**2))
    assert 0.85 <= ratio <= 1.25, ratio
    assert np.mean(np.abs(values) > 3 * p) <= 0.01
    without_pairs = pixel_precision({k: v for k, v in cloud.items() if k != "pair"}, lat, lon, ppd, k=64)[0]
    assert np.sqrt(np.mean(values**2) / np.mean(without_pairs**2)) > 2.0


def test_fusion_with_the_prior_weights_by_precision_and_states_its_sigma() -> None:
    """Dense pixels of varying precision and a prior of 400 m, with independent and with correlated errors (rho
    0.6): the fused value recovers the truth better than either input (barely, when correlated), and its stated sigma is honest (true / stated
    within 0.9-1.1, <= 1 % beyond 3 sigma). NaN dense values take the prior; NaN prior, the dense value.
    """
    rng = np.random.default_rng(11)
    n, sp = 200_000, 400.0
    truth = rng.normal(0.0, 2000.0, n)
    sd = rng.uniform(150.0, 1200.0, n)
    for rho in (0.0, 0.6):
        z1, z2 = rng.standard_normal(n), rng.standard_normal(n)
        e_prior = sp * z1
        e_dense = sd * (rho * z1 + np.sqrt(1.0 - rho**2) * z2)
        value, sigma = fuse_with_prior(truth + e_dense, sd, truth + e_prior, sp, rho)
        err = value - truth
        rms = float(np.sqrt(np.mean(err**2)))
        # better than either input; with correlated errors (weights that ignore the correlation) barely better
        assert rms < (0.97 if rho == 0.0 else 1.0) * min(sp, float(np.sqrt(np.mean(e_dense**2))))
        assert 0.9 <= rms / float(np.sqrt(np.mean(sigma**2))) <= 1.1
        assert np.mean(np.abs(err) > 3 * sigma) <= 0.01
    v, s_ = fuse_with_prior(np.array([np.nan, 10.0, 10.0]), np.array([np.nan, 100.0, np.nan]),
                            np.array([5.0, np.nan, 20.0]), 100.0)
    assert v[0] == 5.0 and s_[0] == 100.0  # no dense value: the prior
    assert v[1] == 10.0 and s_[1] == 100.0  # no prior: the dense value
    assert v[2] == pytest.approx(15.0) and s_[2] == pytest.approx(100.0 / np.sqrt(2.0))  # median sigma filled in


def test_the_control_distance_is_the_chord_to_the_nearest_point() -> None:
    r = MERCURY.datum_radius_m
    pts = latlon_to_xyz(np.array([0.0, 10.0]), np.array([0.0, 0.0]), height_m=np.array([3000.0, -2000.0]),
                        datum_radius_m=r)
    d = control_distance(pts, np.array([0.0, 4.0, 10.0]), np.array([0.0, 1.0]), r)
    deg = 2 * r * math.sin(math.radians(0.5))  # chord of one degree on the datum
    assert d[0, 0] == pytest.approx(0.0, abs=1e-6) and d[2, 0] == pytest.approx(0.0, abs=1e-6)
    assert d[0, 1] == pytest.approx(deg, rel=1e-9)
    assert d[1, 0] == pytest.approx(2 * r * math.sin(math.radians(2.0)), rel=1e-9)
