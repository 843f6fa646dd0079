"""report.json as tables, network statistics, residuals and pointing errors agree with what the run wrote."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.io.network_store import read_network
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.viz import (
    image_residuals,
    network_statistics,
    point_residuals,
    pointing_errors,
    problem_images,
    read_report,
    report_tables,
    residuals_by_level,
)


def test_report_tables(tiny_run: Path) -> None:
    report = read_report(tiny_run)
    t = report_tables(report)
    s = dict(zip(t["summary"]["key"], t["summary"]["value"]))
    assert s["tiles non-empty"] == report["tiles"]["non_empty"]
    assert s["images controlled"] == report["images"]["controlled"]
    assert len(t["levels"]) == len(report["levels"]["region"]) + len(report["levels"]["hemisphere"]) + 1
    assert list(t["failed_tiles"]["tile"]) == [f["tile"] for f in report["tiles"]["failed"]]
    v = dict(zip(t["validation"]["key"], t["validation"]["value"]))
    assert v["pointing_error_urad.adjusted_rms"] == report["validation"]["pointing_error_urad"]["adjusted_rms"]
    assert "grid.n_points" in set(t["dem"]["key"])


def test_read_report_of_unfinished_run(tmp_path: Path) -> None:
    (tmp_path / "run.json").write_text("{}")
    with pytest.raises(StoreError, match="has not finished"):
        read_report(tmp_path)


def test_network_statistics_match_the_adjustment(tiny_run: Path) -> None:
    stats = network_statistics(tiny_run).set_index(["level", "id"])
    store = RunStore(tiny_run)
    for level in ("region", "hemisphere", "global"):
        for uid in store.completed_units(level):
            s = store.read_summary(level, uid)
            if s["ok"]:
                assert stats.loc[(level, uid), "rms_px"] == pytest.approx(s["rms_px"], rel=1e-9)
                assert stats.loc[(level, uid), "measures"] >= s["measures"]
    assert stats.xs("tile", level="level")["rms_px"].isna().all()


def test_residuals_per_image_and_point(tiny_run: Path, tiny_mission) -> None:
    store = RunStore(tiny_run)
    net = read_network(store.network_path("global", 0))
    im = image_residuals(net, tiny_mission).set_index("image_id")
    sid, _, _, table = read_solution(store.solution_path("global", 0))
    table = table.set_index("image_id")
    used = table["n_measures"] > 0
    np.testing.assert_allclose(im.loc[table.index[used], "rms_px"], table.loc[used, "rms_px"], rtol=1e-9)
    np.testing.assert_array_equal(im.loc[table.index[used], "n_active"], table.loc[used, "n_measures"])
    pts = point_residuals(net)
    assert len(pts) == net.n_points
    assert pts["lon"].between(-180, 180).all() and pts["lat"].between(-90, 90).all()
    # pooled over points, the per-point RMS gives back the network's
    ok = pts["n_active"] > 0
    pooled = np.sqrt(np.sum(pts.loc[ok, "rms_px"] ** 2 * pts.loc[ok, "n_active"]) / pts.loc[ok, "n_active"].sum())
    assert pooled == pytest.approx(store.read_summary("global", 0)["rms_px"], rel=1e-9)
    res = residuals_by_level(tiny_run)
    assert set(res["level"]) == {"region", "hemisphere", "global"}
    g = res[(res["level"] == "global") & res["active"]]
    assert len(g) == int(net.active_measures().sum())


def test_pointing_errors_match_the_report_validation(tiny_run: Path, tiny_mission) -> None:
    pe = pointing_errors(tiny_run, tiny_mission)
    v = json.loads((tiny_run / "report.json").read_text())["validation"]["pointing_error_urad"]
    assert len(pe) == v["images"]
    assert np.sqrt(np.mean(pe["a_priori_urad"] ** 2)) == pytest.approx(v["a_priori_rms"], rel=1e-9)
    assert np.sqrt(np.mean(pe["adjusted_urad"] ** 2)) == pytest.approx(v["adjusted_rms"], rel=1e-9)
    assert (pe["ifov_urad"] > 0).all()
    px = json.loads((tiny_run / "report.json").read_text())["validation"]["image_space_error_px"]
    assert np.sqrt(np.nanmean(pe["a_priori_px"] ** 2)) == pytest.approx(px["a_priori_rms"], rel=1e-9)
    assert np.sqrt(np.nanmean(pe["adjusted_px"] ** 2)) == pytest.approx(px["adjusted_rms"], rel=1e-9)
    for name, row in px["by_instrument"].items():
        sel = pe[pe["instrument"] == name]
        assert len(sel) == row["images"]


def test_problem_images(tiny_run: Path) -> None:
    report = read_report(tiny_run)
    p = problem_images(tiny_run)
    assert set(p.loc[p["problem"] == "uncontrolled", "image_id"]) == set(report["images"]["uncontrolled"])
    assert set(p.loc[p["problem"] == "excluded", "image_id"]) == set(report["images"]["excluded"])
    assert (p["detail"].str.len() > 0).all()
