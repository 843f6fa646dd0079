"""A chunk that fails to grid is a recorded value: the rest of dem.zarr is written, the chunk is NaN, a resume redoes it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.config.dem import DemConfig
from mercury_dem.exceptions import DiskFullError
from mercury_dem.geometry.body import MERCURY
from mercury_dem.pipeline import dem_stage
from mercury_dem.pipeline.dem_stage import FAILED_CHUNKS_ATTR, failed_chunks_of, grid_dem, regrid_failed_chunks
from mercury_dem.compute import SyncClient

CFG = DemConfig(pixels_per_degree=1, chunk_size=48, max_distance_m=400_000.0, coverage_pixel_km=40.0)
REAL_GRID_CHUNK = dem_stage.grid_chunk


def _layers(path):
    g = zarr.open_group(str(path), mode="r")
    return {name: g[name][...] for name in g.array_keys() if g[name].ndim == 2}


def _failing(bad, calls, exc=None):
    """grid_chunk that raises for the chunk ``bad`` (bounds) and counts the chunks it is asked for."""
    real = REAL_GRID_CHUNK

    def fake(index, grid, bounds, cfg, **kw):
        calls.append(tuple(bounds))
        if tuple(bounds) == bad:
            raise exc if exc is not None else RuntimeError("injected fault in this chunk")
        return real(index, grid, bounds, cfg, **kw)

    return fake


@pytest.fixture(scope="module")
def normal(tmp_path_factory, global_cloud):
    path = tmp_path_factory.mktemp("normal") / "dem.zarr"
    return path, grid_dem(global_cloud, CFG, path, coverage=False, body=MERCURY)


@pytest.mark.parametrize("client", [None, SyncClient()], ids=["no-client", "sync-client"])
def test_a_failed_chunk_is_recorded_the_rest_written_and_a_resume_grids_only_it(
        normal, global_cloud, tmp_path, monkeypatch, client):
    """The stage completes with one chunk failing: the summary and the store name the chunk and the
    reason, every other pixel equals the normal DEM, the chunk's pixels are NaN with no points;
    regridding (the resume) grids that chunk alone and the store then equals the normal one."""
    ref_path, ref_summary = normal
    ref = _layers(ref_path)
    bad = (48, 96, 48, 96)  # an inner chunk of the 180 x 360 grid (4 x 8 chunks of 48)
    calls: list[tuple[int, ...]] = []
    monkeypatch.setattr(dem_stage, "grid_chunk", _failing(bad, calls))
    path = tmp_path / "dem.zarr"
    summary = grid_dem(global_cloud, CFG, path, client, coverage=False, record_failures=True, body=MERCURY)
    assert len(calls) == ref_summary["n_chunks"]
    (f,) = summary["failed_chunks"]
    assert f["bounds"] == list(bad) and "RuntimeError: injected fault in this chunk" in f["error"]
    assert "again" in f["what_to_do"] and f["pixels"] == 48 * 48
    assert f["lat_deg"] == [90 - 95.5, 90 - 48.5] and f["lon_deg"] == [48.5, 95.5]
    assert failed_chunks_of(path) == summary["failed_chunks"]
    got = _layers(path)
    inside = np.zeros(ref["elevation"].shape, bool)
    inside[bad[0]:bad[1], bad[2]:bad[3]] = True
    for name in ref:  # every map layer of the store
        np.testing.assert_array_equal(got[name][~inside], ref[name][~inside], err_msg=name)
    assert np.isnan(got["elevation"][inside]).all() and not got["point_count"][inside].any()
    ref_gap_inside = int(np.isnan(ref["elevation"][inside]).sum())
    assert summary["no_value_pixels"] == ref_summary["no_value_pixels"] + inside.sum() - ref_gap_inside

    # the resume: only the failed chunk is gridded again, and the store is the normal one
    calls.clear()
    monkeypatch.setattr(dem_stage, "grid_chunk", _failing(None, calls))
    out = regrid_failed_chunks(global_cloud, CFG, path, client, body=MERCURY)
    assert calls == [bad] and out["regridded"] == [list(bad)] and out["failed_chunks"] == []
    got = _layers(path)
    for name in ref:
        np.testing.assert_array_equal(got[name], ref[name], err_msg=name)
    attrs = zarr.open_group(str(path), mode="r").attrs
    assert FAILED_CHUNKS_ATTR not in attrs and attrs["no_value_pixels"] == ref_summary["no_value_pixels"]


def test_a_chunk_failing_again_stays_listed_with_its_new_error(global_cloud, tmp_path, monkeypatch):
    """A resume whose chunk fails again keeps it in the record, with the new reason."""
    bad = (0, 48, 0, 48)
    monkeypatch.setattr(dem_stage, "grid_chunk", _failing(bad, [], ValueError("first")))
    path = tmp_path / "dem.zarr"
    grid_dem(global_cloud, CFG, path, coverage=False, record_failures=True, body=MERCURY)
    monkeypatch.setattr(dem_stage, "grid_chunk", _failing(bad, [], ValueError("second")))
    out = regrid_failed_chunks(global_cloud, CFG, path, body=MERCURY)
    (f,) = out["failed_chunks"]
    assert f["bounds"] == list(bad) and f["error"] == "ValueError: second"
    assert json.loads(zarr.open_group(str(path), mode="r").attrs[FAILED_CHUNKS_ATTR])[0]["error"] == "ValueError: second"


def test_a_full_disk_in_a_chunk_still_stops_the_stage(global_cloud, tmp_path, monkeypatch):
    """A full disk is not the chunk's fault: the stage stops and leaves no store."""
    monkeypatch.setattr(dem_stage, "grid_chunk", _failing((0, 48, 0, 48), [], DiskFullError("disk full")))
    with pytest.raises(DiskFullError):
        grid_dem(global_cloud, CFG, tmp_path / "dem.zarr", coverage=False, record_failures=True, body=MERCURY)
    assert not (tmp_path / "dem.zarr").exists()


