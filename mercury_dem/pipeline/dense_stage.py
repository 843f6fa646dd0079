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
   ``right_px``), written atomically by its task, marked ``complete`` in its attributes with the tile's summary;
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
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config import Config
from mercury_dem.exceptions import CorruptUnitError, DiskFullError, MercuryDemError
from mercury_dem.io.run_store import DEM_DENSE_FILE, DEM_DENSE_SCRATCH_FILE, DENSE_FILE, RunStore, read_solution

#: Columns of a tile's cloud (name -> dtype); ``left_px``/``right_px`` are (N, 2).
CLOUD_COLUMNS: dict[str, Any] = {
    "lat": np.float64, "lon": np.float64, "height": np.float64, "sigma_h_m": np.float32, "miss_m": np.float32,
    "angle_deg": np.float32, "score": np.float32, "pair": np.int32, "left_px": np.float32, "right_px": np.float32,
}

#: ``source`` layer of the dense DEM.
SOURCE_NONE, SOURCE_DENSE, SOURCE_SPARSE = 0, 1, 2

#: Robust scatter: 1.4826 x median absolute deviation.
MAD_TO_SIGMA = 1.4826


def tile_group_name(tile_id: int) -> str:
    """The group of a tile's cloud in ``dense.zarr`` (``tile_007``)."""
    return f"tile_{int(tile_id):03d}"


# --------------------------------------------------------------------------- inputs (pure helpers)
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


def cap_per_tile(rows: list[Any], tile_of: dict[str, int], max_per_tile: int,
                 tiles: tuple[int, ...] = ()) -> tuple[list[Any], dict[int, list[int]]]:
    """Apply the per-tile cap and the tile subset to selected pairs (best rank first).

    Returns the rows (capped ones rejected with the reason) and tile id -> indices of its selected rows,
    in rank order.
    """
    from mercury_dem.dense.pairs import REJECTED, SELECTED

    out = list(rows)
    per_tile: dict[int, list[int]] = {}
    for i in sorted((i for i, r in enumerate(out) if r.status == SELECTED), key=lambda i: out[i].rank):
        t = int(tile_of.get(out[i].left, -1))
        if tiles and t not in tiles:
            out[i] = replace(out[i], status=REJECTED, rank=0, reason=f"tile {t} not in dense.tiles")
            continue
        got = per_tile.setdefault(t, [])
        if len(got) >= max_per_tile:
            out[i] = replace(out[i], status=REJECTED, rank=0,
                             reason=f"cap: tile {t} already has {max_per_tile} better-ranked pairs")
            continue
        got.append(i)
    return out, {t: v for t, v in per_tile.items() if v}


def dense_grid_ppd(pixel_scales_m: NDArray[np.float64], factor: float, datum_radius_m: float) -> float:
    """Pixels per degree of the dense DEM: ``factor`` x the median pixel scale, rounded to a multiple of 0.5
    (so 180 and 360 degrees are whole pixels), at least 0.5.
    """
    pixel_m = factor * float(np.median(pixel_scales_m))
    raw = 2.0 * math.pi * datum_radius_m / 360.0 / pixel_m
    return max(0.5, round(raw * 2.0) / 2.0)


def snapped_bounds(bounds: tuple[float, float, float, float], ppd: float) -> tuple[float, float, float, float]:
    """(lat_min, lat_max, lon_min, lon_max) snapped outward to whole pixels of ``ppd`` (latitudes within +-90)."""
    a0, a1, o0, o1 = bounds
    lat0 = max(-90.0, math.floor(a0 * ppd + 1e-9) / ppd)
    lat1 = min(90.0, math.ceil(a1 * ppd - 1e-9) / ppd)
    lon0 = math.floor(o0 * ppd + 1e-9) / ppd
    lon1 = math.ceil(o1 * ppd - 1e-9) / ppd
    if lon1 - lon0 > 360.0:
        lon1 = lon0 + 360.0
    return lat0, lat1, lon0, lon1


