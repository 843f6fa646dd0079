"""Bundle Adjustment in the Large (BAL): the text format parsed (:func:`parse_bal`) and the camera model.

The BAL text format (Agarwal et al., ECCV 2010; ``../shared/data/README.md``):
a header ``n_cameras n_points n_observations``, one line per observation
``camera_index point_index x y``, then 9 numbers per camera (rotation vector (3),
translation t (3), focal f, radial k1, k2) and 3 per point. Projection:
``P = R X + t``, ``p = -P[:2] / P[2]``, ``r = f (1 + k1 |p|^2 + k2 |p|^4) p``,
residual ``r - observed``; cost ``0.5 sum r^2``.

In the model the rotation is kept as a matrix and updated on the left,
``R <- exp([d theta]x) R``, so its Jacobian is simply ``-[R X]x``; the other six
camera parameters (t, f, k1, k2) are additive.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.kernels import bal_project
from mercury_dem.adjust.solver import SolverOptions, SolverResult, levenberg_marquardt
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.pose import angles_from_rotation, rotation_from_angles


@dataclass(frozen=True)
class BalProblem:
    """A BAL problem as read from its file.

    Attributes
    ----------
    camera_index, point_index : (M,) int
    observations : (M, 2) image coordinates (BAL convention: centred, y up)
    cameras : (n_cam, 9) rotation vector (rad), t, f, k1, k2
    points : (n_pt, 3)
    """

    camera_index: NDArray[np.int64]
    point_index: NDArray[np.int64]
    observations: NDArray[np.float64]
    cameras: NDArray[np.float64]
    points: NDArray[np.float64]

    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_observations(self) -> int:
        return len(self.observations)


def parse_bal(text: str, path: str | Path) -> BalProblem:
    """The problem in the text of a BAL file (``path`` names it in messages; nothing is opened).

    Raises :class:`AdjustmentError` naming the file when it is malformed. Reading the file is
    :func:`mercury_dem.io.bal.read_bal`.
    """
    tokens = text.split()
    try:
        if len(tokens) < 3:
            raise ValueError("no header 'n_cameras n_points n_observations'")
        n_cam, n_pt, n_obs = (int(t) for t in tokens[:3])
        if min(n_cam, n_pt, n_obs) < 0:
            raise ValueError(f"negative count in header {' '.join(tokens[:3])}")
        need = 3 + 4 * n_obs + 9 * n_cam + 3 * n_pt
        if len(tokens) != need:
            raise ValueError(f"the header's counts need {need} numbers, found {len(tokens)}")
        table = np.array(tokens[3 : 3 + 4 * n_obs], dtype=str).reshape(n_obs, 4)
        cam_idx, pt_idx = table[:, 0].astype(np.int64), table[:, 1].astype(np.int64)  # integers, not 1.5 or nan
        obs = table[:, 2:4].astype(np.float64)
        rest = np.array(tokens[3 + 4 * n_obs : need], dtype=np.float64)
        if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(rest))):
            raise ValueError("a value is not a finite number")
    except (ValueError, OverflowError) as exc:
        raise AdjustmentError(f"BAL file {path} is malformed: {exc}") from None
    if cam_idx.min(initial=0) < 0 or cam_idx.max(initial=-1) >= n_cam or pt_idx.min(initial=0) < 0 or pt_idx.max(initial=-1) >= n_pt:
        raise AdjustmentError(f"BAL file {path}: an observation names a camera or point beyond the header's counts")
    return BalProblem(
        camera_index=cam_idx,
        point_index=pt_idx,
        observations=obs,
        cameras=rest[: 9 * n_cam].reshape(n_cam, 9).copy(),
        points=rest[9 * n_cam :].reshape(n_pt, 3).copy(),
    )


@dataclass(frozen=True)
class BalState:
    """Parameters during the adjustment: rotations (n_cam, 3, 3), intrinsics+t (n_cam, 6), points (n_pt, 3)."""

    rotations: NDArray[np.float64]
    params: NDArray[np.float64]  # t (3), f, k1, k2
    points: NDArray[np.float64]

    def cameras(self) -> NDArray[np.float64]:
        """Cameras in the BAL layout (n_cam, 9)."""
        return np.concatenate([angles_from_rotation(self.rotations), self.params], axis=1)


class BalModel:
    """The BAL camera as a :class:`~mercury_dem.adjust.solver.BlockModel` (camera_dim 9)."""

    camera_dim = 9

    def __init__(self, problem: BalProblem):
        self.problem = problem
        self.n_cameras = problem.n_cameras
        self.n_points = problem.n_points
        self.camera_index = problem.camera_index
        self.point_index = problem.point_index

    def initial_state(self) -> BalState:
        cams = self.problem.cameras
        return BalState(rotation_from_angles(cams[:, :3]), cams[:, 3:].copy(), self.problem.points.copy())

    def _run(self, state: BalState, jacobian: bool) -> tuple[NDArray[np.float64], ...]:
        m = len(self.camera_index)
        res = np.empty((m, 2))
        jc = np.empty((m, 2, 9) if jacobian else (0, 2, 9))
        jp = np.empty((m, 2, 3) if jacobian else (0, 2, 3))
        bal_project(state.rotations, state.params, state.points, self.camera_index, self.point_index,
                    self.problem.observations, res, jc, jp, jacobian)
        return res, jc, jp

    def residuals(self, state: BalState) -> NDArray[np.float64]:
        return self._run(state, False)[0]

    def linearize(self, state: BalState) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Residuals and analytic Jacobians (compiled loop, :func:`~mercury_dem.adjust.kernels.bal_project`)."""
        res, jc, jp = self._run(state, True)
        return res, jc, jp

    def camera_prior(self, state: BalState) -> None:
        return None

    def point_prior(self, state: BalState) -> None:
        return None

    def retract(self, state: BalState, d_camera: NDArray[np.float64], d_point: NDArray[np.float64]) -> BalState:
        return BalState(
            np.matmul(rotation_from_angles(d_camera[:, :3]), state.rotations),
            state.params + d_camera[:, 3:],
            state.points + d_point,
        )

    def parameter_norm(self, state: BalState) -> float:
        return float(np.sqrt(np.sum(state.params**2) + np.sum(state.points**2) + 3 * self.n_cameras))


