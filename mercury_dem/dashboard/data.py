"""What the dashboard shows, as plain column dicts (computed from the store; no Bokeh here).

The dashboard polls :func:`dashboard_data` and pushes only the parts that changed.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.io.run_store import RunStore
from mercury_dem.plan.tree import LEVELS
from mercury_dem.viz.figures import LEVEL_COLOURS, signed_lon
from mercury_dem.viz.status import STATE_COLOURS, STATES, level_progress, run_info, sigma0_history, unit_status


def _num(x: Any) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return float("nan")
    return v


def _text(x: Any, fmt: str = "{:.0f}") -> str:
    v = _num(x)
    return "-" if not np.isfinite(v) else fmt.format(v)


def tile_columns(units: Any, tile_size_deg: float) -> dict[str, list[Any]]:
    """Quad columns of the tile map: left/right (signed east lon), bottom/top (lat), tile, state, colour, hover text."""
    from mercury_dem.geometry.tiling import TileGrid

    t = units[units["level"] == "tile"]
    ids = t["id"].to_numpy(dtype=np.int64)
    if ids.size:
        la0, la1, lo0, lo1 = (np.asarray(b, dtype=np.float64) for b in TileGrid(tile_size_deg).bounds(ids))
    else:
        la0 = la1 = lo0 = lo1 = np.zeros(0)
    left = signed_lon(lo0)
    states = t["state"].tolist()
    return {
        "left": left.tolist(), "right": (left + (lo1 - lo0)).tolist(), "bottom": la0.tolist(), "top": la1.tolist(),
        "tile": [int(i) for i in ids], "state": states, "colour": [STATE_COLOURS[s] for s in states],
        "error": [e or "" for e in t["error"]],
        "images": [_text(v) for v in t["images"]], "points": [_text(v) for v in t["points"]],
        "seconds": [_text(v, "{:.1f}") for v in t["seconds"]],
    }


def progress_columns(units: Any) -> dict[str, list[Any]]:
    """Stacked-bar columns: level and the count per state."""
    p = level_progress(units)
    return {"level": p["level"].tolist(), **{s: [int(v) for v in p[s]] for s in STATES}}


def sigma0_columns(history: Any) -> dict[str, list[Any]]:
    """Multi-line columns: one line (xs iterations, ys σ0) per adjustment unit."""
    out: dict[str, list[Any]] = {"xs": [], "ys": [], "name": [], "level": [], "colour": []}
    for (level, _), g in history.groupby(["level", "id"], sort=False):
        y = g["sigma0"].to_numpy(dtype=float)
        keep = np.isfinite(y) & (y > 0)
        out["xs"].append(g["iteration"].to_numpy()[keep].tolist())
        out["ys"].append(y[keep].tolist())
        out["name"].append(str(g["name"].iloc[0]))
        out["level"].append(str(level))
        out["colour"].append(LEVEL_COLOURS.get(str(level), "#000000"))
    return out


def _status_word(info: dict[str, Any], progress: dict[str, list[Any]]) -> str:
    if info["finished"]:
        return "finished"
    total = sum(progress["pending"]) + sum(progress["running"]) + sum(progress["done"]) + sum(progress["failed"])
    return "waiting for the plan" if total == 0 else "in progress"


def info_html(info: dict[str, Any], units: Any, progress: dict[str, list[Any]], dask_link: str | None) -> str:
    """Header, counts and timings table, and the Dask dashboard link (HTML-escaped values)."""
    e = html.escape
    link = dask_link or info.get("dashboard_link")
    status = _status_word(info, progress)
    rows = []
    for k, level in enumerate(progress["level"]):
        u = units[(units["level"] == level) & (units["state"] == "done")]
        secs = np.nansum(u["seconds"].to_numpy(dtype=float)) if len(u) else 0.0
        rows.append(
            f"<tr><td>{e(level)}</td>" + "".join(f"<td class='n-{s}'>{progress[s][k]}</td>" for s in STATES)
            + f"<td>{secs:.1f}</td></tr>")
    timings = ", ".join(f"{e(str(k))} {float(v):.1f} s" for k, v in (info.get("timings") or {}).items())
    dask = (f"<a href='{e(link)}' target='_blank' id='dask-link'>Dask dashboard</a>" if link
            else "Dask dashboard: not recorded for this run")
    return (
        f"<div id='run-info' data-status='{e(status)}'>"
        f"<b>run</b> {e(str(info['run']))} &nbsp; <b>mission</b> {e(str(info.get('mission')))}<br>"
        f"<b>status</b> <span id='run-status'>{e(status)}</span> &nbsp; {dask}"
        "<table style='border-collapse:collapse;margin-top:6px' border='1' cellpadding='3'>"
        "<tr><th>level</th>" + "".join(f"<th>{s}</th>" for s in STATES) + "<th>unit seconds</th></tr>"
        + "".join(rows) + "</table>"
        + (f"<div>timings: {timings}</div>" if timings else "") + "</div>"
    )


def tiles_html(tiles: dict[str, list[Any]]) -> str:
    """The tile states as text (one span per tile, state in a data attribute): readable and checkable."""
    spans = "".join(
        f"<span class='tile tile-{s}' data-tile='{t}' data-state='{s}' title='{html.escape(err)}' "
        f"style='display:inline-block;margin:1px;padding:1px 4px;background:{c}'>{t}</span>"
        for t, s, c, err in zip(tiles["tile"], tiles["state"], tiles["colour"], tiles["error"]))
    return f"<div id='tile-states'><b>tiles</b> {spans or '(no plan yet)'}</div>"


def dashboard_data(run: str | Path | RunStore, dask_link: str | None = None) -> dict[str, Any]:
    """Everything the page shows, from the store: tiles, progress, sigma0 (column dicts), info and tiles HTML."""
    store = run if isinstance(run, RunStore) else RunStore(run)
    units = unit_status(store)
    info = run_info(store)
    tile_size = 10.0
    try:
        import json

        tile_size = float(json.loads(store.run_json.read_text())["config"]["tiling"]["tile_size_deg"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    tiles = tile_columns(units, tile_size)
    progress = progress_columns(units)
    return {
        "tiles": tiles,
        "progress": progress,
        "sigma0": sigma0_columns(sigma0_history(store)),
        "info": info_html(info, units, progress, dask_link),
        "tiles_html": tiles_html(tiles),
        "status": _status_word(info, progress),
        "levels": list(LEVELS),
    }
