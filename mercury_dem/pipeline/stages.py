"""Stage runners: each reads its inputs from the run store, calls pure functions, writes atomically.

Every runner takes plain arguments (paths, ids, the configuration) and returns a
small JSON-able summary dict, so it runs the same in a Dask task, in the
synchronous client or in a plain loop. Expected failures (a tile with no
overlapping images, a region whose tiles all failed, an unsolvable adjustment)
are returned as ``{"ok": False, "error": "..."}`` summaries, and written, so the
run goes on and a resumed run does not retry them (``--force`` does).

Thin runners (issue 20): a runner loads its inputs, calls the library and saves. The decisions that
change a result are library functions (:mod:`mercury_dem.adjust.cascade`, :mod:`mercury_dem.adjust.datum`,
:func:`mercury_dem.network.check.singular_parts`, :func:`mercury_dem.altimetry.constraints.shot_tiles_for_points`);
summaries are typed (:mod:`mercury_dem.pipeline.results`, serialized there) and every file is written by
:class:`~mercury_dem.io.run_store.RunStore` (``write_plan``, ``write_unit``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from mercury_dem.compute.failures import raise_if_run_stopping, run_stopping_error
from mercury_dem.config import Config, to_dict
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.geometry.pose import validate_pose
from mercury_dem.io.run_store import RunStore, read_solution, unit_name  # unit_name: re-exported
from mercury_dem.mission import Mission, open_mission
from mercury_dem.pipeline.results import (
    FailureSummary,
    TileCounts,
    TileSummary,
    UnitFailure,
    UnitFiles,
    UnitSolution,
    UnitSummary,
    UnitTiming,
    failure_of,
    read_summary,
)
from mercury_dem.plan.tree import CHILD_LEVEL as LEVEL_CHILD
from mercury_dem.plan.tree import child_ids as _tree_child_ids

if TYPE_CHECKING:
    from mercury_dem.altimetry.constraints import AltimetryShotsArrays
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.network.model import ControlNetwork

#: Point ids of tile t start at t * POINT_ID_STRIDE, so ids stay unique when tiles merge.
POINT_ID_STRIDE = 10_000_000


# --------------------------------------------------------------------------- plan
def plan_run(store: RunStore, mission: Mission, config: Config) -> dict[str, Any]:
    """Tile of every image and the a-priori overlap graph, written to ``RUN/plan``.

    Images whose geometry is unusable (NaN, non-orthonormal rotation) are kept in
    the table with ``excluded_reason`` and take no further part
    (:func:`~mercury_dem.plan.images.plan_images` is the plan).
    """
    from mercury_dem.plan.images import plan_images

    t0 = time.perf_counter()
    cat = mission.catalog
    ids = cat["image_id"].to_numpy(dtype=str)
    cameras, cam_idx, positions, rotations, excluded = apriori_geometry(mission, ids)
    plan = plan_images(ids, cat["center_lat"].to_numpy(dtype=float), cat["center_lon"].to_numpy(dtype=float),
                       cameras, cam_idx, positions, rotations, excluded, tile_size_deg=config.tiling.tile_size_deg,
                       min_overlap_fraction=config.tiling.min_overlap_fraction,
                       datum_radius_m=mission.body.datum_radius_m)
    ok = plan.ok
    images = pd.DataFrame({
        "image_id": ids, "tile_id": plan.tile, "region_id": plan.region,
        "excluded_reason": plan.excluded.astype(str),
    })
    pairs = pd.DataFrame({
        "i": plan.i, "j": plan.j, "image_i": ids[plan.i], "image_j": ids[plan.j], "fraction": plan.fraction,
    })
    info = {
        "tile_size_deg": plan.tile_size_deg,
        "tiles_total": plan.tiles_total,
        "non_empty_tiles": plan.non_empty_tiles(),
        "images": int(ids.size),
        "excluded": {str(a): str(b) for a, b in zip(ids[~ok], plan.excluded[~ok])},
        "overlap_pairs": int(len(pairs)),
        "seconds": time.perf_counter() - t0,
    }
    store.write_plan(images, pairs, info)
    return info


def apriori_geometry(mission: Mission, ids: np.ndarray) -> tuple[list[Any], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each image's camera (distinct cameras and the index of each image's), a-priori position and rotation, and
    why an image's geometry is unusable ("" when it is usable; its pose then stays zero / identity).
    """
    cameras: list[Any] = []
    cam_idx = np.zeros(ids.size, dtype=np.int64)
    positions = np.zeros((ids.size, 3))
    rotations = np.tile(np.eye(3), (ids.size, 1, 1))
    excluded = np.full(ids.size, "", dtype=object)
    for k, image_id in enumerate(ids):
        try:
            cam = mission.camera(image_id)
            c, r = mission.a_priori_pose(image_id)
            validate_pose(image_id, c, r)
        except MercuryDemError as exc:
            excluded[k] = str(exc)
            continue
        if cam not in cameras:
            cameras.append(cam)
        cam_idx[k] = cameras.index(cam)
        positions[k], rotations[k] = c, r
    return cameras, cam_idx, positions, rotations, excluded


