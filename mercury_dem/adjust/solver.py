"""Levenberg-Marquardt over camera blocks and points, with the Schur complement.

The core knows nothing about cameras: a :class:`BlockModel` gives whitened
residuals (M, 2) of its measures and their Jacobian blocks with respect to the
measure's camera block (M, 2, c) and point (M, 2, 3), optional prior
pseudo-observations on cameras and points, and a ``retract`` that applies a step
(so rotations can be updated multiplicatively). :class:`InMemoryEngine` builds and
solves its normal equations for the package's one loop
(:func:`~mercury_dem.adjust.lm.run_levenberg_marquardt`, shared with the blocked
adjuster), so the same code runs the BAL problems (:mod:`mercury_dem.adjust.bal`)
and the planetary framing camera (:mod:`mercury_dem.adjust.framing`).

The step control (in :mod:`~mercury_dem.adjust.lm`) is the classical one (Nielsen; also Ceres'): damping
``lambda * clip(diag(J^T J), 1e-6, 1e32)`` on both camera and point blocks,
gain ratio of actual to predicted decrease, ``lambda *= max(1/3, 1 - (2 rho - 1)^3)``
on success and ``lambda *= nu, nu *= 2`` on failure. Robust losses enter by
iterative reweighting. Between iterations each measure is tested against the
other measures of its point (:func:`deletion_statistic`, the drop of the point's
least-squares cost when the measure is left out and the point refitted); those
beyond ``median + k MAD`` of the statistic's square roots are rejected (weight
zero) and rejected ones that come back well within the limit are re-admitted, one
measure per point and round either way, a point whose inconsistency two measures
explain equally losing both (:func:`proposed_accepted`, the rules every engine
applies per point). Rejection starts only once the
robust solve has settled (a step lowering the cost by less than ``reject_after``):
at the a-priori state the residuals mostly show pointing errors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from mercury_dem.adjust.kernels import normal_blocks, point_rhs, prior_blocks, reduced_rhs
from mercury_dem.adjust.lm import Proposal, Trial, run_levenberg_marquardt
from mercury_dem.adjust.lm import SolverOptions as SolverOptions  # re-exported: part of this module's API
from mercury_dem.adjust.problem import IndexArray
from mercury_dem.adjust.robust import loss_rho
from mercury_dem.adjust.schur import ReducedSolver, SchurStructure, choose_method, inv3

Prior = tuple[NDArray[np.float64], NDArray[np.float64]]

#: A rejected measure is re-admitted only below this fraction of the rejection limit.
READMIT_FRACTION = 0.8

#: Directions of a measure whose redundancy with respect to its point (eigenvalue of
#: ``I - H``) is below this are not tested (see :func:`deletion_statistic`). Small on
#: purpose: a NAC measure next to WAC ones has a redundancy of ~(10 m / 170 m)^2 = 0.003
#: and a gross error there is still worth testing.
MIN_REDUNDANCY = 1e-4


class BlockModel(Protocol):
    """What the solver needs from a camera model (see module docstring)."""

    camera_dim: int
    n_cameras: int
    n_points: int

    @property
    def camera_index(self) -> IndexArray:
        """Camera of each measure (M,)."""

    @property
    def point_index(self) -> IndexArray:
        """Point of each measure (M,)."""

    def residuals(self, state: Any) -> NDArray[np.float64]:
        """Whitened residuals (M, 2) (NaN where a point cannot be projected)."""

    def linearize(self, state: Any) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Residuals (M, 2), d r / d camera (M, 2, c), d r / d point (M, 2, 3)."""

    def camera_prior(self, state: Any) -> Prior | None:
        """Whitened prior residuals (n_cam, k) and Jacobians (n_cam, k, c), or None."""

    def point_prior(self, state: Any) -> Prior | None:
        """Whitened prior residuals (n_pt, k) and Jacobians (n_pt, k, 3), or None."""

    def retract(self, state: Any, d_camera: NDArray[np.float64], d_point: NDArray[np.float64]) -> Any:
        """The state moved by camera steps (n_cam, c) and point steps (n_pt, 3)."""


