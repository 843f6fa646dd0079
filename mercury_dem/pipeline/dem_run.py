"""The DEM stage of a run: grid the global adjusted point cloud, make products, validate against truth."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from mercury_dem.compute import runs_in_process
from mercury_dem.config import Config
from mercury_dem.dem.cloud import point_cloud
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.io.run_store import (
    COVERAGE_FILE,
    DEM_APRIORI_FILE,
    DEM_FILE,
    PRODUCTS_DIR,
    REGISTRATION_DIR,
    REGISTRATION_MAPS,
    REGISTRATION_TILES_JSON,
    RunStore,
)
from mercury_dem.mission import Mission
from mercury_dem.pipeline.results import UnitSummary, read_summary

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient


def _open_map(path: str) -> Any:
    import xarray as xr

    return xr.open_zarr(path, consolidated=False)


def _shape_reference_of_maps(store: RunStore, registration: dict[str, Any], body: Any, ref: Any) -> dict[str, Any]:
    """The registered and merged DEMs against the configured shape model (report.json
    ``dem.reference_by_map``), over the same pixels as the adjusted DEM's comparison (within
    ``reference.max_point_distance_m`` of a control point: the maps share the adjusted DEM's grid).
    """
    from dataclasses import replace

    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.pipeline.reference_check import compare_with_references

    adjusted = open_dem(store.dem_path)
    shape_only = replace(ref, dem=None, altimetry=())
    out: dict[str, Any] = {}
    for key in REGISTRATION_MAPS:
        try:
            ds = _open_map(registration[key])
            dist = adjusted["distance_to_nearest_point"].transpose("lat", "lon")
            if ds["elevation"].transpose("lat", "lon").shape != dist.shape:
                raise ValueError(f"the {key} map's grid {ds['elevation'].shape} is not the DEM's {dist.shape}")
            ds = ds.assign(distance_to_nearest_point=(("lat", "lon"), dist.values))
            out[key] = compare_with_references(ds, body, shape_only)
        except (OSError, KeyError, ValueError) as exc:
            out[key] = {"error": str(exc)}
    return out


def global_levelling(store: RunStore) -> dict[str, Any] | None:
    """The global adjustment's levelling decision (:func:`mercury_dem.adjust.datum.levelling_decision`), or None.

    None when the global summary has none (a run made before the decision existed, or with
    ``adjust.point_prior_recentre_levels`` without ``global``): the registration then levels on the
    shots' mean, as it always did.
    """
    try:
        summary = read_summary(store, "global", 0)
    except (OSError, ValueError, KeyError, MercuryDemError):
        return None
    level = summary.levelling if isinstance(summary, UnitSummary) else None
    return level if level is not None and "level_to_mean" in level else None


def register_to_mission_altimetry(store: RunStore, mission: Mission, config: Config, client: ComputeClient | None,
                                  rep: Any) -> dict[str, Any] | None:
    """Register ``dem.zarr`` to the mission's altimetry and merge them (``dem.register_to_altimetry``).

    None when the mission has no altimetry or the setting is off; a failure is recorded as a value
    (``{"error": ...}``) and the run goes on with its DEM.
    """
    alt = mission.altimetry
    if not config.dem.register_to_altimetry or alt is None or not alt.n_shots:
        return None
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.pipeline.register_stage import register_dem_store
    from mercury_dem.validate.registration import profile_check

    level = global_levelling(store)
    rep.message(f"registration: the DEM onto {alt.n_shots} altimetry shots, per tile"
                + ("" if level is None or level["level_to_mean"] else ", not levelled on their mean (" + level["reason"] + ")"))
    t = time.perf_counter()
    try:
        summary = register_dem_store(store.dem_path, mission.read_altimetry(), store.root, client,
                                     body=mission.body, overwrite=True, source=f"mission {mission.path} altimetry",
                                     settings=config.registration, tiles=TileGrid(config.tiling.tile_size_deg),
                                     level_to_mean=True if level is None else bool(level["level_to_mean"]))
    except MercuryDemError as exc:
        rep.message(f"registration: failed ({exc})")
        return {"error": f"registration to the mission's altimetry: {exc}"}
    for name in REGISTRATION_MAPS.values():  # a bucket run: committed like dem.zarr (no-ops locally)
        store.commit_zarr(name)
    store.commit_tree(REGISTRATION_DIR)
    tiles = summary.pop("tiles", [])
    summary["tiles_table"] = str(Path(summary["tables"]) / REGISTRATION_TILES_JSON)
    summary["tiles_failed"] = [t_ for t_ in tiles if not t_.get("ok", True)]
    # Seed 004's check (registration.check_min_profiles; the key keeps the seed's 20 in its name)
    summary["tiles_20_profiles"], summary["improved_share"] = profile_check(
        tiles, config.registration.check_min_profiles)
    rep.message(f"registration: {summary['tiles_registered']} tiles registered in {time.perf_counter() - t:.1f} s")
    return summary


def _grid_or_resume(store: RunStore, pts: Any, dem_cfg: Any, client: ComputeClient | None, body: Any, rep: Any) -> dict[str, Any]:
    """``dem.zarr``: gridded (a bucket run: straight into the bucket, :mod:`~mercury_dem.pipeline.dem_bucket`),
    its failed chunks gridded again (resume), or reused when complete.
    """
    from mercury_dem.pipeline.dem_stage import failed_chunks_of, grid_dem, regrid_failed_chunks

    attrs = {"source": "global adjusted control points"}
    remote = store.url is not None
    if remote:
        store.fetch_zarr(COVERAGE_FILE)
    fetched = store.fetch_zarr(DEM_FILE)
    if fetched and not failed_chunks_of(store.dem_path):
        return {"path": str(store.dem_path), "reused": True}
    if remote:  # new, or the chunks without a marker; then the committed store into the cache, for the products
        from mercury_dem.pipeline.dem_bucket import grid_dem_on_bucket

        summary = grid_dem_on_bucket(store, pts, dem_cfg, client, body=body, attrs=attrs, progress=rep)
        store.fetch_zarr(DEM_FILE)  # the template rebuilt in the cache has no token: the committed store is fetched
        return summary
    if fetched:  # resume: only the chunks that failed last time
        return regrid_failed_chunks(pts, dem_cfg, store.dem_path, client, body=body, progress=rep)
    return grid_dem(pts, dem_cfg, store.dem_path, client, body=body, attrs=attrs, progress=rep, record_failures=True)


def _checks(store: RunStore, mission: Mission, config: Config, rep: Any) -> dict[str, Any]:
    """The DEM against the configured references (``reference``) and against the body's shape (``shape_check``)."""
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.pipeline.reference_check import check_against_body_shape, compare_with_references

    out: dict[str, Any] = {}
    ref = config.reference
    if ref.dem or ref.altimetry or ref.shape_harmonics:
        out["reference"] = compare_with_references(open_dem(store.dem_path), mission.body, ref)
    out["shape_check"] = check_against_body_shape(open_dem(store.dem_path), mission, ref.max_point_distance_m)
    if out["shape_check"].get("status") == "gross_error":
        rep.message(f"ERROR: DEM minus the body's shape: bias {out['shape_check']['bias_m']:+.0f} m "
                    f"({out['shape_check']['cause']})")
    return out