def tile_pairs(images: pd.DataFrame, pairs: pd.DataFrame, tile_id: int) -> list[tuple[str, str]]:
    """(reference, match) pairs of a tile: every tile image with every image overlapping it.

    A pair of two images of the tile is matched once (the first in catalog order is
    the reference); a pair with one image outside the tile has the tile's image as
    reference (the neighbouring tile matches it again the other way round; the
    merge joins the two).
    """
    in_tile = images["tile_id"].to_numpy() == tile_id
    ok = images["excluded_reason"].to_numpy(dtype=str) == ""
    i, j = pairs["i"].to_numpy(), pairs["j"].to_numpy()
    ids = images["image_id"].to_numpy(dtype=str)
    a_in, b_in = in_tile[i] & ok[i] & ok[j], in_tile[j] & ok[i] & ok[j]
    out: list[tuple[str, str]] = []
    for a, b in zip(i[a_in], j[a_in]):
        out.append((ids[a], ids[b]))  # i < j: the first is the reference
    for a, b in zip(i[b_in & ~a_in], j[b_in & ~a_in]):
        out.append((ids[b], ids[a]))
    return out


def _geometry(mission: Mission, image_ids: list[str]) -> tuple[dict[str, Any], list[Any], np.ndarray, np.ndarray, np.ndarray]:
    from mercury_dem.match.pretransform import ImageGeometry

    geom: dict[str, Any] = {}
    cameras, positions, rotations = [], [], []
    for image_id in image_ids:
        cam = mission.camera(image_id)
        c, r = mission.a_priori_pose(image_id)
        geom[image_id] = ImageGeometry.of(cam, c, r, mission.sun_position(image_id), mission.body.datum_radius_m)
        cameras.append(cam)
        positions.append(c)
        rotations.append(r)
    return geom, cameras, np.array(positions).reshape(-1, 3), np.array(rotations).reshape(-1, 3, 3), np.array(image_ids)


# --------------------------------------------------------------------------- tiles
def run_tile(run_root: str, tile_id: int, config: Config) -> dict[str, Any]:
    """Match every image of a tile with its overlaps and build the tile's control network.

    Returns the tile's summary in its JSON form (:class:`~mercury_dem.pipeline.results.TileSummary`), as written.
    """
    store = RunStore(run_root)
    if store.unit_complete("tile", tile_id):
        return store.read_summary("tile", tile_id)
    t0 = time.perf_counter()
    try:
        counts, files = _run_tile(store, tile_id, config)
    except MercuryDemError as exc:
        raise_if_fatal(exc, "tile", tile_id, store)
        return _write_unit(store, "tile", tile_id, TileSummary(id=int(tile_id), error=f"tile {tile_id}: {exc}",
                                                               failure=failure_of(exc)), t0)
    ok = counts.points > 0
    summary = TileSummary(id=int(tile_id), ok=ok, error=None if ok else _no_points_reason(tile_id, counts),
                          counts=counts, failure=None if ok else _no_points_failure(counts))
    return _write_unit(store, "tile", tile_id, summary, t0, files=files)


