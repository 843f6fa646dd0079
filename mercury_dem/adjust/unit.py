"""How one unit's merged network is adjusted (region, hemisphere, globe, or an imported ISIS network): pure.

:func:`adjust_unit_network` is the whole per-unit strategy, in this order:

1. the unit's configuration (:func:`~mercury_dem.adjust.cascade.unit_config`): islands allowed, images
   without measures held and named;
2. the solver: in memory, or over point blocks for a large unit of ``blocked_levels``
   (:func:`~mercury_dem.adjust.cascade.adjusts_by_blocks`);
3. where the free points start and their radius constraint is centred: the body's shape, the datum
   sphere or the network (:func:`~mercury_dem.adjust.datum.centre_point_priors`);
4. whether the block is re-centred on its own surface first (the levelling decision,
   :func:`~mercury_dem.adjust.datum.recentre_on_block`);
5. the solve itself, with the altimetry's radius constraints when there are shots;
6. the unit's summary (the ``levels`` rows of report.json): sizes, residuals, images whose RMS exceeds
   ``AdjustConfig.rms_flag_px``, islands.

The altimetry package sits above this one (it imports ``adjust/``), so what it contributes — which
points the shots would constrain (for the levelling decision) and the two-pass adjustment with radius
constraints from the shots — comes in as a :class:`HeightTerms` object the caller makes
(:class:`mercury_dem.altimetry.unit_terms.AltimetryTerms`); without one, no point is held by altimetry.
Arrays and dataclasses in and out: no path, no store, no printing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.datum import LevellingDecision, levelling_decision, recentre_on_block, recentres
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.config.adjust import AdjustConfig

if TYPE_CHECKING:
    from mercury_dem.network.model import ControlNetwork

__all__ = ["HeightTerms", "UnitAdjustment", "adjust_unit_network", "flagged_images", "point_prior_centre",
           "unit_summary"]

#: ``solve(problem, config) -> AdjustmentResult``: one adjustment (in memory or over point blocks).
Solve = Callable[[AdjustmentProblem, AdjustConfig], AdjustmentResult]


class HeightTerms(Protocol):
    """What the altimetry contributes to a unit's adjustment (made by the caller: altimetry sits above adjust/)."""

    def levelling(self, points_xyz: NDArray[np.float64], cfg: AdjustConfig) -> LevellingDecision:
        """The block's levelling decision (:func:`~mercury_dem.adjust.datum.levelling_decision`) with the
        points the shots would constrain counted.
        """
        ...

    def adjust(self, problem: AdjustmentProblem, cfg: AdjustConfig,
               solve: Solve) -> tuple[AdjustmentResult, dict[str, Any]] | None:
        """The adjustment with radius constraints from the shots, and its summary; None without shots."""
        ...


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


