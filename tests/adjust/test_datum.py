"""The tie points' radius constraint centred on the block's own surface instead of the datum sphere.

Centred on the datum, a 10 km radius constraint pulls weakly determined points toward the sphere by a
share of their true height (the demo's bent block, issue 21 §5). Re-centring it on the median radius of
the neighbours in a loosely constrained first pass removes that regression and keeps the constraint's
hold on the weak points. Checked on synthetic networks with a known surface (seeds 3 and 11; 3 is the one
looked at first, 11 was run once after the method was fixed).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.datum import neighbour_radii
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.pipeline.adjust_adapter import on_datum, recentre_on_block
from mercury_dem.validate.synthetic_network import make_synthetic_network


def test_neighbour_radii_follow_a_smooth_surface_through_noise_and_gross_points() -> None:
    rng = np.random.default_rng(5)
    u = rng.normal(size=(20_000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    shape = 2000.0 * u[:, 2] ** 2 - 1500.0 * u[:, 0]  # a degree-2 body shape, m
    noise = rng.normal(0.0, 300.0, len(u))
    gross = rng.random(len(u)) < 0.03
    noise[gross] += rng.choice([-1, 1], gross.sum()) * 20_000.0
    xyz = u * (DATUM_RADIUS_M + shape + noise)[:, None]
    r = neighbour_radii(xyz, k=50)
    err = r - DATUM_RADIUS_M - shape
    # The median of 50 values with 300 m noise: ~1.25 · 300 / √50 ≈ 53 m; the shape's change across a
    # neighbourhood (~2° on the unit sphere at this density) adds a few tens of metres; the 3 % of gross
    # points move a median by a few percent of the noise.
    assert np.sqrt(np.mean(err**2)) < 100.0
    assert np.abs(err).max() < 400.0
    # Points that are not usable give no radius to others; non-finite points get NaN, nothing else does.
    xyz_bad = xyz.copy()
    xyz_bad[:10] = np.nan
    usable = ~gross
    r2 = neighbour_radii(xyz_bad, usable, k=50)
    assert np.isnan(r2[:10]).all() and np.isfinite(r2[10:]).all()
    assert np.sqrt(np.mean((r2[10:] - DATUM_RADIUS_M - shape[10:]) ** 2)) < 100.0
    assert np.isnan(neighbour_radii(xyz, np.zeros(len(xyz), bool))).all()


@pytest.mark.parametrize("seed", [3, 11])
def test_recentred_radius_constraint_removes_the_pull_toward_the_datum(seed: int) -> None:
    # Weak heights on purpose: 2-3 views within 5 degrees of nadir, 3 km of relief (waves of 75-750 km).
    net = make_synthetic_network(10_000, rng=np.random.default_rng(seed), relief_m=3000.0, max_emission_deg=5.0,
                                 min_views=2, max_views=3, outlier_fraction=0.0)
    problem = dataclasses.replace(net.problem, points=on_datum(net.problem.points))
    cfg = AdjustConfig(pointing_sigma_deg=float(np.degrees(450e-6)), radius_sigma_m=10_000.0)
    true_r = np.linalg.norm(net.true_points, axis=1)
    true_h = true_r - DATUM_RADIUS_M

    def height_error(result):
        ok = ~result.underdetermined_points
        e = np.linalg.norm(result.points, axis=1)[ok] - true_r[ok]
        slope = np.polyfit(true_h[ok], e, 1)[0]  # -s: the points keep (1 - s) of their true height
        return slope, float(np.sqrt(np.mean(e**2)))

    datum_slope, datum_rms = height_error(bundle_adjust(problem, cfg))
    recentred, summary = recentre_on_block(problem, cfg)
    new_slope, new_rms = height_error(bundle_adjust(recentred, cfg))
    loose_slope, loose_rms = height_error(bundle_adjust(problem, dataclasses.replace(cfg, radius_sigma_m=1e5)))
    # Measured (seeds 3 / 11): slope -0.16 / -0.11 on the datum, -0.01 / 0.00 re-centred; RMS 566 / 671 m on
    # the datum, 386 / 441 m re-centred, 536 / 766 m with the constraint loosened to 100 km.
    assert datum_slope < -0.08
    assert abs(new_slope) < 0.04
    assert new_rms < 0.8 * datum_rms
    assert new_rms < 0.9 * loose_rms
    assert summary["recentred_points"] > 0.9 * len(true_r)
    assert summary["centre_height_m"]["p5"] < -1000 < 1000 < summary["centre_height_m"]["p95"]