def _no_points_failure(s: TileCounts) -> UnitFailure:
    """The kind of a tile without control points: no pairs to match, or pairs that matched nothing."""
    return UnitFailure.NO_PAIRS if s.pairs == 0 else UnitFailure.NO_MATCH


def _no_points_reason(tile_id: int, s: TileCounts) -> str:
    if s.pairs == 0:
        return (f"tile {tile_id}: no overlapping image pairs ({s.images} images); "
                "nothing to match — add images that overlap these or accept them as uncontrolled")
    top = ", ".join(f"{k} ({v})" for k, v in sorted(s.pair_failures.items(), key=lambda kv: -kv[1])[:3])
    return f"tile {tile_id}: {s.pairs} pairs gave no control point; pair failures: {top or 'none'}"


@dataclasses.dataclass(frozen=True)
class TileInputs:
    """What a tile's matching reads: its pairs, the images' pixels and geometry, and the matching configuration."""

    ref_ids: list[str]  # the tile's own usable images
    pairs: list[tuple[str, str]]  # (reference, match), :func:`tile_pairs`
    pixels: dict[str, Any]  # image id -> pixels, None where unreadable
    image_errors: dict[str, str]  # image id -> why its pixels are unusable
    geometry: dict[str, Any]  # image id -> ImageGeometry
    cameras: list[Any]
    positions: np.ndarray  # (n, 3) a priori, in ``ids`` order
    rotations: np.ndarray  # (n, 3, 3)
    ids: np.ndarray  # every image involved, sorted
    radiometry: dict[str, tuple[Any, Any]]  # image id -> (saturation, dn_scale)
    match_cfg: Any  # the run's MatchConfig


def _run_tile(store: RunStore, tile_id: int, config: Config) -> tuple[TileCounts, UnitFiles]:
    from mercury_dem.match.result import failure_counts, iter_rows
    from mercury_dem.match.tile import match_tile

    mission = open_mission(store.read_run()["mission"])
    t = tile_inputs(store, mission, tile_id, config)
    matches, reports = match_tile(t.pixels, t.geometry, t.pairs, t.match_cfg, tracks=t.match_cfg.tracks,
                                  radiometry=t.radiometry, pointing_sigma_urad=pointing_sigma_urad_for(mission, config))
    rows = pd.DataFrame(list(iter_rows(reports)))
    net = _tile_network(t, matches, reports, tile_id, config, mission.body.datum_radius_m)
    failures, redundant = failure_counts(reports)
    counts = TileCounts(
        images=len(t.ref_ids),
        images_involved=len(t.ids),
        pairs=len(t.pairs),
        pairs_matched=int((rows["status"] == "matched").sum()) if len(rows) else 0,
        routes=rows["route"].value_counts().to_dict() if len(rows) else {},
        pair_failures=failures,
        image_errors=t.image_errors,
        points=int(net.n_points),
        measures=int(net.n_measures),
        pairs_redundant=redundant,
    )
    return counts, UnitFiles(network=net, pairs=rows)


