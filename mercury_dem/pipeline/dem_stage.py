"""The DEM stage: grid a point cloud into ``dem.zarr`` chunk by chunk, on Dask or in-process.

How it runs
-----------
1. The point cloud is validated and indexed once (:func:`~mercury_dem.dem.grid.build_point_index`);
   on Dask the index (bucketed footprints + radii) is scattered with ``broadcast=True``, so it
   reaches every worker once, not once per chunk.
2. A template store is written with ``to_zarr(compute=False)``: coordinates, CRS
   (``spatial_ref``), attributes and empty arrays whose Zarr chunks are the map chunks.
3. One task per map chunk grids it (:func:`~mercury_dem.dem.grid.grid_chunk`, halo
   included) and writes its region straight into the store; it returns a few
   counts. The full map is never gathered in one process.
4. The point-cloud coverage (reference 001) is computed and stored beside the DEM
   (``coverage.zarr``) and in the DEM attributes.

The whole store is built under a temporary name and renamed when complete
(:func:`mercury_dem.io.atomic.atomic_directory`); its completion mark is the root
attribute ``complete = true`` instead of that module's marker file (zarr warns about
unknown files inside a store).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np
from numpy.typing import NDArray

from mercury_dem.compute import ThreadPoolClient, as_completed, client_or_sync, runs_in_process
from mercury_dem.compute.failures import lost_to_the_cluster
from mercury_dem.compute.lazy import lazy_full
from mercury_dem.dem.coverage import CoverageResult, point_coverage
from mercury_dem.dem.extent import config_with_extent
from mercury_dem.dem.grid import (
    LAYERS,
    GridSpec,
    PointIndex,
    build_point_index,
    config_with_no_value_distance,
    grid_chunk,
)
from mercury_dem.dem.memory import check_memory, estimate_memory_bytes
from mercury_dem.dem.store_schema import (
    ATTRS,
    COORD_ATTRS,
    NAN_FILL_ATTR,
    gridding_attr,
    layer_compressors,
    root_attrs,
    spatial_ref_extra,
)
from mercury_dem.exceptions import DiskFullError, GridError, StoreError
from mercury_dem.geometry.body import Body
from mercury_dem.io.atomic import atomic_directory, disk_full_cause
from mercury_dem.io.crs_cache import spatial_ref_attrs
from mercury_dem.io.run_store import COVERAGE_FILE

if TYPE_CHECKING:
    import xarray as xr
    import zarr

    from mercury_dem.compute.client import ComputeClient
    from mercury_dem.config import Config
    from mercury_dem.config.dem import DemConfig

__all__ = ["grid_dem", "make_products", "open_dem",  # noqa: F822 (lazy re-exports: __getattr__)
           "estimate_memory_bytes", "check_memory", "dem_template", "create_store", "StoreWriter"]


class StoreWriter(Protocol):
    """What :func:`grid_dem` asks of a process that writes its store for it
    (:class:`mercury_dem.pipeline.store_writer.ForkedStoreWriter`, which imports this module to create the
    store; the protocol keeps the two modules from importing each other).
    """

    def create(self, store: str, grid: Any, cfg: Any, attrs: dict[str, Any] | None, body: Any,
               name: str | None = None) -> Mapping[str, Any] | None:
        """Create the empty store; its layers for region writes, or None when it declines (then the caller writes)."""
        ...

    def update_attrs(self, attrs: dict[str, Any]) -> None:
        """Set the store's final root attributes."""
        ...

    def complete(self, tmp: Any = None) -> None:
        """Mark the store complete and wait (the store's ``mark_complete``)."""
        ...

    def abort(self) -> None:
        """Stop without marking the store complete, and wait (idempotent)."""
        ...


