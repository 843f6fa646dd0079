"""The DEM stage of a bucket run: every chunk gridded where its task runs and written straight to the bucket.

On a disk run the DEM's chunk tasks write regions of a Zarr store on a shared disk
(:func:`mercury_dem.pipeline.dem_stage.grid_dem`). A bucket run (``--out s3://…``) has no shared
disk, so before this the client gridded every chunk itself into its local cache. Now:

1. **The client** (:func:`grid_dem_on_bucket`) writes the store's template — the coordinate
   arrays and every array's metadata, *not* the root ``zarr.json`` — to ``RUN/dem.zarr`` on the
   bucket, and ``RUN/dem_chunks/plan.json`` naming what the chunks are of (grid, DEM settings,
   the global network's commit token).
2. **Each chunk task** (:func:`grid_chunk_to_bucket`, on a worker) reads the point cloud from
   the bucket (the committed global network, fetched into the worker's cache and indexed once
   per worker process), grids its chunk, writes the chunk's objects straight into the bucket's
   ``dem.zarr`` (zarr with the URL; fsspec's configuration gives the endpoint and credentials)
   and then, **last**, its marker ``RUN/dem_chunks/<row0>_<col0>.json`` (its counts and a commit
   token). A chunk without a marker is not trusted.
3. **The client** computes the coverage (``coverage.zarr``, committed as before) and uploads the
   root ``zarr.json`` — with ``complete = true`` and the DEM's counts — last: the store's own
   commit marker (:mod:`mercury_dem.io.remote`).

Resume: a committed ``dem.zarr`` (root ``zarr.json`` present) is reused as before. Otherwise, if
``plan.json`` is the same (same grid, settings and global network), chunks with a marker are
skipped and only the others are gridded again; a different plan (``--force global``, other DEM
settings) removes the chunks and markers first. The store equals the disk run's bit for bit (the
same chunk function on the same points).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import zarr
from numpy.typing import NDArray

from mercury_dem.compute import as_completed, runs_in_process
from mercury_dem.dem.cloud import point_cloud
from mercury_dem.dem.grid import GridSpec, PointIndex, build_point_index, config_with_no_value_distance, grid_chunk
from mercury_dem.dem.memory import check_memory
from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import Body
from mercury_dem.io.remote import RemoteDir, forget_cached
from mercury_dem.io.run_store import COVERAGE_FILE, DEM_CHUNKS_DIR, DEM_CHUNKS_PLAN_FILE, DEM_FILE, RunStore
from mercury_dem.pipeline.dem_stage import (
    chunk_failure,
    coverage_summary,
    create_store,
    final_attrs,
    grid_summary,
    judge_chunk_results,
    mark_zarr_complete,
    result_or_record,
)

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient
    from mercury_dem.config import Config
    from mercury_dem.config.dem import DemConfig

__all__ = ["grid_chunk_to_bucket", "grid_dem_on_bucket"]

# The names under the run (the DEM store, the prefix of the chunk markers and of the plan they belong to,
# the coverage store) are the run store's (io/run_store.py: DEM_FILE, DEM_CHUNKS_DIR, ...).


def _marker_name(bounds: tuple[int, int, int, int]) -> str:
    return f"{bounds[0]}_{bounds[2]}.json"


@functools.lru_cache(maxsize=2)
def _worker_index(run_url: str, global_token: str, datum_radius_m: float) -> PointIndex:
    """The global network's adjusted points, indexed; once per worker process and commit of the network."""
    from mercury_dem.io.network_store import read_network

    store = RunStore(run_url)
    token = store.remote.commit_token("global/0")
    if token != global_token:
        raise RuntimeError(f"{run_url}: the global network changed while the DEM was gridded "
                           f"(commit {token}, not {global_token}); resume the run")
    return build_point_index(point_cloud(read_network(store.network_path("global", 0))), datum_radius_m)


