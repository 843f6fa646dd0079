"""The dense stage (issue 31) of ``mercury-dem run`` on a copy of the tiny sync run (no second full run).

The copy is resumed with ``dense.enabled`` and ``--force dense``: the cascade and the DEM are reused, the
dense stage runs in-process. Measured 2026-12-02 on the 2-core session machine (shared, loaded), tiny seed 42,
after chips are split until epipolar (``dense.max_vertical_px``): 40 of 273 candidate pairs selected over 11
tiles, 40 chips in 2,203 parts (0 failed), 1,051,624 points; dense DEM at 5.5 pixel/deg (3 x the pairs' median
pixel scale of 2.7 km); on the 28,804 pixels the dense points reach (and the sparse DEM covers) the dense DEM
alone is 487 m RMSE against the truth, the sparse DEM resampled there 428 m: ratio 1.14; fused with the sparse DEM
by their precisions (``dense.sparse_sigma_m``, session 4) 412 m, ratio 0.96. Issue 31's <= 0.5 is **not** met on
the tiny mission (docs/design/dense.md, "What bounds the ratio"; seed 7: 1.25 alone, 0.99 fused). The stage
takes 52-130 s (the machine's load). Session 5: the cloud moved by the registration's transform and the dense pixels
levelled on the altimetry's mean: 406 m, bias +2 m (before -28 m), ratio 0.95 (docs/benchmarks/dense.md).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.pipeline.conftest import tiny_config

#: What was measured on the tiny mission (module docstring); the regression guards allow 15 % on top.
MEASURED_RATIO = 0.96  # fused with the sparse DEM (dense.sparse_sigma_m)
MEASURED_DENSE_RMSE_M = 412.0
MEASURED_DENSE_ALONE_RMSE_M = 487.0


@pytest.fixture(scope="module")
def dense_run(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
              tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], float]:
    """A copy of the tiny sync run resumed with the dense stage: (run, report, seconds)."""
    from mercury_dem.pipeline.graph import run_pipeline

    run, _ = sync_run
    out = tmp_path_factory.mktemp("dense") / "run"
    shutil.copytree(run, out)  # a real copy: the resumed run rewrites the products
    t = time.perf_counter()
    report = run_pipeline(tiny_mission_path, out, tiny_config(dense={"enabled": True}), scheduler="sync",
                          stream=None, force="dense")
    return out, report, time.perf_counter() - t


def _cloud_groups(run: Path) -> list[Path]:
    return sorted(p for p in (run / "dense.zarr").iterdir() if p.name.startswith("tile_"))


def test_the_dense_stage_writes_the_cloud_per_tile(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    import zarr

    from mercury_dem.pipeline.dense_stage import CLOUD_COLUMNS, tile_complete

    run, report, _ = dense_run
    dense = report["dense"]
    groups = _cloud_groups(run)
    assert len(groups) == dense["tiles"]["run"] > 0 and not dense["tiles"]["failed"]
    pairs = zarr.open_group(str(run / "dense.zarr"), mode="r").attrs["pairs"]
    assert len(pairs) == dense["pairs"]["selected"] > 0
    total = 0
    for g in groups:
        assert tile_complete(g)
        z = zarr.open_group(str(g), mode="r")
        n = z["height"].shape[0]
        assert set(CLOUD_COLUMNS) <= set(z.array_keys())
        assert all(z[k].shape[0] == n for k in CLOUD_COLUMNS)
        pair = np.asarray(z["pair"][...])
        assert n == 0 or (pair.min() >= 0 and pair.max() < len(pairs))
        sigma = np.asarray(z["sigma_h_m"][...])
        assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
        assert np.all(np.abs(np.asarray(z["lat"][...])) <= 90)
        total += n
    assert total == dense["points"] > 100_000  # measured 1,051,624
    # every chip rectified in parts that are epipolar (a 500-km image is not): measured 2,203 parts of 40 chips
    assert dense["chip_parts"] > 4 * dense["chips"] and dense["chip_parts_failed"] >= 0
    assert dense["chips"] > 0 and dense["chips_failed"] == len([f for f in dense["failures"] if f["chip"]])
    assert "range" in dense["removed"] and dense["memory_bytes_max_task"] > 0


def test_the_dense_dem_has_elevation_precision_and_source(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.pipeline.dense_dem import SOURCE_DENSE, SOURCE_NONE, SOURCE_SPARSE

    run, report, _ = dense_run
    ds = open_dem(run / "dem_dense.zarr").load()
    src = ds["source"].values
    elev, dense, sparse = ds["elevation"].values, ds["elevation_dense"].values, ds["sparse_on_grid"].values
    assert set(np.unique(src)) <= {SOURCE_NONE, SOURCE_DENSE, SOURCE_SPARSE}
    assert np.array_equal(src == SOURCE_DENSE, np.isfinite(dense))
    # dense pixels: the dense value fused with the sparse DEM by precision (dense.sparse_sigma_m), so it lies between
    # the two (float32 rounding aside), and is the dense value alone where the sparse DEM has none; then levelled on
    # the altimetry's mean (dense.level_to_altimetry): a blend of the tiles' offsets, within their range
    lv = report["dense"]["dem"]["altimetry_level"] or {"offset_min_m": 0.0, "offset_max_m": 0.0}
    a, b = min(0.0, lv["offset_min_m"]), max(0.0, lv["offset_max_m"])
    d = src == SOURCE_DENSE
    both = d & np.isfinite(sparse)
    lo, hi = np.minimum(dense, sparse)[both], np.maximum(dense, sparse)[both]
    assert np.all((elev[both] >= lo + a - 1e-2) & (elev[both] <= hi + b + 1e-2))
    moved = np.abs(elev[both] - dense[both]) > 1.0
    assert moved.mean() > 0.5  # the fusion acts (a mutant that keeps the dense value alone fails)
    alone = d & ~np.isfinite(sparse)
    assert np.all((elev[alone] - dense[alone] >= a - 1e-2) & (elev[alone] - dense[alone] <= b + 1e-2))
    assert np.array_equal(elev[src == SOURCE_SPARSE], sparse[src == SOURCE_SPARSE])
    assert np.all(np.isnan(elev[src == SOURCE_NONE]))
    prec = ds["precision_m"].values
    assert np.all(np.isnan(prec[src != SOURCE_DENSE]))
    assert np.isfinite(prec[src == SOURCE_DENSE]).mean() > 0.5
    block = report["dense"]["dem"]
    assert block["pixels_per_degree"] == ds.attrs["pixels_per_degree"]
    # the rule: 3 x the pairs' median pixel scale, to a multiple of 0.5 pixel/deg
    raw = 2 * np.pi * 2439.4e3 / 360 / (3 * block["median_pair_pixel_scale_m"])
    assert abs(block["pixels_per_degree"] - raw) <= 0.25
    assert block["source_fraction"]["dense"] > 0.2  # measured 0.35 (the rest of the map is outside the images)


def test_the_dense_dem_has_the_sparse_dems_products(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    """GeoTIFF/COG, PDS with labels, ISIS cube, statistics and browse of the dense DEM, its values, the side-by-side
    hillshade, and the orthoimages on it (issue 31 section 3).
    """
    import rasterio

    from mercury_dem.pipeline.dem_stage import open_dem

    run, report, _ = dense_run
    prod = run / "products" / "dense"
    block = report["dense"]["products"]
    assert "error" not in block, block
    for rel in ("dem.tif", "pds/equirectangular.tif", "pds/equirectangular.xml", "isis/dem_radius.cub",
                "statistics.json", "browse/hillshade.png", "browse/colour_hillshade.png",
                "browse/dense_vs_sparse_hillshade.png"):
        assert (prod / rel).stat().st_size > 0, rel
    assert not [p for p in prod.rglob("*") if ".tmp-" in p.name]  # written under temporary names, renamed
    assert block["browse_title"].startswith("Mercury dense DEM (")
    ds = open_dem(run / "dem_dense.zarr").load()
    elev = ds["elevation"].transpose("lat", "lon").values
    with rasterio.open(prod / "dem.tif") as src:
        tif = src.read(1, masked=True).filled(np.nan)
    assert tif.shape == elev.shape
    ok = np.isfinite(elev)
    assert np.array_equal(np.isfinite(tif), ok)
    assert np.array_equal(np.sort(tif[ok]), np.sort(elev[ok]))  # the product layer's values, dense and fallback
    orth = report["dense"]["ortho"]
    assert orth["images"] > 0 and not orth["skipped"]
    made = [m for m in orth["mosaics"].values() if "path" in m]
    assert made and all(m["dtm"]["pixel_m"] == pytest.approx(report["dense"]["dem"]["pixel_m"]) for m in made)
    assert all(m["pixel_m"] < m["dtm"]["pixel_m"] for m in made)  # native scale finer than the DTM's
    with rasterio.open(made[0]["dtm"]["path"]) as src:
        assert src.overviews(1) and src.crs is not None


def test_the_report_has_the_dense_entries(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    run, report, seconds = dense_run
    on_disk = json.loads((run / "report.json").read_text())
    dense = on_disk["dense"]
    pairs = dense["pairs"]
    assert pairs["selected"] + pairs["rejected"] == pairs["candidates"] == len(pairs["table"])
    assert all(r["reason"] for r in pairs["table"] if r["status"] == "rejected")
    assert sum(pairs["rejected_by_reason"].values()) >= pairs["rejected"]
    val = on_disk["validation"]["dem"]
    for key in ("dense", "sparse_on_dense_grid", "dense_on_dense_pixels", "sparse_on_dense_pixels"):
        assert val[key]["rmse_m"] > 0 and val[key]["bias_m"] is not None, key
        # error against distance to the nearest control point (issue 31 section 3)
        assert sum(r["n"] for r in val[key]["error_vs_distance"]) == val[key]["n_compared"], key
    assert on_disk["timings"]["dense"] > 0
    from mercury_dem.pipeline.report import dense_lines

    text = dense_lines(dense)
    assert f"{pairs['selected']} of {pairs['candidates']} candidate pairs selected" in text and "dense DEM:" in text
    assert "dense products: " in text and "orthoimages on the dense DEM: " in text
    print(f"dense stage {on_disk['timings']['dense']:.1f} s, resumed run {seconds:.1f} s")


def test_dense_dem_against_sparse_on_the_dense_grid(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    """What holds on the tiny mission (guards at the measurement + 15 %); the issue's goal is the xfail below."""
    _, report, _ = dense_run
    val = report["validation"]["dem"]
    dense, sparse = val["dense_on_dense_pixels"], val["sparse_on_dense_pixels"]
    ratio = report["dense"]["dem"]["rmse_ratio_dense_over_sparse"]
    print(f"dense {dense['rmse_m']:.0f} m, sparse {sparse['rmse_m']:.0f} m on {dense['n_compared']} pixels: "
          f"ratio {ratio:.2f}")
    assert ratio == pytest.approx(dense["rmse_m"] / sparse["rmse_m"])
    assert dense["rmse_m"] <= 1.15 * MEASURED_DENSE_RMSE_M
    assert ratio <= 1.15 * MEASURED_RATIO
    assert ratio <= 1.02  # fused by their precisions, the dense DEM is not worse than the sparse one
    # issue 31 done-when 1: |bias| <= 25 m after registration. The cloud moved by the registration's transform and
    # the dense pixels levelled on the altimetry's mean (shots: 1 m range noise, 3 m radial orbit error per
    # profile, ~300,000 on the dense pixels: the level's own error is below a metre); measured +2 m (alone +6 m;
    # before, in the adjusted frame: -28 m, alone -61 m; moved but not levelled: +38 m)
    block = report["dense"]["dem"]
    assert block["frame"] == "registered to altimetry" and block["altimetry_level"]["tiles"] > 0
    assert abs(dense["bias_m"]) <= 25.0
    alone = val["dense_alone_on_dense_pixels"]
    assert dense["rmse_m"] < alone["rmse_m"] <= 1.15 * MEASURED_DENSE_ALONE_RMSE_M
    # the same pixels: the dense DEM's pixels that the sparse DEM also covers
    assert dense["n_compared"] == sparse["n_compared"] > 10_000


