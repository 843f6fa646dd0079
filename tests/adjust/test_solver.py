"""The Schur-complement core: exact algebra, solver agreement, held unknowns, failure handling."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.adjust.bundle import bundle_adjust, make_model, solver_options
from mercury_dem.adjust.kernels import normal_blocks
from mercury_dem.adjust.robust import loss_rho, rejection_limit
from mercury_dem.adjust.schur import HAVE_CHOLMOD, ReducedSolver, SchurStructure, inv3
from mercury_dem.adjust.solver import SolverOptions, levenberg_marquardt
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import make_synthetic_network


def test_inv3_matches_numpy():
    a = np.random.default_rng(0).normal(size=(50, 3, 3)) + 3 * np.eye(3)
    np.testing.assert_allclose(inv3(a), np.linalg.inv(a), rtol=1e-10, atol=1e-12)


def test_schur_complement_equals_dense_algebra():
    """S = U - W V^-1 W^T assembled block-sparse equals the dense computation, including a point
    measured twice in one image (both orders of the pair must be summed)."""
    rng = np.random.default_rng(1)
    n_cam, n_pt, c = 5, 9, 4
    cam = np.concatenate([rng.integers(0, n_cam, 30), [2, 2]])
    pt = np.concatenate([rng.integers(0, n_pt, 30), [4, 4]])
    m = len(cam)
    jc, jp, r = rng.normal(size=(m, 2, c)), rng.normal(size=(m, 2, 3)), rng.normal(size=(m, 2))
    u, g_c = np.zeros((n_cam, c, c)), np.zeros((n_cam, c))
    v, g_p = np.zeros((n_pt, 3, 3)), np.zeros((n_pt, 3))
    w = np.empty((m, c, 3))
    normal_blocks(r, jc, jp, cam, pt, u, g_c, v, g_p, w)
    u += np.eye(c)
    v += np.eye(3)
    st = SchurStructure.build(cam, pt, n_cam, n_pt, c)
    s_sparse = st.to_bsr(st.schur_blocks(w, inv3(v), u)).toarray()
    # dense
    big = np.zeros((2 * m, c * n_cam + 3 * n_pt))
    for k in range(m):
        big[2 * k : 2 * k + 2, c * cam[k] : c * cam[k] + c] = jc[k]
        big[2 * k : 2 * k + 2, c * n_cam + 3 * pt[k] : c * n_cam + 3 * pt[k] + 3] = jp[k]
    h = big.T @ big + np.eye(big.shape[1])
    ncc = c * n_cam
    s_dense = h[:ncc, :ncc] - h[:ncc, ncc:] @ np.linalg.solve(h[ncc:, ncc:], h[ncc:, :ncc])
    np.testing.assert_allclose(s_sparse, s_dense, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(g_c.ravel(), (big.T @ r.ravel())[:ncc])


@pytest.fixture(scope="module")
def clean_network():
    return make_synthetic_network(8000, rng=np.random.default_rng(3), min_views=3, outlier_fraction=0.0)


def test_linear_solvers_agree(clean_network):
    """dense LAPACK, CHOLMOD, SuperLU and PCG reach the same minimum."""
    prob = clean_network.problem
    base = dict(reject_outliers=False, robust_loss="none",
                sigma0_tolerance=1e-9)
    results = {}
    methods = ["dense", "splu", "pcg"] + (["cholmod"] if HAVE_CHOLMOD else [])
    for method in methods:
        cfg = AdjustConfig(**base, solver="pcg" if method == "pcg" else "direct", pcg_tolerance=1e-6)
        model = make_model(prob, cfg)
        opt = solver_options(prob, cfg, prob.held_images)
        import mercury_dem.adjust.solver as solver_mod

        original = solver_mod.choose_method
        solver_mod.choose_method = lambda *_a, _m=method: _m  # force the method
        try:
            res = levenberg_marquardt(model, model.initial_state(), opt)
        finally:
            solver_mod.choose_method = original
        assert res.linear_method == method
        results[method] = res
    ref = results["dense"]
    for method, res in results.items():
        assert res.final_cost == pytest.approx(ref.final_cost, rel=1e-6), method
        np.testing.assert_allclose(res.state.omega, ref.state.omega, atol=2e-8)


def test_held_images_and_points_do_not_move(clean_network):
    prob = clean_network.problem
    cfg = AdjustConfig(held_images=(prob.image_ids[0], prob.image_ids[3]),
                       solve_positions=True)
    held_pts = np.zeros(prob.n_points, bool)
    held_pts[:10] = True
    from dataclasses import replace

    res = bundle_adjust(replace(prob, held_points=held_pts), cfg)
    assert np.all(res.pointing_corrections[[0, 3]] == 0.0)
    assert np.all(res.position_corrections[[0, 3]] == 0.0)
    np.testing.assert_array_equal(res.points[:10], prob.points[:10])
    assert np.abs(res.pointing_corrections[1:3]).max() > 0
    assert res.converged


def test_step_never_accepted_keeps_the_start_and_says_why(clean_network):
    """A model whose every trial step fails (NaN) stops with the best (initial) state and the reason."""
    prob = clean_network.problem
    cfg = AdjustConfig()
    model = make_model(prob, cfg)
    start = model.initial_state()
    real = model.residuals

    def residuals(state):
        r = real(state)
        return r if state is start else np.full_like(r, np.nan)

    model.residuals = residuals  # type: ignore[method-assign]
    res = levenberg_marquardt(model, start, SolverOptions(max_iterations=5, max_rejected_steps=4))
    assert res.state is start
    assert not res.converged and res.reason.startswith("no decrease possible")
    assert res.final_cost == res.initial_cost


def test_robust_losses():
    s = np.array([0.0, 0.25, 1.0, 4.0, 100.0])
    rho, w = loss_rho(s, "huber", 1.0)
    np.testing.assert_allclose(rho, [0, 0.25, 1.0, 3.0, 19.0])
    np.testing.assert_allclose(w, [1, 1, 1, 0.5, 0.1])
    rho, w = loss_rho(s, "cauchy", 1.0)
    np.testing.assert_allclose(w, 1 / (1 + s))
    np.testing.assert_allclose(rho, np.log1p(s))
    with pytest.raises(ValueError, match="unknown robust loss"):
        loss_rho(s, "tukey", 1.0)


def test_rejection_limit_is_median_plus_k_mad():
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    # median 3, MAD 1 -> 3 + 3 * 1.4826
    assert rejection_limit(x, np.ones(5, bool), 3.0, 0.0) == pytest.approx(3 + 3 * 1.4826)
    assert rejection_limit(x, np.ones(5, bool), 3.0, 50.0) == 50.0


def test_reduced_solver_reports_indefinite_systems():
    import scipy.sparse as sp

    a = sp.bsr_matrix(-np.eye(6), blocksize=(3, 3))
    for method in ["dense"] + (["cholmod"] if HAVE_CHOLMOD else []):
        x, info = ReducedSolver(method, 3).solve(a, -np.broadcast_to(np.eye(3), (2, 3, 3)), np.ones(6))
        assert not info.ok and np.all(np.isnan(x))
