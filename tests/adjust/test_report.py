"""Reports, tables, a-posteriori sigmas and the network adapter."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.network import network_with_result, problem_from_network
from mercury_dem.adjust.report import images_table, points_table, residuals_table, text_report
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.adjustment_report import write_adjustment_report
from mercury_dem.network.model import ControlNetwork, PointType
from mercury_dem.validate.synthetic_network import make_synthetic_network


def test_tables_and_text_report(accuracy_result, tmp_path):
    res = accuracy_result
    img, pts, resid = images_table(res), points_table(res), residuals_table(res)
    assert len(img) == len(res.image_ids) and len(pts) == len(res.point_ids) and len(resid) == res.n_measures
    assert resid["rejected"].sum() == res.n_rejected
    assert np.allclose(pts["radius_m"], np.linalg.norm(res.points, axis=1))
    text = text_report(res)
    for key in ("sigma0", "ITERATIONS", "RMS residual", "rejected measures", "WORST IMAGES"):
        assert key in text
    assert len([ln for ln in text.splitlines() if ln.strip()[:4].strip().isdigit()]) >= res.iterations
    paths = write_adjustment_report(res, tmp_path / "adjust")
    assert pd.read_csv(paths["images"]).shape[0] == len(res.image_ids)
    summary = json.loads(paths["summary"].read_text())
    assert summary["rejected"] == res.n_rejected and len(summary["sigma0_per_iteration"]) == res.iterations
    assert not list((tmp_path / "adjust").glob(".*tmp*"))


def test_posterior_sigmas_match_actual_errors():
    """A-posteriori point sigmas agree with the actual point errors (chi-like ratio between 0.5 and 2).

    The measure sigma is set to the injected noise: the covariance is scaled by
    sigma0^2, which is right only when measures and priors are mis-weighted by
    the same factor (with a 1 px sigma for 0.25 px noise the prior-dominated
    directions come out 2x too optimistic, as jigsaw's would).
    """
    net = make_synthetic_network(6000, rng=np.random.default_rng(9), min_views=3, outlier_fraction=0.0,
                                 measure_sigma_px=0.25)
    cfg = AdjustConfig(posterior_sigmas=True, reject_outliers=False,
                       robust_loss="none")
    res = bundle_adjust(net.problem, cfg)
    assert res.point_sigmas is not None and res.image_sigmas is not None and res.posterior_seconds > 0
    ok = ~res.underdetermined_points
    err = res.points[ok] - net.true_points[ok]
    ratio = np.sqrt(np.mean(np.sum(err**2, axis=1) / np.sum(res.point_sigmas[ok] ** 2, axis=1)))
    print(f"point error / a-posteriori sigma RMS ratio {ratio:.2f}; median sigma {np.median(res.point_sigmas[ok], axis=0)} m")
    assert 0.5 < ratio < 2.0


def test_problem_from_network_round_trip(small_network):
    p = small_network.problem
    m = p.n_measures
    sigma = np.full((m, 2), 0.5)
    sigma[0] = np.nan  # unknown -> default
    ignored = np.zeros(m, bool)
    ignored[1] = True
    ptype = np.full(p.n_points, PointType.FREE, np.int8)
    ptype[2] = PointType.FIXED
    net = ControlNetwork.from_arrays(
        np.array(p.image_ids), np.arange(p.n_points, dtype=np.int64) + 1000, p.measure_point, p.measure_image,
        p.measures[:, 0], p.measures[:, 1], apriori_xyz=p.points, sigma=sigma, measure_ignored=ignored, point_type=ptype)
    cams = [p.cameras[k] for k in p.image_camera]
    prob, idx = problem_from_network(net, cams, p.positions, p.rotations, pointing_sigma_urad=450.0)
    assert prob.n_measures == m - 1 and 1 not in idx
    assert prob.measure_sigma[0] == 1.0 and np.all(prob.measure_sigma[1:] == 0.5)
    assert prob.held_points[2] and prob.held_points.sum() == 1
    assert len(prob.cameras) == len(set(cams))
    assert prob.point_ids[0] == 1000
    res = bundle_adjust(prob, AdjustConfig(max_iterations=3))
    out = network_with_result(net, res, idx)
    assert np.isnan(out.residuals[1]).all() and np.isfinite(out.residuals[idx]).all()
    np.testing.assert_array_equal(out.adjusted_xyz, res.points)
    np.testing.assert_array_equal(out.residuals[idx], -res.residuals_px)  # measured - computed