def test_the_points_stated_precision_on_its_calibration_seed(dense_run: tuple[Path, dict[str, Any], float],
                                                             tiny_mission_path: Path) -> None:
    """``dense.sigma_scale`` (1.2), ``dense.sigma_floor_px`` (0.15) and ``dense.sigma_height_floor_factor`` (0.5)
    were fitted on this seed's and seed 7's clouds, so this guards the fit, it does not show it: measured true RMS /
    stated RMS 0.92 and 0.10 % beyond 3 sigma (seed 7: 0.99, 0.59 %; seed 1234, not fitted: docs/design/dense.md).
    """
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dense_stage import read_cloud

    run, _, _ = dense_run
    cloud = read_cloud(run / "dense.zarr")
    truth = open_mission(tiny_mission_path).need_truth().surface()
    err = cloud["height"] - truth.height(cloud["lat"], cloud["lon"])
    sigma = cloud["sigma_h_m"].astype(np.float64)
    ratio = float(np.sqrt(np.mean(err**2) / np.mean(sigma**2)))
    beyond = float(np.mean(np.abs(err) > 3 * sigma))
    print(f"true/stated {ratio:.2f}, beyond 3 sigma {100 * beyond:.2f} %")
    assert 0.7 <= ratio <= 1.5
    assert beyond <= 0.01


