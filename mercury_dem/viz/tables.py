"""``report.json`` as pandas tables, and the images that had a problem with the reason why."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.exceptions import StoreError
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.pipeline.results import TileSummary, UnitSummary, read_summary
from mercury_dem.plan.tree import ADJUSTED_LEVELS
from mercury_dem.viz.status import as_store


def read_report(run: str | Path | RunStore) -> dict[str, Any]:
    """The run's report.json; StoreError (saying what to do) when the run has not finished."""
    store = as_store(run)
    if not store.report_json.is_file():
        raise StoreError(f"{store.root} has no report.json yet: the run has not finished; "
                         "resume it with 'mercury-dem run' or watch it with 'mercury-dem dashboard'")
    return json.loads(store.report_json.read_text())


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        elif not isinstance(v, list):
            out[key] = v
    return out


def report_tables(report: dict[str, Any]) -> dict[str, pd.DataFrame]:
    """The report as tables.

    Returns
    -------
    dict with ``summary`` (key, value: tile and image counts), ``levels`` (one row per
    region, hemisphere and the globe), ``failed_tiles`` (tile, error), ``timings``
    (stage, seconds), ``validation`` (key, value; empty without truth) and ``dem``
    (key, value of the DEM block, flattened; empty without a DEM).
    """
    t, im = report["tiles"], report["images"]
    summary = pd.DataFrame([
        ("tiles total", t["total"]), ("tiles non-empty", t["non_empty"]), ("tiles succeeded", t["succeeded"]),
        ("tiles failed", len(t["failed"])), ("images input", im["input"]), ("images controlled", im["controlled"]),
        ("images uncontrolled", len(im["uncontrolled"])), ("images excluded", len(im.get("excluded", {}))),
    ], columns=["key", "value"])
    rows = []
    for level in ("region", "hemisphere"):
        rows += [{"level": level, **r} for r in report["levels"].get(level) or []]
    if report["levels"].get("global"):
        rows.append({"level": "global", **report["levels"]["global"]})
    cols = ["level", "id", "name", "ok", "images", "points", "measures", "rms_px", "sigma0", "rejected",
            "iterations", "converged", "seconds", "error"]
    levels = pd.DataFrame(rows)
    levels = levels.reindex(columns=[c for c in cols if c in levels.columns] if len(levels) else cols)
    failed = pd.DataFrame(t["failed"], columns=["tile", "error"])
    timings = pd.DataFrame(list(report.get("timings", {}).items()), columns=["stage", "seconds"])
    val = _flatten(report.get("validation") or {})
    dem = _flatten({k: v for k, v in (report.get("dem") or {}).items() if k != "files"})
    return {
        "summary": summary, "levels": levels, "failed_tiles": failed, "timings": timings,
        "validation": pd.DataFrame(list(val.items()), columns=["key", "value"]),
        "dem": pd.DataFrame(list(dem.items()), columns=["key", "value"]),
    }


def problem_images(run: str | Path | RunStore, rms_flag_px: float | None = None) -> pd.DataFrame:
    """Images with a problem and why: one row per (image, problem).

    Problems, from the store: ``excluded`` (unusable geometry, from the plan),
    ``unreadable`` (a tile could not read the image), ``flagged`` (RMS residual above
    the adjustment's flag threshold in some unit; the unit is given), ``weak`` (too
    few measures to determine the pointing) and ``uncontrolled`` (no measure in the
    global solution). Columns: image_id, problem, unit, detail.
    """
    store = as_store(run)
    rows: list[tuple[str, str, str, str]] = []
    images, _, _ = store.read_plan()
    for iid, why in zip(images["image_id"], images["excluded_reason"]):
        if why:
            rows.append((str(iid), "excluded", "plan", str(why)))
    for tid in store.completed_units("tile"):
        tile = read_summary(store, "tile", tid)
        for iid, why in (tile.image_errors if isinstance(tile, TileSummary) else {}).items():
            rows.append((str(iid), "unreadable", f"tile {tid}", str(why)))
    for level in ADJUSTED_LEVELS:
        for uid in store.completed_units(level):
            s = read_summary(store, level, uid)
            if not isinstance(s, UnitSummary):
                continue
            for f in s.flagged_images:
                if rms_flag_px is None or f["rms_px"] > rms_flag_px:
                    rows.append((f["image"], "flagged", s.name, f"RMS residual {f['rms_px']:.2f} px"))
            for iid in s.weak_images:
                rows.append((str(iid), "weak", s.name, "too few measures to determine its pointing"))
    if store.unit_complete("global", 0) and store.solution_path("global", 0).is_file():
        sid, _, _, table = read_solution(store.solution_path("global", 0))
        nm = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(sid.size, int)
        in_solution = set(sid[nm > 0].tolist())
        excluded = {r[0] for r in rows if r[1] == "excluded"}
        for iid in images["image_id"]:
            if iid not in in_solution and iid not in excluded:
                rows.append((str(iid), "uncontrolled", "global", "no control measure in the global network"))
    return pd.DataFrame(rows, columns=["image_id", "problem", "unit", "detail"])