def tile_inputs(store: RunStore, mission: Mission, tile_id: int, config: Config) -> TileInputs:
    """Read a tile's inputs: its pairs from the plan, every involved image's pixels (an unreadable or unusable
    image is named in ``image_errors``, not raised), geometry and radiometry.
    """
    from mercury_dem.match.prepare import pixel_faults

    images, pairs, _ = store.read_plan()
    pair_list = tile_pairs(images, pairs, tile_id)
    ref_ids = images.loc[(images["tile_id"] == tile_id) & (images["excluded_reason"] == ""), "image_id"].tolist()
    involved = sorted({x for p in pair_list for x in p} | set(ref_ids))
    pixels: dict[str, Any] = {}
    image_errors: dict[str, str] = {}
    for image_id in involved:
        try:
            pixels[image_id] = mission.read_image(image_id)
        except MercuryDemError as exc:
            pixels[image_id] = None
            image_errors[image_id] = str(exc)
    geom, cameras, positions, rotations, ids = _geometry(mission, involved)
    radiometry = {i: (r.saturation, r.dn_scale) for i in involved for r in [mission.radiometry(i)]}
    match_cfg = config.match
    image_errors.update(pixel_faults(pixels, radiometry, match_cfg))
    return TileInputs(ref_ids, pair_list, pixels, image_errors, geom, cameras, positions, rotations, ids,
                      radiometry, match_cfg)


def _tile_network(t: TileInputs, matches: Any, reports: list[Any], tile_id: int, config: Config,
                  datum_radius_m: float) -> ControlNetwork:
    """The tile's control network from its matches (:func:`~mercury_dem.network.build.build_network`); point ids
    start at ``tile_id * POINT_ID_STRIDE``; measures of convergent pairs weighted by their convergence.
    """
    from mercury_dem.network.build import build_network, convergence_sigma_factor

    conv = np.array([r.convergence_deg for r in reports], np.float64)
    factor = convergence_sigma_factor(conv[matches.pair] if conv.size else np.zeros(0),
                                      config.network.convergent_sigma_from_deg, config.network.convergent_sigma_max_factor)
    return build_network(
        t.ids, matches, t.cameras, t.positions, t.rotations,
        sigma_factor=factor,
        tolerance_px=config.network.merge_tolerance_px,
        point_id_start=int(tile_id) * POINT_ID_STRIDE,
        sigma_px=config.network.measure_sigma_px,
        metadata={"level": "tile", "tile_id": str(tile_id)},
        datum_radius_m=datum_radius_m,
    ).network


def _write_unit(store: RunStore, level: str, unit_id: int, summary: TileSummary | UnitSummary, t0: float,
                files: UnitFiles | None = None) -> dict[str, Any]:
    """Write a unit through :meth:`RunStore.write_unit` with its timing; return its summary's JSON form."""
    out = dataclasses.replace(summary, timing=UnitTiming.since(t0)).to_json()
    store.write_unit(level, unit_id, out, (files or UnitFiles()).writers())
    return out


# --------------------------------------------------------------------------- cascade
def child_ids(level: str, unit_id: int, config: Config) -> list[int]:
    """Ids of the units of the level below that make up a region, hemisphere or the globe."""
    return _tree_child_ids(level, unit_id, config.tiling.tile_size_deg)


def run_adjust_unit(run_root: str, level: str, unit_id: int, config: Config,
                    children: list[dict[str, Any]] | None = None, engine_factory: Any = None) -> dict[str, Any]:
    """Merge the networks of a unit's children and bundle adjust them (region, hemisphere, globe).

    ``children`` are the children's summaries (passed so a task graph orders the
    work; the data itself is read from the store). ``engine_factory``: where a blocked
    adjustment's point blocks go (:func:`~mercury_dem.adjust.unit.adjust_unit_network`).
    """
    store = RunStore(run_root)
    if store.unit_complete(level, unit_id):
        return store.read_summary(level, unit_id)
    t0 = time.perf_counter()
    try:
        summary, files = _adjust_unit(store, level, unit_id, config, engine_factory=engine_factory)
    except MercuryDemError as exc:
        raise_if_fatal(exc, level, unit_id, store)
        summary = UnitSummary(level, int(unit_id), error=f"{unit_name(level, unit_id)}: {exc}", failure=failure_of(exc))
        files = UnitFiles()
    return _write_unit(store, level, unit_id, summary, t0, files=files)