@pytest.mark.xfail(strict=True, reason="issue 31 goal: dense RMSE <= 0.5 x sparse on the dense grid; measured "
                   "0.96 on the tiny mission fused with the sparse DEM, 1.14 alone (docs/design/dense.md)")
def test_issue_31_goal_dense_at_most_half_the_sparse_rmse(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    _, report, _ = dense_run
    assert report["dense"]["dem"]["rmse_ratio_dense_over_sparse"] <= 0.5


def test_a_complete_tile_is_not_recomputed(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    from mercury_dem.pipeline.dense_stage import run_dense_tile

    run, report, _ = dense_run
    tile = int(_cloud_groups(run)[0].name.split("_")[1])
    t = time.perf_counter()
    again = run_dense_tile(str(run), tile, [], tiny_config(dense={"enabled": True}), 1000.0)
    assert again["reused"] is True and again["tile"] == tile and time.perf_counter() - t < 5.0
    import zarr

    assert again["points"] == zarr.open_group(str(_cloud_groups(run)[0]), mode="r")["height"].shape[0]
    assert str(tile) in report["dense"]["tile_seconds"]


def test_a_bad_pair_is_recorded_and_the_tile_goes_on(dense_run: tuple[Path, dict[str, Any], float]) -> None:
    import zarr

    from mercury_dem.pipeline.dense_stage import run_dense_tile, tile_group_name

    run, report, _ = dense_run
    first = zarr.open_group(str(run / "dense.zarr"), mode="r").attrs["pairs"][0]
    tile = 9999  # no such tile in the plan: a group of its own, removed below
    try:
        s = run_dense_tile(str(run), tile, [(7, "NO_SUCH_IMAGE", first["right"]), (0, first["left"], first["right"])],
                           tiny_config(dense={"enabled": True}), 1000.0)
        assert s["ok"] and len(s["failures"]) == 1
        assert "pair NO_SUCH_IMAGE/" in s["failures"][0]["error"] and "NO_SUCH_IMAGE" in s["failures"][0]["error"]
        assert s["failures"][0]["failure"] == "no_pose"  # its kind, from the exception (dense.failures)
        assert s["points"] > 0  # the good pair went on
    finally:
        shutil.rmtree(run / "dense.zarr" / tile_group_name(tile), ignore_errors=True)