@dataclass
class SolverResult:
    """Outcome of :func:`levenberg_marquardt`."""

    state: Any
    initial_cost: float
    final_cost: float
    sigma0: float
    iterations: int
    converged: bool
    reason: str
    accepted: NDArray[np.bool_]  # (M,) measures accepted (not rejected) at the end
    frozen_points: NDArray[np.bool_]  # (n_pt,) points with too few accepted measures (not adjusted)
    residuals: NDArray[np.float64]  # (M, 2) whitened residuals at the final state
    log: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0
    linear_method: str = ""
    dof: int = 0


def _prior_cost(p: Prior | None) -> float:
    return 0.0 if p is None else 0.5 * float(np.sum(p[0] ** 2))


def _cost(model: BlockModel, state: Any, use: NDArray[np.bool_], opt: SolverOptions) -> tuple[float, NDArray[np.float64]]:
    """Cost 0.5 sum rho(|r|^2) over the measures in use, plus the priors; and the residuals."""
    r = model.residuals(state)
    s = np.sum(r * r, axis=1)
    rho, _ = loss_rho(np.where(use, s, 0.0), opt.loss, opt.loss_scale)
    c = 0.5 * float(np.sum(rho[use])) + _prior_cost(model.camera_prior(state)) + _prior_cost(model.point_prior(state))
    if np.any(~np.isfinite(s[use])):
        c = float("nan")
    return c, r


def _sum_by_point(x: NDArray[np.float64], pt: IndexArray, sel: NDArray[np.bool_], n_pt: int) -> NDArray[np.float64]:
    """Sums over each point's selected measures of ``x`` (M, ...) -> (n_pt, ...), by ``bincount`` per component."""
    flat = x.reshape(len(x), -1)
    out = np.empty((n_pt, flat.shape[1]))
    for k in range(flat.shape[1]):  # loop over the (<= 9) components, not over measures
        out[:, k] = np.bincount(pt[sel], weights=flat[sel, k], minlength=n_pt)
    return out.reshape((n_pt,) + x.shape[1:])


