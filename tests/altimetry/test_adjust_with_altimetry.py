"""Altimetry inside the bundle adjustment: the tie points' heights come right at the source."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.altimetry.constraints import AltimetryShotsArrays, bundle_adjust_with_altimetry
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import make_synthetic_network, pointing_errors

DATUM = 2_439_400.0


def _shots_around(net, rng: np.random.Generator) -> AltimetryShotsArrays:
    """Simulated altimetry on the true surface: 8 shots within 700 m around half of the true points, 1 m noise."""
    return AltimetryShotsArrays(*net.altimetry_shots(rng, per_point=8, reach_m=700.0, noise_m=1.0), 1.0)


@pytest.mark.parametrize("seed", [4, 29])
def test_altimetry_constraints_fix_the_heights(seed: int) -> None:
    rng = np.random.default_rng(seed)
    net = make_synthetic_network(12_000, rng=rng, min_views=3, outlier_fraction=0.0, noise_px=0.25,
                                 relief_m=1500.0)
    # As the pipeline does: a-priori points on the datum, held by a loose radius constraint.
    pts = net.problem.points
    problem = dataclasses.replace(net.problem, points=pts / np.linalg.norm(pts, axis=1, keepdims=True) * DATUM)
    cfg = AdjustConfig(radius_sigma_m=10_000.0)
    shots = _shots_around(net, rng)

    def height_error(points):
        ok = np.all(np.isfinite(points), axis=1)
        return np.linalg.norm(points[ok], axis=1) - np.linalg.norm(net.true_points[ok], axis=1)

    plain = bundle_adjust(problem, cfg)
    alt, priors = bundle_adjust_with_altimetry(problem, cfg, shots)  # quadratic surfaces where determined
    flat, flat_priors = bundle_adjust_with_altimetry(problem, cfg, shots, surface="plane")
    e0, e1 = height_error(plain.points), height_error(alt.points)
    c = priors.constrained & np.all(np.isfinite(alt.points), axis=1)
    e1c = np.linalg.norm(alt.points[c], axis=1) - np.linalg.norm(net.true_points[c], axis=1)
    ifov = np.array([net.problem.cameras[k].ifov_rad for k in net.problem.image_camera])
    # Pointing of the images the block determines (>= 30 accepted measures, as tests/adjust/test_accuracy.py):
    # a weak image's few points may sit far from their true place, where the altimetry is another height.
    sel = plain.accepted_per_image >= 30
    p0 = np.linalg.norm(pointing_errors(plain.rotations, net.true_rotations)[0][sel, :2], axis=1) / ifov[sel]
    p1 = np.linalg.norm(pointing_errors(alt.rotations, net.true_rotations)[0][sel, :2], axis=1) / ifov[sel]
    pf = np.linalg.norm(pointing_errors(flat.rotations, net.true_rotations)[0][sel, :2], axis=1) / ifov[sel]
    cf = flat_priors.constrained & np.all(np.isfinite(flat.points), axis=1)
    efc = np.linalg.norm(flat.points[cf], axis=1) - np.linalg.norm(net.true_points[cf], axis=1)
    print(f"seed {seed}: constrained {priors.summary()}; height bias {e0.mean():.1f} -> {e1.mean():.1f} m, "
          f"RMS {np.sqrt(np.mean(e0**2)):.1f} -> {np.sqrt(np.mean(e1**2)):.1f} m (constrained points "
          f"{np.sqrt(np.mean(e1c**2)):.1f} m); pointing RMS "
          f"{np.sqrt(np.mean(p0**2)):.3f} -> {np.sqrt(np.mean(p1**2)):.3f} px")
    assert priors.summary()["constrained_points"] > 0.3 * len(net.true_points)
    assert alt.converged
    # Heights: the bias gone; the constrained points at a few metres (1 m shots on a terrain of 1.5 km
    # relief), every point better on average. The determined images' pointing: seed 4 0.96 -> 0.80 px, seed 29
    # 0.51 -> 0.54 px (its far points' cruder constraints): within 10 %.
    assert abs(e0.mean()) > 10.0 and abs(e1.mean()) < 3.0
    assert np.sqrt(np.mean(e1c**2)) < 4.0
    # The quadratic follows the terrain's curvature where a plane cannot: constrained points' radius RMS with
    # planes 6.0 / 6.0 m (seeds 4 / 29), with quadratics 1.3 / 2.5 m; the pointing no worse (0.806 -> 0.803,
    # 0.551 -> 0.537 px). Same points constrained.
    assert cf.sum() == c.sum()
    assert np.sqrt(np.mean(e1c**2)) < 0.7 * np.sqrt(np.mean(efc**2))
    assert np.sqrt(np.mean(p1**2)) <= np.sqrt(np.mean(pf**2)) * 1.01
    assert np.sqrt(np.mean((e1c / priors.sigma_m[c]) ** 2)) < 1.5  # within the sigmas the constraints claimed
    assert np.sqrt(np.mean(e1**2)) < 0.75 * np.sqrt(np.mean(e0**2))
    assert np.sqrt(np.mean(p1**2)) <= np.sqrt(np.mean(p0**2)) * 1.10


def test_quadratic_surface_follows_a_bowl_and_falls_back_to_the_plane_on_profiles() -> None:
    """A 10 km disc of shots on a bowl (a crater's floor, curvature 1/40 km): the plane's intercept is the
    disc's mean height, 1/2 k R²/2 above the centre; the quadratic's is the centre's, within its noise. Shots
    on two parallel profiles do not determine the curvature across them: the plane (or line) is kept."""
    from mercury_dem.altimetry.constraints import radius_priors_within

    rng = np.random.default_rng(8)
    R, k = 10_000.0, 1.0 / 40_000.0  # r = datum + k/2 (e² + n²): 1.25 km deep at the disc's edge
    point = np.array([[DATUM, 0.0, 0.0]])  # lat 0, lon 0: east = y, north = z
    rho, phi = R * np.sqrt(rng.random(400)), rng.uniform(0, 2 * np.pi, 400)
    e, n = rho * np.cos(phi), rho * np.sin(phi)
    lat, lon = np.degrees(n / DATUM), np.degrees(e / DATUM)
    r = DATUM + 0.5 * k * (e**2 + n**2) + rng.normal(0.0, 1.0, e.size)
    quad = radius_priors_within(point, lat, lon, r, search_radius_m=R)
    plane = radius_priors_within(point, lat, lon, r, search_radius_m=R, surface="plane")
    assert abs(quad.radius_m[0] - DATUM) < 4 * quad.sigma_m[0] and quad.sigma_m[0] < 5.0
    assert abs(plane.radius_m[0] - DATUM - k * R**2 / 4) < 50.0  # the disc's mean: 625 m above the centre
    assert plane.sigma_m[0] > 200.0  # its roughness says the plane does not fit
    # two profiles 3 km apart, running north
    n2 = np.tile(np.linspace(-9000.0, 9000.0, 40), 2)
    e2 = np.repeat([-1500.0, 1500.0], 40)
    r2 = DATUM + 0.5 * k * (e2**2 + n2**2)
    lat2, lon2 = np.degrees(n2 / DATUM), np.degrees(e2 / DATUM)
    q2 = radius_priors_within(point, lat2, lon2, r2, search_radius_m=R)
    p2 = radius_priors_within(point, lat2, lon2, r2, search_radius_m=R, surface="plane")
    assert q2.radius_m[0] == p2.radius_m[0] and q2.sigma_m[0] == p2.sigma_m[0]
    with pytest.raises(ValueError, match="surface"):
        radius_priors_within(point, lat, lon, r, search_radius_m=R, surface="cubic")