def test_every_chunk_failing_is_an_error_and_leaves_no_store(global_cloud, tmp_path, monkeypatch):
    """No chunk gridded: a GridError naming the first error, not an empty DEM called done."""
    from mercury_dem.exceptions import GridError

    def fail(index, grid, bounds, cfg, **kw):
        raise RuntimeError("broken kernel")

    monkeypatch.setattr(dem_stage, "grid_chunk", fail)
    with pytest.raises(GridError, match="none of the 32 chunks.*RuntimeError: broken kernel"):
        grid_dem(global_cloud, CFG, tmp_path / "dem.zarr", coverage=False, record_failures=True, body=MERCURY)
    # without record_failures (mercury-dem grid) the first error stops the call, as before
    with pytest.raises(RuntimeError, match="broken kernel"):
        grid_dem(global_cloud, CFG, tmp_path / "dem.zarr", coverage=False, body=MERCURY)
    assert not (tmp_path / "dem.zarr").exists()


def test_a_damaged_failed_chunks_record_is_a_named_store_error(normal, tmp_path):
    """The record read back on resume: damaged, it is a StoreError naming the store and the fix."""
    import shutil

    from mercury_dem.exceptions import StoreError

    path = tmp_path / "dem.zarr"
    shutil.copytree(normal[0], path)
    assert failed_chunks_of(path) == [] and failed_chunks_of(tmp_path / "absent.zarr") == []
    for bad in ("{not json", json.dumps({"bounds": [0, 1]}), json.dumps([{"bounds": [0, 1]}])):
        zarr.open_group(str(path), mode="r+").attrs[FAILED_CHUNKS_ATTR] = bad
        with pytest.raises(StoreError, match=f"{path}.*damaged.*--force dem"):
            failed_chunks_of(path)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_failed_chunks_record(normal, tmp_path_factory, data):
    """Any bytes in the record (a valid one cut, characters replaced or inserted): a list of chunk records
    with four whole-number bounds, or a StoreError naming the store; never another exception."""
    import shutil

    from mercury_dem.exceptions import StoreError

    path = tmp_path_factory.mktemp("fuzz") / "dem.zarr"
    shutil.copytree(normal[0], path)
    seed = json.dumps([{"bounds": [48, 96, 0, 48], "pixels": 2304, "error": "RuntimeError: x"},
                       {"bounds": [0, 48, 48, 96], "pixels": 2304}])
    text = seed
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(text)))
        how = data.draw(st.sampled_from(("cut", "replace", "insert")))
        ch = data.draw(st.sampled_from(list('0123456789-.,:[]{}"e ') + ["x", "\u00e9", "null", "1e400"]))
        text = text[:i] if how == "cut" else text[:i] + ch + text[i + (how == "replace"):]
    zarr.open_group(str(path), mode="r+").attrs[FAILED_CHUNKS_ATTR] = text
    try:
        records = failed_chunks_of(path)
    except StoreError as exc:
        assert str(path) in str(exc) and "--force dem" in str(exc)
    else:
        assert all(len(r["bounds"]) == 4 and all(type(v) is int for v in r["bounds"]) for r in records)