def _no_children_reason(store: RunStore, level: str, unit_id: int, child_level: str, config: Config) -> str:
    """Why a unit has nothing to merge: each failed child named with its own error, the empty ones counted."""
    failed = []
    empty = 0
    for c in child_ids(level, unit_id, config):
        if not store.unit_complete(child_level, c):
            empty += 1
            continue
        err = read_summary(store, child_level, c).error or "no network"
        failed.append(str(err))
    parts = "; ".join(failed[:5]) + (f"; ... {len(failed) - 5} more" if len(failed) > 5 else "")
    return (f"no successful {child_level} network to merge: {len(failed)} failed"
            + (f" ({parts})" if failed else "") + f", {empty} without images or not run"
            + " — images in no other network keep their a-priori pointing")


def _adjust_unit(store: RunStore, level: str, unit_id: int, config: Config,
                 engine_factory: Any = None) -> tuple[UnitSummary, UnitFiles]:
    from mercury_dem.pipeline.unit_merge import merge_children

    child_level = LEVEL_CHILD[level]
    kids = [c for c in child_ids(level, unit_id, config)
            if store.unit_complete(child_level, c) and read_summary(store, child_level, c).ok]
    if not kids:
        raise _NoInput(_no_children_reason(store, level, unit_id, child_level, config))
    if level in config.adjust.streamed_merge_levels:
        return _adjust_unit_streamed(store, level, unit_id, kids, config, engine_factory)
    merged_all = merge_children(store, level, unit_id, kids, config)
    return _adjust_unit_in_memory(store, level, unit_id, kids, merged_all, config, engine_factory)


def _adjust_unit_in_memory(store: RunStore, level: str, unit_id: int, kids: list[int], merged_all: ControlNetwork,
                           config: Config, engine_factory: Any = None,
                           streamed: dict[str, Any] | None = None) -> tuple[UnitSummary, UnitFiles]:
    """The unit's merged network adjusted in memory; ``streamed``: why a unit of ``streamed_merge_levels`` was."""
    from mercury_dem.adjust.unit import adjust_unit_network
    from mercury_dem.altimetry.unit_terms import AltimetryTerms
    from mercury_dem.network.check import singular_parts

    merged = merged_all.drop_unused_images()
    if merged.n_measures == 0:
        raise _NoInput("the merged network has no measures")
    singular = singular_parts(merged_all, merged)
    mission = open_mission(store.read_run()["mission"])
    ids = [str(x) for x in merged.image_ids]
    cameras, positions, rotations, start_rot = _unit_geometry(store, mission, LEVEL_CHILD[level], kids, ids)
    adjust_cfg = config.adjust
    adj = adjust_unit_network(merged, cameras, positions, rotations, adjust_cfg,
                              pointing_sigma_urad=pointing_sigma_urad_for(mission, config),
                              initial_rotations=start_rot, datum_radius_m=mission.body.datum_radius_m,
                              heights=AltimetryTerms(unit_altimetry(mission, merged, level, adjust_cfg)),
                              recentre_point_priors=level in adjust_cfg.point_prior_recentre_levels, level=level,
                              engine_factory=engine_factory, prior_shape=prior_shape_of(mission))
    adjustment = dict(adj.summary)
    if streamed is not None:
        adjustment["streamed"] = streamed
    return _unit_result(level, unit_id, kids, adjustment, singular, ids, adj,
                        UnitFiles(network=adj.network, bundleout=adj.text_report))