def _registration_products(store: RunStore, config: Config, registration: dict[str, Any], files: list[str],
                           rep: Any) -> None:
    """The registered and merged DEMs' products; their files appended to ``files``, statistics to ``registration``."""
    from mercury_dem.pipeline.register_stage import make_registration_products

    t = time.perf_counter()
    reg_products = make_registration_products(store.root, store.products_dir, config, overwrite=True)
    files += reg_products["files"]
    registration["products"] = {k: {f: reg_products[k][f] for f in ("statistics", "skipped")} for k in REGISTRATION_MAPS}
    rep.message(f"products of the registered and merged DEMs: {len(reg_products['files'])} files in "
                f"{time.perf_counter() - t:.1f} s")


def _validation(store: RunStore, net: Any, dem_cfg: Any, client: ComputeClient | None, body: Any, truth: Any, adjusted: Any,
                registration: dict[str, Any] | None, rep: Any) -> dict[str, Any]:
    """Accuracy against the truth (:func:`~mercury_dem.dem.accuracy.dem_accuracy`) of the adjusted DEM, the
    registered and merged ones, and of a DEM of the a-priori points (gridded into a temporary store).
    """
    from mercury_dem.dem.accuracy import dem_accuracy
    from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

    validation: dict[str, Any] = {"adjusted": adjusted}
    if registration is not None and "error" not in registration:
        for key in REGISTRATION_MAPS:
            ds = _open_map(registration[key])
            validation[key] = dem_accuracy(ds["elevation"].values, ds["lat"].values, ds["lon"].values, truth)
    tmp = store.root / DEM_APRIORI_FILE
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        grid_dem(point_cloud(net, adjusted=False), dem_cfg, tmp, client, coverage=False, body=body,
                 record_failures=True, attrs={"source": "a-priori control points"}, progress=rep,
                 label="dem (a-priori points)")
        ds = open_dem(tmp)
        validation["a_priori"] = dem_accuracy(ds["elevation"].values, ds["lat"].values, ds["lon"].values, truth,
                                              ds["distance_to_nearest_point"].values)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return validation


