"""The DEM stage of a run with a chunk that fails: recorded in report.json, the rest written, a resume redoes it."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import zarr

from mercury_dem.pipeline import dem_stage
from mercury_dem.pipeline.graph import run_pipeline

from .conftest import read_report, tiny_config

REAL_GRID_CHUNK = dem_stage.grid_chunk


def _maps(path):
    g = zarr.open_group(str(path), mode="r")
    return {name: g[name][...] for name in g.array_keys() if g[name].ndim == 2}


@pytest.mark.integration
def test_a_run_records_a_failed_dem_chunk_and_its_resume_grids_it(sync_run, tiny_mission_path, tmp_path,
                                                                  monkeypatch):
    """``--force dem`` on a finished run with one chunk of the DEM failing: the run completes, report.json's
    ``dem.failed_chunks`` names the chunk and the reason, every other pixel equals the normal run's and the
    chunk is NaN; the next run (a resume) grids that chunk again and dem.zarr equals the normal run's."""
    ref_run, _ = sync_run
    run = tmp_path / "run"
    shutil.copytree(ref_run, run)
    ref = _maps(ref_run / "dem.zarr")
    rows, cols = ref["elevation"].shape
    bad = (64, min(128, rows), 64, min(128, cols))  # tiny_config: 64-pixel chunks

    def fake(index, grid, bounds, cfg, **kw):
        if tuple(bounds) == bad:
            raise RuntimeError("injected fault in this chunk")
        return REAL_GRID_CHUNK(index, grid, bounds, cfg, **kw)

    monkeypatch.setattr(dem_stage, "grid_chunk", fake)
    report = run_pipeline(tiny_mission_path, run, tiny_config(), scheduler="sync", stream=None, force="dem")
    assert read_report(run)["dem"]["failed_chunks"] == report["dem"]["failed_chunks"]
    (f,) = report["dem"]["failed_chunks"]
    assert f["bounds"] == list(bad) and f["error"] == "RuntimeError: injected fault in this chunk"
    assert "again" in f["what_to_do"]
    got = _maps(run / "dem.zarr")
    inside = np.zeros((rows, cols), bool)
    inside[bad[0]:bad[1], bad[2]:bad[3]] = True
    for name in ref:
        np.testing.assert_array_equal(got[name][~inside], ref[name][~inside], err_msg=name)
    assert np.isnan(got["elevation"][inside]).all()
    assert json.loads(zarr.open_group(str(run / "dem.zarr"), mode="r").attrs["failed_chunks"])[0]["bounds"] == list(bad)

    monkeypatch.setattr(dem_stage, "grid_chunk", REAL_GRID_CHUNK)
    report = run_pipeline(tiny_mission_path, run, tiny_config(), scheduler="sync", stream=None)
    assert report["dem"]["failed_chunks"] == [] and report["dem"]["grid"]["regridded"] == [list(bad)]
    got = _maps(run / "dem.zarr")
    for name in ref:
        np.testing.assert_array_equal(got[name], ref[name], err_msg=name)