def adjust_unit_network(
    network: ControlNetwork,
    cameras: list[Any],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    config: AdjustConfig,
    *,
    pointing_sigma_urad: float,
    datum_radius_m: float,
    initial_rotations: NDArray[np.float64] | None = None,
    heights: HeightTerms | None = None,
    recentre_point_priors: bool = False,
    level: str | None = None,
    engine_factory: Any = None,
    prior_shape: Any = None,
) -> UnitAdjustment:
    """Adjust a merged network whose a-priori pose is ``positions``/``rotations`` (the strategy: module docstring),
    the rotations wrong by ``pointing_sigma_urad`` per axis (1 sigma, µrad: the run's a-priori pointing sigma).

    ``initial_rotations`` (a lower level's solution) is where the iteration starts; the pointing
    constraint stays centred on the a-priori ``rotations``. Islands (disconnected groups of images) are
    adjusted together, each held by its a-priori constraints, and reported by id; images whose RMS residual
    exceeds ``config.rms_flag_px`` are flagged; images without measures are held at their a-priori pose
    and named (``images_without_measures``).

    ``heights`` (:class:`HeightTerms`): the altimetry's part — the tie points near shots get radius
    constraints from them (two passes) and count in the levelling decision. None: no shots.

    ``recentre_point_priors``: the radius constraints of the non-held points are first re-centred on the
    block's own surface (:func:`~mercury_dem.adjust.datum.recentre_on_block`, one more adjustment) instead
    of the datum sphere — when the block calls for it (the levelling decision: wide enough to carry its
    own surface, not mostly held by the altimetry); the decision is the summary's ``levelling``.

    ``prior_shape`` (:class:`~mercury_dem.reference.body_shape.BodyShape`, a real mission's body shape): with
    ``config.point_prior_center == "shape"`` the free points start on it and their radius constraint is
    ``config.point_prior_shape_sigma_m`` (else the shape's ``prior_sigma_m``) instead of ``radius_sigma_m``
    (altimetry-constrained points keep the altimetry's); the block is not re-centred on its own surface (the
    shape carries the long wavelengths re-centring is for). None: the datum sphere; the summary's
    ``point_prior_centre`` says which.

    ``level``: the unit's level; a unit of ``config.blocked_levels`` with at least
    ``config.blocked_min_measures`` measures is adjusted over point blocks
    (:func:`~mercury_dem.adjust.blocked_bundle.blocked_bundle_adjust`, every pass: re-centring, altimetry,
    its blocks placed by ``engine_factory``), which gives the same solution to solver tolerance;
    ``summary["blocked"]`` says so.
    """
    from mercury_dem.adjust.cascade import unit_config
    from mercury_dem.adjust.network import network_with_result, problem_from_network
    from mercury_dem.adjust.report import text_report

    ids = np.asarray(network.image_ids).astype(str)
    cfg, no_measures = unit_config(config, ids.tolist(), network.measure_image)
    problem, measure_index = problem_from_network(
        network, cameras, positions, rotations, cfg, initial_rotations=initial_rotations,
        pointing_sigma_urad=pointing_sigma_urad,
    )
    solve, blocked = unit_solver(cfg, level, problem.n_measures, engine_factory)
    problem, cfg, centre = point_prior_centre(problem, cfg, datum_radius_m, prior_shape)
    extra: dict[str, Any] = {}
    decision = None
    if recentre_point_priors:
        decision = _levelling(problem.points, cfg, heights, prior_shape if centre["centre"] == "shape" else None)
        if recentres(decision, cfg):
            problem, extra["point_prior"] = recentre_on_block(problem, cfg, datum_radius_m, adjust=solve)
    with_shots = heights.adjust(problem, cfg, solve) if heights is not None else None
    if with_shots is not None:
        result, extra["altimetry"] = with_shots
    else:
        result = solve(problem, cfg)
    summary = unit_summary(result, problem, ids, no_measures, cfg.rms_flag_px)
    if blocked:
        summary["blocked"] = result.extra.get("blocked")
    if "altimetry" in extra:
        summary["altimetry"] = extra["altimetry"]
    summary["point_prior_centre"] = centre
    if "point_prior" in extra:
        summary["point_prior"] = extra["point_prior"]
    if decision is not None:
        summary["levelling"] = decision.summary()
    return UnitAdjustment(
        network=network_with_result(network, result, measure_index),
        rotations=np.asarray(result.rotations),
        positions=np.asarray(result.positions),
        image_measures=np.asarray(result.accepted_per_image, dtype=np.int64),
        image_rms_px=np.asarray(result.rms_per_image, dtype=np.float64),
        summary=summary,
        text_report=text_report(result, cfg, pointing_sigma_urad=pointing_sigma_urad),
    )


def unit_solver(cfg: AdjustConfig, level: str | None, n_measures: int, engine_factory: Any = None) -> tuple[Solve, bool]:
    """The unit's solve: :func:`~mercury_dem.adjust.bundle.bundle_adjust`, or the blocked adjustment for a large
    unit of ``cfg.blocked_levels`` (:func:`~mercury_dem.adjust.cascade.adjusts_by_blocks`); and whether blocked.
    """
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.adjust.cascade import adjusts_by_blocks

    if not adjusts_by_blocks(cfg, level, n_measures):
        return bundle_adjust, False
    from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust

    def solve(p: AdjustmentProblem, c: AdjustConfig) -> AdjustmentResult:
        return blocked_bundle_adjust(p, c, block_points=cfg.blocked_block_points, engine_factory=engine_factory)

    return solve, True


