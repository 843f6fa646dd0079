"""Bundle adjustment of one unit (region, hemisphere, globe): network in, adjusted network and pointing out.

Joins the control network (:mod:`mercury_dem.network`) and the adjustment engine
(:mod:`mercury_dem.adjust`) for the stage runners, and turns the result into the
unit's summary (the ``levels`` rows of report.json).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M


def on_datum(xyz: NDArray[np.float64], datum_radius_m: float = DATUM_RADIUS_M) -> NDArray[np.float64]:
    """Points moved radially onto the datum sphere (direction kept; zero vectors kept as they are).

    The a-priori point of a control point is, as in ISIS with an ellipsoid shape,
    where its ray meets the shape model — not the intersection of rays under the
    a-priori pointing: with pointing errors of a few hundred µrad and the small
    convergence of most pairs, that triangulation misplaces heights by kilometres, and
    a radius constraint centred there pins the points (and, through them, the pointing)
    to those errors. Measured on the tiny mission (global level, same network): image
    registration error 0.90 px with the triangulated centre, 0.37 px with the datum.
    """
    xyz = np.asarray(xyz, np.float64)
    r = np.linalg.norm(xyz, axis=-1, keepdims=True)
    return np.where(r > 0, xyz * (datum_radius_m / np.where(r > 0, r, 1.0)), xyz)


@dataclass(frozen=True)
class UnitAdjustment:
    network: Any  # ControlNetwork with adjusted points, residuals, rejections
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    image_measures: NDArray[np.int64]  # accepted measures per image
    image_rms_px: NDArray[np.float64]
    summary: dict[str, Any]
    text_report: str = ""  # jigsaw-like bundleout.txt of the solve


def adjust_network(
    network: Any,
    cameras: list[Any],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    config: AdjustConfig,
    *,
    initial_rotations: NDArray[np.float64] | None = None,
    rms_flag_px: float = 2.0,
    datum_radius_m: float = DATUM_RADIUS_M,
    altimetry: Any = None,
) -> UnitAdjustment:
    """Adjust a merged network whose a-priori pose is ``positions``/``rotations``.

    ``initial_rotations`` (a lower level's solution) is where the iteration
    starts; the pointing constraint stays centred on the a-priori ``rotations``.

    Islands (disconnected groups of images) are adjusted together, each held by
    its a-priori constraints, and reported by id; images whose RMS residual
    exceeds ``rms_flag_px`` are flagged; images without measures are held at their
    a-priori pose and named (``images_without_measures``).

    ``altimetry`` (:class:`~mercury_dem.altimetry.constraints.AltimetryShotsArrays`): the tie
    points near shots get radius constraints from them
    (:func:`~mercury_dem.altimetry.constraints.bundle_adjust_with_altimetry`, two passes).
    """
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.adjust.network import network_with_result, problem_from_network
    from mercury_dem.adjust.report import text_report

    cfg = dataclasses.replace(config, allow_islands=True)
    ids = np.asarray(network.image_ids).astype(str)
    # An image without a measure (an imported or edited network) carries no information: it is held at its
    # a-priori pose and named, instead of making the whole solve an AdjustmentError.
    no_measures = ids[np.bincount(network.measure_image, minlength=network.n_images) == 0]
    if no_measures.size:
        cfg = dataclasses.replace(cfg, held_images=tuple(dict.fromkeys([*cfg.held_images, *no_measures.tolist()])))
    problem, measure_index = problem_from_network(
        network, cameras, positions, rotations, cfg, initial_rotations=initial_rotations
    )
    if cfg.point_prior_center == "datum":
        held = np.asarray(problem.held_points, bool)[:, None]
        problem = dataclasses.replace(problem, points=np.where(held, problem.points, on_datum(problem.points, datum_radius_m)))
    altimetry_summary: dict[str, Any] | None = None
    if altimetry is not None and len(altimetry.radius_m):
        from mercury_dem.altimetry.constraints import bundle_adjust_with_altimetry

        result, priors = bundle_adjust_with_altimetry(
            problem, cfg, altimetry, search_radius_m=cfg.altimetry_search_m, min_shots=cfg.altimetry_min_shots,
            horizontal_sigma_m=cfg.altimetry_horizontal_sigma_m,
        )
        altimetry_summary = {"shots": int(len(altimetry.radius_m)), **priors.summary()}
    else:
        result = bundle_adjust(problem, cfg)
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
        "images_without_measures": no_measures.tolist(),
    }
    if altimetry_summary is not None:
        summary["altimetry"] = altimetry_summary
    return UnitAdjustment(
        network=adjusted,
        rotations=np.asarray(result.rotations),
        positions=np.asarray(result.positions),
        image_measures=np.asarray(result.accepted_per_image, dtype=np.int64),
        image_rms_px=rms_img,
        summary=summary,
        text_report=text_report(result, cfg),
    )
