"""Unit states read from the store: a finished run agrees with its report; a partial store infers states."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.run_store import RunStore
from mercury_dem.viz import expected_units, level_progress, run_info, sigma0_history, tile_status, unit_status


def _report(run: Path) -> dict:
    return json.loads((run / "report.json").read_text())


def test_finished_run_matches_report(tiny_run: Path) -> None:
    report = _report(tiny_run)
    units = unit_status(tiny_run)
    tiles = units[units["level"] == "tile"]
    assert len(tiles) == report["tiles"]["non_empty"]
    assert (tiles["state"] == "done").sum() == report["tiles"]["succeeded"]
    failed = tiles[tiles["state"] == "failed"]
    assert dict(zip(failed["id"], failed["error"])) == {f["tile"]: f["error"] for f in report["tiles"]["failed"]}
    for row in report["levels"]["region"] + report["levels"]["hemisphere"] + [report["levels"]["global"]]:
        u = units[(units["name"] == row["name"])].iloc[0]
        assert u["state"] == ("done" if row["ok"] else "failed")
        if row["ok"]:
            assert u["sigma0"] == pytest.approx(row["sigma0"], rel=1e-12)
    prog = level_progress(units).set_index("level")
    assert prog.loc["tile", "total"] == report["tiles"]["non_empty"]
    assert prog.loc["global", "done"] == 1 and prog[["pending", "running"]].to_numpy().sum() == 0
    assert run_info(tiny_run)["finished"] is True


def test_tile_bounds_hold_their_images(tiny_run: Path, tiny_mission) -> None:
    tiles = tile_status(tiny_run).set_index("tile")
    cat = tiny_mission.catalog
    grid = TileGrid(10.0)
    t = grid.tile_of(cat["center_lat"].to_numpy(), cat["center_lon"].to_numpy())
    assert set(t.tolist()) == set(tiles.index.tolist())
    lat, lon = cat["center_lat"].to_numpy(), np.mod(cat["center_lon"].to_numpy(), 360.0)
    b = tiles.loc[t]
    assert np.all((b["lat_min"].to_numpy() <= lat) & (lat < b["lat_max"].to_numpy()))
    assert np.all((b["lon_min"].to_numpy() <= lon) & (lon < b["lon_max"].to_numpy()))


def test_sigma0_history_ends_at_the_final_sigma0(tiny_run: Path) -> None:
    hist = sigma0_history(tiny_run)
    units = unit_status(tiny_run).set_index(["level", "id"])
    for (level, uid), g in hist.groupby(["level", "id"]):
        assert g["sigma0"].iloc[-1] == pytest.approx(units.loc[(level, uid), "sigma0"], rel=1e-12)
        assert len(g) == units.loc[(level, uid), "iterations"]


def test_partial_store_states(tiny_run: Path, tmp_path: Path) -> None:
    """A run caught after the tiles of one region: that region running, the other regions pending."""
    part = tmp_path / "run"
    part.mkdir()
    shutil.copy(tiny_run / "run.json", part / "run.json")
    shutil.copytree(tiny_run / "plan", part / "plan")
    units = expected_units(RunStore(part))
    grid = TileGrid(10.0)
    region = next(r for r in units["region"] if sum(int(grid.region_of_tile(t)) == r for t in units["tile"]) >= 2)
    mine = [t for t in units["tile"] if int(grid.region_of_tile(t)) == region]
    for t in mine:
        shutil.copytree(tiny_run / "tile" / str(t), part / "tile" / str(t))
    (part / "tile" / str(mine[-1]) / ".complete").unlink()  # caught mid-write: not a unit yet
    st = unit_status(part).set_index(["level", "id"])["state"]
    assert st[("region", region)] == "pending"
    (part / "tile" / str(mine[-1]) / ".complete").touch()
    st = unit_status(part).set_index(["level", "id"])["state"]
    assert st[("region", region)] == "running"
    assert all(st[("tile", t)] in ("done", "failed") for t in mine)
    others = [t for t in units["tile"] if t not in mine]
    assert all(st[("tile", t)] == "pending" for t in others)
    assert all(st[("region", r)] == "pending" for r in units["region"] if r != region)
    assert st[("global", 0)] == "pending"
    assert run_info(part)["finished"] is False
    assert len(sigma0_history(part)) == 0


def test_store_before_the_plan_and_not_a_run(tmp_path: Path) -> None:
    (tmp_path / "run.json").write_text(json.dumps({"mission": "m", "config": {}}))
    assert len(unit_status(tmp_path)) == 0
    assert len(tile_status(tmp_path)) == 0
    with pytest.raises(StoreError, match="not a mercury-dem run"):
        unit_status(tmp_path / "nowhere")
