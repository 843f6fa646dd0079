"""Where a run stands, read from its store only (works for a running, finished or remote run).

States of a unit (a tile, region, hemisphere or the globe):

``done``
    its directory is complete and its summary says ``ok``;
``failed``
    complete, summary not ``ok`` (the reason is the summary's ``error``);
``running``
    inferred, for the adjustment levels only: the unit is not written yet but every
    child it needs is (a unit is written atomically at its end, so the store cannot
    tell a running tile from a queued one; on Dask a "running" region may still
    wait for the adjustment resource);
``pending``
    anything else the plan expects.

Nothing here imports Dask; every function takes a run directory (or a
:class:`~mercury_dem.io.run_store.RunStore`) and returns pandas tables.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.atomic import is_complete
from mercury_dem.io.run_store import RunStore
from mercury_dem.pipeline.results import Summary, TileSummary, UnitSummary, summary_from_json
from mercury_dem.plan.tree import ADJUSTED_LEVELS, CHILD_LEVEL, LEVELS, MergeTree, merge_tree

#: The unit states, in display order.
STATES = ("pending", "running", "done", "failed")
#: Colours of the states (shared by the matplotlib figures and the dashboard).
STATE_COLOURS = {"pending": "#d9d9d9", "running": "#f0ad4e", "done": "#3c9a5f", "failed": "#d9534f"}

UNIT_COLUMNS = ("level", "id", "name", "state", "error", "images", "points", "measures", "rms_px", "sigma0",
                "iterations", "seconds")


def as_store(run: str | Path | RunStore) -> RunStore:
    """A :class:`RunStore` for a path (or the store itself); StoreError when there is no run.json."""
    return run if isinstance(run, RunStore) else RunStore.open(run)


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # absent, or being replaced this instant: the next poll sees it


def _plan(store: RunStore) -> dict[str, Any] | None:
    return _read_json(store.plan_json) if is_complete(store.plan_dir) else None


def _tile_grid(store: RunStore, plan: dict[str, Any] | None) -> TileGrid:
    if plan is not None:
        return TileGrid(float(plan["tile_size_deg"]))
    run = _read_json(store.run_json) or {}
    return TileGrid(float(run.get("config", {}).get("tiling", {}).get("tile_size_deg", 10.0)))


def _summary(store: RunStore, level: str, unit_id: int) -> Summary | None:
    """The typed summary of a complete unit; None before (the level and id default to the unit's own)."""
    d = store.unit_dir(level, unit_id)
    raw = _read_json(store.summary_path(level, unit_id)) if is_complete(d) else None
    return None if raw is None else summary_from_json({"level": level, "id": int(unit_id), **raw})


def _unit_row(level: str, unit_id: int, name: str, s: Summary | None, state: str) -> dict[str, Any]:
    figures: dict[str, Any] = {}
    if isinstance(s, TileSummary):
        figures = {"images": s.images, "points": s.points, "measures": s.measures}
    elif isinstance(s, UnitSummary):
        figures = {"images": s.images, "points": s.points, "measures": s.measures, "rms_px": s.rms_px,
                   "sigma0": s.sigma0, "iterations": s.iterations}
    return {
        "level": level, "id": int(unit_id), "name": name, "state": state,
        "error": (s.error if s is not None else None) or "",
        **{k: figures.get(k) for k in ("images", "points", "measures", "rms_px", "sigma0", "iterations")},
        "seconds": s.seconds if s is not None else None,
    }


def _state(s: Summary | None, ready: bool) -> str:
    if s is not None:
        return "done" if s.ok else "failed"
    return "running" if ready else "pending"


def _tree(store: RunStore, plan: dict[str, Any] | None) -> MergeTree | None:
    """The run's merge tree (:func:`mercury_dem.plan.tree.merge_tree` of its sorted tiles), None before the plan."""
    if plan is None:
        return None
    grid = _tile_grid(store, plan)
    return merge_tree(grid.tile_size_deg, sorted(int(t) for t in plan["non_empty_tiles"]))


def expected_units(store: RunStore, plan: dict[str, Any] | None = None) -> dict[str, list[int]]:
    """Units the run will compute per level (from the plan; empty lists before the plan exists)."""
    tree = _tree(store, plan if plan is not None else _plan(store))
    return {lvl: list(tree.units[lvl]) if tree is not None else [] for lvl in LEVELS}


def unit_status(run: str | Path | RunStore) -> pd.DataFrame:
    """One row per expected unit of every level: level, id, name, state, error, counts, rms, sigma0, seconds."""
    from mercury_dem.io.run_store import unit_name

    store = as_store(run)
    tree = _tree(store, _plan(store))
    rows: list[dict[str, Any]] = []
    written: dict[tuple[str, int], bool] = {}
    for level in LEVELS:
        for uid in tree.units[level] if tree is not None else ():
            s = _summary(store, level, uid)
            written[(level, uid)] = s is not None
            kids = [(CHILD_LEVEL[level], c) for c in tree.children.get((level, uid), ())] if level != "tile" else []
            ready = bool(kids) and all(written.get(k, False) for k in kids)
            rows.append(_unit_row(level, uid, unit_name(level, uid), s, _state(s, ready)))
    return pd.DataFrame(rows, columns=list(UNIT_COLUMNS))


def tile_status(run: str | Path | RunStore) -> pd.DataFrame:
    """The expected tiles with their bounds (deg, east longitude 0..360), region and state.

    Columns: tile, lat_min, lat_max, lon_min, lon_max, region, state, error, images,
    points, measures, seconds.
    """
    store = as_store(run)
    plan = _plan(store)
    grid = _tile_grid(store, plan)
    units = unit_status(store)
    t = units[units["level"] == "tile"].reset_index(drop=True)
    ids = t["id"].to_numpy(dtype=np.int64)
    la0, la1, lo0, lo1 = (np.asarray(b, dtype=np.float64) for b in grid.bounds(ids)) if ids.size else [np.zeros(0)] * 4
    return pd.DataFrame({
        "tile": ids, "lat_min": la0, "lat_max": la1, "lon_min": lo0, "lon_max": lo1,
        "region": grid.region_of_tile(ids) if ids.size else np.zeros(0, np.int64),
        "state": t["state"], "error": t["error"], "images": t["images"], "points": t["points"],
        "measures": t["measures"], "seconds": t["seconds"],
    })


def level_progress(units: pd.DataFrame) -> pd.DataFrame:
    """Counts per level and state from :func:`unit_status`: level, total, pending, running, done, failed."""
    rows = []
    for level in LEVELS:
        u = units[units["level"] == level]
        counts = {s: int((u["state"] == s).sum()) for s in STATES}
        rows.append({"level": level, "total": int(len(u)), **counts})
    return pd.DataFrame(rows, columns=["level", "total", *STATES])


def sigma0_history(run: str | Path | RunStore) -> pd.DataFrame:
    """σ0 per iteration of every written adjustment unit: level, id, name, iteration, sigma0."""
    from mercury_dem.io.run_store import unit_name

    store = as_store(run)
    rows = []
    for level in ADJUSTED_LEVELS:
        for uid in store.completed_units(level):
            s = _summary(store, level, uid)
            for k, v in enumerate(s.sigma0_history if isinstance(s, UnitSummary) else []):
                rows.append({"level": level, "id": uid, "name": unit_name(level, uid), "iteration": k,
                             "sigma0": float(v) if v is not None else np.nan})
    return pd.DataFrame(rows, columns=["level", "id", "name", "iteration", "sigma0"])


def run_info(run: str | Path | RunStore) -> dict[str, Any]:
    """Small facts of a run: mission, created, finished (report.json present), dask dashboard link, timings."""
    store = as_store(run)
    info = _read_json(store.run_json) or {}
    report = _read_json(store.report_json) if store.report_json.is_file() else None
    link = info.get("dashboard_link") or ((report or {}).get("execution") or {}).get("dashboard_link")
    return {
        "run": str(store.root),
        "mission": info.get("mission"),
        "created": info.get("created"),
        "finished": report is not None,
        "dashboard_link": link,
        "execution": (report or {}).get("execution"),
        "timings": (report or {}).get("timings", {}),
        "infrastructure_failure": info.get("infrastructure_failure"),  # why the last run stopped (no worker, ...)
    }
