"""The dense stereo stage of a run (issue 31; docs/design/dense.md): pairs, chips per tile, the cloud, the dense DEM.

After the DEM stage (the sparse ``dem.zarr`` and, where the mission has altimetry, the registration):

1. **Pairs**, once, in the driver: the overlap graph's edges among the images the global adjustment controlled,
   with their adjusted geometry (``global/0/solution.parquet``), through
   :func:`mercury_dem.dense.pairs.select_stereo_pairs`; each selected pair belongs to the tile of its left image
   (the plan's tile, as in matching), capped per tile (``dense.max_pairs_per_tile``); every candidate and the
   reason of each rejection go into the report.
2. **One Dask task per tile** (:func:`run_dense_tile`): the tile's pairs in rank order, each left image cut into
   chips (:func:`mercury_dem.dense.chip.chip_grid`), each chip through
   :func:`mercury_dem.dense.chip.dense_chip` about the sparse DEM (``surface_height``), with the tile's height
   margin (``dense.height_margin_factor`` x the robust scatter of the tile's tie points about the sparse DEM,
   at least ``dense.min_height_margin_m``). A chip or pair that fails is recorded with its reason and the
   others go on. Memory per task: the tile's images (float32) + one chip's SGM cost volumes (stated,
   ``memory_bytes``).
3. **The cloud**: ``dense.zarr/tile_XXX/`` (columnar: ``lat``, ``lon``, ``height``, ``sigma_h_m``, ``miss_m``,
   ``angle_deg``, ``score``, ``pair`` (index into ``dense.zarr``'s ``pairs`` attribute), ``left_px``,
   ``right_px``, ``sigma_match_px`` (the matcher's own disparity sigma) and ``m_per_px`` (height per pixel of
   disparity), from which ``sigma_h_m`` is made), written atomically by its task, marked ``complete`` in its attributes with the tile's summary;
   a resumed run skips complete tiles.
4. **The dense DEM** ``dem_dense.zarr``: the cloud gridded by the DEM stage's gridding (``dem.method``, ...)
   at ``dense.grid_pixel_factor`` x the pairs' median pixel scale; where no dense point reaches, the sparse DEM
   resampled (bilinear) as fallback; layers ``elevation``, ``precision_m``, ``source`` (0 none, 1 dense,
   2 sparse fallback) and the gridding's own.

Stages never call each other: this one reads what the earlier ones committed.
"""

from __future__ import annotations

import math
import shutil
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np
from numpy.typing import NDArray

from mercury_dem.compute.failures import lost_to_the_cluster, raise_if_run_stopping
from mercury_dem.config import Config
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.io.run_store import DEM_DENSE_FILE, DENSE_FILE, RunStore, read_solution

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient

#: Columns of a tile's cloud (name -> dtype); ``left_px``/``right_px`` are (N, 2).
CLOUD_COLUMNS: dict[str, Any] = {
    "lat": np.float64, "lon": np.float64, "height": np.float64, "sigma_h_m": np.float32, "miss_m": np.float32,
    "angle_deg": np.float32, "score": np.float32, "pair": np.int32, "left_px": np.float32, "right_px": np.float32,
    "sigma_match_px": np.float32, "m_per_px": np.float32,
}



def tile_group_name(tile_id: int) -> str:
    """The group of a tile's cloud in ``dense.zarr`` (``tile_007``)."""
    return f"tile_{int(tile_id):03d}"


# --------------------------------------------------------------------------- inputs
def criteria_of(config: Config) -> Any:
    """The :class:`~mercury_dem.dense.pairs.StereoPairCriteria` of ``config.dense``."""
    from mercury_dem.dense.pairs import StereoPairCriteria

    d = config.dense
    lo, hi = d.best_parallax_height
    return StereoPairCriteria(
        min_parallax_height=d.min_parallax_height, max_parallax_height=d.max_parallax_height,
        best_parallax_height=(lo, hi), max_scale_ratio=d.max_scale_ratio,
        max_incidence_difference_deg=d.max_incidence_difference_deg,
        max_sun_azimuth_difference_deg=d.max_sun_azimuth_difference_deg, max_incidence_deg=d.max_incidence_deg,
        min_overlap=d.min_overlap, max_pairs_per_image=d.max_pairs_per_image)