def point_prior_centre(problem: AdjustmentProblem, cfg: AdjustConfig, datum_radius_m: float,
                       prior_shape: Any = None) -> tuple[AdjustmentProblem, AdjustConfig, dict[str, Any]]:
    """The problem with its free points centred as ``cfg.point_prior_center`` says, the configuration whose
    ``radius_sigma_m`` is the shape's sigma when they are on a shape, and the summary's ``point_prior_centre``.

    ``"shape"`` without ``prior_shape`` (a synthetic mission, a body without a shape model) is the datum
    sphere, and the summary says why (:func:`~mercury_dem.adjust.datum.centre_point_priors`).
    """
    from mercury_dem.adjust.datum import centre_point_priors

    problem = centre_point_priors(problem, cfg.point_prior_center, datum_radius_m, shape=prior_shape)
    cfg, centre = prior_centre_config(cfg, datum_radius_m, prior_shape)
    return problem, cfg, centre


def prior_centre_config(cfg: AdjustConfig, datum_radius_m: float, prior_shape: Any = None
                        ) -> tuple[AdjustConfig, dict[str, Any]]:
    """:func:`point_prior_centre`'s configuration and summary alone (the points are moved elsewhere: by block)."""
    on_shape = cfg.point_prior_center == "shape" and prior_shape is not None
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
    return cfg, centre


def _levelling(points: NDArray[np.float64], cfg: AdjustConfig, heights: HeightTerms | None,
               shape: Any) -> LevellingDecision:
    """The levelling decision; on a body's ``shape`` a block the altimetry does not hold is not re-centred."""
    if heights is not None:
        decision = heights.levelling(points, cfg)
    else:  # no shots: no point is held by altimetry
        decision = levelling_decision(points, None, min_extent_deg=cfg.point_prior_recentre_min_extent_deg,
                                      max_altimetry_share=cfg.point_prior_recentre_max_altimetry_share)
    if shape is not None and decision.level_to_mean:  # (not held by the altimetry: that reason stands)
        decision = dataclasses.replace(decision, recentre=False, reason=(
            f"the block spans {decision.extent_deg:.1f} deg and the altimetry constrains "
            f"{decision.altimetry_share:.0%} of its points; the others are centred on the body's shape "
            f"({shape.name}), which carries the long wavelengths re-centring is for: not re-centred "
            "(levelled on the shots' mean if registered)"))
    return decision


def flagged_images(ids: NDArray[np.str_], rms_per_image: NDArray[np.float64], rms_flag_px: float) -> list[dict[str, Any]]:
    """The images whose RMS residual (px) exceeds ``rms_flag_px``, as ``{"image", "rms_px"}`` rows (NaN: not flagged)."""
    rms = np.asarray(rms_per_image, dtype=np.float64)
    return [{"image": str(ids[k]), "rms_px": float(rms[k])} for k in np.flatnonzero(np.nan_to_num(rms) > rms_flag_px)]


def unit_summary(result: AdjustmentResult, problem: AdjustmentProblem, ids: NDArray[np.str_],
                 no_measures: list[str], rms_flag_px: float) -> dict[str, Any]:
    """The unit's summary (a ``levels`` row of report.json, before the optional keys): sizes, residuals,
    rejections, convergence, images over ``rms_flag_px``, islands (listed when more than one).
    """
    islands = [[str(ids[i]) for i in isl] for isl in result.diagnosis.islands]
    return {
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
        "flagged_images": flagged_images(ids, result.rms_per_image, rms_flag_px),
        "islands": islands if len(islands) > 1 else [],
        "images_without_measures": no_measures,
    }
