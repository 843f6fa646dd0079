"""The tiny mission end to end on a real S3 API (moto on 127.0.0.1): run, resume, lost markers, half-written units.

The mission is read from the bucket too. The bucket run equals the local ``sync_run``
bit for bit (same networks, poses, DEM), since the same code computes every unit in
the local cache and the bucket only stores it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rioxarray  # noqa: F401  (registers the .rio accessor the tests read the CRS with)
import xarray as xr
import yaml

from mercury_dem.cli import main
from mercury_dem.config import to_dict
from mercury_dem.io.network_store import read_network
from mercury_dem.io.remote import RemoteDir
from mercury_dem.io.run_store import RunStore, read_solution

from ..s3_server import make_bucket, s3_endpoint  # noqa: F401 - the fixture
from .conftest import tiny_config

pytestmark = pytest.mark.integration

MISSION, RUN = "s3://e2e/mission", "s3://e2e/run"
VOLATILE = {"seconds", "started_at", "finished_at"}


@pytest.fixture(scope="module")
def s3_run(s3_endpoint: str, tiny_mission_path: Path, tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The tiny mission uploaded to the bucket and run there with ``--scheduler sync``: the CLI arguments."""
    make_bucket("e2e")
    remote = RemoteDir(MISSION)
    files = [p for p in sorted(tiny_mission_path.rglob("*")) if p.is_file()]
    remote.fs.put([str(p) for p in files], [remote.key(p.relative_to(tiny_mission_path).as_posix()) for p in files])
    cfg = tmp_path_factory.mktemp("s3cfg") / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(to_dict(tiny_config())))
    args = ["run", MISSION, "--out", RUN, "--scheduler", "sync", "--config", str(cfg), "--quiet"]
    assert main(args) == 0
    return args


def commits(store: RunStore) -> dict[str, str | None]:
    """The commit token of every unit and of the DEM store: a recomputed unit gets a new one."""
    r = store.remote
    out: dict[str, str | None] = {"dem.zarr": r.commit_token("dem.zarr", last="zarr.json", token_marker=False)}
    for level in ("tile", "region", "hemisphere", "global"):
        for uid in r.list(level):
            out[f"{level}/{uid}"] = r.commit_token(f"{level}/{uid}")
    return out


def levels(report: dict[str, Any]) -> dict[str, Any]:
    def clean(row: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in row.items() if k not in VOLATILE}

    lv = report["levels"]
    return {k: [clean(r) for r in v] if isinstance(v, list) else clean(v) for k, v in lv.items()}


def test_bucket_run_equals_the_local_run(s3_run: list[str], sync_run: tuple[Path, dict[str, Any]],
                                         tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    local, local_report = sync_run
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "fresh-cache"))  # read what the bucket holds
    store = RunStore.open(RUN)
    assert store.read_run()["mission"] == MISSION
    report = __import__("json").loads(store.report_json.read_text())
    assert report["run"] == RUN and report["mission"] == MISSION and levels(report) == levels(local_report)
    for level in ("tile", "region", "hemisphere", "global"):
        assert store.completed_units(level) == RunStore(local).completed_units(level)
    ids0, rot0, pos0, _ = read_solution(RunStore(local).solution_path("global", 0))
    ids1, rot1, pos1, _ = read_solution(store.solution_path("global", 0))
    assert (ids0 == ids1).all() and np.array_equal(rot0, rot1) and np.array_equal(pos0, pos1)
    n0, n1 = read_network(RunStore(local).network_path("global", 0)), read_network(store.network_path("global", 0))
    assert np.array_equal(n0.adjusted_xyz, n1.adjusted_xyz, equal_nan=True)
    assert np.array_equal(n0.measure_rejected, n1.measure_rejected)
    # dem.zarr is a Zarr store on the bucket, read here straight from S3 (not from the cache)
    dem = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False, decode_coords="all")
    ref = xr.open_zarr(local / "dem.zarr", consolidated=False, decode_coords="all")
    assert dem.attrs["complete"] is True
    np.testing.assert_array_equal(dem["elevation"].values, ref["elevation"].values)
    assert dem.rio.crs == ref.rio.crs
    cov = xr.open_zarr(f"{RUN}/coverage.zarr", consolidated=False)
    assert set(cov.data_vars) == set(xr.open_zarr(local / "coverage.zarr", consolidated=False).data_vars)
    products = sorted(p.relative_to(local / "products").as_posix() for p in (local / "products").rglob("*") if p.is_file())
    r = store.remote
    on_bucket = sorted(str(k)[len(r.key("products")) + 1:] for k in r.fs.find(r.key("products")))
    assert on_bucket == products and "dem.tif" in products