def _dem_tail(store: RunStore, mission: Mission, config: Config, net: Any, dem_cfg: Any, client: ComputeClient | None,
              rep: Any) -> tuple[dict[str, Any], str | None]:
    """What follows the gridding of ``dem.zarr``: the products, checks, registration (and its products) and the
    validation; returns the report's keys they fill and the products' table. ``client`` grids the a-priori DEM
    and registers the tiles (None: in this process).
    """
    from mercury_dem.products.make import make_products

    truth = mission.truth.surface().height if mission.truth is not None else None
    rep.message("products: writing GeoTIFF/ISIS/PDS products and browse images")
    t = time.perf_counter()
    products = make_products(store.dem_path, store.products_dir, config, truth_height=truth, overwrite=True)
    out: dict[str, Any] = {"statistics": products.get("statistics"), "files": [str(f) for f in products.get("files", [])],
                           "products_skipped": products.get("skipped", {})}
    rep.message(f"products: {len(products.get('files', []))} files in {time.perf_counter() - t:.1f} s")
    out.update(_checks(store, mission, config, rep))
    registration = register_to_mission_altimetry(store, mission, config, client, rep)
    if registration is not None:
        out["registration"] = registration
        if "error" not in registration:
            _registration_products(store, config, registration, out["files"], rep)
            if config.reference.shape_harmonics:
                out["reference_by_map"] = _shape_reference_of_maps(store, registration, mission.body, config.reference)
    store.commit_tree(PRODUCTS_DIR)  # a bucket run: the whole products directory, once
    if truth is not None:
        out["validation"] = _validation(store, net, dem_cfg, client, mission.body, truth, products.get("accuracy"),
                                        registration, rep)
    return out, products.get("table")


def dem_tail_task(run_url: str, config: Config, dem_cfg: Any) -> tuple[dict[str, Any], str | None, str]:
    """Task body of a bucket run's DEM stage after the gridding (:func:`_dem_tail`), on a worker.

    Reads what it needs from the bucket into this worker's cache (the run, its mission, the committed
    ``dem.zarr`` and ``coverage.zarr``, the global network) and commits what it makes to the bucket (products,
    registered and merged maps, registration tables: each committed as on a disk run's client, atomically);
    returns the report's keys, the products' table and its progress messages (the client prints them).
    """
    import io

    from mercury_dem.io.network_store import read_network
    from mercury_dem.mission import open_mission
    from mercury_dem.progress import Reporter

    store = RunStore.open(run_url)
    mission = open_mission(store.read_run()["mission"])
    for name in (DEM_FILE, COVERAGE_FILE):  # a cached copy of other content has another token (io.remote): fetched
        store.fetch_zarr(name)
    log = io.StringIO()
    out, table = _dem_tail(store, mission, config, read_network(store.network_path("global", 0)), dem_cfg, None,
                           Reporter(log, mode="lines"))
    return out, table, log.getvalue()


def run_dem_stage(store: RunStore, mission: Mission, config: Config, client: ComputeClient | None, stream: TextIO | None = sys.stdout) -> dict[str, Any]:
    """Grid ``dem.zarr`` from the global network, then the products, checks, registration and validation; returns
    the report's ``dem`` block.

    ``client`` is the run's (the synchronous client grids in this process). A chunk that fails is recorded
    (``failed_chunks``: which, why, what to do), its pixels left NaN, and a resume grids only it again. On a
    bucket run (``store.url``) the chunk tasks write straight into the bucket's ``dem.zarr``
    (:mod:`mercury_dem.pipeline.dem_bucket`), and what follows (products, checks, registration, validation:
    :func:`_dem_tail`) runs as one task on a worker (:func:`dem_tail_task`), which reads the bucket and commits
    its results there, so the client holds only the point cloud it grids from (issue 33: the client stays
    light). With the synchronous client they run in this process. With truth, the a-priori points are gridded
    too (into a temporary store), so the report shows what the adjustment bought.
    """
    from mercury_dem.dem.extent import config_with_extent
    from mercury_dem.io.network_store import read_network
    from mercury_dem.progress import Reporter

    rep, t0 = Reporter(stream), time.perf_counter()
    net = read_network(store.network_path("global", 0))
    pts = point_cloud(net, adjusted=True)
    # Unset map bounds come from the adjusted cloud, once: the a-priori DEM is gridded on the same map.
    dem_cfg = config_with_extent(config.dem, pts) if pts.shape[0] else config.dem
    grid_summary = _grid_or_resume(store, pts, dem_cfg, client, mission.body, rep)
    out: dict[str, Any] = {
        "points": int(pts.shape[0]), "grid": {k: v for k, v in grid_summary.items() if k != "coverage"},
        "coverage": grid_summary.get("coverage"),
        "failed_chunks": grid_summary.get("failed_chunks", []),  # chunks not gridded (pixels NaN); [] when none
    }
    del pts
    if store.url is not None and client is not None and not runs_in_process(client):  # on a worker, from the bucket
        rep.message("dem stage: products, checks, registration and validation in one task on a worker")
        tail, table, log = client.submit(dem_tail_task, store.url, config, dem_cfg, pure=False).result()
        out["tail_on_worker"] = True
        if stream is not None:
            stream.write(log)
    else:  # a disk run (its client registers and grids), or a bucket run with the synchronous client: here
        tail, table = _dem_tail(store, mission, config, net, dem_cfg, None if store.url is not None else client, rep)
        out["tail_on_worker"] = False
    out.update(tail)
    rep.message(f"dem stage: done in {time.perf_counter() - t0:.1f} s")
    if stream is not None and table:
        print(table, file=stream)
    return out
