"""The tiny mission end to end: the report contract, accuracy against truth, products, resume, bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from mercury_dem.cli import main
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.io.network_store import read_network
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.pipeline.graph import run_pipeline

from .conftest import read_report, tiny_config


def global_solution(run: Path) -> tuple[np.ndarray, np.ndarray]:
    ids, rot, _, _ = read_solution(RunStore(run).solution_path("global", 0))
    order = np.argsort(ids)
    return ids[order], rot[order]


def test_report_contract(sync_run: tuple[Path, dict[str, Any]]) -> None:
    run, report = sync_run
    assert read_report(run) == json.loads(json.dumps(report))
    t = report["tiles"]
    assert t["total"] == 648 and 0 < t["non_empty"] <= t["total"]
    assert t["succeeded"] + len(t["failed"]) == t["non_empty"]
    for f in t["failed"]:
        assert f["error"].startswith(f"tile {f['tile']}:")  # every failure names its tile and why
    levels = report["levels"]
    assert levels["region"] and levels["hemisphere"] and levels["global"]["ok"]
    for row in levels["region"] + levels["hemisphere"] + [levels["global"]]:
        assert {"id", "ok", "error"} <= set(row)
        if row["ok"]:
            for key in ("images", "points", "measures", "rms_px", "sigma0", "rejected", "iterations", "seconds"):
                assert key in row, key
    tile_errors = [f["error"] for f in t["failed"]]
    for row in levels["region"]:
        if not row["ok"]:  # a region with nothing to merge names its failed tiles and their reasons
            assert "no successful tile network to merge" in row["error"]
            assert any(e in row["error"] for e in tile_errors), row["error"]
    im = report["images"]
    assert im["input"] == im["controlled"] + len(im["uncontrolled"])
    assert {"plan", "tile", "region", "hemisphere", "global", "total"} <= set(report["timings"])
    assert report["config"]["tiling"]["tile_size_deg"] == 10.0
    assert "numpy" in report["versions"]
    v = report["validation"]
    assert {"a_priori_rms", "adjusted_rms"} <= set(v["pointing_error_urad"])
    assert {"median", "p95"} <= set(v["point_error_m"]) and v["ifov_urad"] > 0


def test_global_network_is_the_union_of_the_regions(sync_run: tuple[Path, dict[str, Any]]) -> None:
    run, report = sync_run
    glob = read_network(RunStore(run).network_path("global", 0))
    regions = [r for r in report["levels"]["region"] if r["ok"]]
    assert glob.n_images == report["levels"]["global"]["images"]
    assert glob.n_images <= sum(r["images"] for r in regions)  # border images are shared, not duplicated
    assert np.isfinite(glob.adjusted_xyz[~glob.point_rejected]).all()


def test_adjustment_improves_the_a_priori_pointing(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """Pointing perturbed by 450 urad per axis comes out closer to the truth, and points near the surface."""
    _, report = sync_run
    v = report["validation"]
    p = v["pointing_error_urad"]
    # 450 urad per axis is ~780 urad per image; the adjustment must at least cut it by a quarter
    assert p["adjusted_rms"] < 0.75 * p["a_priori_rms"], v
    # control points within a few pixels (tiny: ~2 km/pixel) of their true position
    assert v["point_error_m"]["median"] < 2.0 * 2000.0, v


def test_adjustment_recovers_pointing_within_half_an_ifov(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """Pointing perturbed by 450 urad per axis is recovered to <= 0.5 IFOV (issue 6, section 5).

    The error is measured where it matters, in each image's own pixels: the true
    ground under a 9x9 grid of pixels projected with the adjusted pose (a NAC pixel
    of tiny is 102 urad, a WAC pixel 716 urad, so one angle for both would say little).
    A-priori it is ~2.8 px (NAC ~4.9, WAC ~1.0); the noise-free optimum of this
    network is ~0.31 px (no ground control: the block is held by the pointing priors).
    The angle across the boresight must come down too; the twist about the boresight
    moves the edge of a 256-pixel image by only ~0.05 px per 400 urad and is reported,
    not required.
    """
    _, report = sync_run
    v = report["validation"]
    img = v["image_space_error_px"]
    assert v["adjusted_rms_in_ifov"] == img["adjusted_rms"]
    assert img["adjusted_rms"] <= 0.5, v
    assert img["adjusted_rms"] < 0.25 * img["a_priori_rms"], v
    for inst, row in img["by_instrument"].items():
        assert row["adjusted_rms"] <= 0.6, (inst, v)
    p = v["pointing_error_urad"]
    assert p["adjusted_boresight_rms"] < 0.4 * p["a_priori_boresight_rms"], v
    assert p["adjusted_boresight_rms"] <= 0.5 * v["ifov_urad"], v


def test_dem_store_and_products(sync_run: tuple[Path, dict[str, Any]], tiny_mission) -> None:
    """dem.zarr holds a DEM of the tiny mission's surface (filled where there are points, following the truth,
    heights = radius - datum), and its GeoTIFF product holds the same values."""
    import rasterio

    run, report = sync_run
    ds = xr.open_zarr(run / "dem.zarr", decode_coords="all", consolidated=False)
    assert {"elevation", "radius", "point_count", "distance_to_nearest_point", "spread"} <= set(ds.data_vars)
    e, count = ds["elevation"].values.astype(np.float64), ds["point_count"].values
    ok = np.isfinite(e)
    # every cell with control points has a height, and the map is not just those cells (measured 0.47 filled)
    assert (count > 0).any() and ok[count > 0].all() and ok.mean() > 0.4, (ok.mean(), (count > 0).mean())
    assert ds.attrs["no_value_pixels"] == int((~ok).sum())
    np.testing.assert_allclose(ds["radius"].values[ok] - DATUM_RADIUS_M, e[ok], atol=0.25)  # float32 radii
    # the heights follow the truth: closer to it than a flat DEM at its mean height (507 m RMS here; the DEM
    # 458 m, correlation 0.47), and the report's comparison (cos(lat)-weighted) says the same
    la, lo = np.meshgrid(ds["lat"].values, ds["lon"].values, indexing="ij")
    truth = tiny_mission.need_truth().surface().height(la, np.mod(lo, 360.0))[ok]
    rmse = float(np.sqrt(np.mean((e[ok] - truth) ** 2)))
    assert rmse < 0.95 * float(np.std(truth)) and np.corrcoef(e[ok], truth)[0, 1] > 0.3, rmse
    assert rmse == pytest.approx(report["validation"]["dem"]["adjusted"]["rmse_m"], rel=0.1)
    with rasterio.open(run / "products" / "dem.tif") as f:
        tif = f.read(1, masked=True).filled(np.nan)
        assert f.tags()["BODY"] == "MERCURY" and f.units == ("m",)
    np.testing.assert_array_equal(tif[ok], e[ok].astype(np.float32))
    assert np.isnan(tif[~ok]).all()
    d = report["validation"]["dem"]
    assert d["adjusted"]["n_compared"] > 0 and d["a_priori"]["n_compared"] > 0
    # The tiny mission's map stays inside +-65 deg: the caps are named as not written, and are not there.
    assert np.abs(ds["lat"].values).max() < 65.0
    caps = {"pds/north_polar.tif", "pds/south_polar.tif"}
    assert set(report["dem"]["products_skipped"]) == caps
    assert not any((run / "products" / rel).exists() for rel in caps)
    assert (run / "products/pds/equirectangular.tif").exists()


def test_products_command_on_a_run_compares_with_the_truth(sync_run: tuple[Path, dict[str, Any]], tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    # 'mercury-dem products RUN' finds the run's mission: the same accuracy as the run's report,
    # and profiles that carry the truth beside the DEM.
    run, report = sync_run
    out = tmp_path / "products"
    assert main(["products", str(run), "--out", str(out), "--profile", "0,-5,10,5"]) == 0
    assert "DEM minus truth (m): RMSE" in capsys.readouterr().out
    acc = json.loads((out / "accuracy.json").read_text())
    assert acc["rmse_m"] == pytest.approx(report["validation"]["dem"]["adjusted"]["rmse_m"], rel=1e-9)
    prof = np.genfromtxt(out / "profile_1.csv", delimiter=",", names=True)
    ok = np.isfinite(prof["elevation_m"])
    assert ok.any() and np.isfinite(prof["truth_m"]).all()
    rmse = float(np.sqrt(np.mean((prof["elevation_m"][ok] - prof["truth_m"][ok]) ** 2)))
    assert rmse < 3 * acc["rmse_m"] + 200.0  # the profile is the DEM against the same truth


def test_resume_skips_finished_units_and_gives_the_same_result(
    sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path
) -> None:
    run, _ = sync_run
    copy = tmp_path / "resumed"
    shutil.copytree(run, copy)
    store = RunStore(copy)
    # as if the run was killed during the regional adjustments
    for level in ("hemisphere", "global"):
        store.remove_level(level)
    shutil.rmtree(store.unit_dir("region", store.completed_units("region")[0]))
    (copy / "report.json").unlink()
    shutil.rmtree(copy / "dem.zarr")
    tile_stamps = {p: p.stat().st_mtime_ns for p in (copy / "tile").glob("*/summary.json")}
    report = run_pipeline(tiny_mission_path, copy, tiny_config(), scheduler="sync", stream=None)
    assert report["levels"]["global"]["ok"]
    assert {p: p.stat().st_mtime_ns for p in tile_stamps} == tile_stamps  # no tile recomputed
    ids0, rot0 = global_solution(run)
    ids1, rot1 = global_solution(copy)
    assert (ids0 == ids1).all() and np.allclose(rot0, rot1, atol=1e-12)


def test_corrupt_image_is_named_and_the_run_goes_on(tiny_mission_path: Path, tmp_path: Path) -> None:
    mission = tmp_path / "mission"
    shutil.copytree(tiny_mission_path, mission)
    from mercury_dem.mission import open_mission

    victim = open_mission(mission).image_ids[0]
    chunks = [p for p in (mission / "images.zarr" / victim).rglob("*") if p.is_file() and p.name != "zarr.json"]
    assert chunks, "the image has chunk files"
    for p in chunks:
        p.write_bytes(b"\x00garbage")
    report = run_pipeline(mission, tmp_path / "run", tiny_config(), scheduler="sync", stream=None, dem=False)
    errors = report["tiles"]["image_errors"]
    assert victim in errors and victim in errors[victim]
    assert report["levels"]["global"]["ok"]
    assert victim in report["images"]["uncontrolled"]


def test_run_refuses_another_missions_run(sync_run: tuple[Path, dict[str, Any]], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    run, _ = sync_run
    other = tmp_path / "other_mission"
    other.mkdir()
    assert main(["run", str(other), "--out", str(run), "--scheduler", "sync"]) == 2
    assert "holds a run of mission" in capsys.readouterr().err


def test_report_command(sync_run: tuple[Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]) -> None:
    run, report = sync_run
    assert main(["report", str(run)]) == 0
    out = capsys.readouterr().out
    assert "global" in out and "pointing error vs truth" in out
    for f in report["tiles"]["failed"]:  # each failure printed once, named once
        name = f"tile {f['tile']}"
        assert f"  {name}: {f['error'][len(name) + 2:]}" in out
        assert f"{name}: {name}:" not in out
    dem = report["validation"]["dem"]
    rows = [line.split() for line in out.splitlines() if line.strip().startswith(("adjusted points", "a-priori points"))]
    assert [r[0] for r in rows] == ["adjusted", "a-priori"]
    for r, key in zip(rows, ("adjusted", "a_priori")):  # RMSE and bias as in report.json, in metres
        assert float(r[2]) == pytest.approx(dem[key]["rmse_m"], abs=0.5)
        assert float(r[3]) == pytest.approx(dem[key]["bias_m"], abs=0.5)
    for rel, why in report["dem"]["products_skipped"].items():
        assert f"not written: products/{rel} ({why})" in out
    assert main(["report", str(run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tiles"] == report["tiles"]


def test_report_and_verify_start_without_heavy_libraries(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """``report`` loads no table or array library (not even numpy); ``verify`` only numpy (region names)."""
    from tests.test_cli_startup import NOT_FOR_SMALL_COMMANDS, loaded_by_command

    run, _ = sync_run
    assert loaded_by_command(["report", str(run)], (*NOT_FOR_SMALL_COMMANDS, "numpy", "pyarrow")) == []
    assert loaded_by_command(["verify", str(run)], (*NOT_FOR_SMALL_COMMANDS, "pyarrow")) == []


# slow: a second whole run (15 deg tiles, ~45 s here) for an invariance of the tiling, not a stage; .ci/run runs it
@pytest.mark.slow
def test_global_solution_does_not_depend_on_the_tile_size(sync_run: tuple[Path, dict[str, Any]],
                                                         tiny_mission_path: Path, tmp_path: Path) -> None:
    """10 deg and 15 deg tiles (issue 6, section 1) give the same globally adjusted pointing.

    The tiles only group the reference images; every image is still matched with
    every image it overlaps, so the networks differ only in how pairs were grouped
    and merged. The two solutions must agree far better than either agrees with the
    truth (~0.37 px): measured 0.09 px RMS apart in each image's pixels (2026-11-22).
    """
    from mercury_dem.mission import open_mission
    from mercury_dem.validate.run import image_space_error_px

    run10, rep10 = sync_run
    rep15 = run_pipeline(tiny_mission_path, tmp_path / "tiles15", tiny_config(tiling={"tile_size_deg": 15.0}),
                         scheduler="sync", stream=None, dem=False)
    assert rep15["config"]["tiling"]["tile_size_deg"] == 15.0
    assert rep15["tiles"]["non_empty"] < rep10["tiles"]["non_empty"]
    assert rep15["validation"]["adjusted_rms_in_ifov"] <= 0.5
    ids10, rot10, pos10, _ = read_solution(RunStore(run10).solution_path("global", 0))
    ids15, rot15, pos15, _ = read_solution(RunStore(tmp_path / "tiles15").solution_path("global", 0))
    assert set(map(str, ids10)) == set(map(str, ids15))
    mission = open_mission(tiny_mission_path)
    height = mission.need_truth().surface().height
    at10 = {str(i): k for k, i in enumerate(ids10)}
    apart = np.array([
        image_space_error_px(mission.camera(str(i)), pos15[k], rot15[k], pos10[at10[str(i)]], rot10[at10[str(i)]], height, datum_radius_m=DATUM_RADIUS_M)
        for k, i in enumerate(ids15)
    ])
    assert np.sqrt(np.mean(apart**2)) <= 0.2, apart
    assert np.sqrt(np.mean(apart**2)) < 0.5 * rep10["validation"]["adjusted_rms_in_ifov"]


def test_adjust_command_redoes_a_level_and_writes_jigsaw_like_reports(
    sync_run: tuple[Path, dict[str, Any]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``mercury-dem adjust RUN --level global`` re-adjusts the stored global network: same solution."""
    run, report = sync_run
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    before = read_solution(RunStore(copy).solution_path("global", 0))
    assert (copy / "global" / "0" / "bundleout.txt").read_text().count("sigma0") >= 1
    code = main(["adjust", str(copy), "--level", "global", "--report-dir", str(tmp_path / "tables"), "--json"])
    assert code == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["ok"] and rows[0]["measures"] == report["levels"]["global"]["measures"]
    after = read_solution(RunStore(copy).solution_path("global", 0))
    assert (before[0] == after[0]).all() and np.allclose(before[1], after[1], atol=1e-9)
    tables = tmp_path / "tables" / "global_0"
    assert {"bundleout.txt", "images.csv", "points.csv", "residuals.csv", "summary.json"} <= {p.name for p in tables.iterdir()}
    assert "ITERATIONS" in (tables / "bundleout.txt").read_text()


