"""Recovery of a synthetic truth (issue #5, section 5)."""

from __future__ import annotations

import numpy as np

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import pointing_errors


def _ifov(problem):
    return np.array([problem.cameras[k].ifov_rad for k in problem.image_camera])


def test_pointing_recovered_to_half_ifov(accuracy_network, accuracy_result):
    """Boresight pointing (the rotation about the camera X and Y axes) within 0.5 IFOV RMS for images
    with >= 30 accepted measures.

    Checked on the raw error (no common rotation removed): with positions known,
    the block's datum is fixed well enough here that removing the common rotation
    (an unweighted mean over all images, weak ones included) changes the figure by
    < 0.1 IFOV (both printed). The figure over all images is printed and bounded
    loosely (images with few measures are weakly determined). The twist about the
    boresight moves pixels by angle x distance from the centre (< 362 px), so it is
    ~100x less observable than the boresight; it is reported, not bounded to 0.5 IFOV.
    """
    net, res = accuracy_network, accuracy_result
    raw, common, rel = pointing_errors(res.rotations, net.true_rotations)
    ifov = _ifov(net.problem)
    sel = res.accepted_per_image >= 30
    assert sel.sum() >= 50
    boresight = np.linalg.norm(raw[:, :2], axis=1) / ifov
    boresight_rel = np.linalg.norm(rel[:, :2], axis=1) / ifov
    apriori = np.linalg.norm(net.pointing_error[:, :2], axis=1) / ifov
    rms = float(np.sqrt(np.mean(boresight[sel] ** 2)))
    print(f"boresight RMS (>=30 measures) {rms:.3f} IFOV raw, {np.sqrt(np.mean(boresight_rel[sel]**2)):.3f} after "
          f"removing the common rotation; all images {np.sqrt(np.mean(boresight**2)):.3f}; a-priori "
          f"{np.sqrt(np.mean(apriori[sel]**2)):.2f}; twist RMS {np.sqrt(np.mean((raw[sel, 2] / ifov[sel])**2)):.2f} IFOV")
    assert rms <= 0.5
    assert np.sqrt(np.mean(boresight**2)) <= 1.0
    assert np.sqrt(np.mean(apriori[sel] ** 2)) > 5.0  # the a-priori error was real


def test_residuals_and_sigma0(accuracy_result):
    res = accuracy_result
    assert res.converged, res.reason
    assert res.rms_px <= 0.5
    # sigma0 estimates the injected noise (0.25 px) given the assumed 1 px sigma
    assert 0.2 < res.sigma0 < 0.32
    assert res.initial_rms_px > 3.0


def test_outliers_rejected(accuracy_network, accuracy_result):
    """>= 99 % of injected outliers rejected and <= 1 % of good measures (on this seed; over
    several seeds in test_outliers.py)."""
    out, rej = accuracy_network.outlier, accuracy_result.rejected
    frac_out = rej[out].mean()
    frac_good = rej[~out].mean()
    print(f"outliers rejected {frac_out:.4f} ({out.sum()}), good rejected {frac_good:.4f}")
    assert frac_out >= 0.99
    assert frac_good <= 0.01


def test_point_errors_in_metres(accuracy_network, accuracy_result):
    """Point errors against truth, in metres: a-priori errors (hundreds of m) shrink to tens."""
    res, net = accuracy_result, accuracy_network
    ok = ~res.underdetermined_points
    err = np.linalg.norm(res.points - net.true_points, axis=1)[ok]
    err0 = np.linalg.norm(net.problem.points - net.true_points, axis=1)[ok]
    print(f"point error median {np.median(err):.1f} m, 90 % {np.percentile(err, 90):.1f} m "
          f"(a-priori {np.median(err0):.1f} m, {np.percentile(err0, 90):.1f} m)")
    assert np.median(err) < 0.25 * np.median(err0)


def test_noise_free_network_fits_exactly(small_network):
    """Without noise or outliers the adjustment reaches a zero-residual minimum.

    On this small block (20 images over a few hundred km, no ground control,
    positions known) the pointing is NOT recovered to the truth: pointing and
    points trade off along weak directions of the block (5 IFOV / 200 m here,
    with residuals of 0.03 px), which the pointing prior pins near the a-priori
    mean. Larger blocks average this out (test_pointing_recovered_to_half_ifov);
    docs/design/adjust.md discusses the datum.
    """
    net = small_network
    cfg = AdjustConfig(radius_sigma_m=None, reject_outliers=False,
                       robust_loss="none", sigma0_tolerance=1e-10)
    res = bundle_adjust(net.problem, cfg)
    raw, _, _ = pointing_errors(res.rotations, net.true_rotations)
    ifov = _ifov(net.problem)
    assert res.initial_rms_px > 3.0
    assert res.rms_px < 0.05
    after = np.sqrt(np.mean((np.linalg.norm(raw[:, :2], axis=1) / ifov) ** 2))
    before = np.sqrt(np.mean((np.linalg.norm(net.pointing_error[:, :2], axis=1) / ifov) ** 2))
    assert after < 0.6 * before