def test_readers_of_a_run_take_its_url(s3_run: list[str], sync_run: tuple[Path, dict[str, Any]], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # both exports stamp the same Created time
    assert main(["report", RUN]) == 0
    assert "global" in capsys.readouterr().out
    assert main(["export-isis", RUN, str(tmp_path / "bucket.net"), "--level", "global"]) == 0
    assert main(["export-isis", str(sync_run[0]), str(tmp_path / "local.net"), "--level", "global"]) == 0
    assert (tmp_path / "bucket.net").read_bytes() == (tmp_path / "local.net").read_bytes()


def test_resume_on_the_bucket_recomputes_nothing(s3_run: list[str]) -> None:
    store = RunStore(RUN)
    before = commits(store)
    assert main(s3_run) == 0
    assert commits(store) == before


def test_units_without_a_marker_are_recomputed(s3_run: list[str], tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    store = RunStore(RUN)
    r = store.remote
    before = commits(store)
    tile = store.completed_units("tile")[0]
    region = [u for u in store.completed_units("region") if store.read_summary("region", u)["ok"]][0]
    tile_net = read_network(store.network_path("tile", tile))
    _, region_rot, _, _ = read_solution(store.solution_path("region", region))
    # a lost marker: the tile's data is all there, its marker is not
    r.remove(f"tile/{tile}/.complete")
    # a half-written unit: a writer died part way (some objects missing, a truncated summary, no marker)
    net_keys = sorted(str(k) for k in r.fs.find(r.key(f"region/{region}/network.zarr")))
    r.fs.rm(net_keys[::2])
    r.write_bytes(f"region/{region}/summary.json", b'{"ok": tr')
    r.remove(f"region/{region}/.complete")
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "another-machine"))
    assert main(s3_run) == 0
    after = commits(store)
    changed = {k for k in before if after[k] != before[k]}
    assert changed == {f"tile/{tile}", f"region/{region}"}  # exactly those two; their parents stay as committed
    fresh = RunStore(RUN)
    assert fresh.read_summary("region", region)["ok"]
    assert np.array_equal(read_network(fresh.network_path("tile", tile)).apriori_xyz, tile_net.apriori_xyz,
                          equal_nan=True)
    assert np.array_equal(read_solution(fresh.solution_path("region", region))[1], region_rot)


@pytest.mark.slow
def test_a_local_cluster_on_the_bucket_equals_the_sync_run(s3_endpoint: str, tiny_mission_path: Path,
                                                          sync_run: tuple[Path, dict[str, Any]]) -> None:
    # two worker processes, each with the shared cache: tasks get the URL, read and commit through the bucket
    from mercury_dem.pipeline.graph import run_pipeline

    make_bucket("e2e-cluster")
    report = run_pipeline(tiny_mission_path, "s3://e2e-cluster/run", tiny_config(), workers=2, threads_per_worker=1,
                          stream=None)
    assert report["execution"]["mode"] == "local"
    ids0, rot0, _, _ = read_solution(RunStore(sync_run[0]).solution_path("global", 0))
    ids1, rot1, _, _ = read_solution(RunStore("s3://e2e-cluster/run").solution_path("global", 0))
    assert (ids0 == ids1).all() and np.array_equal(rot0, rot1)
    assert RunStore("s3://e2e-cluster/run").remote.exists("performance.html")
    # the DEM stage's products, registration and validation ran as a task on a worker process (issue 33 item 3)
    assert report["dem"]["tail_on_worker"] is True and report["dem"]["statistics"] == sync_run[1]["dem"]["statistics"]
    assert RunStore("s3://e2e-cluster/run").remote.exists("products/dem.tif")
    # and the global solution's validation against the truth too, equal to the in-process one's
    v0, v1 = dict(sync_run[1]["validation"]), dict(report["validation"])
    assert v0.pop("dem")["adjusted"] == v1.pop("dem")["adjusted"] and v1 == v0


