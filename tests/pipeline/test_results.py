"""Typed unit summaries (pipeline.results): the JSON they write holds every key and value the readers use, and reads back."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from mercury_dem.io.atomic import is_complete, verify_complete
from mercury_dem.io.network_store import read_network
from mercury_dem.io.run_store import RunStore, read_solution, unit_name
from mercury_dem.network import ControlNetwork
from mercury_dem.pipeline.results import (
    FailureSummary,
    TileCounts,
    TileSummary,
    UnitFiles,
    UnitSolution,
    UnitSummary,
    UnitTiming,
    summary_from_json,
)

TIMING = UnitTiming(seconds=1.5, finished_at=1_800_000_001.5, started_at=1_800_000_000.0)
COUNTS = TileCounts(images=3, images_involved=5, pairs=4, pairs_matched=3, routes={"features": 3},
                    pair_failures={"too few matches (N)": 1}, image_errors={"X": "image X: blank"}, points=120,
                    measures=300)
ADJUSTMENT = {  # an adjustment summary as adjust.unit builds it (order kept), with its optional keys
    "images": 4, "points": 120, "measures": 300, "rms_px": 0.12, "initial_rms_px": 2.5, "sigma0": 0.2,
    "rejected": 3, "underdetermined_points": 0, "weak_images": [], "iterations": 7, "converged": True,
    "reason": "converged", "sigma0_history": [3.0, 0.2], "linear_method": "schur", "solve_seconds": 0.3,
    "flagged_images": [{"image": "A", "rms_px": 2.5}], "islands": [], "images_without_measures": ["Z"],
    "altimetry": {"shots": 10}, "levelling": {"recentre": False},
}


#: A tile's summary.json as the readers (report.json, viz.status, the dashboard) read it: every key written out
#: by hand, not built by the code under test, so a key dropped, renamed or filled wrongly fails. Key order is not
#: part of the contract (JSON objects are unordered; the readers look keys up).
TILE_JSON: dict[str, Any] = {
    "level": "tile", "id": 7, "ok": True, "error": None,
    "images": 3, "images_involved": 5, "pairs": 4, "pairs_matched": 3, "routes": {"features": 3},
    "pair_failures": {"too few matches (N)": 1}, "image_errors": {"X": "image X: blank"}, "points": 120,
    "measures": 300, "pairs_redundant": 0,
    "seconds": 1.5, "finished_at": 1_800_000_001.5, "started_at": 1_800_000_000.0,
}


def test_tile_summary_writes_every_key_the_readers_use_and_round_trips() -> None:
    for ok in (True, False):
        typed = TileSummary(id=7, ok=ok, error=None if ok else "tile 7: why", counts=COUNTS, timing=TIMING)
        d = typed.to_json()
        assert d == {**TILE_JSON, "ok": ok, "error": None if ok else "tile 7: why"}
        assert TileSummary.from_json(d) == typed and summary_from_json(json.loads(json.dumps(d))) == typed
        assert (typed.images, typed.points, typed.measures, typed.seconds) == (3, 120, 300, 1.5)
    failed = TileSummary(id=7, error="tile 7: unreadable", timing=TIMING).to_json()
    assert failed == {"level": "tile", "id": 7, "ok": False, "error": "tile 7: unreadable", "seconds": 1.5,
                      "finished_at": 1_800_000_001.5, "started_at": 1_800_000_000.0}
    assert summary_from_json(failed).to_json() == failed
    assert TileSummary.from_json(failed).counts is None


def test_unit_summary_writes_every_key_the_readers_use_and_round_trips() -> None:
    singular = {"count": 2, "ids": [5, 9]}
    adjustment = {**ADJUSTMENT, "images_without_measures": ["Y", "Z"]}
    typed = UnitSummary("region", 3, ok=True, children=[1, 2], adjustment=adjustment,
                        single_measure_points=singular, timing=TIMING)
    d = typed.to_json()
    want = {
        "level": "region", "id": 3, "name": unit_name("region", 3), "ok": True, "error": None, "children": [1, 2],
        "images": 4, "points": 120, "measures": 300, "rms_px": 0.12, "initial_rms_px": 2.5, "sigma0": 0.2,
        "rejected": 3, "underdetermined_points": 0, "weak_images": [], "iterations": 7, "converged": True,
        "reason": "converged", "sigma0_history": [3.0, 0.2], "linear_method": "schur", "solve_seconds": 0.3,
        "flagged_images": [{"image": "A", "rms_px": 2.5}], "islands": [], "images_without_measures": ["Y", "Z"],
        "altimetry": {"shots": 10}, "levelling": {"recentre": False},
        "single_measure_points": {"count": 2, "ids": [5, 9]},
        "seconds": 1.5, "finished_at": 1_800_000_001.5, "started_at": 1_800_000_000.0,
    }
    assert d == want
    assert UnitSummary.from_json(d) == typed and summary_from_json(json.loads(json.dumps(d))) == typed
    assert (typed.images, typed.rms_px, typed.sigma0, typed.iterations, typed.seconds) == (4, 0.12, 0.2, 7, 1.5)
    assert typed.levelling == {"recentre": False} and typed.flagged_images == [{"image": "A", "rms_px": 2.5}]
    failed = UnitSummary("global", 0, error="global: no input", timing=TIMING).to_json()
    assert failed == {"level": "global", "id": 0, "name": "global", "ok": False, "error": "global: no input",
                      "seconds": 1.5, "finished_at": 1_800_000_001.5, "started_at": 1_800_000_000.0}
    assert summary_from_json(failed).to_json() == failed


def test_failure_summary() -> None:
    try:
        raise RuntimeError("boom")
    except RuntimeError as exc:
        f = FailureSummary.of("hemisphere", 1, exc)
    d = f.to_json()
    assert set(d) == {"level", "id", "name", "ok", "error", "failure", "traceback"} and d["failure"] == "unexpected"
    assert d["name"] == "hemisphere south" and d["ok"] is False
    assert d["error"] == "hemisphere south: unexpected RuntimeError: boom" and "boom" in d["traceback"]
    assert summary_from_json(d) == f


def test_unit_files_are_written_by_the_run_store(tmp_path: Path) -> None:
    store = RunStore(tmp_path / "run")
    net = ControlNetwork.from_arrays(["A", "B"], [1], [0, 0], [0, 1], [1.0, 2.0], [3.0, 4.0],
                                     apriori_xyz=np.ones((1, 3)))
    rng = np.random.default_rng(3)
    sol = UnitSolution(np.array(["A", "B"]), rng.normal(size=(2, 3, 3)), rng.normal(size=(2, 3)),
                       {"n_measures": np.array([1, 1])})
    summary = UnitSummary("region", 2, ok=True, children=[4], adjustment={"images": 2}, timing=TIMING).to_json()
    store.write_unit("region", 2, summary, UnitFiles(network=net, solution=sol, bundleout="report\n").writers())
    d = store.unit_dir("region", 2)
    assert is_complete(d) and verify_complete(d) == []
    assert sorted(p.name for p in d.iterdir() if not p.name.startswith(".")) == [
        "bundleout.txt", "network.zarr", "solution.parquet", "summary.json"]
    assert store.read_summary("region", 2) == summary
    ids, rot, pos, table = read_solution(store.solution_path("region", 2))
    assert ids.tolist() == ["A", "B"] and np.array_equal(rot, sol.rotations) and np.array_equal(pos, sol.positions)
    assert table["n_measures"].tolist() == [1, 1]
    assert read_network(store.network_path("region", 2)).n_measures == 2
    tile = TileSummary(id=1, ok=True, counts=COUNTS, timing=TIMING).to_json()
    store.write_unit("tile", 1, tile, UnitFiles(network=net, pairs=pd.DataFrame({"route": ["features"]})).writers())
    assert sorted(p.name for p in store.unit_dir("tile", 1).iterdir() if not p.name.startswith(".")) == [
        "network.zarr", "pairs.parquet", "summary.json"]


@pytest.mark.integration
def test_every_summary_of_a_run_round_trips(sync_run: tuple[Path, dict[str, Any]]) -> None:
    run, _ = sync_run
    paths = sorted(run.glob("*/*/summary.json"))
    assert any(p.parts[-3] == "tile" for p in paths) and any(p.parts[-3] == "global" for p in paths)
    for p in paths:
        d = json.loads(p.read_text())
        typed = summary_from_json(d)
        assert isinstance(typed, TileSummary if d["level"] == "tile" else UnitSummary)
        assert typed.to_json() == d, p


def _dict_level_row(s: dict[str, Any]) -> dict[str, Any]:
    """report.json's level row as report.py built it from the summary dict (before session 13)."""
    from mercury_dem.pipeline.report import LEVEL_KEYS

    return {k: s.get(k) for k in LEVEL_KEYS if k in s or k in ("id", "ok", "error")}


