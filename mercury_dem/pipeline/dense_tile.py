"""The dense stage's tile task (issue 31; docs/design/dense.md, "The stage", step 3): one tile's pairs, chip by
chip, into the tile's cloud ``dense.zarr/tile_XXX`` (:mod:`mercury_dem.io.dense_store`).

Load (the run's mission, the adjusted geometry, the sparse DEM) -> call (:func:`mercury_dem.dense.chip.chip_grid`,
:func:`mercury_dem.dense.chip.dense_chip` per chip) -> save (the columns and the tile's summary, atomically). A chip
that raises and a pair without an image or adjusted pose are recorded with their reason and its kind
(:class:`mercury_dem.dense.failures.DenseFailure`) and the rest goes on; a tile task that raises is a failed tile
with its :class:`mercury_dem.pipeline.results.UnitFailure`.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.compute.failures import raise_if_run_stopping
from mercury_dem.config import Config
from mercury_dem.dense.failures import DenseFailure, chip_failure_of, pair_failure_of
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.io.dense_store import (
    CLOUD_COLUMNS,
    empty_column,
    read_tile_summary,
    tile_complete,
    tile_group_name,
    write_tile_group,
)
from mercury_dem.io.run_store import DENSE_FILE, RunStore
from mercury_dem.pipeline.dense_inputs import SparseSurface, adjusted_geometry, matcher_of, open_sparse_surface
from mercury_dem.pipeline.results import UnitFailure, failure_of

#: Per-chip counts summed over a tile (``ChipResult`` attribute -> the summary's key).
_CHIP_COUNTS = {"interior_pixels": "interior_pixels", "matched": "matched", "parts": "chip_parts",
                "parts_failed": "chip_parts_failed"}


class TileCloud:
    """What a tile task gathers: the points' columns, the counts, hole and filter counts, failures, a row per pair."""

    def __init__(self) -> None:
        self.cols: dict[str, list[NDArray[Any]]] = {k: [] for k in CLOUD_COLUMNS}
        self.counts = {"pairs": 0, "chips": 0, "chips_failed": 0, "chips_capped": 0, "interior_pixels": 0,
                       "matched": 0, "points": 0, "chip_parts": 0, "chip_parts_failed": 0}
        self.holes: dict[str, int] = {}
        self.removed: dict[str, int] = {}
        self.failures: list[dict[str, Any]] = []
        self.per_pair: list[dict[str, Any]] = []
        self.sgm_max = 0

    def fail(self, row: dict[str, Any], chip: Any, error: str, failure: DenseFailure) -> None:
        """Record a failed pair (``chip`` None) or chip with its reason and its kind."""
        window = None if chip is None else [chip.x0, chip.y0, chip.width, chip.height]
        self.failures.append({"pair": row["pair"], "left": row["left"], "right": row["right"], "chip": window,
                              "error": error, "failure": failure.value})
        if chip is not None:
            self.counts["chips_failed"] += 1

    def add(self, row: dict[str, Any], res: Any, points: Any, removed_range: int) -> None:
        """One chip's result (``points``: its points after the range filter, which removed ``removed_range``)."""
        n = len(points)
        self.removed["range"] = self.removed.get("range", 0) + removed_range
        self.sgm_max = max(self.sgm_max, res.sgm_memory_bytes)
        for attr, key in _CHIP_COUNTS.items():
            self.counts[key] += int(getattr(res, attr))
        self.counts["points"] += n
        row["points"] += n
        for into, part in ((self.holes, res.holes), (self.removed, res.removed)):
            for k, v in part.items():
                into[k] = into.get(k, 0) + v
        for k in ("lat", "lon", "height", "sigma_h_m", "miss_m", "angle_deg", "score", "left_px", "right_px"):
            self.cols[k].append(getattr(points, k))
        self.cols["pair"].append(np.full(n, row["pair"]))
        for k in ("sigma_match_px", "m_per_px"):
            v = getattr(points, k)
            self.cols[k].append(v if v is not None else np.full(n, np.nan))

    def arrays(self) -> dict[str, NDArray[Any]]:
        """The tile's columns, typed as :data:`CLOUD_COLUMNS`."""
        return {k: (np.concatenate(self.cols[k]).astype(dt) if self.cols[k] else empty_column(k))
                for k, dt in CLOUD_COLUMNS.items()}

    def summary(self, tile_id: int, height_margin_m: float, image_bytes: int, seconds: float) -> dict[str, Any]:
        """The tile's summary (stored in its group and returned by the task)."""
        return {"tile": int(tile_id), "ok": True, **self.counts, "holes": self.holes, "removed": self.removed,
                "failures": self.failures, "pairs_table": self.per_pair, "height_margin_m": float(height_margin_m),
                "memory_bytes": {"images": image_bytes, "sgm_max": int(self.sgm_max),
                                 "total": image_bytes + int(self.sgm_max)},
                "seconds": round(seconds, 3)}


class _Tile:
    """A tile task's inputs: the mission, the adjusted geometry, the sparse surface, the settings, the images read."""

    def __init__(self, store: RunStore, config: Config, height_margin_m: float):
        from mercury_dem.mission import open_mission

        self.mission = open_mission(store.read_run()["mission"])
        self.geometry = adjusted_geometry(store, self.mission)
        self.surface: SparseSurface = open_sparse_surface(store.dem_path)
        self.settings, self.limits = matcher_of(config)
        self.d = config.dense
        self.margin = float(height_margin_m)
        self.images: dict[str, NDArray[np.float32]] = {}

    def image(self, image_id: str) -> NDArray[np.float32]:
        if image_id not in self.images:
            self.images[image_id] = np.asarray(self.mission.read_image(image_id), np.float32)
        return self.images[image_id]

    def image_bytes(self) -> int:
        return sum(int(v.nbytes) for v in self.images.values())


