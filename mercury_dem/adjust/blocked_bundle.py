"""``blocked_bundle_adjust``: :func:`~mercury_dem.adjust.bundle.bundle_adjust`'s contract over point blocks.

The pipeline's hemisphere and global units use it once they exceed
``adjust.blocked_min_measures`` (:func:`mercury_dem.adjust.unit.adjust_unit_network`):
the problem is cut into blocks of consecutive points, run through the blocked
Levenberg-Marquardt loop (:func:`~mercury_dem.adjust.blocked.blocked_levenberg_marquardt`,
in this process: :class:`~mercury_dem.adjust.blocked.SyncEngine`) and the blocks' state
is gathered back into an :class:`~mercury_dem.adjust.result.AdjustmentResult` in the
problem's own measure order, so reports, the adjusted network, altimetry's two passes
and the re-centred point priors work on it unchanged. Same loop, same rules: the result
equals ``bundle_adjust``'s to solver tolerance (``tests/adjust/test_blocked_bundle.py``).

Limits (those of the blocked loop): pointing only (``adjust.solve_positions`` is an
error); a-posteriori covariances (``adjust.posterior_sigmas``) of the images and sigmas of the
points, exact at any size (``blocked.blocked_posterior_sigmas``: the selected inverse of the reduced
system's sparse factor, :mod:`~mercury_dem.adjust.posterior`; the points' on the shards). The diagnosis (islands, images without measures) still runs on the
whole image-point graph, which the pipeline has in memory anyway.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.blocked import (
    BlockShard,
    CameraSetup,
    SyncEngine,
    blocked_levenberg_marquardt,
    blocked_posterior_sigmas,
    options_from_config,
)
from mercury_dem.adjust.bundle import check_projectable, held_image_mask, rms_by_group
from mercury_dem.adjust.diagnose import check_solvable, diagnose
from mercury_dem.adjust.problem import AdjustmentProblem, stated_pointing_sigma_urad
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.pose import angles_from_rotation
from mercury_dem.network.blocks import BlockData

#: ``(blocks, setup, options) -> context manager of an Engine`` (see :func:`blocked_bundle_adjust`)
EngineFactory = Callable[[list[BlockData], CameraSetup, Any], AbstractContextManager[Any]]


def point_blocks(problem: AdjustmentProblem, block_points: int) -> tuple[list[BlockData], list[NDArray[np.int64]]]:
    """Blocks of ``block_points`` consecutive points and, per block, its measures' indices in ``problem``."""
    order = np.argsort(problem.measure_point, kind="stable")
    mp = problem.measure_point[order]
    n_blocks = max(1, -(-problem.n_points // max(1, int(block_points))))
    edges = np.linspace(0, problem.n_points, n_blocks + 1).astype(np.int64)
    radius = problem.point_radius_sigma
    blocks, index = [], []
    for b in range(n_blocks):
        p0, p1 = int(edges[b]), int(edges[b + 1])
        m0, m1 = np.searchsorted(mp, [p0, p1])
        sel = order[m0:m1]
        blocks.append(BlockData(
            b, p0, problem.points[p0:p1], problem.measure_image[sel], mp[m0:m1] - p0, problem.measures[sel],
            problem.measure_sigma[sel], problem.held_points[p0:p1], None, None,
            point_radius_sigma=None if radius is None else np.asarray(radius[p0:p1], np.float64)))
        index.append(sel)
    return blocks, index


def blocked_bundle_adjust(problem: AdjustmentProblem, config: AdjustConfig | None = None, *,
                          block_points: int = 25_000, engine_factory: EngineFactory | None = None) -> AdjustmentResult:
    """Adjust pointing and points like :func:`~mercury_dem.adjust.bundle.bundle_adjust`, over point blocks.

    Parameters
    ----------
    problem : the network and its a-priori geometry (``initial_rotations`` is where the iteration starts).
    config : the adjustment configuration (``solve_positions`` must be false).
    block_points : points per block (each block keeps ~0.3 kB a measure between iterations and needs
        ~1 kB a measure of temporaries while it is linearized: docs/design/adjust.md).
    engine_factory : ``engine_factory(blocks, setup, options)`` gives a context manager whose value is an
        :class:`~mercury_dem.adjust.blocked.Engine` holding ``blocks`` (e.g. one
        :class:`~mercury_dem.adjust.blocked.BlockShard` per Dask worker:
        ``mercury_dem.pipeline.shard_engine.worker_shard_engine``); leaving the context releases them.
        None: one shard in this process.

    Returns
    -------
    AdjustmentResult in ``problem``'s measure and point order; ``image_sigmas``, ``image_covariances`` (pointing,
    rad) and ``point_sigmas`` (XYZ, m) when ``config.posterior_sigmas``.

    Raises
    ------
    AdjustmentError : an unsolvable network (as ``bundle_adjust``), ``solve_positions``, or measures that
        cannot be projected at the a-priori state.
    """
    config = config or AdjustConfig()
    if config.solve_positions:
        raise AdjustmentError("the blocked adjustment solves pointing only: set adjust.solve_positions: false "
                              "or raise adjust.blocked_min_measures above this unit's measures")
    t0 = time.perf_counter()
    held = held_image_mask(problem, config)
    diag = diagnose(problem, config.min_point_measures, config.min_image_measures)
    check_solvable(problem, diag, held, config.allow_islands)
    setup = CameraSetup(tuple(problem.cameras), np.asarray(problem.image_camera, np.int64),
                        np.asarray(problem.positions, np.float64), np.asarray(problem.rotations, np.float64), held,
                        stated_pointing_sigma_urad(problem.pointing_sigma_urad),
                        (config.point_longitude_sigma_m, config.point_latitude_sigma_m, config.radius_sigma_m),
                        config.blocked_float32, config.blocked_recompute_w)
    opt = options_from_config(config, float(np.median(problem.measure_sigma)))
    omega0 = np.zeros((problem.n_images, 3))
    if problem.initial_rotations is not None:  # as FramingModel.initial_state
        omega0 = angles_from_rotation(np.matmul(problem.initial_rotations, np.swapaxes(problem.rotations, -1, -2)))
    blocks, index = point_blocks(problem, block_points)
    index_of = {b.block: ix for b, ix in zip(blocks, index)}
    point_start = {b.block: b.point_start for b in blocks}
    del index
    if engine_factory is None:
        context: Any = contextlib.nullcontext(SyncEngine([BlockShard(blocks, setup, opt)]))
    else:
        context = engine_factory(blocks, setup, opt)
    del blocks
    points = np.array(problem.points, np.float64, copy=True)
    point_sigmas = None
    frozen = np.zeros(problem.n_points, bool)
    accepted = np.ones(problem.n_measures, bool)
    resid = np.zeros((problem.n_measures, 2))
    with context as engine:
        where = getattr(engine, "description", "in process")
        n_blocks = 0
        # the blocks without measures are dropped by the shards: the results name the blocks they hold
        r0 = np.full((problem.n_measures, 2), np.nan)
        for part in engine.call("initial_residuals", omega0):
            for blk, r in part:
                r0[index_of[blk]] = r
        check_projectable(problem, r0)
        initial_rms = float(np.sqrt(np.mean(r0 * r0)))
        del r0
        res = blocked_levenberg_marquardt(engine, setup, opt, initial_omega=omega0)
        post = None
        if config.posterior_sigmas:
            post = blocked_posterior_sigmas(engine, setup, res, points=True)
        if post is not None and post.point_sigmas is not None:
            point_sigmas = np.zeros((problem.n_points, 3))
            for blk, sig in post.point_sigmas:
                point_sigmas[point_start[blk]:point_start[blk] + len(sig)] = sig
        for part in engine.call("block_results"):
            n_blocks += len(part)
            for blk, pts, frz, act, r in part:
                ix = index_of[blk]
                p0 = int(point_start[blk])
                points[p0:p0 + len(pts)] = pts
                frozen[p0:p0 + len(pts)] = frz
                accepted[ix] = act
                resid[ix] = r
    rejected = ~accepted
    keep = accepted & ~frozen[problem.measure_point]
    sq = np.sum(resid * resid, axis=1)
    rms_img, n_img_acc = rms_by_group(problem.measure_image, sq, keep, problem.n_images)
    rms_pt, n_pt_acc = rms_by_group(problem.measure_point, sq, keep, problem.n_points)
    rk = resid[keep]
    rms = float(np.sqrt(np.mean(rk * rk))) if rk.size else float("nan")
    return AdjustmentResult(
        image_ids=problem.image_ids, point_ids=problem.point_ids, rotations=res.rotations,
        positions=np.asarray(problem.positions, np.float64).copy(), pointing_corrections=res.omega,
        position_corrections=np.zeros((problem.n_images, 3)), points=points, measure_image=problem.measure_image,
        measure_point=problem.measure_point, residuals_px=resid, rejected=rejected, sigma0=res.sigma0, rms_px=rms,
        rms_sample_px=float(np.sqrt(np.mean(rk[:, 0] ** 2))) if rk.size else float("nan"),
        rms_line_px=float(np.sqrt(np.mean(rk[:, 1] ** 2))) if rk.size else float("nan"),
        initial_rms_px=initial_rms, rms_per_image=rms_img, rms_per_point=rms_pt, accepted_per_image=n_img_acc,
        accepted_per_point=n_pt_acc, underdetermined_points=frozen,
        weak_images=(n_img_acc < config.min_image_measures) & ~held, iterations=res.iterations,
        converged=res.converged, reason=res.reason, log=tuple(res.log), seconds=time.perf_counter() - t0,
        solve_seconds=res.seconds, linear_method=res.linear_method, dof=res.dof, diagnosis=diag,
        extra={"blocked": {"blocks": n_blocks, "block_points": int(block_points), "engine": where,
                           "posterior_sigmas": "not asked (adjust.posterior_sigmas)" if post is None else
                           f"images and points (exact: selected inverse of the {post.method} factor)"}},
        image_sigmas=None if post is None else post.image_sigmas,
        image_covariances=None if post is None else post.image_covariances, point_sigmas=point_sigmas,
        posterior_seconds=0.0 if post is None else post.seconds,
    )
