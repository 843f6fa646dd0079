"""BAL reader, camera model and the goal cost on problem-49 (issue #5, section 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mercury_dem.adjust.bal import BalModel, BalProblem, adjust_bal, bal_cost
from mercury_dem.adjust.solver import SolverOptions
from mercury_dem.cli import main
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.io.bal import read_bal


def test_initial_costs_exact(bal_path):
    assert bal_cost(read_bal(bal_path("problem-49-7776-pre.txt"))) == pytest.approx(8.50912460680839605629e05, rel=1e-13)
    assert bal_cost(read_bal(bal_path("dubrovnik-3-7-pre.txt"))) == pytest.approx(2764.219984422157, rel=1e-13)


def test_problem49_reaches_goal_cost(bal_path):
    """Below 1.3409e+04 (scipy's result) within 6 iterations, as Ceres does in 5."""
    _, res = adjust_bal(read_bal(bal_path("problem-49-7776-pre.txt")), SolverOptions(max_iterations=6))
    costs = [e["cost"] for e in res.log]
    assert min(costs) <= 1.3409e04
    assert all(b <= a for a, b in zip(costs, costs[1:]))  # monotone


def _tiny_problem(rng: np.random.Generator) -> BalProblem:
    n_cam, n_pt = 4, 12
    cams = np.zeros((n_cam, 9))
    cams[:, :3] = rng.normal(0, 0.1, (n_cam, 3))
    cams[:, 3:6] = rng.normal(0, 0.5, (n_cam, 3)) + [0, 0, -10]
    cams[:, 6] = 500.0
    cams[:, 7] = 1e-2
    cams[:, 8] = -1e-3
    pts = rng.normal(0, 1, (n_pt, 3))
    ci = np.repeat(np.arange(n_cam), n_pt)
    pi = np.tile(np.arange(n_pt), n_cam)
    return BalProblem(ci, pi, rng.normal(0, 50, (len(ci), 2)), cams, pts)


def test_bal_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    prob = _tiny_problem(rng)
    model = BalModel(prob)
    st = model.initial_state()
    r, jc, jp = model.linearize(st)
    assert np.allclose(r, model.residuals(st))
    for k in range(9):
        d = np.zeros((prob.n_cameras, 9))
        h = 1e-6 * max(1.0, abs(prob.cameras[0, 3 + k - 3]) if k >= 3 else 1.0)
        d[:, k] = h
        zero = np.zeros((prob.n_points, 3))
        num = (model.residuals(model.retract(st, d, zero)) - model.residuals(model.retract(st, -d, zero))) / (2 * h)
        assert np.allclose(num, jc[:, :, k], rtol=1e-5, atol=1e-5 * np.abs(jc[:, :, k]).max()), k
    for k in range(3):
        d = np.zeros((prob.n_points, 3))
        d[:, k] = 1e-6
        zc = np.zeros((prob.n_cameras, 9))
        num = (model.residuals(model.retract(st, zc, d)) - model.residuals(model.retract(st, zc, -d))) / 2e-6
        assert np.allclose(num, jp[:, :, k], rtol=1e-5, atol=1e-6 * np.abs(jp).max())


def test_bal_recovers_noise_free_synthetic_problem():
    """Observations made by the model itself, cameras perturbed: the cost goes to ~0."""
    rng = np.random.default_rng(5)
    prob = _tiny_problem(rng)
    model = BalModel(prob)
    obs = model.residuals(model.initial_state()) + prob.observations  # exact projections
    cams = prob.cameras.copy()
    cams[:, :3] += rng.normal(0, 1e-3, cams[:, :3].shape)
    cams[:, 3:6] += rng.normal(0, 1e-2, (len(cams), 3))
    pert = BalProblem(prob.camera_index, prob.point_index, obs, cams, prob.points + rng.normal(0, 1e-2, prob.points.shape))
    _, res = adjust_bal(pert, SolverOptions(max_iterations=50, function_tolerance=1e-14))
    assert res.initial_cost > 1.0
    assert res.final_cost < 1e-10


def test_read_bal_errors(tmp_path):
    with pytest.raises(AdjustmentError, match="cannot read BAL file"):
        read_bal(tmp_path / "missing.txt")
    bad = tmp_path / "bad.txt"
    bad.write_text("2 1 1\n0 0 1.0 2.0\n")
    with pytest.raises(AdjustmentError, match="malformed"):
        read_bal(bad)
    bad.write_text("1 1 1\n3 0 1.0 2.0\n" + " 0" * 12 + "\n")
    with pytest.raises(AdjustmentError, match="beyond the header"):
        read_bal(bad)


def test_adjust_bal_command_json(capsys, bal_path):
    path = bal_path("dubrovnik-3-7-pre.txt")
    assert main(["adjust-bal", str(path), "--json", "--max-iterations", "50"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["initial_cost"] == pytest.approx(2764.219984422157, rel=1e-12)
    assert rec["final_cost"] < 0.05
    assert rec["solver_seconds"] > 0 and rec["read_seconds"] >= 0


def test_adjust_bal_command_missing_file(capsys):
    assert main(["adjust-bal", "/nonexistent/problem.txt"]) == 2
    assert "cannot read BAL file" in capsys.readouterr().err