def grid_chunk_to_bucket(run_url: str, global_token: str, grid: GridSpec, bounds: tuple[int, int, int, int],
                         cfg: Any, datum_radius_m: float) -> dict[str, Any]:
    """Task body: grid one chunk from the bucket's point cloud, write it into the bucket's ``dem.zarr``,
    then its marker; return its counts (as :func:`~mercury_dem.pipeline.dem_stage.grid_dem`'s chunks do).
    """
    t0 = time.perf_counter()
    index = _worker_index(run_url, global_token, datum_radius_m)
    layers = grid_chunk(index, grid, bounds, cfg)
    remote = RemoteDir(run_url)
    r0, r1, c0, c1 = bounds
    for name, arr in layers.items():
        zarr.open_array(remote.url_of(f"{DEM_FILE}/{name}"), mode="r+")[r0:r1, c0:c1] = arr
    elev = layers["elevation"]
    valid = np.isfinite(elev)
    summary = {
        "bounds": list(bounds),
        "pixels": int(elev.size),
        "no_value": int((~valid).sum()),
        "min": float(elev[valid].min()) if valid.any() else None,
        "max": float(elev[valid].max()) if valid.any() else None,
        "seconds": time.perf_counter() - t0,
        "token": uuid.uuid4().hex,
    }
    remote.write_bytes(f"{DEM_CHUNKS_DIR}/{_marker_name(bounds)}", json.dumps(summary).encode())  # last
    return summary


def grid_chunk_to_bucket_or_record(run_url: str, global_token: str, grid: GridSpec, bounds: tuple[int, int, int, int],
                                   cfg: Any, datum_radius_m: float) -> dict[str, Any]:
    """:func:`grid_chunk_to_bucket`, with the chunk's own failure returned as a record, not raised.

    The record is the disk run's (:func:`~mercury_dem.pipeline.dem_stage.chunk_failure`: bounds, lat/lon,
    error, what to do); the chunk gets no marker, so the next run grids it again. A full disk is re-raised.
    """
    try:
        return grid_chunk_to_bucket(run_url, global_token, grid, bounds, cfg, datum_radius_m)
    except Exception as exc:  # the chunk's own failure: recorded, the other chunks go on
        return chunk_failure(grid, bounds, exc)


def _upload_template(store: RunStore, grid: GridSpec, cfg: Any, attrs: dict[str, Any] | None, body: Body) -> Path:
    """The store's template in the cache; every object but the root ``zarr.json`` uploaded. Returns the cache path."""
    local = store.dem_path
    forget_cached(local)  # the directory and its cache token: the template is not the committed store
    create_store(str(local), grid, cfg, attrs, body)
    files = [p for p in sorted(local.rglob("*")) if p.is_file() and p.relative_to(local).as_posix() != "zarr.json"]
    remote = store.remote
    remote.fs.put([str(p) for p in files], [remote.key(f"{DEM_FILE}/{p.relative_to(local).as_posix()}") for p in files])
    return local


def _chunk_plan(store: RunStore, grid: GridSpec, cfg: Any, attrs: dict[str, Any] | None, body: Body,
                global_token: str) -> tuple[Path, set[str]]:
    """The store's template (in the cache) and the markers of the chunks committed before under the same plan.

    The same plan (grid, settings, global network, body, attributes) as the bucket's ``plan.json``: the template
    again, locally only, and the markers found. Another plan (or none): the chunks, markers and store removed, the
    template uploaded (all but the root ``zarr.json``) and the plan written; no marker.
    """
    from mercury_dem.config import to_dict

    plan = {"grid": dataclasses.asdict(grid), "dem": to_dict(cfg) if dataclasses.is_dataclass(cfg) else repr(cfg),
            "global_token": global_token, "body": body.name, "attrs": attrs or {}}
    plan = json.loads(json.dumps(plan, default=str))
    remote = store.remote
    remote.remove(f"{DEM_FILE}/zarr.json")  # from here the store is not trusted (it was not, or fetch_zarr had taken it)
    old = remote.read_bytes(f"{DEM_CHUNKS_DIR}/{DEM_CHUNKS_PLAN_FILE}")
    if old is not None and json.loads(old) == plan:
        local = store.dem_path  # the same template again, locally only: its root zarr.json is committed last
        forget_cached(local)  # the directory and its cache token: the template is not the committed store
        create_store(str(local), grid, cfg, attrs, body)
        return local, {n for n in remote.list(DEM_CHUNKS_DIR) if n != DEM_CHUNKS_PLAN_FILE}
    remote.remove(DEM_CHUNKS_DIR)
    remote.remove(DEM_FILE)
    local = _upload_template(store, grid, cfg, attrs, body)
    remote.write_bytes(f"{DEM_CHUNKS_DIR}/{DEM_CHUNKS_PLAN_FILE}", json.dumps(plan).encode())
    return local, set()