def test_report_rows_from_typed_summaries_are_the_dict_rows() -> None:
    from mercury_dem.pipeline.report import _level_row

    singular = {"count": 2, "ids": [5, 9]}
    done = UnitSummary("region", 3, ok=True, children=[1, 2], adjustment=dict(ADJUSTMENT),
                       single_measure_points=singular, timing=TIMING)
    failed = UnitSummary("global", 0, error="global: no input", timing=TIMING)
    try:
        raise RuntimeError("boom")
    except RuntimeError as exc:
        crashed = FailureSummary.of("hemisphere", 1, exc)
    for typed in (done, failed, crashed, UnitSummary("region", 4, error="region 4: x")):
        d = typed.to_json()
        row = _level_row(typed)
        assert row == _dict_level_row(d), typed
    assert _level_row(done)["seconds"] == TIMING.seconds and _level_row(done)["children"] == [1, 2]
    assert "seconds" not in _level_row(crashed) and _level_row(crashed)["ok"] is False


def test_summaries_of_older_runs_read_as_the_dict_readers_had_them() -> None:
    # a tile summary without image_errors nor the wall-clock keys, a region without started_at
    old_tile = {"level": "tile", "id": 2, "ok": True, "error": None, "images": 3, "images_involved": 3, "pairs": 2,
                "pairs_matched": 2, "routes": {}, "pair_failures": {}, "points": 10, "measures": 25, "seconds": 4.0}
    t = summary_from_json(old_tile)
    assert isinstance(t, TileSummary) and t.counts is not None
    assert (t.images, t.points, t.measures, t.image_errors, t.seconds) == (3, 10, 25, {}, 4.0)
    assert t.counts.pairs_redundant == 0  # a count older runs did not record (session 14)
    assert t.timing is not None and t.timing.started_at is None
    old_region = {"level": "region", "id": 1, "name": unit_name("region", 1), "ok": True, "error": None, "children": [0],
                  "images": 3, "points": 10, "measures": 25, "rms_px": 0.2, "sigma0": 0.9, "iterations": 4,
                  "seconds": 2.0}
    r = summary_from_json(old_region)
    assert isinstance(r, UnitSummary)
    assert (r.images, r.rms_px, r.sigma0, r.iterations, r.seconds) == (3, 0.2, 0.9, 4, 2.0)
    assert r.sigma0_history == [] and r.flagged_images == [] and r.weak_images == [] and r.levelling is None
    assert r.to_json() == old_region  # nothing invented on the way back


def test_status_rows_read_typed_summaries(tmp_path: Path) -> None:
    from mercury_dem.viz.status import _summary, _unit_row

    store = RunStore(tmp_path / "run")
    tile = TileSummary(id=1, ok=True, counts=COUNTS, timing=TIMING).to_json()
    store.write_unit("tile", 1, tile, {})
    region = UnitSummary("region", 2, ok=True, children=[1], adjustment=dict(ADJUSTMENT), timing=TIMING).to_json()
    store.write_unit("region", 2, region, {})
    for level, uid, d in (("tile", 1, tile), ("region", 2, region)):
        row = _unit_row(level, uid, unit_name(level, uid), _summary(store, level, uid), "done")
        assert row == {"level": level, "id": uid, "name": unit_name(level, uid), "state": "done", "error": "",
                       **{k: d.get(k) for k in ("images", "points", "measures", "rms_px", "sigma0", "iterations",
                                                "seconds")}}
    assert _summary(store, "region", 9) is None
