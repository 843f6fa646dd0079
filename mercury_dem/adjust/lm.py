"""The package's one Levenberg-Marquardt loop, over an engine that owns the parameters and the data.

The loop decides; the engine computes. :func:`run_levenberg_marquardt` holds the step control (damping
``lambda``, the gain ratio of actual to predicted decrease, ``lambda *= max(1/3, 1 - (2 rho - 1)^3)`` on success
and ``lambda *= nu, nu *= 2`` on a refused step), the rejection rounds (when they start, the limit
``median + k MAD`` over every measure's deletion statistic, the round count, the cycle rule) and convergence.
An :class:`LMEngine` builds and solves the damped normal equations, evaluates the cost, keeps or drops a trial
step and decides, point by point, which measures a limit accepts. Two engines implement it:

* :class:`~mercury_dem.adjust.solver.InMemoryEngine`: a :class:`~mercury_dem.adjust.solver.BlockModel` with all its
  measures in this process (BAL problems, the framing camera of ``bundle_adjust``);
* :class:`~mercury_dem.adjust.blocked.BlockedEngine`: the cameras here, the points in shards of point blocks, in
  process or on Dask workers (only camera-sized sums travel).

So a change of the step control or of the rejection schedule is made once and both adjusters follow
(``tests/adjust/test_blocked.py::test_blocked_equals_the_in_memory_adjuster`` guards that they agree).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.robust import rejection_limit

#: A trial step is taken when its gain ratio (actual over predicted decrease) exceeds this.
MIN_GAIN = 1e-3


@dataclass(frozen=True)
class SolverOptions:
    """Options of the loop and of its engines (``solver`` .. ``held_points``); the typed config maps onto these.

    Importable from :mod:`mercury_dem.adjust.solver` too, where the adjusters take them.
    """

    max_iterations: int = 50
    function_tolerance: float = 1e-6  # relative decrease of the cost (i.e. ~2x that of sigma0)
    step_tolerance: float = 1e-10  # |step| relative to |parameters|
    initial_lambda: float = 1e-4
    loss: str = "none"
    loss_scale: float = 1.0  # whitened units (measure sigmas)
    reject_k: float | None = None  # k of the k x MAD rejection; None: no rejection
    reject_floor: float = 1.0  # never reject below this whitened norm
    reject_settled_fraction: float = 1e-4  # fewer rejection changes than this share of measures count as settled
    reject_max_rounds: int = 8  # rejection rounds after which the rejected set is kept
    reject_after: float = 0.05  # rejection starts once a step lowers the cost by less than this, relative
    min_point_measures: int = 2
    solver: str = "auto"  # auto | direct | pcg
    direct_max_unknowns: int = 30_000
    pcg_tolerance: float = 0.1
    pcg_max_iterations: int = 500
    max_rejected_steps: int = 12
    held_cameras: NDArray[np.bool_] | None = None
    held_points: NDArray[np.bool_] | None = None


class Trial(NamedTuple):
    """One damped trial step, as the engine computed it (the trial state is kept until :meth:`LMEngine.accept`)."""

    predicted: float  # decrease of the damped linear model; <= 0 or NaN: no usable step
    cost: float  # cost at the trial state; NaN when the system could not be solved or the state not evaluated
    step_norm: float  # |step| over every unknown (cameras and points)
    linear_iterations: int  # of the reduced camera system's solver (0 for a direct solve)


class Proposal(NamedTuple):
    """An accepted set proposed under a rejection limit: how many measures change, and a key of the set."""

    changes: int
    key: int  # equal keys: the same accepted set (the loop watches for cycles with it)


class LMEngine(Protocol):
    """What :func:`run_levenberg_marquardt` needs of an adjuster (see the module docstring).

    The state (parameters, accepted measures, robust weights) lives in the engine; the loop only holds scalars.
    A trial that the loop refuses is simply not accepted: the next :meth:`trial` replaces it.
    """

    #: measures in the problem (the share of changes under which a rejection round counts as settled)
    n_measures: int

    def start(self) -> float:
        """The cost at the starting state under the starting accepted set (every measure)."""
        ...

    def linearize(self) -> None:
        """Build the undamped normal equations at the current state (robust weights, priors, held unknowns)."""
        ...

    def trial(self, lam: float) -> Trial:
        """Solve the normal equations damped by ``lam``, step, and evaluate the cost at the trial state."""
        ...

    def accept(self) -> float:
        """Adopt the last trial state; returns the parameter norm at the state before it."""
        ...

    def dof_counts(self) -> tuple[int, int]:
        """(observations, unknowns) at the current accepted set, priors included."""
        ...

    def deletion_norms(self) -> NDArray[np.float64]:
        """Square roots of every measure's deletion statistic at the current state (kept for :meth:`propose`)."""
        ...

    def propose(self, limit: float) -> Proposal:
        """The accepted set that ``limit`` gives under the per-point rules (kept until :meth:`settle`)."""
        ...

    def settle(self, union: bool) -> int:
        """Finalize the proposal (``union``: the cycle rule, keep every measure accepted before or now); changes."""
        ...

    def apply_rejection(self) -> float:
        """Adopt the settled accepted set; the cost at the current state under it."""
        ...

    def n_rejected(self) -> int:
        """Measures currently rejected."""
        ...

    def timings(self) -> dict[str, float]:
        """Seconds of this iteration's parts worth logging beyond the loop's own (may be empty)."""
        ...


@dataclass
class LMOutcome:
    """What the loop found; the adjusted state itself stays in the engine."""

    initial_cost: float
    final_cost: float
    sigma0: float
    dof: int
    iterations: int
    converged: bool
    reason: str
    rejected: int
    log: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0


