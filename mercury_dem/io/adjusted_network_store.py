"""A unit adjusted straight from its merged store, its adjusted network written back by blocks.

For the hemisphere and global units of ``adjust.streamed_merge_levels``: the store
:func:`~mercury_dem.io.merged_network_store.stream_merge` wrote (the merged network plus its point blocks) is
adjusted by the blocked adjustment, each shard reading its own blocks (in this process, or one actor per Dask
worker through ``engine_factory``), and the adjusted network (points' adjusted coordinates, measures' residuals
and rejections, as :func:`~mercury_dem.adjust.network.network_with_result` records them; only the images with
measures, as ``drop_unused_images`` keeps them) is written a few blocks at a time to a new network store, built
under a temporary name and moved into place complete (:func:`~mercury_dem.io.atomic.atomic_directory`).

The calling process holds the camera system, per-image and per-point bookkeeping (the point ids, a flag a point)
and one block at a time: never the merged network nor its ``AdjustmentProblem``. The same solution as
:func:`~mercury_dem.adjust.unit.adjust_unit_network` over point blocks (tests/pipeline/test_unit_streamed_adjust.py).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import zarr
from numpy.typing import NDArray

from mercury_dem.adjust.blocked import (
    BlockShard,
    CameraSetup,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
)
from mercury_dem.adjust.datum import centred_points
from mercury_dem.adjust.problem import stated_pointing_sigma_urad
from mercury_dem.adjust.unit_streamed import BlockTally, StreamedProblemSize, StreamedUnitResult, UnitBlockPrior
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.pose import angles_from_rotation
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.io.network_store import CHUNK_ROWS, FORMAT_NAME, FORMAT_VERSION, write_strings
from mercury_dem.io.synthetic_network_store import BlockedNetwork, ColumnAppender, StoredBlocks
from mercury_dem.network.model import MEASURE_COLUMNS, OPTIONAL_POINT_COLUMNS, POINT_COLUMNS, PointType

#: blocks whose adjusted rows are fetched from the shards at once while the network is written back
FETCH_BLOCKS = 4


@dataclass(frozen=True)
class StoredUnitAdjustment:
    """A unit adjusted from its store: as :class:`~mercury_dem.adjust.unit.UnitAdjustment`, the network on disk."""

    network_path: Path
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    image_measures: NDArray[np.int64]
    image_rms_px: NDArray[np.float64]
    summary: dict[str, Any]
    text_report: str


def stored_image_ids(path: str | Path) -> NDArray[np.str_]:
    """The merged store's image ids (every child's image, with or without measures)."""
    return BlockedNetwork(path).store.image_ids.astype(str)


def adjust_stored_unit(
    path: str | Path, out: str | Path, image_ids: Sequence[str], cameras: Sequence[Any],
    positions: NDArray[np.float64], rotations: NDArray[np.float64], config: AdjustConfig, *,
    pointing_sigma_urad: float, datum_radius_m: float, initial_rotations: NDArray[np.float64] | None = None,
    engine_factory: Any = None, prior_shape: Any = None,
) -> StoredUnitAdjustment:
    """Adjust the merged store at ``path`` by its blocks and write the adjusted network to ``out``.

    ``image_ids``: the unit's images (those with measures, in the store's order) with their ``cameras`` and
    a-priori ``positions``/``rotations``; ``initial_rotations``: where the iteration starts (the children's
    reconciled solutions). The rest as :func:`~mercury_dem.adjust.unit.adjust_unit_network` (whose callers
    decide with :func:`~mercury_dem.adjust.unit_streamed.streamed_fallback_reason` that this path applies).
    Raises :class:`~mercury_dem.exceptions.AdjustmentError` for an unsolvable network,
    :class:`~mercury_dem.exceptions.StoreError` for a damaged store.
    """
    from mercury_dem.adjust.report import text_report
    from mercury_dem.adjust.unit import prior_centre_config, unit_summary

    t0 = time.perf_counter()
    net = BlockedNetwork(path)
    ids = tuple(str(i) for i in image_ids)
    index = {k: i for i, k in enumerate(ids)}
    image_map = np.array([index.get(str(k), -1) for k in net.store.image_ids], np.int64)
    cfg, centre = prior_centre_config(dataclasses.replace(config, allow_islands=True), datum_radius_m, prior_shape)
    prior = UnitBlockPrior(image_map, config.point_prior_center, float(datum_radius_m), prior_shape)
    blocks = StoredBlocks(str(net.root), tuple(range(net.n_blocks)), prior)
    held = _held(ids, cfg)
    tally = BlockTally(len(ids))
    for blk in blocks:
        tally.add_graph(blk, cfg.min_point_measures)
    diag = tally.diagnosis(cfg.min_image_measures)
    tally.check_solvable(diag, held, ids)
    setup, opt, omega0 = _setup(net, cameras, positions, rotations, held, cfg, pointing_sigma_urad, initial_rotations)
    context = (contextlib.nullcontext(SyncEngine([BlockShard(blocks, setup, opt)])) if engine_factory is None
               else engine_factory(blocks, setup, opt))
    with context as engine:
        where = getattr(engine, "description", "in process")
        initial_rms = _initial_rms(engine, omega0, ids)
        res = blocked_levenberg_marquardt(engine, setup, opt, initial_omega=omega0)
        point_ids, frozen, n_blocks = write_adjusted_network(net, Path(out), engine, prior, ids, tally)
    rms, rms_s, rms_l = tally.rms()
    rms_img = tally.rms_per_image()
    result = StreamedUnitResult(
        image_ids=ids, point_ids=point_ids, rotations=res.rotations, positions=np.asarray(positions, np.float64).copy(),
        n_measures=tally.n_measures, n_rejected=tally.rejected, rms_px=rms, rms_sample_px=rms_s, rms_line_px=rms_l,
        initial_rms_px=initial_rms, sigma0=res.sigma0, underdetermined_points=frozen,
        weak_images=(tally.keep_image < cfg.min_image_measures) & ~held, rms_per_image=rms_img,
        accepted_per_image=tally.keep_image, diagnosis=diag, iterations=res.iterations, converged=res.converged,
        reason=res.reason, log=tuple(res.log), linear_method=res.linear_method, dof=res.dof,
        solve_seconds=res.seconds, seconds=time.perf_counter() - t0)
    size = StreamedProblemSize(len(ids), net.n_points, tally.n_measures)
    summary = unit_summary(cast(Any, result), cast(Any, size), np.array(ids), [], cfg.rms_flag_px)
    summary["blocked"] = {"blocks": n_blocks, "block_points": int(config.blocked_block_points), "engine": where,
                          "posterior_sigmas": "not asked (adjust.posterior_sigmas)"}
    summary["point_prior_centre"] = centre
    return StoredUnitAdjustment(Path(out), res.rotations, result.positions, tally.keep_image, rms_img, summary,
                                text_report(cast(Any, result), cfg, pointing_sigma_urad=pointing_sigma_urad))


def _held(ids: tuple[str, ...], cfg: AdjustConfig) -> NDArray[np.bool_]:
    """As :func:`~mercury_dem.adjust.bundle.held_image_mask` (``adjust.held_images``, unknown ids an error)."""
    held = np.zeros(len(ids), bool)
    index = {k: i for i, k in enumerate(ids)}
    unknown = [k for k in cfg.held_images if k not in index]
    if unknown:
        raise AdjustmentError(f"adjust.held_images names images not in the network: {unknown[:10]}")
    held[[index[k] for k in cfg.held_images]] = True
    return held


def _setup(net: BlockedNetwork, cameras: Sequence[Any], positions: NDArray[np.float64],
           rotations: NDArray[np.float64], held: NDArray[np.bool_], cfg: AdjustConfig, pointing_sigma_urad: float,
           initial_rotations: NDArray[np.float64] | None) -> tuple[CameraSetup, Any, NDArray[np.float64]]:
    """The camera setup, solver options and start as ``problem_from_network`` + ``blocked_bundle_adjust`` make them."""
    distinct: dict[Any, int] = {}
    image_camera = np.array([distinct.setdefault(c, len(distinct)) for c in cameras], dtype=np.int64)
    rot = np.asarray(rotations, np.float64)
    setup = CameraSetup(tuple(distinct), image_camera, np.asarray(positions, np.float64), rot, held,
                        stated_pointing_sigma_urad(pointing_sigma_urad),
                        (cfg.point_longitude_sigma_m, cfg.point_latitude_sigma_m, cfg.radius_sigma_m),
                        cfg.blocked_float32, cfg.blocked_recompute_w)
    median = float(net.store.attrs.get("streamed_merge", {}).get("median_sigma_px", 1.0))
    opt = options_from_config(cfg, median)
    omega0 = np.zeros((len(rot), 3))
    if initial_rotations is not None:  # as FramingModel.initial_state
        omega0 = angles_from_rotation(np.matmul(np.asarray(initial_rotations, np.float64), np.swapaxes(rot, -1, -2)))
    return setup, opt, omega0


def _initial_rms(engine: Any, omega0: NDArray[np.float64], ids: tuple[str, ...]) -> float:
    """The a-priori RMS residual (px) summed on the shards; an error if a measure cannot be projected there."""
    sq = n = bad = 0.0
    for part in engine.call("initial_residual_sums", omega0):
        for s, c, b in part:
            sq, n, bad = sq + s, n + c, bad + b
    if bad:
        raise AdjustmentError(f"{int(bad)} measures cannot be projected at the a-priori pointing (the point behind "
                              "the camera or off the body): fix their a-priori points or reject them")
    return float(np.sqrt(sq / n)) if n else float("nan")


def write_adjusted_network(net: BlockedNetwork, out: Path, engine: Any, prior: UnitBlockPrior,
                           ids: tuple[str, ...], tally: BlockTally) -> tuple[NDArray[Any], NDArray[np.bool_], int]:
    """The adjusted network written to ``out`` a few blocks at a time (the layout of ``write_network``); the
    residual statistics added to ``tally``. Returns the point ids, each point's frozen flag and the blocks the
    shards held (those with measures).
    """
    store = net.store
    optional = tuple(n for n in OPTIONAL_POINT_COLUMNS if n in store.attrs.get("optional_columns", []))
    point_ids = store.column_rows("point_ids", 0, store.n_points)
    frozen = np.zeros(store.n_points, bool)
    n_held = 0
    with atomic_directory(out) as tmp:
        g = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        write_strings(g, "image_ids", np.array(ids))
        if point_ids.dtype.kind == "U":
            write_strings(g, "point_ids", point_ids)
        else:
            g.create_array("point_ids", data=point_ids.astype(np.int64), chunks=(max(1, min(CHUNK_ROWS, len(point_ids))),))
        pcols = ColumnAppender(g, {**POINT_COLUMNS, **{n: OPTIONAL_POINT_COLUMNS[n] for n in optional}})
        mcols = ColumnAppender(g, MEASURE_COLUMNS)
        for b0 in range(0, net.n_blocks, FETCH_BLOCKS):
            want = tuple(range(b0, min(net.n_blocks, b0 + FETCH_BLOCKS)))
            got = {r[0]: r for part in engine.call("block_results_of", want) for r in part}
            n_held += len(got)
            for b in want:
                p, m = _block_rows(net, b, (*POINT_COLUMNS, *optional), tuple(MEASURE_COLUMNS))
                _adjusted_rows(net, b, p, m, got.get(b), prior, frozen, tally)
                pcols.append(p)
                mcols.append(m)
        pcols.flush()
        mcols.flush()
        g.attrs.update({
            "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "n_images": len(ids), "n_points": store.n_points,
            "n_measures": store.n_measures, "point_id_kind": "str" if point_ids.dtype.kind == "U" else "int64",
            "optional_columns": list(optional), "metadata": dict(store.metadata),
        })
    return point_ids, frozen, n_held


def _block_rows(net: BlockedNetwork, b: int, pnames: tuple[str, ...],
                mnames: tuple[str, ...]) -> tuple[dict[str, NDArray[Any]], dict[str, NDArray[Any]]]:
    p0, p1 = int(net.point_offsets[b]), int(net.point_offsets[b + 1])
    m0, m1 = int(net.measure_offsets[b]), int(net.measure_offsets[b + 1])
    return ({k: net.store.column_rows(k, p0, p1) for k in pnames},
            {k: net.store.column_rows(k, m0, m1) for k in mnames})


def _adjusted_rows(net: BlockedNetwork, b: int, p: dict[str, NDArray[Any]], m: dict[str, NDArray[Any]],
                   got: Any, prior: UnitBlockPrior, frozen: NDArray[np.bool_], tally: BlockTally) -> None:
    """Block ``b``'s stored rows ``p``/``m`` made the adjusted network's (in place), as ``network_with_result``."""
    p0 = int(net.point_offsets[b])
    mp = m["measure_point"] - p0
    bad_point = p["point_ignored"] | p["point_rejected"]
    active = np.flatnonzero(~(m["measure_ignored"] | m["measure_rejected"] | bad_point[mp]))
    m["measure_image"] = prior.image_map[m["measure_image"]]
    m["residuals"] = np.full((len(mp), 2), np.nan)
    if got is None:  # no active measure: the points stay at their centred a-priori place, as in memory
        p["adjusted_xyz"] = centred_points(p["apriori_xyz"], p["point_type"] == PointType.FIXED, prior.center,
                                           prior.datum_radius_m, prior.shape)
        return
    _, pts, frz, acc, r = got
    p["adjusted_xyz"] = np.asarray(pts, np.float64)
    frozen[p0:p0 + len(frz)] = frz
    m["residuals"][active] = -r
    rejected = np.asarray(m["measure_rejected"]).copy()
    rejected[active] = ~acc
    m["measure_rejected"] = rejected
    keep = acc & ~np.asarray(frz)[mp[active]]
    tally.add_result(m["measure_image"][active], keep, np.asarray(r, np.float64), acc)
