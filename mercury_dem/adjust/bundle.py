"""``bundle_adjust``: the planetary bundle adjustment from a problem and its configuration.

Joins the pieces: validation and diagnosis (:mod:`~mercury_dem.adjust.diagnose`),
the framing-camera model (:mod:`~mercury_dem.adjust.framing`), the Schur
Levenberg-Marquardt core (:mod:`~mercury_dem.adjust.solver`) and the statistics
of :class:`~mercury_dem.adjust.result.AdjustmentResult`. Pure: arrays in,
arrays out; writing reports is :mod:`~mercury_dem.adjust.report`'s job.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.diagnose import check_solvable, diagnose
from mercury_dem.adjust.framing import FramingModel
from mercury_dem.adjust.kernels import normal_blocks, prior_blocks
from mercury_dem.adjust.posterior import image_covariances, point_covariances, selected_inverse, sigmas_of
from mercury_dem.adjust.problem import AdjustmentProblem, unprojectable, unprojectable_error
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.adjust.robust import loss_rho
from mercury_dem.adjust.schur import SchurStructure, inv3
from mercury_dem.adjust.solver import SolverOptions, levenberg_marquardt
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError


def held_image_mask(problem: AdjustmentProblem, config: AdjustConfig) -> NDArray[np.bool_]:
    """The problem's held images plus those named in ``config.held_images`` (unknown ids are an error)."""
    held = problem.held_images.copy()
    if config.held_images:
        index = {k: i for i, k in enumerate(problem.image_ids)}
        unknown = [k for k in config.held_images if k not in index]
        if unknown:
            raise AdjustmentError(f"adjust.held_images names images not in the network: {unknown[:10]}")
        held[[index[k] for k in config.held_images]] = True
    return held


def make_model(problem: AdjustmentProblem, config: AdjustConfig) -> FramingModel:
    """The framing-camera model with the configured a-priori constraints."""
    return FramingModel(
        problem,
        position_sigma_m=config.position_sigma_m if config.solve_positions else None,
        point_sigma_m=(config.point_longitude_sigma_m, config.point_latitude_sigma_m, config.radius_sigma_m),
    )


def solver_options(problem: AdjustmentProblem, config: AdjustConfig, held_images: NDArray[np.bool_]) -> SolverOptions:
    """Map the typed config onto the core's options (whitened units use the median measure sigma)."""
    sigma = float(np.median(problem.measure_sigma))
    return SolverOptions(
        max_iterations=config.max_iterations,
        function_tolerance=2.0 * config.sigma0_tolerance,
        step_tolerance=config.step_tolerance,
        loss=config.robust_loss,
        loss_scale=config.robust_scale,
        reject_k=config.reject_k_mad if config.reject_outliers else None,
        reject_floor=config.reject_min_px / sigma,
        min_point_measures=config.min_point_measures,
        solver=config.solver,
        direct_max_unknowns=config.direct_max_unknowns,
        pcg_tolerance=config.pcg_tolerance,
        pcg_max_iterations=config.pcg_max_iterations,
        held_cameras=held_images,
        held_points=problem.held_points,
    )