def height_margins(points_xyz: NDArray[np.float64], surface: Callable[..., NDArray[np.float64]],
                   datum_radius_m: float, tile_size_deg: float, factor: float, floor_m: float,
                   min_points: int = 20) -> tuple[dict[int, float], float]:
    """Per tile the height search margin: ``factor`` x the robust scatter of its tie points' heights about the
    surface, at least ``floor_m``; the run's value (all points) for tiles with fewer than ``min_points``.

    Returns (tile id -> margin in m, the run's margin).
    """
    from mercury_dem.geometry.body import xyz_to_latlon
    from mercury_dem.geometry.tiling import TileGrid

    if points_xyz.shape[0] == 0:
        return {}, floor_m
    lat, lon, h = xyz_to_latlon(points_xyz, datum_radius_m)
    res = h - surface(lat, lon)
    ok = np.isfinite(res)
    tiles = TileGrid(tile_size_deg).tile_of(lat, lon)

    def margin(r: NDArray[np.float64]) -> float:
        s = MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)))) if r.size else 0.0
        return max(floor_m, factor * s)

    run = margin(res[ok])
    out: dict[int, float] = {}
    for t in np.unique(tiles[ok]):
        r = res[ok & (tiles == t)]
        out[int(t)] = margin(r) if r.size >= min_points else run
    return out, run


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
              "matched": 0, "points": 0}
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
                                 sigma_floor_px=d.sigma_floor_px)
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
    from mercury_dem.pipeline.stages import fatal_error

    try:
        return run_dense_tile(run_root, tile_id, pairs, config, margin)
    except Exception as exc:  # noqa: BLE001 - recorded as a value; a full disk still stops the run
        fatal = fatal_error(exc, "tile", tile_id, run_root)
        if fatal is exc:
            raise
        if fatal is not None:
            raise fatal from exc
        return {"tile": int(tile_id), "ok": False, "error": f"dense tile {tile_id}: {type(exc).__name__}: {exc}"}


# --------------------------------------------------------------------------- the driver
def run_dense_stage(store: RunStore, mission: Any, config: Config, client: Any,
                    stream: TextIO | None = sys.stdout) -> dict[str, Any]:
    """Select the pairs, run the tiles on ``client``, grid the dense DEM; returns the report's ``dense`` block
    (with ``validation``: the dense DEM and the sparse DEM on the dense grid against the truth, when known).
    """
    import json

    import zarr

    from mercury_dem.dem.cloud import point_cloud
    from mercury_dem.dense.pairs import SELECTED, select_stereo_pairs
    from mercury_dem.io.network_store import read_network
    from mercury_dem.pipeline.executors import as_completed
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
    rows, per_tile = cap_per_tile(rows, tile_of, d.max_pairs_per_tile, d.tiles)
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
        except (DiskFullError, CorruptUnitError):
            raise  # stops the run, as in the cascade
        except Exception as exc:  # noqa: BLE001 - a lost task after its retries: recorded, the rest goes on
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


