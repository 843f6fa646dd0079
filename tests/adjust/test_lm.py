"""The one Levenberg-Marquardt loop (``adjust/lm.py``) over engines written here: a linear least-squares problem
with known truth, and scripted engines for the refused-step and rejection-cycle rules.
"""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.adjust.lm import LMEngine, Proposal, SolverOptions, Trial, run_levenberg_marquardt


class LinearEngine:
    """``r = A x - y``, cost ``0.5 |r|^2``; the damped normal equations solved densely (no rejection)."""

    def __init__(self, a: np.ndarray, y: np.ndarray):
        self.a, self.y = a, y
        self.x = np.zeros(a.shape[1])
        self.n_measures = len(y)

    def _cost(self, x: np.ndarray) -> float:
        r = self.a @ x - self.y
        return 0.5 * float(r @ r)

    def start(self) -> float:
        return self._cost(self.x)

    def linearize(self) -> None:
        self.n = self.a.T @ self.a
        self.g = self.a.T @ (self.a @ self.x - self.y)
        self.d = np.clip(np.diag(self.n), 1e-6, 1e32)

    def trial(self, lam: float) -> Trial:
        dx = np.linalg.solve(self.n + lam * np.diag(self.d), -self.g)
        self._next = self.x + dx
        pred = 0.5 * (lam * float(dx @ (self.d * dx)) - float(self.g @ dx))
        return Trial(pred, self._cost(self._next), float(np.linalg.norm(dx)), 0)

    def accept(self) -> float:
        before = float(np.linalg.norm(self.x))
        self.x = self._next
        return before

    def dof_counts(self) -> tuple[int, int]:
        return self.n_measures, self.a.shape[1]

    def deletion_norms(self) -> np.ndarray:
        raise AssertionError("no rejection asked")

    def propose(self, limit: float) -> Proposal:
        raise AssertionError("no rejection asked")

    def settle(self, union: bool) -> int:
        raise AssertionError("no rejection asked")

    def apply_rejection(self) -> float:
        raise AssertionError("no rejection asked")

    def n_rejected(self) -> int:
        return 0

    def timings(self) -> dict[str, float]:
        return {}


def test_the_loop_recovers_a_linear_least_squares_truth() -> None:
    """200 observations of 4 unknowns with 0.01 noise: the least-squares solution (to 1e-9) and the truth within
    4 standard errors; sigma0 the injected noise to 15 %.
    """
    rng = np.random.default_rng(32)
    a = rng.normal(size=(200, 4))
    x_true = np.array([1.0, -2.0, 0.5, 3.0])
    noise = 0.01
    y = a @ x_true + rng.normal(0.0, noise, 200)
    eng = LinearEngine(a, y)
    engine: LMEngine = eng
    out = run_levenberg_marquardt(engine, SolverOptions(max_iterations=20, function_tolerance=1e-12))
    assert out.converged and out.reason.startswith("converged")
    x_ls = np.linalg.lstsq(a, y, rcond=None)[0]
    assert np.abs(eng.x - x_ls).max() < 1e-9
    se = noise * np.sqrt(np.diag(np.linalg.inv(a.T @ a)))
    assert np.all(np.abs(eng.x - x_true) < 4 * se)
    assert out.sigma0 == pytest.approx(noise, rel=0.15)
    assert out.dof == 196 and out.rejected == 0
    costs = [e["cost"] for e in out.log]
    assert all(b <= a_ for a_, b in zip(costs, costs[1:]))


class Scripted:
    """An engine whose every trial lowers the cost by a tiny fixed share and whose rejection rounds propose the
    accepted-set keys given (10 changes of 100 measures each: never settled).
    """

    def __init__(self, keys: list[int], refuse: bool = False):
        self.keys, self.refuse = list(keys), refuse
        self.n_measures = 100
        self.cost = 1000.0
        self.settled: list[bool] = []
        self.applied = 0

    def start(self) -> float:
        return self.cost

    def linearize(self) -> None:
        pass

    def trial(self, lam: float) -> Trial:
        if self.refuse:
            return Trial(1.0, float("nan"), float("nan"), 0)
        return Trial(1e-3 * self.cost, 0.999 * self.cost, 1.0, 0)

    def accept(self) -> float:
        self.cost *= 0.999
        return 10.0

    def dof_counts(self) -> tuple[int, int]:
        return 200, 10

    def deletion_norms(self) -> np.ndarray:
        return np.linspace(0.0, 3.0, self.n_measures)

    def propose(self, limit: float) -> Proposal:
        return Proposal(10, self.keys.pop(0))

    def settle(self, union: bool) -> int:
        self.settled.append(union)
        return 10

    def apply_rejection(self) -> float:
        self.applied += 1
        self.cost *= 0.5  # fewer measures in use
        return self.cost

    def n_rejected(self) -> int:
        return 10 * self.applied

    def timings(self) -> dict[str, float]:
        return {"extra_seconds": 0.0}


def test_a_cycling_rejected_set_is_settled_by_the_union_and_the_rounds_end() -> None:
    """Keys A, B, A: the third round sees A again, settles with the union (the cycle rule) and freezes the set."""
    eng = Scripted([7, 8, 7])
    opt = SolverOptions(max_iterations=6, function_tolerance=0.0, step_tolerance=0.0, reject_k=3.0)
    out = run_levenberg_marquardt(eng, opt)
    assert eng.settled == [False, False, True]
    assert [e.get("rejection_cycle", False) for e in out.log[:3]] == [False, False, True]
    assert all(e.get("rejection_frozen") for e in out.log[3:]) and len(out.log) == 6
    assert out.reason == "iteration limit" and not out.converged
    assert out.rejected == 30 and out.log[2]["rejected"] == 30
    # the next step starts from the engine's cost under the new set (the entry keeps the step's cost)
    assert out.log[0]["cost"] == pytest.approx(1000.0 * 0.999)
    assert out.log[1]["cost"] == pytest.approx(1000.0 * 0.999 * 0.5 * 0.999)
    assert "extra_seconds" in out.log[0]


def test_refused_steps_raise_lambda_and_stop_the_loop() -> None:
    """Every trial refused: lambda grows by nu = 2, 4, 8, ... and the loop stops at the first iteration."""
    eng = Scripted([], refuse=True)
    opt = SolverOptions(max_iterations=5, initial_lambda=1e-4, max_rejected_steps=12)
    out = run_levenberg_marquardt(eng, opt)
    assert out.iterations == 1 and not out.converged and out.reason.startswith("no decrease possible")
    assert out.log[0]["lambda"] == pytest.approx(1e-4 * 2.0 ** sum(range(1, 13)))
    assert out.final_cost == out.initial_cost == 1000.0