def half_sum_of_squares(r: NDArray[np.float64]) -> float:
    """0.5 sum r^2 of finite ``r`` without overflow in the squares; ``inf`` only when the sum itself exceeds
    float64's range (about 1.8e308).

    ``np.sum(r * r)`` overflows (a RuntimeWarning, then inf) as soon as one |r| passes ~1.3e154, though
    the cost may still be representable; here the squares are of ``r / max|r|`` (at most 1) and the
    scale is multiplied back in Python floats (which give inf, not a warning, past the range).
    """
    if r.size == 0:
        return 0.0
    s = float(np.max(np.abs(r)))
    if s == 0.0:
        return 0.0
    q = float(np.sum(np.square(r / s)))
    return 0.5 * s * (s * q)


def bal_cost(problem: BalProblem, state: BalState | None = None) -> float:
    """0.5 sum of squared residuals of a BAL problem (at ``state``, default the file's values).

    ``inf`` when the cost exceeds float64's range (values near 1e308 in the file);
    :class:`AdjustmentError` when a residual itself is not finite (the projection overflowed).
    """
    model = BalModel(problem)
    with np.errstate(over="ignore", invalid="ignore"):  # reported below, as an error naming the cause
        r = model.residuals(model.initial_state() if state is None else state)
    if not np.all(np.isfinite(r)):
        bad = int(np.argmax(~np.isfinite(r.reshape(problem.n_observations, -1)).all(axis=1)))
        raise AdjustmentError(
            f"BAL problem: the residual of observation {bad} is not finite (its projection overflows float64; the "
            f"largest |value| is {_largest(problem):.3g}); rescale the problem"
        )
    return half_sum_of_squares(r)


def _largest(problem: BalProblem) -> float:
    return float(max((np.max(np.abs(a)) for a in (problem.observations, problem.cameras, problem.points) if a.size),
                     default=0.0))


def adjust_bal(problem: BalProblem, options: SolverOptions | None = None) -> tuple[BalState, SolverResult]:
    """Adjust a BAL problem (plain least squares unless ``options`` say otherwise).

    Returns the final state and the solver's result (costs 0.5 sum r^2, log with
    the cost and elapsed seconds per iteration). :class:`AdjustmentError` when the
    initial cost is not a finite float64 (values near 1e308 in the file): the solver's
    squares would overflow.
    """
    cost = bal_cost(problem)
    if not np.isfinite(cost):
        raise AdjustmentError(
            f"BAL problem: the initial cost exceeds float64's range (largest |value| {_largest(problem):.3g}); "
            "rescale the problem before adjusting it"
        )
    model = BalModel(problem)
    res = levenberg_marquardt(model, model.initial_state(), options or SolverOptions(max_iterations=50))
    return res.state, res