def grid_dense_dem(store: RunStore, config: Config, ppd: float, client: Any, body: Any, rep: Any,
                   median_pixel_scale_m: float) -> dict[str, Any]:
    """Grid the cloud into ``dem_dense.zarr`` with the sparse DEM as fallback; returns the report's block."""
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.pipeline.dem_stage import atomic_store, grid_dem, open_dem

    cloud = read_cloud(store.root / DENSE_FILE)
    xyz = latlon_to_xyz(cloud["lat"], cloud["lon"], height_m=cloud["height"], datum_radius_m=body.datum_radius_m)
    sparse = open_dem(store.dem_path)
    sl, so = sparse["lat"].values, sparse["lon"].values
    half = 0.5 / float(sparse.attrs.get("pixels_per_degree", 1.0 / abs(sl[1] - sl[0]) if sl.size > 1 else 1.0))
    bounds = snapped_bounds((float(sl.min()) - half, float(sl.max()) + half, float(so.min()) - half,
                             float(so.max()) + half), ppd)
    cfg = replace(config.dem, pixels_per_degree=ppd, lat_min=bounds[0], lat_max=bounds[1], lon_min=bounds[2],
                  lon_max=bounds[3], method="median11", neighbours=config.dense.grid_neighbours)
    scratch = store.root / DEM_DENSE_SCRATCH_FILE
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        summary = grid_dem(xyz, cfg, scratch, client, coverage=False, body=body, record_failures=True,
                           attrs={"source": "dense stereo points"}, progress=rep, label="dem (dense points)")
        g = open_dem(scratch).load()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    lat, lon = g["lat"].values, g["lon"].values
    elev = g["elevation"].transpose("lat", "lon").values.astype(np.float64)
    lat2, lon2 = np.meshgrid(lat, lon, indexing="ij")
    surf = open_sparse_surface(store.dem_path)
    fallback = surf.sample(lat2, lon2)
    has_dense = np.isfinite(elev)
    source = np.where(has_dense, SOURCE_DENSE, np.where(np.isfinite(fallback), SOURCE_SPARSE, SOURCE_NONE))
    final = np.where(has_dense, elev, fallback)
    precision = pixel_precision(cloud, lat, lon, ppd, int(config.dense.grid_neighbours))
    precision = np.where(has_dense, precision, np.nan)
    ds = g.copy()
    dims = g["elevation"].dims
    ds["elevation"] = (("lat", "lon"), final.astype(np.float32))
    ds["elevation"] = ds["elevation"].transpose(*dims)
    ds["elevation_dense"] = (("lat", "lon"), elev.astype(np.float32))
    ds["sparse_on_grid"] = (("lat", "lon"), fallback.astype(np.float32))
    ds["sparse_on_grid"].attrs["long_name"] = "the sparse DEM (dem.zarr) resampled bilinearly on this grid"
    ds["precision_m"] = (("lat", "lon"), precision.astype(np.float32))
    ds["source"] = (("lat", "lon"), source.astype(np.uint8))
    ds["source"].attrs.update({"flag_values": [SOURCE_NONE, SOURCE_DENSE, SOURCE_SPARSE],
                               "flag_meanings": "none dense sparse_fallback"})
    ds["precision_m"].attrs.update({"units": "m", "long_name": "stated 1-sigma precision of the dense elevation: "
                                    "1.2533 x the median stated sigma_h of the pixel's points / sqrt(min(n, "
                                    "dense.grid_neighbours)); NaN where the pixel holds no dense point"})
    ds.attrs.update({"source": "dense stereo points; sparse DEM (dem.zarr) resampled where no dense point reaches",
                     "grid_rule": f"{config.dense.grid_pixel_factor:g} x the pairs' median pixel scale "
                                  f"{median_pixel_scale_m:.0f} m -> {ppd:g} pixel/deg",
                     "pixels_per_degree": ppd})
    for v in ds.data_vars:
        ds[v].encoding = {}
    out_path = store.root / DEM_DENSE_FILE
    with atomic_store(out_path, overwrite=True) as tmp:
        ds.to_zarr(str(tmp), mode="w", zarr_format=3, consolidated=False)
    n = source.size
    return {"path": str(out_path), "pixels_per_degree": ppd, "median_pair_pixel_scale_m": median_pixel_scale_m,
            "pixel_m": 2 * math.pi * body.datum_radius_m / 360.0 / ppd, "shape": list(source.shape),
            "bounds": list(bounds), "points": int(xyz.shape[0]),
            "source_fraction": {"dense": float((source == SOURCE_DENSE).sum() / n),
                                "sparse_fallback": float((source == SOURCE_SPARSE).sum() / n),
                                "none": float((source == SOURCE_NONE).sum() / n)},
            "failed_chunks": summary.get("failed_chunks", []),
            "precision_median_m": float(np.nanmedian(precision)) if np.isfinite(precision).any() else None}


