"""Bundle adjustment of one unit (region, hemisphere, globe): network in, adjusted network and pointing out.

Joins the control network (:mod:`mercury_dem.network`) and the adjustment engine
(:mod:`mercury_dem.adjust`) for the stage runners, and turns the result into the
unit's summary (the ``levels`` rows of report.json).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.datum import recentre_on_block
from mercury_dem.config.adjust import AdjustConfig

if TYPE_CHECKING:
    from mercury_dem.network.model import ControlNetwork


@dataclass(frozen=True)
class UnitAdjustment:
    """The result of adjusting one unit's network: the network, the poses, per-image counts, summary and report."""

    network: ControlNetwork  # with adjusted points, residuals, rejections
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    image_measures: NDArray[np.int64]  # accepted measures per image
    image_rms_px: NDArray[np.float64]
    summary: dict[str, Any]
    text_report: str = ""  # jigsaw-like bundleout.txt of the solve


def adjust_network(
    network: ControlNetwork,
    cameras: list[Any],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    config: AdjustConfig,
    *,
    pointing_sigma_urad: float,
    initial_rotations: NDArray[np.float64] | None = None,
    rms_flag_px: float = 2.0,
    datum_radius_m: float,
    altimetry: Any = None,
    recentre_point_priors: bool = False,
    level: str | None = None,
    engine_factory: Any = None,
    prior_shape: Any = None,
) -> UnitAdjustment:
    """Adjust a merged network whose a-priori pose is ``positions``/``rotations``, the rotations wrong by
    ``pointing_sigma_urad`` per axis (1 sigma, µrad: the run's a-priori pointing sigma).

    ``initial_rotations`` (a lower level's solution) is where the iteration
    starts; the pointing constraint stays centred on the a-priori ``rotations``.

    Islands (disconnected groups of images) are adjusted together, each held by
    its a-priori constraints, and reported by id; images whose RMS residual
    exceeds ``rms_flag_px`` are flagged; images without measures are held at their
    a-priori pose and named (``images_without_measures``).

    ``altimetry`` (:class:`~mercury_dem.altimetry.constraints.AltimetryShotsArrays`): the tie
    points near shots get radius constraints from them
    (:func:`~mercury_dem.altimetry.constraints.bundle_adjust_with_altimetry`, two passes).

    ``recentre_point_priors``: the radius constraints of the non-held points are first re-centred
    on the block's own surface (:func:`recentre_on_block`, one more adjustment) instead of the
    datum sphere — when the block calls for it (:func:`~mercury_dem.altimetry.levelling.levelling_for`: wide
    enough to carry its own surface, not mostly held by the altimetry); the decision is the summary's
    ``levelling``.

    ``prior_shape`` (:class:`~mercury_dem.reference.body_shape.BodyShape`, a real mission's body shape): with
    ``config.point_prior_center == "shape"`` the free points start on it and their radius constraint is
    ``config.point_prior_shape_sigma_m`` (else the shape's ``prior_sigma_m``) instead of ``radius_sigma_m``
    (altimetry-constrained points keep the altimetry's); the block is not re-centred on its own surface (the
    shape carries the long wavelengths re-centring is for). None: the datum sphere; the summary's
    ``point_prior_centre`` says which.

    ``level``: the unit's level; a unit of ``config.blocked_levels`` with at least
    ``config.blocked_min_measures`` measures is adjusted over point blocks
    (:func:`~mercury_dem.adjust.cascade.adjusts_by_blocks`)
    (:func:`~mercury_dem.adjust.blocked_bundle.blocked_bundle_adjust`, every pass: re-centring,
    altimetry), which gives the same solution to solver tolerance; ``summary["blocked"]`` says so.
    """
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.adjust.cascade import adjusts_by_blocks, unit_config
    from mercury_dem.adjust.datum import centre_point_priors
    from mercury_dem.adjust.network import network_with_result, problem_from_network
    from mercury_dem.adjust.report import text_report

    ids = np.asarray(network.image_ids).astype(str)
    # islands allowed, images without measures held and named (adjust.cascade.unit_config)
    cfg, no_measures = unit_config(config, ids, network.measure_image)
    problem, measure_index = problem_from_network(
        network, cameras, positions, rotations, cfg, initial_rotations=initial_rotations,
        pointing_sigma_urad=pointing_sigma_urad,
    )
    solve = bundle_adjust
    blocked = adjusts_by_blocks(cfg, level, problem.n_measures)
    if blocked:
        from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust

        def solve(p: Any, c: AdjustConfig) -> Any:
            return blocked_bundle_adjust(p, c, block_points=cfg.blocked_block_points, engine_factory=engine_factory)
    on_shape = cfg.point_prior_center == "shape" and prior_shape is not None
    problem = centre_point_priors(problem, cfg.point_prior_center, datum_radius_m, shape=prior_shape)
    if on_shape:
        sigma = cfg.point_prior_shape_sigma_m or float(prior_shape.prior_sigma_m)
        cfg = dataclasses.replace(cfg, radius_sigma_m=sigma)
        centre: dict[str, Any] = {"centre": "shape", "shape": prior_shape.name, "radius_sigma_m": sigma}
    elif cfg.point_prior_center in ("datum", "shape"):
        centre = {"centre": "datum", "datum_radius_m": float(datum_radius_m), "radius_sigma_m": cfg.radius_sigma_m}
        if cfg.point_prior_center == "shape":
            centre["why"] = "no shape model for this run (a synthetic mission or a body without one)"
    else:
        centre = {"centre": "network", "radius_sigma_m": cfg.radius_sigma_m}
    prior_summary: dict[str, Any] | None = None
    decision = None
    if recentre_point_priors:
        from mercury_dem.altimetry.levelling import levelling_for, recentres

        decision = levelling_for(problem.points, cfg, altimetry)
        if on_shape and decision.level_to_mean:  # (not held by the altimetry: that reason stands)
            decision = dataclasses.replace(decision, recentre=False, reason=(
                f"the block spans {decision.extent_deg:.1f} deg and the altimetry constrains "
                f"{decision.altimetry_share:.0%} of its points; the others are centred on the body's shape "
                f"({prior_shape.name}), which carries the long wavelengths re-centring is for: not re-centred "
                "(levelled on the shots' mean if registered)"))
        if recentres(decision, cfg):
            problem, prior_summary = recentre_on_block(problem, cfg, datum_radius_m, adjust=solve)
    altimetry_summary: dict[str, Any] | None = None
    if altimetry is not None and len(altimetry.radius_m):
        from mercury_dem.altimetry.constraints import bundle_adjust_with_altimetry

        result, priors = bundle_adjust_with_altimetry(
            problem, cfg, altimetry, search_radius_m=cfg.altimetry_search_m, min_shots=cfg.altimetry_min_shots,
            horizontal_sigma_m=cfg.altimetry_horizontal_sigma_m, surface=cfg.altimetry_surface, adjust=solve,
        )
        altimetry_summary = {"shots": int(len(altimetry.radius_m)), **priors.summary()}
    else:
        result = solve(problem, cfg)
    adjusted = network_with_result(network, result, measure_index)
    rms_img = np.asarray(result.rms_per_image, dtype=np.float64)
    flagged = [
        {"image": str(ids[k]), "rms_px": float(rms_img[k])}
        for k in np.flatnonzero(np.nan_to_num(rms_img) > rms_flag_px)
    ]
    islands = [[str(ids[i]) for i in isl] for isl in result.diagnosis.islands]
    summary = {
        "images": int(problem.n_images),
        "points": int(problem.n_points),
        "measures": int(problem.n_measures),
        "rms_px": float(result.rms_px),
        "initial_rms_px": float(result.initial_rms_px),
        "sigma0": float(result.sigma0),
        "rejected": int(np.sum(result.rejected)),
        "underdetermined_points": int(np.sum(result.underdetermined_points)),
        "weak_images": [str(ids[k]) for k in np.flatnonzero(result.weak_images)],
        "iterations": int(result.iterations),
        "converged": bool(result.converged),
        "reason": str(result.reason),
        "sigma0_history": [float(e.get("sigma0", np.nan)) for e in result.log],
        "linear_method": result.linear_method,
        "solve_seconds": float(result.solve_seconds),
        "flagged_images": flagged,
        "islands": islands if len(islands) > 1 else [],
        "images_without_measures": no_measures,
    }
    if blocked:
        summary["blocked"] = result.extra.get("blocked")
    if altimetry_summary is not None:
        summary["altimetry"] = altimetry_summary
    summary["point_prior_centre"] = centre
    if prior_summary is not None:
        summary["point_prior"] = prior_summary
    if decision is not None:
        summary["levelling"] = decision.summary()
    return UnitAdjustment(
        network=adjusted,
        rotations=np.asarray(result.rotations),
        positions=np.asarray(result.positions),
        image_measures=np.asarray(result.accepted_per_image, dtype=np.int64),
        image_rms_px=rms_img,
        summary=summary,
        text_report=text_report(result, cfg, pointing_sigma_urad=pointing_sigma_urad),
    )