def _chunk_tokens(r: RemoteDir) -> dict[str, str]:
    import json

    return {n: json.loads(r.read_bytes(f"dem_chunks/{n}"))["token"] for n in r.list("dem_chunks") if n != "plan.json"}


def test_dem_chunks_are_committed_one_by_one_and_resumed(s3_run: list[str], sync_run: tuple[Path, dict[str, Any]],
                                                         tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each DEM chunk is a unit on the bucket (its objects, then its marker); a resume grids only the chunks
    without a marker, and the store is the local run's."""
    import json

    store = RunStore(RUN)
    r = store.remote
    tokens = _chunk_tokens(r)
    cs = tiny_config().dem.chunk_size
    shape = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False)["elevation"].shape
    assert len(tokens) == math.ceil(shape[0] / cs) * math.ceil(shape[1] / cs) > 1
    # the root zarr.json lost (the store's commit) and one chunk half-written: its marker and data gone
    victim = sorted(tokens)[0]
    r0, c0 = (int(v) for v in victim[:-5].split("_"))
    r.remove("dem.zarr/zarr.json")
    r.remove(f"dem_chunks/{victim}")
    r.remove(f"dem.zarr/elevation/c/{r0 // cs}/{c0 // cs}")
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "another-machine"))
    assert main(s3_run) == 0
    after = _chunk_tokens(r)
    assert {n for n in tokens if after[n] != tokens[n]} == {victim}  # only it was gridded again
    report = json.loads(r.read_bytes("report.json"))
    assert report["dem"]["grid"]["chunks_reused"] == len(tokens) - 1
    dem = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False)
    ref = xr.open_zarr(sync_run[0] / "dem.zarr", consolidated=False)
    assert dem.attrs["complete"] is True
    np.testing.assert_array_equal(dem["elevation"].values, ref["elevation"].values)


# slow: two more resumes on the bucket (~45 s here); a failed chunk recorded and regridded is tested on a local run
# (test_dem_chunk_failure.py), a bucket chunk resumed alone just above; .ci/run runs it
@pytest.mark.slow
def test_a_failed_dem_chunk_on_the_bucket_is_recorded_and_resumed(s3_run: list[str], sync_run: tuple[Path, dict[str, Any]],
                                                                  tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A chunk failing on a bucket run is a value: report.json names it, the rest of dem.zarr is committed (the
    chunk NaN, no marker); the next run grids that chunk alone and the store equals the local run's."""
    import json

    from mercury_dem.pipeline import dem_bucket

    store = RunStore(RUN)
    r = store.remote
    tokens = _chunk_tokens(r)
    cs = tiny_config().dem.chunk_size
    victim = sorted(tokens)[-1]
    r0, c0 = (int(v) for v in victim[:-5].split("_"))
    r.remove("dem.zarr/zarr.json")
    r.remove(f"dem_chunks/{victim}")
    r.remove(f"dem.zarr/elevation/c/{r0 // cs}/{c0 // cs}")
    real = dem_bucket.grid_chunk

    def fake(index: Any, grid: Any, bounds: Any, cfg: Any) -> Any:
        if (bounds[0], bounds[2]) == (r0, c0):
            raise RuntimeError("injected fault in this chunk")
        return real(index, grid, bounds, cfg)

    monkeypatch.setattr(dem_bucket, "grid_chunk", fake)
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "machine-1"))
    assert main(s3_run) == 0
    report = json.loads(r.read_bytes("report.json"))
    (f,) = report["dem"]["failed_chunks"]
    assert (f["bounds"][0], f["bounds"][2]) == (r0, c0) and f["error"] == "RuntimeError: injected fault in this chunk"
    assert victim not in _chunk_tokens(r)
    dem = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False)
    ref = xr.open_zarr(sync_run[0] / "dem.zarr", consolidated=False)
    assert dem.attrs["complete"] is True and json.loads(dem.attrs["failed_chunks"])[0]["bounds"] == f["bounds"]
    got, want = dem["elevation"].values, ref["elevation"].values
    inside = np.zeros(got.shape, bool)
    inside[f["bounds"][0]:f["bounds"][1], f["bounds"][2]:f["bounds"][3]] = True
    assert np.isnan(got[inside]).all()
    np.testing.assert_array_equal(got[~inside], want[~inside])

    monkeypatch.setattr(dem_bucket, "grid_chunk", real)
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "machine-2"))
    before = _chunk_tokens(r)
    assert main(s3_run) == 0
    after = _chunk_tokens(r)
    assert set(after) == set(tokens) and all(after[n] == before[n] for n in before)  # only the victim gridded
    report = json.loads(r.read_bytes("report.json"))
    assert report["dem"]["failed_chunks"] == [] and report["dem"]["grid"]["chunks_reused"] == len(tokens) - 1
    dem = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False)
    assert "failed_chunks" not in dem.attrs
    np.testing.assert_array_equal(dem["elevation"].values, want)