def _adjust_unit_streamed(store: RunStore, level: str, unit_id: int, kids: list[int], config: Config,
                          engine_factory: Any = None) -> tuple[UnitSummary, UnitFiles]:
    """A unit of ``adjust.streamed_merge_levels``: merged by parts into a scratch store and adjusted from its
    blocks, the adjusted network written back by blocks (never in this process whole); in memory where that
    path does not apply yet, the summary's ``streamed`` saying why.
    """
    from mercury_dem.adjust.unit_streamed import streamed_fallback_reason
    from mercury_dem.io.adjusted_network_store import adjust_stored_unit, stored_image_ids
    from mercury_dem.io.merged_network_store import stored_singular_parts
    from mercury_dem.io.network_store import read_network
    from mercury_dem.pipeline.unit_merge import adjusted_scratch, streamed_children

    mission = open_mission(store.read_run()["mission"])
    cfg = config.adjust
    with streamed_children(store, level, unit_id, kids, config, mission) as (path, merge):
        if merge.stats.n_measures == 0:
            raise _NoInput("the merged network has no measures")
        reason = streamed_fallback_reason(cfg, level, merge.stats.n_measures,
                                          altimetry=_has_altimetry(mission, level, cfg))
        if reason is not None:
            return _adjust_unit_in_memory(store, level, unit_id, kids, read_network(path / "network"), config,
                                          engine_factory, streamed={"used": False, "reason": reason})
        singular = stored_singular_parts(path / "network")
        unused = set(singular["images_without_measures"])
        ids = [i for i in stored_image_ids(path).tolist() if i not in unused]
        cameras, positions, rotations, start_rot = _unit_geometry(store, mission, LEVEL_CHILD[level], kids, ids)
        adj = adjust_stored_unit(path, adjusted_scratch(store, level, unit_id), ids, cameras, positions, rotations,
                                 cfg, pointing_sigma_urad=pointing_sigma_urad_for(mission, config),
                                 datum_radius_m=mission.body.datum_radius_m, initial_rotations=start_rot,
                                 engine_factory=engine_factory, prior_shape=prior_shape_of(mission))
    adjustment = dict(adj.summary)
    adjustment["streamed"] = {"used": True, "merge_parts": merge.merge_parts, "blocks": merge.n_blocks,
                              "merged_measures": merge.stats.n_measures}
    return _unit_result(level, unit_id, kids, adjustment, singular, ids, adj,
                        UnitFiles(network_dir=adj.network_path, bundleout=adj.text_report))