def deletion_statistic(
    r: NDArray[np.float64],
    jp: NDArray[np.float64],
    pt: IndexArray,
    member: NDArray[np.bool_],
    fixed: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How much each measure disagrees with the other measures of its point.

    For a point whose ``member`` measures are ``S``, with whitened residuals
    ``r`` (M, 2) and Jacobians ``Jp`` (M, 2, 3), the point's cost after its best
    linearized correction is ``SSR(S) = a - g^T V^-1 g`` (``a = sum |r|^2``,
    ``g = sum Jp^T r``, ``V = sum Jp^T Jp``). The statistic of a member ``i`` is the
    drop ``SSR(S) - SSR(S - i)`` when it is left out, computed as
    ``e_i^T (I - H_ii)^-1 e_i`` with ``e_i = r_i - Jp_i V^-1 g`` (its residual once
    the point is refitted) and ``H_ii = Jp_i V^-1 Jp_i^T`` (2 x 2, its leverage on
    the point); for a non-member it is the rise ``SSR(S + i) - SSR(S)``, i.e.
    ``e_i^T (I + H_ii)^-1 e_i``. Free of error it is ``chi^2`` with 2 degrees of
    freedom (1 on a 2-ray point) in units of the measure variance, and a measure
    with a gross error gets the largest value of its point wherever the point
    currently is, because the point is refitted without it. Residual norms, even
    standardized by a scalar redundancy ``|r| / sqrt(1 - trace(H) / 2)``, get this
    wrong: an outlier in the finest image of a point drags the point onto itself,
    its own residual is small and the good measures' are large, so a good
    measure was rejected and the outlier stayed (the misses measured before).

    Directions of ``I - H`` with a redundancy below :data:`MIN_REDUNDANCY` are
    not tested (nothing checks a measure along them: a 2-ray point's epipolar
    line, a lone measure). The point's a-priori constraint is left out on
    purpose: on 2-ray points with nearly parallel rays it is what fixes the
    depth, and releasing its tension when a measure is deleted showed up as a
    heavy tail of false alarms (4 % of the good 2-ray measures rejected).
    Least-squares, not robust, normal blocks: the Huber weights of the very
    measures being tested would bias the test. The cameras' share of the
    redundancy is neglected (an image has tens to hundreds of measures).
    Points in ``fixed`` (held) do not move: their statistic is ``|r_i|^2``.

    Returns
    -------
    delta : (M,) the statistic, whitened units squared
    ssr : (n_pt,) ``SSR`` of each point's members
    """
    n_pt = len(fixed)
    ok = member & np.all(np.isfinite(r), axis=1)
    jt = jp.transpose(0, 2, 1)
    v = _sum_by_point(np.matmul(jt, jp), pt, ok, n_pt)
    g = _sum_by_point(np.matmul(jt, r[:, :, None])[:, :, 0], pt, ok, n_pt)
    a = np.bincount(pt[ok], weights=np.sum(r[ok] ** 2, axis=1), minlength=n_pt)
    # A point with a single member has a singular V (nothing fixes it along the ray): a
    # tiny ridge makes the algebra go through and leaves those directions untested.
    tr = np.trace(v, axis1=1, axis2=2)
    v[:, range(3), range(3)] += 1e-9 * tr[:, None]
    untestable = fixed | (tr <= 0.0)
    v[untestable] = np.eye(3)
    g[untestable] = 0.0
    v_inv = inv3(v)
    x = np.matmul(v_inv, g[:, :, None])[:, :, 0]
    e = r - np.matmul(jp, x[pt][:, :, None])[:, :, 0]
    h = np.matmul(np.matmul(jp, v_inv[pt]), jt)  # (M, 2, 2)
    h[fixed[pt]] = 0.0
    sign = np.where(member, -1.0, 1.0)
    a00, a11, a01 = 1.0 + sign * h[:, 0, 0], 1.0 + sign * h[:, 1, 1], sign * h[:, 0, 1]
    # e^T A^-1 e over the eigenvectors of the symmetric 2 x 2 A (principal-axis angle)
    mid = 0.5 * (a00 + a11)
    rad = np.hypot(0.5 * (a00 - a11), a01)
    theta = 0.5 * np.arctan2(2.0 * a01, a00 - a11)
    c, s = np.cos(theta), np.sin(theta)
    delta = np.zeros(len(e))
    for lam, proj in ((mid + rad, c * e[:, 0] + s * e[:, 1]), (mid - rad, -s * e[:, 0] + c * e[:, 1])):
        tested = lam > MIN_REDUNDANCY
        delta += np.where(tested, proj * proj / np.where(tested, lam, 1.0), 0.0)
    ssr = np.maximum(a - np.sum(g * x, axis=1), 0.0)
    return delta, ssr


def all_but_one_per_point(pt: IndexArray, key: NDArray[np.float64], candidates: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Of the ``candidates`` (M,), all but the one of largest ``key`` in each point.

    Used to change at most one measure per point and round: of the measures
    newly beyond the limit only the worst is rejected (the others are spared),
    and of the rejected measures newly back within it only the best comes back.
    One at a time because the statistic of every measure of a point is taken
    with the others as they stand: two measures that are each acceptable next to
    the accepted ones may not be together (they flip in and out every round), and
    after the worst is gone the others' statistics change.
    """
    idx = np.flatnonzero(candidates)
    rest = np.zeros(len(pt), bool)
    if idx.size:
        order = idx[np.lexsort((-np.nan_to_num(key[idx], nan=np.inf), pt[idx]))]
        first = np.ones(len(order), bool)
        first[1:] = pt[order][1:] != pt[order][:-1]
        rest[order[~first]] = True
    return rest


def ambiguous_measures(
    pt: IndexArray, norms: NDArray[np.float64], ssr: NDArray[np.float64], member: NDArray[np.bool_], limit: float
) -> NDArray[np.bool_]:
    """Measures (M,) of points whose inconsistency more than one measure explains; all of those are rejected.

    A measure explains its point's inconsistency when its deletion statistic
    exceeds the limit and the point's other measures agree without it
    (``SSR - delta <= limit^2``). When two measures do (an outlier displaced along
    the epipolar line of itself and one good measure: deleting the third, good
    measure leaves a consistent pair), the data cannot say which one is wrong;
    keeping the worst-by-a-hair would keep the outlier half of the time, so both
    go (and a point left with a lone measure loses it too: the point is then
    flagged as under-determined, not silently wrong).
    """
    expl = member & (norms > limit) & (ssr[pt] - norms**2 <= limit * limit)
    return expl & (np.bincount(pt[expl], minlength=len(ssr)) >= 2)[pt]




def proposed_accepted(
    pt: IndexArray, norms: NDArray[np.float64], ssr: NDArray[np.float64], active: NDArray[np.bool_],
    member: NDArray[np.bool_], held_points: NDArray[np.bool_], limit: float, min_point_measures: int,
) -> NDArray[np.bool_]:
    """The accepted set (M,) a rejection round proposes under ``limit``, from the measures' statistic ``norms``.

    ``norms``: square roots of :func:`deletion_statistic` (whitened units), ``ssr`` its per-point sums,
    ``active``: the measures accepted now, ``member``: those the statistic treated as members of their point.
    The rules, per point: a rejected measure comes back only well inside the limit
    (:data:`READMIT_FRACTION`: hysteresis); of the accepted measures newly beyond it only the worst goes, of
    the rejected ones newly within it only the best comes back (:func:`all_but_one_per_point`; points without
    accepted measures are tested on all theirs, as members, and come back together); measures of a point whose
    inconsistency two of them explain equally all go (:func:`ambiguous_measures`); and a point left with fewer
    than ``min_point_measures`` loses them all (a lone measure cannot show whether it is right: its point
    followed it), unless the point is held.
    """
    new = np.isfinite(norms) & (norms <= np.where(active, limit, READMIT_FRACTION * limit))
    new |= all_but_one_per_point(pt, norms, active & ~new)
    new &= ~all_but_one_per_point(pt, -norms, new & ~active & ~member)
    new &= ~ambiguous_measures(pt, norms, ssr, member, limit)
    lone = np.bincount(pt[new], minlength=len(held_points)) < min_point_measures
    new &= ~(lone[pt] & ~held_points[pt])
    return new


def kept_in_either(
    proposed: NDArray[np.bool_], active: NDArray[np.bool_], pt: IndexArray, held_points: NDArray[np.bool_],
    min_point_measures: int,
) -> NDArray[np.bool_]:
    """The cycle rule's accepted set: every measure accepted now or in ``proposed``, less those of points
    (not held) left with fewer than ``min_point_measures`` of them.
    """
    new = proposed | active
    new &= ~(np.bincount(pt[new], minlength=len(held_points)) < min_point_measures)[pt] | held_points[pt]
    return new


class InMemoryEngine:
    """The :class:`~mercury_dem.adjust.lm.LMEngine` of a :class:`BlockModel` with all its measures here.

    Each iteration's normal equations are reduced to the camera blocks with the Schur complement and solved by
    a :class:`~mercury_dem.adjust.schur.ReducedSolver`; the points follow by back-substitution.
    """

    def __init__(self, model: BlockModel, state: Any, opt: SolverOptions):
        self.model, self.state, self.opt = model, state, opt
        c, n_cam, n_pt = model.camera_dim, model.n_cameras, model.n_points
        self.c, self.n_cam, self.n_pt = c, n_cam, n_pt
        self.cam, self.pt = model.camera_index, model.point_index
        self.n_measures = len(self.cam)
        self.held_c = np.zeros(n_cam, bool) if opt.held_cameras is None else np.asarray(opt.held_cameras, bool)
        self.held_p = np.zeros(n_pt, bool) if opt.held_points is None else np.asarray(opt.held_points, bool)
        self.struct = SchurStructure.build(self.cam, self.pt, n_cam, n_pt, c, eliminate=~self.held_p)
        self.method = choose_method(opt.solver, n_cam * c, opt.direct_max_unknowns)
        self.lin_solver = ReducedSolver(self.method, c, opt.pcg_tolerance, opt.pcg_max_iterations)
        self.active = np.ones(self.n_measures, bool)
        self.use, self.frozen = self._usable(self.active)
        self.n_cam_prior = self.n_pt_prior = 0

    def _usable(self, active: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        counts = np.bincount(self.pt[active], minlength=self.n_pt)
        frozen = (counts < self.opt.min_point_measures) & ~self.held_p
        return active & ~frozen[self.pt], frozen

    def start(self) -> float:
        cost, self.r_now = _cost(self.model, self.state, self.use, self.opt)
        return cost

    def linearize(self) -> None:
        model, opt, c, cam, pt = self.model, self.opt, self.c, self.cam, self.pt
        held_c, fixed = self.held_c, self.held_p | self.frozen
        r, jc, jp = model.linearize(self.state)
        s = np.sum(r * r, axis=1)
        _, w = loss_rho(np.where(self.use, s, 0.0), opt.loss, opt.loss_scale)
        sw = np.sqrt(np.where(self.use, w, 0.0))
        r = r * sw[:, None]
        jc = jc * sw[:, None, None]
        self.jp_raw = jp  # unweighted: the rejection test's (least-squares) point Jacobians
        jp = jp * sw[:, None, None]
        jc[held_c[cam]] = 0.0
        jp[fixed[pt]] = 0.0
        self.u, self.g_c = np.zeros((self.n_cam, c, c)), np.zeros((self.n_cam, c))
        self.v, self.g_p = np.zeros((self.n_pt, 3, 3)), np.zeros((self.n_pt, 3))
        self.wm = np.empty((self.n_measures, c, 3))
        normal_blocks(r, jc, jp, cam, pt, self.u, self.g_c, self.v, self.g_p, self.wm)
        cp = model.camera_prior(self.state)
        if cp is not None:
            self.n_cam_prior = int(np.sum(~held_c)) * cp[0].shape[1]
            prior_blocks(cp[0], cp[1], self.u, self.g_c)
        pp = model.point_prior(self.state)
        if pp is not None:
            self.n_pt_prior = int(np.sum(~fixed)) * pp[0].shape[1]
            prior_blocks(pp[0], pp[1], self.v, self.g_p)
        self.u[held_c], self.g_c[held_c] = np.eye(c), 0.0
        self.v[fixed], self.g_p[fixed] = np.eye(3), 0.0
        self.du = np.clip(np.diagonal(self.u, axis1=1, axis2=2), 1e-6, 1e32)
        self.dv = np.clip(np.diagonal(self.v, axis1=1, axis2=2), 1e-6, 1e32)

    def trial(self, lam: float) -> Trial:
        c, cam, pt, u, v, g_c, g_p, du, dv = self.c, self.cam, self.pt, self.u, self.v, self.g_c, self.g_p, self.du, self.dv
        ud = u.copy()
        ud[:, range(c), range(c)] += lam * du
        vd = v.copy()
        vd[:, range(3), range(3)] += lam * dv
        v_inv = inv3(vd)
        blocks = self.struct.schur_blocks(self.wm, v_inv, ud)
        t_p = np.matmul(v_inv, g_p[:, :, None])[:, :, 0]
        b = -g_c
        reduced_rhs(self.wm, t_p, cam, pt, b)
        dc, info = self.lin_solver.solve(self.struct.to_bsr(blocks), blocks[self.struct.diag_block], b.ravel())
        dc = dc.reshape(self.n_cam, c)
        q = np.zeros((self.n_pt, 3))
        if np.all(np.isfinite(dc)):
            point_rhs(self.wm, dc, cam, pt, q)
        dp = np.matmul(v_inv, (-g_p - q)[:, :, None])[:, :, 0]
        dc[self.held_c] = 0.0
        dp[self.held_p | self.frozen] = 0.0
        pred = 0.5 * (lam * (np.sum(du * dc * dc) + np.sum(dv * dp * dp)) - np.sum(g_c * dc) - np.sum(g_p * dp))
        new_state = self.model.retract(self.state, dc, dp) if info.ok and np.all(np.isfinite(dc)) else None
        new_cost, r_new = float("nan"), None
        if new_state is not None:
            new_cost, r_new = _cost(self.model, new_state, self.use, self.opt)
        self._trial = (new_state, r_new)
        step_norm = float(np.sqrt(np.sum(dc * dc) + np.sum(dp * dp)))
        return Trial(pred, new_cost, step_norm, info.iterations)

    def accept(self) -> float:
        x_norm = float(self.model.parameter_norm(self.state)) if hasattr(self.model, "parameter_norm") else 1.0
        state, r_new = self._trial
        if r_new is None:
            raise RuntimeError("accept() after a trial step that gave no state")
        self.state, self.r_now = state, r_new
        del self._trial
        return x_norm

    def dof_counts(self) -> tuple[int, int]:
        n_obs = 2 * int(np.sum(self.use)) + self.n_cam_prior + self.n_pt_prior
        n_unk = self.c * int(np.sum(~self.held_c)) + 3 * int(np.sum(~self.held_p & ~self.frozen))
        return n_obs, n_unk

    def deletion_norms(self) -> NDArray[np.float64]:
        # Points left without accepted measures are tested on all their measures, so a consistent
        # subset can come back and an inconsistent pair stays out.
        self._member = self.use | (self.frozen & ~self.held_p)[self.pt]
        delta, self._ssr = deletion_statistic(self.r_now, self.jp_raw, self.pt, self._member, self.held_p)
        self._norms = np.sqrt(np.maximum(delta, 0.0))
        return self._norms

    def propose(self, limit: float) -> Proposal:
        new = proposed_accepted(self.pt, self._norms, self._ssr, self.active, self._member, self.held_p, limit,
                                self.opt.min_point_measures)
        self._proposal = new
        return Proposal(int(np.sum(new != self.active)), hash(np.packbits(new).tobytes()))

    def settle(self, union: bool) -> int:
        if union:
            self._proposal = kept_in_either(self._proposal, self.active, self.pt, self.held_p, self.opt.min_point_measures)
        del self._norms, self._ssr, self._member  # until the next round
        return int(np.sum(self._proposal != self.active))

    def apply_rejection(self) -> float:
        self.active = self._proposal
        del self._proposal
        self.use, self.frozen = self._usable(self.active)
        cost, self.r_now = _cost(self.model, self.state, self.use, self.opt)
        return cost

    def n_rejected(self) -> int:
        return int(np.sum(~self.active))

    def timings(self) -> dict[str, float]:
        return {}


def levenberg_marquardt(model: BlockModel, state: Any, opt: SolverOptions | None = None) -> SolverResult:
    """Minimise the (robust) cost of ``model`` from ``state`` (``opt`` None: the defaults of :class:`SolverOptions`).

    The loop is :func:`~mercury_dem.adjust.lm.run_levenberg_marquardt` over an :class:`InMemoryEngine`.

    Returns the best state found with the reason the iteration stopped (``"converged: ..."``,
    ``"iteration limit"``, ``"no decrease possible ..."``). Never raises for a singular or indefinite
    system: such a step is refused like any other step that does not decrease the cost.

    BLAS is limited to one thread meanwhile: the loop makes many small BLAS calls
    (stacked 3x3 products, a dense Cholesky of a few hundred unknowns) for which
    OpenBLAS threads only add overhead, and on a busy machine spinning threads
    made a 441-unknown Cholesky take 300 ms instead of 3 ms.
    """
    opt = SolverOptions() if opt is None else opt
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        engine = InMemoryEngine(model, state, opt)
        out = run_levenberg_marquardt(engine, opt, t0)
    return SolverResult(
        state=engine.state, initial_cost=out.initial_cost, final_cost=out.final_cost, sigma0=out.sigma0,
        iterations=out.iterations, converged=out.converged, reason=out.reason, accepted=engine.active,
        frozen_points=engine.frozen, residuals=engine.r_now, log=out.log, seconds=out.seconds,
        linear_method=engine.method, dof=out.dof,
    )
