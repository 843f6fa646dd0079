"""The outcome of a bundle adjustment."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.diagnose import Diagnosis


@dataclass(frozen=True)
class AdjustmentResult:
    """Adjusted orientation and points, residuals and statistics.

    Attributes
    ----------
    image_ids : (n_img,) ids; point_ids : (n_pt,) int ids
    rotations : (n_img, 3, 3) adjusted body-fixed -> camera rotations
    positions : (n_img, 3) adjusted positions, body-fixed m
    pointing_corrections : (n_img, 3) rad, omega with ``R = rotation_from_angles(omega) @ R_apriori``
    position_corrections : (n_img, 3) m
    points : (n_pt, 3) adjusted points, body-fixed m
    residuals_px : (M, 2) computed - measured (sample, line) at the adjusted state, pixels
    rejected : (M,) bool, measures rejected by the k x MAD test on the deletion statistic (see
        :func:`~mercury_dem.adjust.solver.deletion_statistic`), including both measures of an ambiguous
        point and the lone measure a rejection leaves on its point; measures of points that had fewer
        than ``min_point_measures`` measures from the start are not rejected but unused (see
        ``underdetermined_points``)
    sigma0 : a-posteriori standard deviation of unit weight, sqrt(v^T P v / dof)
    rms_px : RMS residual per coordinate over accepted measures, sqrt(mean(v_s^2 + v_l^2) / 2)
    rms_sample_px, rms_line_px : the same per coordinate
    initial_rms_px : the same at the a-priori state (all measures)
    rms_per_image : (n_img,) px (NaN without accepted measures); rms_per_point : (n_pt,)
    accepted_per_image : (n_img,) int; accepted_per_point : (n_pt,) int
    underdetermined_points : (n_pt,) bool, points left unadjusted (< min measures accepted)
    weak_images : (n_img,) bool, images with fewer than min_image_measures accepted measures
    iterations, converged, reason : how the iteration stopped
    log : one dict per iteration (iteration, cost, sigma0, lambda, rejected, seconds, ...)
    seconds : total wall time; solve_seconds : time in the LM loop
    linear_method : "dense", "cholmod", "splu" or "pcg"
    image_sigmas : (n_img, c) a-posteriori sigmas (rad for pointing, m for position) or None
    image_covariances : (n_img, c, c) a-posteriori covariances of the image parameters (their diagonals are
        ``image_sigmas`` squared; 0 for held images) or None
    point_sigmas : (n_pt, 3) a-posteriori XYZ sigmas, m, or None
    posterior_seconds : cost of the a-posteriori sigmas
    diagnosis : the pre-solve :class:`Diagnosis`
    """

    image_ids: tuple[str, ...]
    point_ids: NDArray[Any]
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    pointing_corrections: NDArray[np.float64]
    position_corrections: NDArray[np.float64]
    points: NDArray[np.float64]
    measure_image: NDArray[np.int64]
    measure_point: NDArray[np.int64]
    residuals_px: NDArray[np.float64]
    rejected: NDArray[np.bool_]
    sigma0: float
    rms_px: float
    rms_sample_px: float
    rms_line_px: float
    initial_rms_px: float
    rms_per_image: NDArray[np.float64]
    rms_per_point: NDArray[np.float64]
    accepted_per_image: NDArray[np.int64]
    accepted_per_point: NDArray[np.int64]
    underdetermined_points: NDArray[np.bool_]
    weak_images: NDArray[np.bool_]
    iterations: int
    converged: bool
    reason: str
    log: tuple[dict[str, Any], ...]
    seconds: float
    solve_seconds: float
    linear_method: str
    dof: int
    diagnosis: Diagnosis
    image_sigmas: NDArray[np.float64] | None = None
    point_sigmas: NDArray[np.float64] | None = None
    posterior_seconds: float = 0.0
    image_covariances: NDArray[np.float64] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_measures(self) -> int:
        return len(self.rejected)

    @property
    def n_rejected(self) -> int:
        return int(np.sum(self.rejected))

    def summary(self) -> dict[str, Any]:
        """Small JSON-safe summary (for run reports)."""
        return {
            "images": len(self.image_ids),
            "points": int(len(self.point_ids)),
            "measures": self.n_measures,
            "rejected": self.n_rejected,
            "sigma0": self.sigma0,
            "rms_px": self.rms_px,
            "initial_rms_px": self.initial_rms_px,
            "iterations": self.iterations,
            "converged": self.converged,
            "reason": self.reason,
            "seconds": self.seconds,
            "linear_method": self.linear_method,
            "underdetermined_points": int(np.sum(self.underdetermined_points)),
            "weak_images": int(np.sum(self.weak_images)),
            "sigma0_per_iteration": [e["sigma0"] for e in self.log],
        }