def test_simulated_mla_ties_the_heights(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """Issue 16 on tiny (simulated MLA, 1 m shots, per-profile orbit errors): the global adjustment's tie points
    are constrained by the altimetry and the DEM is registered to it and merged. Without altimetry this DEM is
    about 500 m low (docs/design/altimetry.md); with it the merged DEM's bias is within 25 m, the RMSE lower,
    and seed 004's check holds: in >= 95 % of the tiles with >= 20 profiles their residual RMS drops."""
    run, report = sync_run
    glob = report["levels"]["global"]
    assert glob["altimetry"]["constrained_points"] > 0.5 * glob["altimetry"]["points"]
    v = report["validation"]["dem"]
    # The merged DEM within 25 m (seed 42 here: 6 m; seed 7, not tuned on: -18 m); the adjusted DEM alone has
    # far less than the ~500 m bias it has without altimetry (seed 42: -17 m; seed 7: -86 m).
    assert abs(v["merged"]["bias_m"]) <= 25.0, v["merged"]["bias_m"]
    assert abs(v["adjusted"]["bias_m"]) <= 100.0, v["adjusted"]["bias_m"]
    for key in ("adjusted", "merged"):
        assert v[key]["rmse_m"] < v["a_priori"]["rmse_m"]
    assert v["merged"]["rmse_m"] < v["adjusted"]["rmse_m"]
    reg = report["dem"]["registration"]
    assert len(reg["tiles_20_profiles"]) >= 5 and reg["improved_share"] >= 0.95
    # The altimetry holds most of tiny's tie points, so the block's heights are the altimetry's: its radius
    # priors are not re-centred on the block and the registered DEM is not levelled on the shots' mean
    # (adjust.datum.levelling_decision; both cost seed 7 13 m of bias when they were on here).
    lev = glob["levelling"]
    assert lev["altimetry_share"] > 0.5 and not lev["recentre"] and not lev["level_to_mean"], lev
    assert lev["extent_deg"] > 10.0  # wide enough to be re-centred, were it not for the altimetry
    assert glob.get("point_prior") is None and reg["mean_level"] is None
    for name in ("registered.zarr", "merged.zarr", "registration/tiles.parquet", "registration/rms_per_tile.png",
                 "products/registered/dem.tif", "products/merged/dem.tif", "products/merged/isis/dem_radius.cub",
                 "products/merged/browse/hillshade.png", "products/registration/rms_per_tile.png"):
        assert (run / name).exists(), name
    assert str(run / "products/merged/dem.tif") in report["dem"]["files"]
    assert reg["products"]["merged"]["statistics"]  # the merged DEM's own statistics table


def test_convergent_pairs_measures_get_larger_sigmas(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """Tile networks: a measure's sigma is the configured one unless it came from a pair converging by more than
    ``network.convergent_sigma_from_deg`` (then larger, at most ``convergent_sigma_max_factor`` times); issue 21."""
    import pandas as pd

    run, _ = sync_run
    cfg = tiny_config().network
    store = RunStore(run)
    s0, smax = cfg.measure_sigma_px, cfg.measure_sigma_px * cfg.convergent_sigma_max_factor
    n_big = n_convergent = 0
    for tile in store.completed_units("tile"):
        net = read_network(store.network_path("tile", tile))
        if net.n_measures == 0:
            continue
        sig = net.sigma[:, 0]
        assert np.all(sig >= s0 - 1e-12) and np.all(sig <= smax + 1e-9), tile
        pairs = pd.read_parquet(store.unit_file("tile", tile, "pairs.parquet"))
        matched = pairs[pairs["status"] == "matched"]
        conv = int((matched["convergence_deg"] > cfg.convergent_sigma_from_deg).sum())
        big = int((sig > s0 + 1e-12).sum())
        assert (big > 0) == (conv > 0), (tile, big, conv)
        n_big += big
        n_convergent += conv
    assert n_convergent > 0, "the tiny mission has pairs converging beyond the limit (the test would say nothing)"