def __getattr__(name: str) -> Any:
    """``make_products`` and ``open_dem`` are re-exported from :mod:`mercury_dem.products.make` on first use:
    importing the products (matplotlib, pyproj) costs a cold ``mercury-dem grid`` ~0.3 s it never needs.
    """
    if name in ("make_products", "open_dem"):
        from mercury_dem.products import make

        return getattr(make, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _dem_config(config: Config | DemConfig) -> DemConfig:
    """Accept a full :class:`~mercury_dem.config.Config` or its ``dem`` section."""
    return cast("DemConfig", getattr(config, "dem", config))


def dem_template(grid: GridSpec, cfg: Any, attrs: dict[str, Any] | None, body: Body) -> xr.Dataset:
    """The lazy (never computed) Dataset that defines the store's layout."""
    import rioxarray  # noqa: F401  (registers the .rio accessor)
    import xarray as xr

    nr, nc = grid.shape
    cs = cfg.chunk_size
    data_vars = {}
    for name, dtype in LAYERS.items():
        fill = 0 if np.dtype(dtype).kind == "i" else np.nan
        arr = lazy_full((nr, nc), fill, dtype, (cs, cs))
        data_vars[name] = xr.Variable(("lat", "lon"), arr, attrs=dict(ATTRS[name]))
    ds = xr.Dataset(
        data_vars,
        coords={
            "lat": ("lat", grid.lat_centres(), dict(COORD_ATTRS["lat"])),
            "lon": ("lon", grid.lon_centres(), dict(COORD_ATTRS["lon"])),
        },
    )
    ds = ds.rio.set_spatial_dims(x_dim="lon", y_dim="lat")
    ds = ds.rio.write_crs(body.datum_geographic_crs())
    ds["spatial_ref"].attrs.update(spatial_ref_extra(body))
    for name in LAYERS:
        ds[name].encoding.update({"chunks": (cs, cs), "grid_mapping": "spatial_ref",
                                  "compressors": layer_compressors()})
        ds[name].attrs.pop("grid_mapping", None)
    ds.attrs.update(root_attrs(grid, cfg, attrs, body))
    return ds


def create_store(
    store: str, grid: GridSpec, cfg: Any, attrs: dict[str, Any] | None, body: Body
) -> tuple[zarr.Group, dict[str, zarr.Array]]:
    """Create the empty ``dem.zarr`` layout with zarr directly: the same metadata as
    ``dem_template(grid, cfg, attrs).to_zarr(store, compute=False)`` (a test checks it)
    without building a Dask-backed Dataset for it (that took ~0.1-0.2 s per store).

    Returns the open group and its map layers (:data:`LAYERS`), ready for region writes:
    opening them again costs ~6 ms per group and ~0.5 ms per array (metadata reads).
    """
    import zarr  # here, not at module level: a forked grid writer keeps zarr out of the gridding process

    nr, nc = grid.shape
    cs = cfg.chunk_size
    group = zarr.open_group(store, mode="w", zarr_format=3, attributes=root_attrs(grid, cfg, attrs, body))
    for name, values in (("lat", grid.lat_centres()), ("lon", grid.lon_centres())):
        arr = group.create_array(name, shape=values.shape, chunks=values.shape, dtype=np.float64,
                                 fill_value=np.nan, dimension_names=[name],
                                 attributes={**COORD_ATTRS[name], "_FillValue": NAN_FILL_ATTR})
        arr[...] = values
    group.create_array("spatial_ref", shape=(), dtype=np.int64, fill_value=0, attributes=spatial_ref_attrs(body))
    layers: dict[str, zarr.Array] = {}
    for name, dtype in LAYERS.items():
        integer = np.dtype(dtype).kind == "i"
        layer_attrs = {**ATTRS[name], "grid_mapping": "spatial_ref"}
        if not integer:
            layer_attrs["_FillValue"] = NAN_FILL_ATTR
        layers[name] = group.create_array(name, shape=(nr, nc), chunks=(cs, cs), dtype=dtype,
                                          fill_value=0 if integer else np.nan, dimension_names=["lat", "lon"],
                                          attributes=layer_attrs, compressors=layer_compressors())
    return group, layers


def _grid_and_write(
    index: PointIndex, grid: GridSpec, bounds: tuple[int, int, int, int], cfg: Any,
    store: str | Mapping[str, zarr.Array], near_points_only: bool = False,
) -> dict[str, Any]:
    """Task body: grid one chunk and write its region into the store; return counts only.

    ``store``: the store's path (a Dask task opens it), or its layers already open
    (:func:`create_store`'s, shared by the chunks of one process).
    """
    t0 = time.perf_counter()
    layers = grid_chunk(index, grid, bounds, cfg, near_points_only=near_points_only)
    r0, r1, c0, c1 = bounds
    if isinstance(store, str):
        import zarr

        group = zarr.open_group(store, mode="r+")
        store = {name: group[name] for name in layers}
    for name, arr in layers.items():
        store[name][r0:r1, c0:c1] = arr
    elev = layers["elevation"]
    valid = np.isfinite(elev)
    return {
        "bounds": bounds,
        "pixels": int(elev.size),
        "no_value": int((~valid).sum()),
        "min": float(elev[valid].min()) if valid.any() else math.nan,
        "max": float(elev[valid].max()) if valid.any() else math.nan,
        "seconds": time.perf_counter() - t0,
    }


#: Root attribute of a ``dem.zarr`` listing its chunks that could not be gridded (JSON; absent when none).
FAILED_CHUNKS_ATTR = "failed_chunks"


def chunk_failure(grid: GridSpec, bounds: tuple[int, int, int, int], exc: BaseException) -> dict[str, Any]:
    """The record of a chunk that could not be gridded: which chunk, why, and what to do.

    A full disk is not the chunk's fault and stops the stage (:class:`~mercury_dem.exceptions.DiskFullError`):
    recording it would leave a store that cannot be completed either.
    """
    if isinstance(exc, DiskFullError) or disk_full_cause(exc) is not None:
        raise exc
    r0, r1, c0, c1 = (int(v) for v in bounds)
    lat = grid.lat_centres(np.arange(r0, r1))
    lon = grid.lon_centres(np.arange(c0, c1))
    return {
        "bounds": [r0, r1, c0, c1],
        "failed": True,
        "pixels": (r1 - r0) * (c1 - c0),
        "lat_deg": [float(lat.min()), float(lat.max())],
        "lon_deg": [float(lon.min()), float(lon.max())],
        "error": f"{type(exc).__name__}: {exc}",
        "what_to_do": ("its pixels are left NaN (point_count 0) and the rest of the DEM is written; run the "
                       "same command again to grid only the failed chunks (the run resumes them), and if it "
                       "fails again report the error"),
        "no_value": (r1 - r0) * (c1 - c0),
        "min": math.nan,
        "max": math.nan,
    }


def _grid_and_write_or_record(
    index: PointIndex, grid: GridSpec, bounds: tuple[int, int, int, int], cfg: Any,
    store: str | Mapping[str, zarr.Array], near_points_only: bool = False,
) -> dict[str, Any]:
    """:func:`_grid_and_write`, with a failure returned as a value (:func:`chunk_failure`), not raised."""
    try:
        return _grid_and_write(index, grid, bounds, cfg, store, near_points_only)
    except Exception as exc:  # the chunk's own failure: recorded, the other chunks go on
        return chunk_failure(grid, bounds, exc)


def result_or_record(grid: GridSpec, bounds: tuple[int, int, int, int], future: Any) -> dict[str, Any]:
    """A chunk task's result, or the record of its failure when the task itself was lost (a dead worker)."""
    try:
        return dict(future.result())
    except Exception as exc:
        if lost_to_the_cluster(exc):  # the scheduler went away: the run's error, not the chunk's
            raise
        return chunk_failure(grid, bounds, exc)


def judge_chunk_results(results: list[dict[str, Any]], where: str, rep: Any, label: str = "dem",
                        all_failed_is_error: bool = True) -> list[dict[str, Any]]:
    """The failed chunks' records among a stage's chunk results, as stored (``failed_chunks``), each reported.

    One line per failed chunk goes to ``rep``; when every chunk failed (and ``all_failed_is_error``)
    there is nothing worth keeping: :class:`GridError` naming ``where`` and the first error, before
    anything is committed. Used by the disk run (:func:`grid_dem`, :func:`regrid_failed_chunks`) and the
    bucket run (:func:`~mercury_dem.pipeline.dem_bucket.grid_dem_on_bucket`).
    """
    failed = [r for r in results if r.get("failed")]
    for line in failed_chunk_lines(failed, label):
        rep.message(line)
    if all_failed_is_error and failed and len(failed) == len(results):  # a stage error, not a partial DEM
        raise GridError(f"{where}: none of the {len(results)} chunks could be gridded (the first: "
                        f"{failed[0]['error']}); nothing was committed")
    return [{k: v for k, v in f.items() if k not in ("failed", "no_value", "min", "max")} for f in failed]


def failed_chunk_lines(failed: list[dict[str, Any]], label: str = "dem") -> list[str]:
    """One line per failed chunk, for the stage's progress messages and the report's text."""
    return [f"{label}: chunk rows {f['bounds'][0]}-{f['bounds'][1]}, columns {f['bounds'][2]}-{f['bounds'][3]} "
            f"(lat {f['lat_deg'][0]:.3f}..{f['lat_deg'][1]:.3f}, lon {f['lon_deg'][0]:.3f}..{f['lon_deg'][1]:.3f}) "
            f"failed: {f['error']}; {f['what_to_do']}" for f in failed]


def _planned_grid(points_xyz: NDArray[np.floating], config: Config | DemConfig, body: Body
                  ) -> tuple[NDArray[np.float64], DemConfig, GridSpec, dict[str, int]]:
    """The points (float64), the DEM settings with unset bounds from the cloud's box
    (:func:`~mercury_dem.dem.extent.config_with_extent`), the grid, and its memory estimate (refused over
    ``dem.memory_limit_gb``); an empty cloud raises its error here, before anything is created.
    """
    cfg = _dem_config(config)
    pts = np.asarray(points_xyz, dtype=np.float64)
    n_points = int(pts.shape[0]) if pts.ndim == 2 else 0
    if n_points and cfg.extent_from_points:
        cfg = config_with_extent(cfg, pts)
    grid = GridSpec.from_config(cfg, body.datum_radius_m)
    est = check_memory(grid, max(n_points, 0), cfg)
    if n_points == 0:
        build_point_index(pts, body.datum_radius_m)  # raises the empty-cloud error
    return pts, cfg, grid, est


def _grid_chunks(index: PointIndex, grid: GridSpec, chunks: list[tuple[int, int, int, int]], cfg: DemConfig,
                 client: ComputeClient | None, layer_arrays: Mapping[str, zarr.Array], store: str,
                 record_failures: bool, task: Any, near_points_only: bool = False) -> list[dict[str, Any]]:
    """One task per chunk (:func:`_grid_and_write`, or its recording form); their results in chunk order.

    In this process, two chunks in flight: one in the compiled kernel (all its threads, GIL released), the
    other being smoothed and written (numpy, compression): the cores stay busy. Each chunk's result is
    independent of the other: the same arrays as a plain loop. On Dask, the index is scattered once to
    every worker and each task opens the store by its path.
    """
    in_process = runs_in_process(client)
    runner = ThreadPoolClient(2) if in_process else client
    target: Any = layer_arrays if in_process else store
    chunk_task = _grid_and_write_or_record if record_failures else _grid_and_write
    try:
        index_f = runner.scatter(index, broadcast=True)
        futures = [runner.submit(chunk_task, index_f, grid, b, cfg, target, near_points_only, pure=False)
                   for b in chunks]
        for _ in as_completed(runner, futures):  # completion order: counts as chunks land
            task.update()
        if record_failures:
            return [result_or_record(grid, b, f) for b, f in zip(chunks, futures)]
        results: list[dict[str, Any]] = runner.gather(futures)
        return results
    finally:
        if in_process:
            runner.close()


def coverage_summary(index: PointIndex, cfg: Any, grid: GridSpec, body: Body, path: Path) -> dict[str, Any]:
    """The point-cloud coverage (:func:`~mercury_dem.dem.coverage.point_coverage`) written to ``path``; its summary."""
    cov = point_coverage(index, cfg.coverage_pixel_km_for(body.datum_radius_m), threads=cfg.query_threads or -1,
                         bounds=(grid.lat_min, grid.lat_max, grid.lon_min, grid.lon_max))
    write_coverage(cov, path, overwrite=True)
    summary: dict[str, Any] = cov.summary()
    return summary


def grid_summary(path: str, grid: GridSpec, cfg: Any, n_points: int, n_chunks: int, results: list[dict[str, Any]],
                 est: dict[str, int], cov_summary: dict[str, Any] | None, failed: list[dict[str, Any]],
                 extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The DEM stage's summary from its chunks' results (``extra``: the bucket run's keys, after ``n_chunks``)."""
    no_value = sum(int(r["no_value"]) for r in results)
    mins = [r["min"] for r in results if r.get("min") is not None and not math.isnan(r["min"])]
    maxs = [r["max"] for r in results if r.get("max") is not None and not math.isnan(r["max"])]
    return {"path": path, "shape": list(grid.shape), "pixels_per_degree": grid.pixels_per_degree,
            "grid_bounds_deg": [grid.lat_min, grid.lat_max, grid.lon_min, grid.lon_max], "method": cfg.method,
            "no_value_distance_m": cfg.max_distance_m, "n_points": n_points, "n_chunks": n_chunks, **(extra or {}),
            "no_value_pixels": no_value, "no_value_fraction": no_value / (grid.shape[0] * grid.shape[1]),
            "elevation_min_m": min(mins) if mins else math.nan, "elevation_max_m": max(maxs) if maxs else math.nan,
            "memory_estimate_bytes": est, "coverage": cov_summary, "failed_chunks": failed}


def final_attrs(summary: dict[str, Any]) -> dict[str, Any]:
    """The store's root attributes known once every chunk is in: counts, coverage, and the failed chunks
    (:data:`FAILED_CHUNKS_ATTR`, read back on resume; absent from a complete DEM).
    """
    out: dict[str, Any] = {"n_points": summary["n_points"], "no_value_pixels": int(summary["no_value_pixels"]),
                           "coverage": json.dumps(summary["coverage"]) if summary["coverage"] else ""}
    if summary["failed_chunks"]:
        out[FAILED_CHUNKS_ATTR] = json.dumps(summary["failed_chunks"])
    return out


def grid_dem(
    points_xyz: NDArray[np.floating], config: Config | DemConfig, out_path: str | Path,
    client: ComputeClient | None = None, *, overwrite: bool = False, attrs: dict[str, Any] | None = None,
    coverage: bool = True, body: Body, progress: Any = None, label: str = "dem", writer: StoreWriter | None = None,
    record_failures: bool = False, near_points_only: bool = False,
) -> dict[str, Any]:
    """Grid a point cloud (N, 3 body-fixed metres) into ``out_path`` (a ``dem.zarr``); return a summary.

    ``config``: Config or DemConfig; ``client``: the run's (the synchronous client or None grid the chunks in
    this process, two at a time: the same result); ``attrs``: extra root attributes; ``coverage``: also the
    point-cloud coverage into ``coverage.zarr`` beside the store; ``body``: heights above its datum sphere, its
    IAU 2015 CRS; ``progress``/``label``: progress lines (presentation only); ``writer``: with ``client=None``,
    a forked process that creates and writes the store (:mod:`mercury_dem.pipeline.store_writer`), stopped if
    this call fails. ``record_failures``: a chunk whose gridding raises is recorded as a value (its pixels NaN,
    the root attribute ``failed_chunks`` lists it, a resume grids only it: :func:`regrid_failed_chunks`), else
    its error stops the call and nothing is written (a full disk always stops it). ``near_points_only``: the
    dense cloud's search (:func:`mercury_dem.dem.grid.grid_chunk`: same elevations). Returns :func:`grid_summary`'s
    dict and ``seconds``; raises :class:`GridError` (an empty cloud, over ``dem.memory_limit_gb``), StoreError.
    """
    from mercury_dem.progress import NULL

    t0 = time.perf_counter()
    rep = progress if progress is not None else NULL
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise StoreError(f"{out_path} already exists; pass overwrite=True (CLI: --overwrite) to replace it")
    pts, cfg, grid, est = _planned_grid(points_xyz, config, body)
    chunks = grid.chunks(cfg.chunk_size)
    if writer is not None and not runs_in_process(client):
        raise ValueError("a forked store writer is for in-process gridding (client=None)")
    forked: list[StoreWriter | None] = [writer]  # the writer, or None once it declined (then this process writes)

    def mark(tmp: Path) -> None:
        (mark_zarr_complete if forked[0] is None else forked[0].complete)(tmp)

    with atomic_store(out_path, overwrite=overwrite, mark_complete=mark) as tmp, \
            _stopping_on_error(writer), ThreadPoolExecutor(max_workers=2) as pool:
        # The index (compiled, GIL released) builds while this thread writes the store's template.
        index_job = pool.submit(build_point_index, pts, body.datum_radius_m)
        layer_arrays = None if writer is None else writer.create(str(tmp), grid, cfg, attrs, body, name=str(out_path))
        if layer_arrays is None:
            forked[0] = None
            group, layer_arrays = create_store(str(tmp), grid, cfg, attrs, body)
        rep.message(f"{label}: indexing {pts.shape[0] if pts.ndim == 2 else 0} points for a {grid.shape[0]} x "
                    f"{grid.shape[1]} grid ({len(chunks)} chunks, {cfg.method})")
        index = index_job.result()
        cfg = config_with_no_value_distance(cfg, index)  # max_distance_m = 0: from the points' spacing
        with rep.task(f"{label} grid", len(chunks), "chunks") as task:
            results = _grid_chunks(index, grid, chunks, cfg, client, layer_arrays, str(tmp), record_failures,
                                   task, near_points_only)
        failed = judge_chunk_results(results, str(out_path), rep, label)
        if coverage:
            rep.message(f"{label}: point coverage")
        cov = coverage_summary(index, cfg, grid, body, out_path.parent / COVERAGE_FILE) if coverage else None
        summary = grid_summary(str(out_path), grid, cfg, index.n_points, len(chunks), results, est, cov, failed)
        # the no-value distance was resolved after the store was created
        done = {"gridding": gridding_attr(cfg), **final_attrs(summary)}
        (group.attrs.update if forked[0] is None else forked[0].update_attrs)(done)
    summary["seconds"] = time.perf_counter() - t0
    return summary


def failed_chunks_of(path: str | Path) -> list[dict[str, Any]]:
    """The failed-chunk records a ``dem.zarr`` carries (:data:`FAILED_CHUNKS_ATTR`); [] when none or no store.

    Raises :class:`StoreError` when the attribute is there but damaged (not the JSON list it writes).
    """
    import zarr

    try:
        raw = zarr.open_group(str(path), mode="r").attrs.get(FAILED_CHUNKS_ATTR, "")
    except (OSError, ValueError, KeyError):
        return []
    try:
        records = json.loads(raw) if raw else []
        if not isinstance(records, list) or not all(
                isinstance(r, dict) and isinstance(r.get("bounds"), list) and len(r["bounds"]) == 4
                and all(type(v) is int and v >= 0 for v in r["bounds"]) for r in records):
            raise ValueError("not a list of chunk records with 4 whole-number bounds")
    except ValueError as exc:
        raise StoreError(f"{path}: its '{FAILED_CHUNKS_ATTR}' attribute is damaged ({exc}); grid the DEM again "
                         f"(mercury-dem run ... --force dem)") from exc
    return records


def regrid_failed_chunks(
    points_xyz: NDArray[np.floating], config: DemConfig, path: str | Path, client: ComputeClient | None = None, *,
    body: Body, progress: Any = None, label: str = "dem",
) -> dict[str, Any]:
    """Grid again, in place, the chunks a ``dem.zarr`` records as failed (the resume of :func:`grid_dem`).

    ``config`` must give the store's grid (the run's DEM settings with its extent, as at the first
    try); the chunks' regions are written over their NaN pixels with the same function as the other
    chunks, so a store whose failed chunks all succeed now equals one gridded whole. The record is
    updated last: a chunk that fails again stays listed (with its new error), one interrupted
    mid-write is still listed and done again next time.

    Returns
    -------
    dict: path, reused (True), regridded (bounds of the chunks now gridded), failed_chunks (those
    still failing), no_value_pixels.
    """
    import zarr

    from mercury_dem.progress import NULL

    rep = progress if progress is not None else NULL
    cfg = _dem_config(config)
    pts = np.asarray(points_xyz, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[0] and cfg.extent_from_points:
        cfg = config_with_extent(cfg, pts)
    grid = GridSpec.from_config(cfg, body.datum_radius_m)
    failed = failed_chunks_of(path)
    group = zarr.open_group(str(path), mode="r+")
    if tuple(group["elevation"].shape) != grid.shape:
        raise StoreError(f"{path}: its grid {tuple(group['elevation'].shape)} is not the configured {grid.shape}; "
                         f"grid the DEM again (mercury-dem run --force dem)")
    todo = [tuple(int(v) for v in f["bounds"]) for f in failed]
    rep.message(f"{label}: {len(todo)} chunk(s) that failed before, gridded again")
    index = build_point_index(pts, body.datum_radius_m)
    cfg = config_with_no_value_distance(cfg, index)  # the same as at the first try: same points, same rule
    layer_arrays = {name: group[name] for name in LAYERS}
    runner = client_or_sync(client)
    index_f = runner.scatter(index, broadcast=True)
    target: Any = layer_arrays if runs_in_process(client) else str(path)  # in this process: the open arrays
    futures = [runner.submit(_grid_and_write_or_record, index_f, grid, b, cfg, target, pure=False) for b in todo]
    results = [result_or_record(grid, b, f) for b, f in zip(todo, futures)]  # type: ignore[arg-type]
    # the DEM was committed before: chunks failing again keep their records, never a stage error
    kept = judge_chunk_results(results, str(path), rep, label, all_failed_is_error=False)
    recovered = sum((b[1] - b[0]) * (b[3] - b[2]) for b in todo) - sum(r["pixels"] for r in kept)
    no_value = int(group.attrs.get("no_value_pixels", 0)) - recovered + sum(
        r["no_value"] for r in results if not r.get("failed"))
    group.attrs["no_value_pixels"] = int(no_value)
    if kept:
        group.attrs[FAILED_CHUNKS_ATTR] = json.dumps(kept)
    else:
        group.attrs.__delitem__(FAILED_CHUNKS_ATTR)
    return {"path": str(path), "reused": True, "regridded": [list(r["bounds"]) for r in results if not r.get("failed")],
            "failed_chunks": kept, "no_value_pixels": int(no_value)}


@contextlib.contextmanager
def _stopping_on_error(writer: StoreWriter | None) -> Iterator[None]:
    """Stop a forked writer (and wait for it) when the block fails, before its store is removed."""
    try:
        yield
    except BaseException:
        if writer is not None:
            writer.abort()
        raise


def mark_zarr_complete(store: Path) -> None:
    """The stores' completion mark: root attribute ``complete = true`` (a marker *file*
    inside a Zarr v3 store would make zarr warn on every open).
    """
    import zarr

    zarr.open_group(str(store), mode="r+").attrs["complete"] = True


@contextlib.contextmanager
def atomic_store(path: Path, overwrite: bool = False,
                 mark_complete: Callable[[Path], None] = mark_zarr_complete) -> Iterator[Path]:
    """:func:`mercury_dem.io.atomic.atomic_directory` with the Zarr completion mark.

    Yields an empty temporary sibling directory to write the store into; renamed to
    ``path`` once marked complete. An existing ``path`` is replaced only then, and
    only with ``overwrite`` (else :class:`StoreError`). ``mark_complete``: what sets the
    mark (a forked writer's :meth:`~mercury_dem.pipeline.store_writer.ForkedStoreWriter.complete`).
    """
    try:
        with atomic_directory(path, overwrite=overwrite, mark_complete=mark_complete) as tmp:
            yield tmp
    except FileExistsError as exc:
        raise StoreError(f"{path} already exists; pass overwrite=True (CLI: --overwrite) to replace it") from exc


def write_coverage(cov: CoverageResult, path: Path, overwrite: bool = False) -> None:
    """Store the coverage maps (sinusoidal equal-area grid) as a small Zarr Dataset."""
    with atomic_store(path, overwrite=overwrite) as tmp:
        ds = cov.to_dataset()
        ds.to_zarr(str(tmp), mode="w", consolidated=False, zarr_format=3)