def convergence_reason(rel_decrease: float, step_norm: float, x_norm: float, opt: SolverOptions) -> str | None:
    """The reason an iteration that changed no rejection has converged, or None.

    Converged when the relative cost decrease of its step is below ``opt.function_tolerance`` or the step is
    below ``opt.step_tolerance`` relative to the parameter norm ``x_norm``.
    """
    if rel_decrease < opt.function_tolerance:
        return f"converged: relative cost decrease {rel_decrease:.2e} < {opt.function_tolerance:g}"
    if step_norm < opt.step_tolerance * (x_norm + opt.step_tolerance):
        return f"converged: step {step_norm:.2e} below tolerance"
    return None


def sigma0_and_dof(cost: float, engine: LMEngine) -> tuple[float, int]:
    """A-posteriori sigma0 ``sqrt(2 cost / dof)`` and the degrees of freedom (at least 1) of ``engine``'s accepted set."""
    n_obs, n_unk = engine.dof_counts()
    dof = max(n_obs - n_unk, 1)
    return float(np.sqrt(2.0 * cost / dof)), dof


def run_levenberg_marquardt(engine: LMEngine, opt: SolverOptions, t0: float | None = None) -> LMOutcome:
    """Minimise ``engine``'s (robust) cost from its current state; the loop of every adjuster.

    Stops with ``"converged: ..."``, ``"iteration limit"`` or ``"no decrease possible ..."`` (no step of
    ``opt.max_rejected_steps`` damped trials lowered the cost; the state is the best found). Never raises for a
    singular or indefinite system: the engine reports such a trial with a NaN cost and it is refused like any
    step that does not decrease the cost. Rejection starts once a step lowers the cost by less than
    ``opt.reject_after`` (relative): before, residuals mostly show the a-priori pointing errors. A round whose
    accepted set was already seen (measures flipping as their points move) keeps every measure accepted in
    either state and ends the rounds. ``t0``: ``time.perf_counter()`` when the caller started (the log's
    ``elapsed``; default now).
    """
    t0 = time.perf_counter() if t0 is None else t0
    cost = engine.start()
    initial_cost = cost
    lam, nu = opt.initial_lambda, 2.0
    log: list[dict[str, Any]] = []
    converged, reason = False, "iteration limit"
    rejecting, seen_sets, rounds, it = False, set(), 0, 0
    rejected = 0  # every measure starts accepted
    rel_decrease = step_norm = x_norm = 0.0
    for it in range(1, opt.max_iterations + 1):
        t_it = time.perf_counter()
        engine.linearize()
        t_lin = time.perf_counter() - t_it
        # -- damped steps until one decreases the cost ------------------------
        accepted_step = False
        lin_iters = 0
        for _ in range(opt.max_rejected_steps):
            tr = engine.trial(lam)
            lin_iters += tr.linear_iterations
            new_cost = tr.cost
            gain = (cost - new_cost) / tr.predicted if tr.predicted > 0 else -1.0
            if np.isfinite(new_cost) and gain > MIN_GAIN:
                step_norm = tr.step_norm
                x_norm = engine.accept()
                rel_decrease = (cost - new_cost) / max(cost, 1e-300)
                cost = new_cost
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                accepted_step = True
                break
            lam *= nu
            nu *= 2.0
        sigma0, _ = sigma0_and_dof(cost, engine)
        entry: dict[str, Any] = {
            "iteration": it, "cost": cost, "sigma0": sigma0, "lambda": lam, "step_accepted": accepted_step,
            "rejected": rejected, "linearize_seconds": t_lin, **engine.timings(),
            "seconds": time.perf_counter() - t_it, "elapsed": time.perf_counter() - t0, "linear_iterations": lin_iters,
        }
        log.append(entry)
        if not accepted_step:
            reason = f"no decrease possible (lambda reached {lam:.3g} after {opt.max_rejected_steps} refused steps)"
            break
        # -- rejection / re-admission between iterations ---------------------
        changed = False
        if opt.reject_k is not None and not rejecting and rel_decrease < opt.reject_after:
            rejecting = True  # the robust solve has settled: residuals now reflect the measures
        if rejecting and rounds >= opt.reject_max_rounds:
            entry["rejection_frozen"] = True  # the rejected set is kept from here on
        elif rejecting and opt.reject_k is not None:
            rounds += 1
            norms = engine.deletion_norms()
            limit = rejection_limit(norms, np.isfinite(norms), opt.reject_k, opt.reject_floor)
            del norms  # 8 bytes a measure
            prop = engine.propose(limit)
            changed = prop.changes > opt.reject_settled_fraction * engine.n_measures
            entry["rejection_changes"] = prop.changes
            union = bool(changed and prop.key in seen_sets)
            n_changed = engine.settle(union)
            if union:
                entry["rejection_cycle"] = True
                rounds = opt.reject_max_rounds
            seen_sets.add(prop.key)
            entry["rejection_limit"] = limit
            if n_changed:
                cost = engine.apply_rejection()
                rejected = engine.n_rejected()
                entry["rejected"] = rejected
        entry["seconds"] = time.perf_counter() - t_it
        if not changed:
            why = convergence_reason(rel_decrease, step_norm, x_norm, opt)
            if why:
                converged, reason = True, why
                break
    sigma0, dof = sigma0_and_dof(cost, engine)
    return LMOutcome(initial_cost=initial_cost, final_cost=cost, sigma0=sigma0, dof=dof, iterations=it,
                     converged=converged, reason=reason, rejected=rejected, log=log, seconds=time.perf_counter() - t0)