def pixel_precision(cloud: dict[str, NDArray[Any]], lat: NDArray[np.float64], lon: NDArray[np.float64],
                    ppd: float, k: int) -> NDArray[np.float64]:
    """Per pixel ``1.2533 x median(sigma_h) / sqrt(min(n, k))`` of the points inside it (NaN: none)."""
    H, W = lat.size, lon.size
    lat_max = float(lat[0]) + 0.5 / ppd
    lon_min = float(lon[0]) - 0.5 / ppd
    i = np.floor((lat_max - cloud["lat"]) * ppd).astype(np.int64)
    j = np.floor(np.mod(cloud["lon"] - lon_min, 360.0) * ppd).astype(np.int64)
    ok = (i >= 0) & (i < H) & (j >= 0) & (j < W) & np.isfinite(cloud["sigma_h_m"])
    flat = i[ok] * W + j[ok]
    sig = cloud["sigma_h_m"][ok].astype(np.float64)
    out = np.full(H * W, np.nan)
    if flat.size:
        order = np.lexsort((sig, flat))
        f, s = flat[order], sig[order]
        starts = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
        counts = np.diff(np.r_[starts, f.size])
        med = 0.5 * (s[starts + (counts - 1) // 2] + s[starts + counts // 2])
        out[f[starts]] = 1.2533 * med / np.sqrt(np.minimum(counts, k))
    return out.reshape(H, W)


def control_distance(control_xyz: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64],
                     datum_radius_m: float) -> NDArray[np.float64]:
    """(H, W) horizontal distance (m, chord on the datum sphere) from each pixel centre to its nearest control point."""
    from scipy.spatial import cKDTree

    from mercury_dem.geometry.body import latlon_to_unit

    foot = control_xyz / np.linalg.norm(control_xyz, axis=1, keepdims=True) * datum_radius_m
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    q = latlon_to_unit(la.ravel(), lo.ravel()) * datum_radius_m
    d, _ = cKDTree(foot).query(q)
    return np.asarray(d, np.float64).reshape(la.shape)


def validate_dense_dem(path: Path, truth: Callable[..., Any], control_xyz: NDArray[np.float64] | None = None,
                       datum_radius_m: float | None = None) -> dict[str, Any]:
    """``validation.dem`` entries: the dense DEM, the sparse DEM on the dense grid, and both over the pixels
    the dense points reach (``source`` = dense) where the sparse DEM has a value, where the issue's ratio is measured.
    """
    from mercury_dem.dem.accuracy import dem_accuracy
    from mercury_dem.pipeline.dem_stage import open_dem

    ds = open_dem(path).load()
    lat, lon = ds["lat"].values, ds["lon"].values
    elev = ds["elevation"].transpose("lat", "lon").values
    source = ds["source"].transpose("lat", "lon").values
    sparse_on_grid_ = ds["sparse_on_grid"].transpose("lat", "lon").values if "sparse_on_grid" in ds else None
    # the comparison: the pixels where the dense points reach and the sparse DEM has a value too
    dense_px = (source == SOURCE_DENSE) & (np.isfinite(sparse_on_grid_) if sparse_on_grid_ is not None else True)
    # the sparse DEM on the dense grid: what the fallback holds where the dense DEM has no value, and the
    # sparse DEM resampled where it has (kept in the store as the fallback's source: re-sampled here)
    sparse_on_grid = ds["sparse_on_grid"].transpose("lat", "lon").values if "sparse_on_grid" in ds else None
    if sparse_on_grid is None:
        raise MercuryDemError(f"{path} has no sparse_on_grid layer")
    # error against the distance to the nearest control point (issue 31 section 3), for every entry
    dist = (control_distance(control_xyz, lat, lon, datum_radius_m)
            if control_xyz is not None and control_xyz.shape[0] and datum_radius_m is not None else None)
    out = {
        "dense": dem_accuracy(elev, lat, lon, truth, dist),
        "sparse_on_dense_grid": dem_accuracy(sparse_on_grid, lat, lon, truth, dist),
        "dense_on_dense_pixels": dem_accuracy(np.where(dense_px, elev, np.nan), lat, lon, truth, dist),
        "sparse_on_dense_pixels": dem_accuracy(np.where(dense_px, sparse_on_grid, np.nan), lat, lon, truth, dist),
    }
    return out


def rmse_ratio(validation: dict[str, Any]) -> float | None:
    """The issue's figure: the dense DEM's RMSE over the sparse DEM's, both on the pixels the dense points reach."""
    a = validation.get("dense_on_dense_pixels", {}).get("rmse_m")
    b = validation.get("sparse_on_dense_pixels", {}).get("rmse_m")
    return float(a / b) if a is not None and b else None