def matcher_of(config: Config) -> tuple[Any, Any]:
    """The ``MatcherSettings`` and ``PointFilter`` of ``config.dense`` (the other fields: their defaults)."""
    from mercury_dem.dense.disparity import MatcherSettings
    from mercury_dem.dense.triangulate import PointFilter

    d = config.dense
    return (MatcherSettings(mode=d.matcher_mode, block_size=d.block_size, refine_window=d.refine_window,
                            max_sigma_px=d.max_sigma_px, min_score=d.min_score),
            PointFilter(max_miss_pixels=d.max_miss_pixels, min_angle_deg=d.min_angle_deg,
                        max_sigma_h_m=d.max_sigma_h_m))


def adjusted_geometry(store: RunStore, mission: Any) -> dict[str, Any]:
    """Image id -> :class:`~mercury_dem.match.pretransform.ImageGeometry` with the global adjustment's pose,
    for the images it controlled (at least one measure).
    """
    from mercury_dem.match.pretransform import ImageGeometry

    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(len(sid))
    out: dict[str, Any] = {}
    for i, r, c, n in zip(sid, rot, pos, nmeas):
        if n > 0 and np.all(np.isfinite(r)) and np.all(np.isfinite(c)):
            out[str(i)] = ImageGeometry.of(mission.camera(str(i)), c, r, mission.sun_position(str(i)),
                                           mission.body.datum_radius_m)
    return out