def _unit_geometry(store: RunStore, mission: Mission, child_level: str, kids: list[int],
                   ids: list[str]) -> tuple[list[Any], Any, Any, Any]:
    """The unit's images' cameras, a-priori positions and rotations, and where the iteration starts (the
    children's reconciled solutions; None above tiles' children).
    """
    cameras = [mission.camera(i) for i in ids]
    positions = np.array([mission.a_priori_pose(i)[0] for i in ids]).reshape(-1, 3)
    rotations = np.array([mission.a_priori_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    start_rot = None
    if child_level != "tile":
        start_rot, _ = reconcile_solutions(store, child_level, kids, ids, rotations, positions)
    return cameras, positions, rotations, start_rot


def _unit_result(level: str, unit_id: int, kids: list[int], adjustment: dict[str, Any], singular: dict[str, Any],
                 ids: list[str], adj: Any, files: UnitFiles) -> tuple[UnitSummary, UnitFiles]:
    """The unit's summary and files from its adjustment (``adj``: in memory or from its store)."""
    adjustment["images_without_measures"] = sorted(set(singular["images_without_measures"])
                                                   | set(adjustment.get("images_without_measures", [])))
    summary = UnitSummary(level, int(unit_id), ok=True, children=kids, adjustment=adjustment,
                          single_measure_points=singular["single_measure_points"])
    solution = UnitSolution(np.array(ids), adj.rotations, adj.positions,
                            {"n_measures": adj.image_measures, "rms_px": adj.image_rms_px})
    return summary, dataclasses.replace(files, solution=solution)


def _has_altimetry(mission: Mission, level: str, adjust_cfg: AdjustConfig) -> bool:
    """Whether the level's units may be constrained by the mission's altimetry (:func:`unit_altimetry`)."""
    shots = getattr(mission, "altimetry", None)
    return level in adjust_cfg.altimetry_levels and shots is not None and bool(getattr(shots, "n_shots", 0))


def prior_shape_of(mission: Mission) -> Any:
    """The shape a real mission's free tie points start on (its body's packaged shape), None for a synthetic
    mission (its body is its truth surface, not the real one; its points stay on the datum as before) or a body
    without a packaged shape.
    """
    if mission.truth is not None:
        return None
    from mercury_dem.reference.body_shape import body_shape

    return body_shape(mission.body.name)


def unit_altimetry(mission: Mission, network: ControlNetwork, level: str,
                   adjust_cfg: AdjustConfig) -> AltimetryShotsArrays | None:
    """The mission's altimetry shots around a unit's tie points, when this level is constrained by them.

    None when the level is not in ``adjust.altimetry_levels`` or the mission has no altimetry. Only
    the tiles holding the unit's points are read (the store keeps one row group per tile).
    """
    if level not in adjust_cfg.altimetry_levels:
        return None
    store = getattr(mission, "altimetry", None)
    if store is None or not getattr(store, "n_shots", 0):
        return None
    from mercury_dem.altimetry.constraints import AltimetryShotsArrays, shot_tiles_for_points

    tiles = shot_tiles_for_points(network.apriori_xyz, store.tile_size_deg, list(store.tiles))
    if not tiles:
        return None
    table = store.read_tiles(tiles, ["lat", "lon", "radius_m", "sigma_m"])
    return AltimetryShotsArrays.from_table(table)


def pointing_sigma_urad_for(mission: Mission, config: Config) -> float:
    """The a-priori pointing sigma of a run (µrad): ``apriori.pointing_sigma_urad``, else the mission's.

    Raises :class:`~mercury_dem.exceptions.ConfigError` when neither says one
    (:func:`mercury_dem.config.apriori.resolve_pointing_sigma_urad`).
    """
    from mercury_dem.config.apriori import resolve_pointing_sigma_urad

    return resolve_pointing_sigma_urad(config.apriori.pointing_sigma_urad, mission.pointing_sigma_urad,
                                       str(getattr(mission, "path", mission)))


class _NoInput(MercuryDemError):
    failure = UnitFailure.NO_INPUT


def reconcile_solutions(store: RunStore, child_level: str, kids: list[int], ids: list[str],
                        rotations: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starting pointing of each image from the children's solutions (read from the store).

    The rule (the child in which the image had the most measures, ties to the earlier child) is
    :func:`mercury_dem.adjust.cascade.warm_start`; this reads the children's ``solution.parquet`` for it.
    """
    from mercury_dem.adjust.cascade import ChildSolution, warm_start

    solutions = []
    for c in kids:  # in the merge tree's order (ascending ids): the tie rule depends on it
        sid, srot, spos, table = read_solution(store.solution_path(child_level, c))
        nmeas = table["n_measures"].to_numpy() if "n_measures" in table else None
        solutions.append(ChildSolution(sid, srot, spos, nmeas))
    return warm_start(ids, rotations, positions, solutions)


def fatal_error(exc: BaseException, level: str, unit_id: int, where: Any) -> MercuryDemError | None:
    """The run-stopping error ``exc`` is for unit (``level``, ``unit_id``), or None when it is the unit's own failure.

    The rule is :func:`mercury_dem.compute.failures.run_stopping_error` (this only names the unit).
    """
    return run_stopping_error(exc, unit_name(level, unit_id), where)


def raise_if_fatal(exc: BaseException, level: str, unit_id: int, store: RunStore) -> None:
    """Re-raise ``exc`` as the run-stopping error it is (:func:`fatal_error`); return when it is not one."""
    raise_if_run_stopping(exc, unit_name(level, unit_id), store.location)


def failure_summary(level: str, unit_id: int, exc: BaseException) -> dict[str, Any]:
    """A summary for a task that died with an unexpected exception (a bug, a lost worker), in its JSON form."""
    return FailureSummary.of(level, unit_id, exc).to_json()


def config_dict(config: Config) -> dict[str, Any]:
    """The configuration tree as a plain nested dict (:func:`mercury_dem.config.to_dict`)."""
    return to_dict(config)