def run_dense_tile(run_root: str, tile_id: int, pairs: list[tuple[int, str, str]], config: Config,
                   height_margin_m: float) -> dict[str, Any]:
    """Match one tile's pairs chip by chip and write its cloud ``dense.zarr/tile_XXX`` atomically.

    ``pairs``: (pair index, left id, right id) in rank order. Returns the tile's summary (also stored in the
    group's attributes): pairs, chips run / failed / capped, points, hole and filter counts, the failures
    (``{"pair", "left", "right", "chip", "error", "failure"}``), seconds and the task's stated memory. An already
    complete group is not recomputed (its stored summary is returned, ``reused``: True).
    """
    store = RunStore(Path(run_root))
    path = store.root / DENSE_FILE / tile_group_name(tile_id)
    if tile_complete(path):
        return {**read_tile_summary(path), "reused": True}
    t0 = time.perf_counter()
    tile = _Tile(store, config, height_margin_m)
    cloud = TileCloud()
    cloud.counts["pairs"] = len(pairs)
    for index, left, right in pairs:
        _run_pair(tile, cloud, int(index), left, right)
    summary = cloud.summary(tile_id, height_margin_m, tile.image_bytes(), time.perf_counter() - t0)
    write_tile_group(path, cloud.arrays(), summary)
    return summary


def _run_pair(tile: _Tile, cloud: TileCloud, index: int, left: str, right: str) -> None:
    """One pair's chips (at most ``dense.max_chips_per_pair``) into ``cloud``."""
    from mercury_dem.dense.chip import chip_grid

    row: dict[str, Any] = {"pair": index, "left": left, "right": right, "chips": 0, "points": 0}
    cloud.per_pair.append(row)
    try:
        a, b = tile.geometry[left], tile.geometry[right]
        li, ri = tile.image(left), tile.image(right)
    except (KeyError, MercuryDemError, OSError, ValueError) as exc:
        why = f"no adjusted pose for {exc}" if isinstance(exc, KeyError) else str(exc)
        cloud.fail(row, None, f"pair {left}/{right}: {why}", pair_failure_of(exc))
        return
    d = tile.d
    chips = chip_grid(a.camera.samples, a.camera.lines, d.chip_size, d.chip_collar)
    cloud.counts["chips_capped"] += max(0, len(chips) - d.max_chips_per_pair)
    for chip in chips[:d.max_chips_per_pair]:
        cloud.counts["chips"] += 1
        row["chips"] += 1
        _run_chip(tile, cloud, row, (li, ri, a, b), chip)


def _run_chip(tile: _Tile, cloud: TileCloud, row: dict[str, Any], pair: tuple[Any, Any, Any, Any], chip: Any) -> None:
    """One chip through :func:`~mercury_dem.dense.chip.dense_chip`, then the range filter (a point farther from the
    sparse DEM than ``dense.max_height_offset_factor`` x the margin is removed), into ``cloud``.
    """
    from mercury_dem.dense.chip import dense_chip

    d = tile.d
    where = f"pair {row['left']}/{row['right']} chip at ({chip.x0}, {chip.y0})"
    try:
        res = dense_chip(*pair, chip, tile.surface, tile.margin, tile.settings, tile.limits,
                         sigma_floor_px=d.sigma_floor_px, max_vertical_px=d.max_vertical_px,
                         min_chip_px=d.min_chip_px, sigma_scale=d.sigma_scale,
                         sigma_height_floor_m=d.sigma_height_floor_factor * tile.margin,
                         sigma_height_cap_m=d.max_height_offset_factor * tile.margin / math.sqrt(3.0))
    except (MercuryDemError, ValueError, np.linalg.LinAlgError) as exc:
        cloud.fail(row, chip, f"{where}: {exc}", chip_failure_of(exc))
        return
    except Exception as exc:  # noqa: BLE001 - OpenCV's cv2.error and the like: recorded, the rest goes on
        cloud.fail(row, chip, f"{where}: {type(exc).__name__}: {exc}", chip_failure_of(exc))
        return
    p = res.points
    far = ~(np.abs(p.height - tile.surface(p.lat, p.lon)) <= d.max_height_offset_factor * tile.margin)
    cloud.add(row, res, p.subset(~far), int(far.sum()))


def tile_task(run_root: str, tile_id: int, pairs: list[tuple[int, str, str]], config: Config,
              margin: float) -> dict[str, Any]:
    """:func:`run_dense_tile`; an exception becomes a failed tile's summary (nothing written), with its kind
    (:func:`~mercury_dem.pipeline.results.failure_of` for the package's own errors, ``unexpected`` for others).
    """
    try:
        return run_dense_tile(run_root, tile_id, pairs, config, margin)
    except Exception as exc:  # noqa: BLE001 - recorded as a value; a full disk still stops the run
        raise_if_run_stopping(exc, f"dense tile {tile_id}", run_root)
        kind = failure_of(exc) if isinstance(exc, MercuryDemError) else UnitFailure.UNEXPECTED
        return {"tile": int(tile_id), "ok": False, "error": f"dense tile {tile_id}: {type(exc).__name__}: {exc}",
                "failure": kind.value}