class SparseSurface:
    """The sparse DEM as the chips' ``surface_height`` (bilinear; NaN filled with the DEM's median height).

    Picklable (arrays only), so a task may build it once and pass it around.
    """

    def __init__(self, values: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64]):
        self.values = np.asarray(values, np.float64)
        self.lat = np.asarray(lat, np.float64)
        self.lon = np.asarray(lon, np.float64)
        finite = self.values[np.isfinite(self.values)]
        self.fill = float(np.median(finite)) if finite.size else 0.0

    def sample(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bilinear values, NaN outside the grid or next to a NaN post."""
        from mercury_dem.reference.sampling import sample_grid

        return np.asarray(sample_grid(self.values, self.lat, self.lon, lat, lon), np.float64)

    def __call__(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        h = self.sample(lat, lon)
        return np.where(np.isfinite(h), h, self.fill)


def open_sparse_surface(dem_path: Path) -> SparseSurface:
    """The sparse DEM store's elevation as a :class:`SparseSurface` (loaded)."""
    from mercury_dem.pipeline.dem_stage import open_dem

    ds = open_dem(dem_path)
    e = ds["elevation"].transpose("lat", "lon")
    return SparseSurface(e.values, e["lat"].values, e["lon"].values)


# --------------------------------------------------------------------------- the tile task
def tile_complete(path: Path) -> bool:
    """A tile group committed by :func:`run_dense_tile` (its ``complete`` attribute)."""
    import zarr

    if not (path / "zarr.json").is_file():
        return False
    try:
        return bool(zarr.open_group(str(path), mode="r").attrs.get("complete", False))
    except Exception:  # noqa: BLE001 - an unreadable group is not complete (recomputed)
        return False


def read_tile_summary(path: Path) -> dict[str, Any]:
    """The summary a tile task stored in its group's attributes."""
    import zarr

    summary: Any = zarr.open_group(str(path), mode="r").attrs["summary"]
    return dict(summary)


def run_dense_tile(run_root: str, tile_id: int, pairs: list[tuple[int, str, str]], config: Config,
                   height_margin_m: float) -> dict[str, Any]:
    """Match one tile's pairs chip by chip and write its cloud ``dense.zarr/tile_XXX`` atomically.

    ``pairs``: (pair index, left id, right id) in rank order. Returns the tile's summary (also stored in the
    group's attributes): pairs, chips run / failed / capped, points, hole and filter counts, the failures
    (``{"pair", "left", "right", "chip", "error"}``), seconds and the task's stated memory. An already
    complete group is not recomputed (its stored summary is returned, ``reused``: True).
    """
    from mercury_dem.dense.chip import chip_grid, dense_chip
    from mercury_dem.mission import open_mission

    store = RunStore(Path(run_root))
    path = store.root / DENSE_FILE / tile_group_name(tile_id)
    if tile_complete(path):
        return {**read_tile_summary(path), "reused": True}
    t0 = time.perf_counter()
    mission = open_mission(store.read_run()["mission"])
    geometry = adjusted_geometry(store, mission)
    surface = open_sparse_surface(store.dem_path)
    settings, limits = matcher_of(config)
    d = config.dense
    images: dict[str, NDArray[np.float32]] = {}
    cols: dict[str, list[NDArray[Any]]] = {k: [] for k in CLOUD_COLUMNS}
    failures: list[dict[str, Any]] = []
    holes: dict[str, int] = {}
    removed: dict[str, int] = {}
    counts = {"pairs": len(pairs), "chips": 0, "chips_failed": 0, "chips_capped": 0, "interior_pixels": 0,
              "matched": 0, "points": 0, "chip_parts": 0, "chip_parts_failed": 0}
    per_pair: list[dict[str, Any]] = []
    sgm_max = 0

    def image(i: str) -> NDArray[np.float32]:
        if i not in images:
            images[i] = np.asarray(mission.read_image(i), np.float32)
        return images[i]

    for index, left, right in pairs:
        row: dict[str, Any] = {"pair": int(index), "left": left, "right": right, "chips": 0, "points": 0}
        per_pair.append(row)
        try:
            a, b = geometry[left], geometry[right]
            li, ri = image(left), image(right)
        except (KeyError, MercuryDemError, OSError, ValueError) as exc:
            why = f"no adjusted pose for {exc}" if isinstance(exc, KeyError) else str(exc)
            failures.append({"pair": int(index), "left": left, "right": right, "chip": None,
                             "error": f"pair {left}/{right}: {why}"})
            continue
        chips = chip_grid(a.camera.samples, a.camera.lines, d.chip_size, d.chip_collar)
        counts["chips_capped"] += max(0, len(chips) - d.max_chips_per_pair)
        for chip in chips[:d.max_chips_per_pair]:
            counts["chips"] += 1
            row["chips"] += 1
            where = f"pair {left}/{right} chip at ({chip.x0}, {chip.y0})"
            try:
                res = dense_chip(li, ri, a, b, chip, surface, height_margin_m, settings, limits,
                                 sigma_floor_px=d.sigma_floor_px, max_vertical_px=d.max_vertical_px,
                                 min_chip_px=d.min_chip_px, sigma_scale=d.sigma_scale,
                                 sigma_height_floor_m=d.sigma_height_floor_factor * height_margin_m,
                                 sigma_height_cap_m=d.max_height_offset_factor * height_margin_m / math.sqrt(3.0))
            except (MercuryDemError, ValueError, np.linalg.LinAlgError) as exc:
                counts["chips_failed"] += 1
                failures.append({"pair": int(index), "left": left, "right": right,
                                 "chip": [chip.x0, chip.y0, chip.width, chip.height], "error": f"{where}: {exc}"})
                continue
            except Exception as exc:  # noqa: BLE001 - OpenCV's cv2.error and the like: recorded, the rest goes on
                counts["chips_failed"] += 1
                failures.append({"pair": int(index), "left": left, "right": right,
                                 "chip": [chip.x0, chip.y0, chip.width, chip.height],
                                 "error": f"{where}: {type(exc).__name__}: {exc}"})
                continue
            p = res.points
            far = ~(np.abs(p.height - surface(p.lat, p.lon)) <= d.max_height_offset_factor * height_margin_m)
            removed["range"] = removed.get("range", 0) + int(far.sum())
            p = p.subset(~far)
            n = len(p)
            sgm_max = max(sgm_max, res.sgm_memory_bytes)
            counts["interior_pixels"] += res.interior_pixels
            counts["matched"] += res.matched
            counts["chip_parts"] += res.parts
            counts["chip_parts_failed"] += res.parts_failed
            counts["points"] += n
            row["points"] += n
            for k, v in res.holes.items():
                holes[k] = holes.get(k, 0) + v
            for k, v in res.removed.items():
                removed[k] = removed.get(k, 0) + v
            cols["lat"].append(p.lat)
            cols["lon"].append(p.lon)
            cols["height"].append(p.height)
            cols["sigma_h_m"].append(p.sigma_h_m)
            cols["miss_m"].append(p.miss_m)
            cols["angle_deg"].append(p.angle_deg)
            cols["score"].append(p.score)
            cols["pair"].append(np.full(n, index))
            cols["left_px"].append(p.left_px)
            cols["right_px"].append(p.right_px)
            cols["sigma_match_px"].append(p.sigma_match_px if p.sigma_match_px is not None else np.full(n, np.nan))
            cols["m_per_px"].append(p.m_per_px if p.m_per_px is not None else np.full(n, np.nan))
    image_bytes = sum(int(v.nbytes) for v in images.values())
    summary = {
        "tile": int(tile_id), "ok": True, **counts, "holes": holes, "removed": removed, "failures": failures,
        "pairs_table": per_pair, "height_margin_m": float(height_margin_m),
        "memory_bytes": {"images": image_bytes, "sgm_max": int(sgm_max), "total": image_bytes + int(sgm_max)},
        "seconds": round(time.perf_counter() - t0, 3),
    }
    arrays = {}
    for k, dt in CLOUD_COLUMNS.items():
        width = 2 if k.endswith("_px") else 0
        empty = np.zeros((0, 2) if width else 0, dt)
        arrays[k] = np.concatenate(cols[k]).astype(dt) if cols[k] else empty
    write_tile_group(path, arrays, summary)
    return summary


def write_tile_group(path: Path, arrays: dict[str, NDArray[Any]], summary: dict[str, Any]) -> None:
    """Write one tile's cloud as a Zarr group, atomically (built under a temporary name, marked complete in its
    attributes with the summary, then renamed); an existing group is replaced only once the new one is whole.
    """
    import json

    import zarr

    from mercury_dem.io.atomic import atomic_directory

    def mark(tmp: Path) -> None:
        g = zarr.open_group(str(tmp), mode="r+")
        g.attrs["summary"] = json.loads(json.dumps(summary, default=float))
        g.attrs["complete"] = True

    with atomic_directory(path, overwrite=True, mark_complete=mark) as tmp:
        g = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        for k, a in arrays.items():
            chunks = (max(1, min(a.shape[0], 1 << 20)),) + a.shape[1:]
            g.create_array(k, data=np.ascontiguousarray(a), chunks=chunks)
        g.attrs["columns"] = {k: ("(N, 2) sample, line, 0-based" if k.endswith("_px") else "(N,)")
                              for k in arrays}


def read_cloud(dense_path: Path, tiles: list[int] | None = None) -> dict[str, NDArray[Any]]:
    """The complete tiles' clouds concatenated (column -> array), in tile order."""
    import zarr

    names = sorted(p.name for p in dense_path.iterdir() if p.name.startswith("tile_")) if dense_path.is_dir() else []
    if tiles is not None:
        want = {tile_group_name(t) for t in tiles}
        names = [n for n in names if n in want]
    out: dict[str, list[NDArray[Any]]] = {k: [] for k in CLOUD_COLUMNS}
    for n in names:
        if not tile_complete(dense_path / n):
            continue
        g = zarr.open_group(str(dense_path / n), mode="r")
        for k in CLOUD_COLUMNS:
            arr: Any = g[k]
            out[k].append(np.asarray(arr[...]))
    return {k: (np.concatenate(v) if v else np.zeros((0, 2) if k.endswith("_px") else 0, CLOUD_COLUMNS[k]))
            for k, v in out.items()}


def _tile_task(run_root: str, tile_id: int, pairs: list[tuple[int, str, str]], config: Config,
               margin: float) -> dict[str, Any]:
    """:func:`run_dense_tile`; an unexpected exception becomes a failed tile's summary (nothing written)."""
    try:
        return run_dense_tile(run_root, tile_id, pairs, config, margin)
    except Exception as exc:  # noqa: BLE001 - recorded as a value; a full disk still stops the run
        raise_if_run_stopping(exc, f"dense tile {tile_id}", run_root)
        return {"tile": int(tile_id), "ok": False, "error": f"dense tile {tile_id}: {type(exc).__name__}: {exc}"}


# --------------------------------------------------------------------------- the driver
def run_dense_stage(store: RunStore, mission: Any, config: Config, client: ComputeClient,
                    stream: TextIO | None = sys.stdout) -> dict[str, Any]:
    """Select the pairs, run the tiles on ``client``, grid the dense DEM; returns the report's ``dense`` block
    (with ``validation``: the dense DEM and the sparse DEM on the dense grid against the truth, when known).
    """
    import json

    import zarr

    from mercury_dem.compute import as_completed
    from mercury_dem.dem.cloud import point_cloud
    from mercury_dem.dem.dense_grid import dense_grid_ppd
    from mercury_dem.dense.pairs import SELECTED, select_stereo_pairs
    from mercury_dem.dense.rules import cap_per_tile, height_margins
    from mercury_dem.io.network_store import read_network
    from mercury_dem.pipeline.dense_dem import grid_dense_dem, rmse_ratio, validate_dense_dem
    from mercury_dem.progress import Reporter

    rep = Reporter(stream)
    t0 = time.perf_counter()
    d = config.dense
    body = mission.body
    geometry = adjusted_geometry(store, mission)
    images, overlaps, _ = store.read_plan()
    tile_of = dict(zip(images["image_id"].astype(str), images["tile_id"].astype(int)))
    candidates = [(str(a), str(b)) for a, b in zip(overlaps["image_i"], overlaps["image_j"])
                  if str(a) in geometry and str(b) in geometry]
    rows = select_stereo_pairs(geometry, criteria_of(config), candidates)
    rows, per_tile = cap_per_tile(rows, tile_of, d.max_pairs_per_tile, d.tiles)  # dense.rules
    selected = [i for i, r in enumerate(rows) if r.status == SELECTED]
    pair_index = {i: k for k, i in enumerate(sorted(selected, key=lambda i: rows[i].rank))}
    pair_records = [{"index": pair_index[i], **rows[i].to_dict()} for i in sorted(selected, key=lambda i: pair_index[i])]
    reasons: dict[str, int] = {}
    for r in rows:
        if r.status != SELECTED:
            for part in r.reason.split("; "):
                key = part.split(" ")[0] if not part.startswith("cap:") else "cap"
                key = {"parallax/height": "parallax_height", "pixel-scale": "scale_ratio",
                       "incidence": "incidence", "sun-azimuth": "sun_azimuth", "overlap": "overlap",
                       "tile": "tile_subset", "no": "no_geometry"}.get(key, key)
                reasons[key] = reasons.get(key, 0) + 1
    rep.message(f"dense: {len(candidates)} candidate pairs, {len(selected)} selected over {len(per_tile)} tiles")

    surface = open_sparse_surface(store.dem_path)
    net = read_network(store.network_path("global", 0))
    tie = point_cloud(net, adjusted=True)
    margins, run_margin = height_margins(tie, surface.sample, body.datum_radius_m, config.tiling.tile_size_deg,
                                         d.height_margin_factor, d.min_height_margin_m)

    dense_path = store.root / DENSE_FILE
    root = zarr.open_group(str(dense_path), mode="a", zarr_format=3)
    records = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()}
               for r in json.loads(json.dumps(pair_records, default=float))]
    if root.attrs.get("pairs") != records:
        # another selection (config changed under --force): the tiles' pair indices would not match
        for p in dense_path.iterdir():
            if p.name.startswith("tile_"):
                shutil.rmtree(p, ignore_errors=True)
        root.attrs["pairs"] = records
    root.attrs["columns"] = {k: str(np.dtype(v)) for k, v in CLOUD_COLUMNS.items()}

    futures = []
    for t in sorted(per_tile):
        plist = [(pair_index[i], rows[i].left, rows[i].right) for i in per_tile[t]]
        futures.append(client.submit(_tile_task, store.location, t, plist, config, margins.get(t, run_margin),
                                     key=f"dense-tile-{t}", pure=False, retries=config.execution.retries))
    tiles: list[dict[str, Any]] = []
    for fut in as_completed(client, futures):
        try:
            s = fut.result()
        except Exception as exc:  # noqa: BLE001 - a lost task after its retries: recorded, the rest goes on
            raise_if_run_stopping(exc, f"dense tile task {getattr(fut, 'key', '?')}", store.location)
            if lost_to_the_cluster(exc):
                raise  # cancelled by the cluster (no worker, the scheduler gone): the run's failure, not the tile's
            s = {"tile": None, "ok": False, "error": f"dense tile task {getattr(fut, 'key', '?')}: {exc}"}
        tiles.append(s)
        rep.message(f"dense: tile {s.get('tile')}: " + (f"{s.get('points', 0)} points from {s.get('chips', 0)} "
                    f"chips in {s.get('seconds', 0):.1f} s" if s.get("ok") else f"FAILED ({s.get('error')})"))
    tiles.sort(key=lambda s: (s.get("tile") is None, s.get("tile") or 0))
    ok_tiles = [s for s in tiles if s.get("ok")]
    failures = [f for s in ok_tiles for f in s.get("failures", [])]
    out: dict[str, Any] = {
        "path": str(dense_path),
        "pairs": {"candidates": len(rows), "selected": len(selected), "rejected": len(rows) - len(selected),
                  "rejected_by_reason": reasons, "table": [r.to_dict() for r in rows]},
        "tiles": {"run": len(tiles), "failed": [s for s in tiles if not s.get("ok")]},
        "chips": int(sum(s.get("chips", 0) for s in ok_tiles)),
        "chips_failed": int(sum(s.get("chips_failed", 0) for s in ok_tiles)),
        "chips_capped": int(sum(s.get("chips_capped", 0) for s in ok_tiles)),
        "chip_parts": int(sum(s.get("chip_parts", 0) for s in ok_tiles)),
        "chip_parts_failed": int(sum(s.get("chip_parts_failed", 0) for s in ok_tiles)),
        "points": int(sum(s.get("points", 0) for s in ok_tiles)),
        "interior_pixels": int(sum(s.get("interior_pixels", 0) for s in ok_tiles)),
        "holes": _sum_dicts(s.get("holes", {}) for s in ok_tiles),
        "removed": _sum_dicts(s.get("removed", {}) for s in ok_tiles),
        "failures": failures,
        "height_margin_m": {"run": run_margin, "per_tile": {str(k): v for k, v in sorted(margins.items())}},
        "memory_bytes_max_task": max((s["memory_bytes"]["total"] for s in ok_tiles if "memory_bytes" in s),
                                     default=0),
        "tile_seconds": {str(s["tile"]): s.get("seconds") for s in ok_tiles},
    }
    scales = np.array([max(r.pixel_scale_left_m, r.pixel_scale_right_m) for r in rows if r.status == SELECTED])
    if out["points"] == 0 or scales.size == 0:
        out["dem"] = {"error": "no dense point: no dense DEM (see dense.pairs and dense.failures)"}
        out["seconds"] = round(time.perf_counter() - t0, 2)
        return out
    ppd = dense_grid_ppd(scales, d.grid_pixel_factor, body.datum_radius_m)
    out["dem"] = grid_dense_dem(store, config, ppd, client, body, rep, median_pixel_scale_m=float(np.median(scales)))
    if mission.truth is not None:
        out["validation"] = validate_dense_dem(store.root / DEM_DENSE_FILE, mission.truth.surface().height, tie,
                                               body.datum_radius_m)
        out["dem"]["rmse_ratio_dense_over_sparse"] = rmse_ratio(out["validation"])
    out["seconds"] = round(time.perf_counter() - t0, 2)
    rep.message(f"dense stage: {out['points']} points, {out['chips']} chips ({out['chips_failed']} failed), "
                f"dense DEM at {ppd:g} pixel/deg in {out['seconds']:.1f} s")
    return out


def _sum_dicts(ds: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for dd in ds:
        for k, v in dd.items():
            out[k] = out.get(k, 0) + int(v)
    return out