def rms_by_group(groups: NDArray[np.int64], sq: NDArray[np.float64], keep: NDArray[np.bool_],
                 n: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Per-coordinate RMS and count of the kept measures of each of ``n`` groups (images or points).

    ``groups`` (M,) each measure's group, ``sq`` (M,) its squared residual norm (two coordinates), ``keep`` (M,)
    the measures counted. Returns ``sqrt(sum sq / (2 count))`` (NaN for a group without kept measures) and count.
    """
    count = np.bincount(groups[keep], minlength=n)
    total = np.bincount(groups[keep], weights=sq[keep], minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(total / (2.0 * count)), count


def check_projectable(problem: AdjustmentProblem, r0: NDArray[np.float64]) -> None:
    """Raise :class:`AdjustmentError` naming the measures whose a-priori residuals ``r0`` are not finite
    (the point behind the camera): the adjustment cannot start from such a state.
    """
    bad = unprojectable(r0)
    if bad.size:
        which = bad[:10]
        raise unprojectable_error(bad.size, "", problem.point_ids[problem.measure_point[which]].tolist(),
                                  [problem.image_ids[i] for i in problem.measure_image[which]])


def bundle_adjust(problem: AdjustmentProblem, config: AdjustConfig | None = None) -> AdjustmentResult:
    """Adjust pointing (and optionally positions) and points of a framing-camera network.

    Raises :class:`AdjustmentError` (naming images/points) when the network is
    unsolvable: islands, images without measures, no point with 2 measures.
    A solve that cannot decrease the cost stops with the best state and the
    reason in ``result.reason``.
    """
    config = config or AdjustConfig()
    t0 = time.perf_counter()
    held = held_image_mask(problem, config)
    diag = diagnose(problem, config.min_point_measures, config.min_image_measures)
    check_solvable(problem, diag, held, config.allow_islands)
    model = make_model(problem, config)
    opt = solver_options(problem, config, held)
    state0 = model.initial_state()
    r0 = model.residuals(state0) * problem.measure_sigma[:, None]
    check_projectable(problem, r0)
    initial_rms = float(np.sqrt(np.mean(r0 * r0)))
    res = levenberg_marquardt(model, state0, opt)
    state = res.state
    resid = res.residuals * problem.measure_sigma[:, None]
    rejected = ~res.accepted
    keep = res.accepted & ~res.frozen_points[problem.measure_point]
    sq = np.sum(resid * resid, axis=1)
    rms_img, n_img_acc = rms_by_group(problem.measure_image, sq, keep, problem.n_images)
    rms_pt, n_pt_acc = rms_by_group(problem.measure_point, sq, keep, problem.n_points)
    rk = resid[keep]
    rms = float(np.sqrt(np.mean(rk * rk))) if rk.size else float("nan")
    image_sigmas = point_sigmas = image_cov = None
    post_s = 0.0
    if config.posterior_sigmas and problem.n_images * model.camera_dim <= config.posterior_max_unknowns:
        tp = time.perf_counter()
        image_cov, point_cov = posterior_covariances(model, state, res.accepted & ~res.frozen_points[problem.measure_point],
                                                     opt, res.sigma0, held)
        image_sigmas = sigmas_of(image_cov)
        point_sigmas = None if point_cov is None else sigmas_of(point_cov)
        post_s = time.perf_counter() - tp
    return AdjustmentResult(
        image_ids=problem.image_ids,
        point_ids=problem.point_ids,
        rotations=model.rotations(state),
        positions=model.positions(state),
        pointing_corrections=state.omega,
        position_corrections=state.position_correction,
        points=state.points,
        measure_image=problem.measure_image,
        measure_point=problem.measure_point,
        residuals_px=resid,
        rejected=rejected,
        sigma0=res.sigma0,
        rms_px=rms,
        rms_sample_px=float(np.sqrt(np.mean(rk[:, 0] ** 2))) if rk.size else float("nan"),
        rms_line_px=float(np.sqrt(np.mean(rk[:, 1] ** 2))) if rk.size else float("nan"),
        initial_rms_px=initial_rms,
        rms_per_image=rms_img,
        rms_per_point=rms_pt,
        accepted_per_image=n_img_acc,
        accepted_per_point=n_pt_acc,
        underdetermined_points=res.frozen_points,
        weak_images=(n_img_acc < config.min_image_measures) & ~held,
        iterations=res.iterations,
        converged=res.converged,
        reason=res.reason,
        log=tuple(res.log),
        seconds=time.perf_counter() - t0,
        solve_seconds=res.seconds,
        linear_method=res.linear_method,
        dof=res.dof,
        diagnosis=diag,
        image_sigmas=image_sigmas,
        point_sigmas=point_sigmas,
        posterior_seconds=post_s,
        image_covariances=image_cov,
    )


def posterior_covariances(
    model: FramingModel,
    state: object,
    use: NDArray[np.bool_],
    opt: SolverOptions,
    sigma0: float,
    held: NDArray[np.bool_],
    points: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """A-posteriori covariances of image parameters (n_img, c, c) and of points' XYZ (n_pt, 3, 3) or None.

    The undamped reduced camera matrix at ``state`` (measures in ``use``, their robust weights, the priors) is
    factored once and its inverse selected on the factor's pattern (:mod:`~mercury_dem.adjust.posterior`): the
    images' diagonal blocks, and with ``points`` each point's
    ``C_p = s0^2 (V^-1 + sum_{m1, m2} Y_m1^T C_c[i1, i2] Y_m2)`` over all pairs of its measures (image pairs of
    the reduced matrix's blocks). Time and memory those of one sparse factorization. Held images and
    unadjusted points get 0.
    """
    c, n_cam, n_pt = model.camera_dim, model.n_cameras, model.n_points
    cam, pt = model.camera_index, model.point_index
    r, jc, jp = model.linearize(state)  # type: ignore[arg-type]
    s = np.sum(r * r, axis=1)
    _, w = loss_rho(s, opt.loss, opt.loss_scale)
    sw = np.sqrt(np.where(use, w, 0.0))
    jc = jc * sw[:, None, None]
    jp = jp * sw[:, None, None]
    jc[held[cam]] = 0.0
    u = np.zeros((n_cam, c, c))
    v = np.zeros((n_pt, 3, 3))
    wm = np.empty((len(cam), c, 3))
    normal_blocks(r * 0.0, jc, jp, cam, pt, u, np.zeros((n_cam, c)), v, np.zeros((n_pt, 3)), wm)
    cp = model.camera_prior(state)  # type: ignore[arg-type]
    prior_blocks(cp[0], cp[1], u, np.zeros((n_cam, c)))
    pp = model.point_prior(state)  # type: ignore[arg-type]
    if pp is not None:
        prior_blocks(pp[0], pp[1], v, np.zeros((n_pt, 3)))
    free_pt = np.bincount(pt[use], minlength=n_pt) >= 2
    v[~free_pt] = np.eye(3)
    u[held] = np.eye(c)
    v_inv = inv3(v)
    struct = SchurStructure.build(cam, pt, n_cam, n_pt, c, eliminate=free_pt)
    inverse = selected_inverse(struct.to_bsr(struct.schur_blocks(wm, v_inv, u)))
    cov_c = image_covariances(inverse, n_cam, c, sigma0, held)
    if not points:
        return cov_c, None
    cov_p = point_covariances(lambda i, k: inverse.blocks(i, k, c), c, sigma0, wm, v_inv, cam, pt, free_pt, held)
    cov_p[~free_pt] = 0.0
    return cov_c, cov_p


def posterior_sigmas(
    model: FramingModel,
    state: object,
    use: NDArray[np.bool_],
    opt: SolverOptions,
    sigma0: float,
    held: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A-posteriori sigmas of image parameters (n_img, c) and point XYZ (n_pt, 3) (:func:`posterior_covariances`)."""
    cov_c, cov_p = posterior_covariances(model, state, use, opt, sigma0, held)
    assert cov_p is not None
    return sigmas_of(cov_c), sigmas_of(cov_p)
