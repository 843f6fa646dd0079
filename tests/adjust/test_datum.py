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
from mercury_dem.adjust.datum import centre_point_priors, neighbour_radii, on_datum, recentre_on_block
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M
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
    problem = dataclasses.replace(net.problem, points=on_datum(net.problem.points, datum_radius_m=DATUM_RADIUS_M))
    cfg = AdjustConfig(radius_sigma_m=10_000.0)
    true_r = np.linalg.norm(net.true_points, axis=1)
    true_h = true_r - DATUM_RADIUS_M

    def height_error(result):
        ok = ~result.underdetermined_points
        e = np.linalg.norm(result.points, axis=1)[ok] - true_r[ok]
        slope = np.polyfit(true_h[ok], e, 1)[0]  # -s: the points keep (1 - s) of their true height
        return slope, float(np.sqrt(np.mean(e**2)))

    datum_slope, datum_rms = height_error(bundle_adjust(problem, cfg))
    recentred, summary = recentre_on_block(problem, cfg, datum_radius_m=DATUM_RADIUS_M)
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


def _cap(rng: np.random.Generator, n: int, radius_deg: float, centre_lat: float = 20.0) -> np.ndarray:
    """Points uniform in area on a spherical cap of angular radius ``radius_deg``, at heights ±1 km."""
    cos_t = 1.0 - rng.random(n) * (1.0 - np.cos(np.radians(radius_deg)))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    s = np.sqrt(1.0 - cos_t**2)
    local = np.c_[s * np.cos(phi), s * np.sin(phi), cos_t]  # around +z
    a = np.radians(90.0 - centre_lat)  # tilt the cap's centre down to centre_lat
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return (local @ rot.T) * (DATUM_RADIUS_M + rng.uniform(-1000.0, 1000.0, n))[:, None]


def test_block_extent_is_the_cap_holding_95_percent_of_the_points() -> None:
    from mercury_dem.adjust.datum import block_extent_deg

    rng = np.random.default_rng(17)
    for radius in (0.5, 3.0, 25.0, 60.0):
        # uniform in area: 95 % of the points lie within the angle a with 1 - cos a = 0.95 (1 - cos radius)
        expect = np.degrees(np.arccos(1.0 - 0.95 * (1.0 - np.cos(np.radians(radius)))))
        got = block_extent_deg(_cap(rng, 20_000, radius))
        assert abs(got / expect - 1.0) < 0.02, (radius, got, expect)
    u = rng.normal(size=(20_000, 3))  # the whole body: hardly a mean direction
    assert block_extent_deg(u) > 120.0
    assert block_extent_deg(np.r_[np.eye(3), -np.eye(3)]) == 180.0
    assert block_extent_deg(np.full((5, 3), np.nan)) == 0.0
    one = _cap(rng, 1, 10.0)
    assert block_extent_deg(np.r_[one, np.full((3, 3), np.nan)]) == 0.0


def test_levelling_decision_follows_the_block_and_its_altimetry() -> None:
    from mercury_dem.adjust.datum import levelling_decision

    rng = np.random.default_rng(23)
    strip, wide = _cap(rng, 3000, 2.0), _cap(rng, 3000, 25.0)
    globe = rng.normal(size=(3000, 3)) * DATUM_RADIUS_M
    # Without altimetry in the adjustment: a strip or stereo pair keeps the datum (it would float), a wide
    # block and the globe are re-centred; nothing held the points, so a registration afterwards levels.
    d = levelling_decision(strip)
    assert not d.recentre and d.level_to_mean and d.altimetry_share == 0.0 and "too small" in d.reason
    for pts in (wide, globe):
        d = levelling_decision(pts)
        assert d.recentre and d.level_to_mean
    # Altimetry holding most points (tiny): neither. Holding a minority (the demo's north): both on a wide
    # block, the level alone on a small one.
    most = rng.random(3000) < 0.8
    few = rng.random(3000) < 0.16
    d = levelling_decision(wide, most)
    assert not d.recentre and not d.level_to_mean and abs(d.altimetry_share - most.mean()) < 1e-12
    assert "altimetry's" in d.reason
    assert levelling_decision(globe, few).recentre and levelling_decision(globe, few).level_to_mean
    d = levelling_decision(strip, few)
    assert not d.recentre and d.level_to_mean
    # The thresholds: 0 extent and share 1 restore "always".
    d = levelling_decision(strip, most, min_extent_deg=0.0, max_altimetry_share=1.0)
    assert d.recentre and d.level_to_mean
    with pytest.raises(ValueError, match="3 values for 3000 points"):
        levelling_decision(wide, most[:3])
    assert d.summary()["extent_deg"] == d.extent_deg


def test_centre_point_priors_moves_free_points_onto_the_datum_and_keeps_held_ones() -> None:
    import dataclasses

    from mercury_dem.adjust.problem import AdjustmentProblem

    rng = np.random.default_rng(11)
    net = make_synthetic_network(300, rng=np.random.default_rng(5))
    problem: AdjustmentProblem = net.problem
    pts = problem.points * (1 + rng.uniform(-1e-3, 1e-3, (problem.n_points, 1)))
    held = np.zeros(problem.n_points, bool)
    held[:5] = True
    problem = dataclasses.replace(problem, points=pts, held_points=held)
    assert centre_point_priors(problem, "triangulated", datum_radius_m=DATUM_RADIUS_M) is problem
    out = centre_point_priors(problem, "datum", DATUM_RADIUS_M)
    r = np.linalg.norm(out.points, axis=1)
    np.testing.assert_allclose(r[~held], DATUM_RADIUS_M, rtol=1e-12)
    np.testing.assert_array_equal(out.points[held], pts[held])
    u_in, u_out = pts / np.linalg.norm(pts, axis=1)[:, None], out.points / r[:, None]
    np.testing.assert_allclose(u_out, u_in, atol=1e-12)  # directions kept


def test_centre_point_priors_on_the_bodys_shape() -> None:
    """'shape': free points move along their directions onto GTMES; held ones stay; no shape: the datum."""
    import dataclasses

    from mercury_dem.reference.body_shape import body_shape

    rng = np.random.default_rng(12)
    net = make_synthetic_network(200, rng=np.random.default_rng(6))
    pts = net.problem.points * (1 + rng.uniform(-1e-3, 1e-3, (net.problem.n_points, 1)))
    held = np.zeros(net.problem.n_points, bool)
    held[:3] = True
    problem = dataclasses.replace(net.problem, points=pts, held_points=held)
    shape = body_shape("MERCURY")
    assert shape is not None
    out = centre_point_priors(problem, "shape", DATUM_RADIUS_M, shape=shape)
    r = np.linalg.norm(out.points, axis=1)
    np.testing.assert_allclose(r[~held], shape.radius_at_xyz(pts)[~held], rtol=1e-12)
    assert np.ptp(r[~held]) > 10.0  # the shape's relief, not a sphere
    np.testing.assert_array_equal(out.points[held], pts[held])
    np.testing.assert_allclose(out.points / r[:, None], pts / np.linalg.norm(pts, axis=1)[:, None], atol=1e-12)
    on_sphere = centre_point_priors(problem, "shape", DATUM_RADIUS_M, shape=None)
    np.testing.assert_allclose(np.linalg.norm(on_sphere.points, axis=1)[~held], DATUM_RADIUS_M, rtol=1e-12)