def test_dem_chunks_run_on_dask_workers(s3_run: list[str], sync_run: tuple[Path, dict[str, Any]]) -> None:
    """The chunk tasks on a dask.distributed cluster read the point cloud from the bucket themselves and write
    the same store (threads here; the slow LocalCluster test above runs the whole run on worker processes)."""
    from distributed import Client, LocalCluster

    from mercury_dem.dem.cloud import point_cloud
    from mercury_dem.dem.extent import config_with_extent
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.pipeline.dem_bucket import _worker_index, grid_dem_on_bucket

    store = RunStore(RUN)
    r = store.remote
    pts = point_cloud(read_network(store.network_path("global", 0)))
    cfg = config_with_extent(tiny_config().dem, pts)
    for n in _chunk_tokens(r):
        r.remove(f"dem_chunks/{n}")  # every chunk must be gridded again
    _worker_index.cache_clear()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        summary = grid_dem_on_bucket(store, pts, cfg, client, body=MERCURY,
                                     attrs={"source": "global adjusted control points"})
        ran_on = client.run(lambda: _worker_index.cache_info().currsize)
    assert summary["on_workers"] and summary["chunks_reused"] == 0 and len(_chunk_tokens(r)) == summary["n_chunks"]
    assert sum(ran_on.values()) >= 1  # the workers built the index (here they share this process's cache)
    dem = xr.open_zarr(f"{RUN}/dem.zarr", consolidated=False)
    ref = xr.open_zarr(sync_run[0] / "dem.zarr", consolidated=False)
    assert dem.attrs["complete"] is True
    np.testing.assert_array_equal(dem["elevation"].values, ref["elevation"].values)
    np.testing.assert_array_equal(dem["point_count"].values, ref["point_count"].values)


def test_dem_stage_tail_runs_on_a_worker(s3_run: list[str]) -> None:
    """A bucket run's products, checks, registration and validation run as one task on a worker (issue 33 item 3):
    it reads the bucket, commits its products there, and its report equals the in-process run's."""
    from distributed import Client, LocalCluster

    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dem_run import run_dem_stage

    store = RunStore.open(RUN)
    # the reference: the same stage on the bucket's current state with its tail in this process (the earlier
    # tests of this module regrid and resume the bucket's DEM, so the run's own report.json is not the reference)
    store.remote.remove("products")
    want = run_dem_stage(store, open_mission(MISSION), tiny_config(), None, stream=None)
    store.remote.remove("products")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        out = run_dem_stage(store, open_mission(MISSION), tiny_config(), client, stream=None)
    assert out["tail_on_worker"] is True and want["tail_on_worker"] is False
    assert set(out) == set(want)
    for key in ("statistics", "shape_check", "products_skipped", "validation"):
        assert out[key] == want[key], key
    reg, reg0 = out.get("registration") or {}, want.get("registration") or {}
    assert {k: v for k, v in reg.items() if not k.startswith("seconds")} == \
        {k: v for k, v in reg0.items() if not k.startswith("seconds")}
    assert sorted(Path(f).name for f in out["files"]) == sorted(Path(f).name for f in want["files"])
    assert store.remote.exists("products/dem.tif")