def _grid_todo(run_url: str, global_token: str, grid: GridSpec, todo: list[tuple[int, int, int, int]], cfg: Any,
               datum: float, client: ComputeClient | None, task: Any) -> list[dict[str, Any]]:
    """The chunks to grid, in this process or on the workers (:func:`grid_chunk_to_bucket_or_record`)."""
    if runs_in_process(client):
        results = []
        for b in todo:
            results.append(grid_chunk_to_bucket_or_record(run_url, global_token, grid, b, cfg, datum))
            task.update()
        return results
    futures = [client.submit(grid_chunk_to_bucket_or_record, run_url, global_token, grid, b, cfg, datum, pure=False)
               for b in todo]
    for _ in as_completed(client, futures):
        task.update()
    return [result_or_record(grid, b, f) for b, f in zip(todo, futures)]


def grid_dem_on_bucket(
    store: RunStore, points_xyz: NDArray[np.floating], config: Config | DemConfig,
    client: ComputeClient | None = None, *, body: Body,
    attrs: dict[str, Any] | None = None, progress: Any = None, label: str = "dem",
) -> dict[str, Any]:
    """Grid the run's ``dem.zarr`` on the bucket, chunk by chunk where the tasks run (module docstring).

    ``store``: a bucket run (``store.url`` set) whose global network is committed; ``points_xyz``: the global
    network's adjusted points (N, 3 body-fixed metres), as the tasks will read them (here: the coverage and the
    counts); ``config``: DemConfig with the map's extent fixed; ``client``: a ``distributed.Client``, or None
    to run the chunk tasks in this process (the same result); ``body``, ``attrs``, ``progress``, ``label``: as
    :func:`~mercury_dem.pipeline.dem_stage.grid_dem`. Returns its summary plus ``chunks_reused`` (chunks whose
    marker a resumed run found) and ``on_workers`` (whether a client ran them).
    """
    from mercury_dem.progress import NULL

    t0 = time.perf_counter()
    rep = progress if progress is not None else NULL
    cfg = getattr(config, "dem", config)
    if store.url is None:
        raise StoreError(f"{store.root} is a local run: grid it with grid_dem")
    grid = GridSpec.from_config(cfg, body.datum_radius_m)
    pts = np.asarray(points_xyz, dtype=np.float64)
    est = check_memory(grid, int(pts.shape[0]), cfg)
    global_token = store.remote.commit_token("global/0")
    if global_token is None:
        raise StoreError(f"{store.url}: the global network is not committed; resume the run")
    index = build_point_index(pts, body.datum_radius_m)  # the coverage's (and the empty-cloud check)
    cfg = config_with_no_value_distance(cfg, index)  # max_distance_m = 0: from the points' spacing, before the plan
    chunks = grid.chunks(cfg.chunk_size)
    local, markers = _chunk_plan(store, grid, cfg, attrs, body, global_token)
    done = [b for b in chunks if _marker_name(b) in markers]
    todo = [b for b in chunks if _marker_name(b) not in markers]
    results = [json.loads(store.remote.read_bytes(f"{DEM_CHUNKS_DIR}/{_marker_name(b)}") or b"{}") for b in done]
    rep.message(f"{label}: {len(todo)} of {len(chunks)} chunks to grid "
                f"{'in this process' if runs_in_process(client) else 'on the workers'}, straight into {store.url}/{DEM_FILE}"
                + (f" ({len(done)} committed before)" if done else ""))
    with rep.task(f"{label} grid", len(todo), "chunks") as task:
        results += _grid_todo(store.url, global_token, grid, todo, cfg, body.datum_radius_m, client, task)
    failed_records = judge_chunk_results(results, f"{store.url}/{DEM_FILE}", rep, label)
    rep.message(f"{label}: point coverage")
    cov = coverage_summary(index, cfg, grid, body, store.coverage_path)
    store.commit_zarr(COVERAGE_FILE)
    summary = grid_summary(f"{store.url}/{DEM_FILE}", grid, cfg, index.n_points, len(chunks), results, est, cov,
                           failed_records, extra={"chunks_reused": len(done), "on_workers": not runs_in_process(client)})
    zarr.open_group(str(local), mode="r+").attrs.update(final_attrs(summary))
    mark_zarr_complete(local)
    store.remote.write_bytes(f"{DEM_FILE}/zarr.json", (local / "zarr.json").read_bytes())  # the store's commit, last
    summary["seconds"] = time.perf_counter() - t0
    return summary
