"""The commit protocol on a real S3 API (moto on 127.0.0.1): marker last, untrusted without it, caches follow commits."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.io.remote import RemoteDir, cache_dir_for, fetch_mission
from mercury_dem.io.run_store import RunStore

from ..s3_server import make_bucket, s3_endpoint  # noqa: F401 - the fixture

pytestmark = pytest.mark.usefixtures("s3_endpoint")


def _unit(store: RunStore, level: str, uid: int, value: float) -> None:
    """A unit as the stage runners write it: files, summary.json, then the local marker."""
    from mercury_dem.io.atomic import atomic_directory, atomic_write_json
    from mercury_dem.io.run_store import write_solution

    with atomic_directory(store.unit_dir(level, uid), overwrite=True) as tmp:
        write_solution(tmp / "solution.parquet", np.array(["a", "b"]), np.tile(np.eye(3), (2, 1, 1)),
                       np.full((2, 3), value))
        atomic_write_json(tmp / "summary.json", {"level": level, "id": uid, "ok": True, "value": value})
    store.commit_unit(level, uid)


def test_the_marker_is_uploaded_after_every_data_object(monkeypatch: pytest.MonkeyPatch) -> None:
    make_bucket("order")
    store = RunStore("s3://order/run")
    calls: list[tuple[str, list[str]]] = []
    fs = store.remote.fs
    real_put, real_pipe = fs.put, fs.pipe_file
    monkeypatch.setattr(fs, "put", lambda l, r, **kw: (calls.append(("put", list(r))), real_put(l, r, **kw))[1])
    monkeypatch.setattr(fs, "pipe_file", lambda p, d, **kw: (calls.append(("pipe", [p])), real_pipe(p, d, **kw))[1])
    _unit(store, "tile", 7, 1.0)
    keys = [k for _, ks in calls for k in ks]
    assert keys[-1] == "order/run/tile/7/.complete"
    assert {"order/run/tile/7/summary.json", "order/run/tile/7/solution.parquet"} <= set(keys[:-1])
    assert store.remote.read_bytes("tile/7/.complete").startswith(b"complete ")


def test_a_unit_without_its_marker_is_not_trusted(tmp_path: Path) -> None:
    make_bucket("untrusted")
    store = RunStore("s3://untrusted/run")
    _unit(store, "region", 3, 2.0)
    assert store.unit_complete("region", 3) and store.completed_units("region") == [3]
    store.remote.remove("region/3/.complete")  # a writer died before its last object
    fresh = RunStore(store.url)
    assert not fresh.unit_complete("region", 3) and fresh.completed_units("region") == []
    with pytest.raises(StoreError, match=r"s3://untrusted/run/region/3 is not complete .*resume the run"):
        fresh.solution_path("region", 3)
    # the next commit replaces the partial data: no object of the old attempt survives
    store.remote.write_bytes("region/3/leftover.bin", b"partial")
    _unit(store, "region", 3, 5.0)
    assert not store.remote.exists("region/3/leftover.bin")
    assert fresh.read_summary("region", 3)["value"] == 5.0


def test_cached_copies_follow_the_buckets_commits(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mercury_dem.io.run_store import read_solution

    make_bucket("follow")
    writer = RunStore("s3://follow/run")
    _unit(writer, "tile", 1, 1.0)
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "other-machine"))
    reader = RunStore("s3://follow/run")
    assert reader.root != writer.root and reader.root == cache_dir_for("s3://follow/run", "runs")
    assert read_solution(reader.solution_path("tile", 1))[2][0, 0] == 1.0
    _unit(writer, "tile", 1, 4.0)  # recomputed elsewhere (--force, a retried task)
    assert read_solution(reader.solution_path("tile", 1))[2][0, 0] == 4.0


def test_run_json_and_report_live_on_the_bucket() -> None:
    make_bucket("files")
    store = RunStore("s3://files/run")
    assert store.is_empty() and not store.has_run()
    store.write_run({"mission": "s3://files/mission"})
    assert store.has_run() and not store.is_empty()
    assert json.loads(store.remote.read_bytes("run.json") or b"") == {"mission": "s3://files/mission"}
    with pytest.raises(StoreError, match="s3://files/nothing is not a mercury-dem run"):
        RunStore.open("s3://files/nothing")


def test_a_mission_is_read_from_the_bucket(tiny_mission_path: Path) -> None:
    from mercury_dem.mission import open_mission

    make_bucket("missions")
    remote = RemoteDir("s3://missions/tiny")
    with pytest.raises(StoreError, match="mission s3://missions/tiny does not exist"):
        open_mission("s3://missions/tiny")
    files = [p for p in sorted(tiny_mission_path.rglob("*")) if p.is_file() and p.name != ".complete"]
    remote.fs.put([str(p) for p in files], [remote.key(p.relative_to(tiny_mission_path).as_posix()) for p in files])
    with pytest.raises(StoreError, match=r"mission s3://missions/tiny is incomplete \(no .complete"):
        open_mission("s3://missions/tiny")  # an interrupted upload
    remote.write_bytes(".complete", b"complete\n")
    m = open_mission("s3://missions/tiny")
    local = open_mission(tiny_mission_path)
    assert m.path == fetch_mission("s3://missions/tiny")
    assert m.image_ids == local.image_ids
    np.testing.assert_array_equal(m.read_image(m.image_ids[0]), local.read_image(local.image_ids[0]))


def test_a_bucket_that_does_not_exist_is_a_clear_error(tmp_path: Path) -> None:
    from mercury_dem.cli import main

    with pytest.raises(StoreError, match=r"s3://no-such-bucket/run: cannot write to the bucket .*check that the bucket"):
        RunStore("s3://no-such-bucket/run").check_writable()
    assert main(["run", str(tmp_path / "m"), "--out", "s3://no-such-bucket/run", "--scheduler", "sync"]) == 2


def test_the_checksum_manifest_travels_with_the_marker(tmp_path: Path) -> None:
    """A bucket unit's marker holds the commit token and the manifest; the fetched copy verifies, a
    changed object on the bucket is named once fetched."""
    from mercury_dem.io.atomic import atomic_directory, atomic_write_json

    make_bucket("sums")
    store = RunStore("s3://sums/run")
    with atomic_directory(store.unit_dir("tile", 4), overwrite=True, checksums=True) as tmp:
        (tmp / "data.bin").write_bytes(bytes(range(256)) * 8)
        atomic_write_json(tmp / "summary.json", {"level": "tile", "id": 4, "ok": True})
    store.commit_unit("tile", 4)
    marker = store.remote.read_bytes("tile/4/.complete").decode()
    token = store.remote.commit_token("tile/4")
    assert marker.startswith(f"complete {token}\n") and '"data.bin"' in marker
    fresh = RunStore(store.url)
    import shutil

    shutil.rmtree(fresh.root, ignore_errors=True)
    assert fresh.verify_unit("tile", 4) == []
    store.remote.write_bytes("tile/4/data.bin", bytes(2048))  # bit rot on the bucket (same size)
    shutil.rmtree(fresh.root, ignore_errors=True)
    assert fresh.verify_unit("tile", 4) == ["data.bin: checksum mismatch (sha256 differs from the committed one)"]


def test_a_zarr_store_rewritten_under_the_same_name_is_fetched_again(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 33: a Zarr store's cache token is its content on the bucket, not its root ``zarr.json``: a store
    rewritten with other values and the same ``zarr.json`` (a regrid under the same plan) is fetched again by a
    reader on another node without ``force``; an unchanged one is not downloaded twice."""
    import shutil

    import zarr

    make_bucket("rewrite")
    writer = RunStore("s3://rewrite/run")
    path = writer.root / "dem.zarr"

    def write(value: float) -> bytes:
        shutil.rmtree(path, ignore_errors=True)
        g = zarr.open_group(str(path), mode="w")
        g.create_array("elevation", shape=(4, 4), chunks=(2, 2), dtype="f4")[:] = value
        g.attrs["complete"] = True
        writer.commit_zarr("dem.zarr")
        return (path / "zarr.json").read_bytes()

    first = write(1.0)
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "other-node"))
    reader = RunStore("s3://rewrite/run")
    assert reader.root != writer.root and reader.fetch_zarr("dem.zarr")
    assert (zarr.open_array(str(reader.root / "dem.zarr" / "elevation"), mode="r")[:] == 1.0).all()
    gets: list[object] = []
    real_get = reader.remote.fs.get
    monkeypatch.setattr(reader.remote.fs, "get", lambda *a, **kw: (gets.append(a), real_get(*a, **kw))[1])
    assert reader.fetch_zarr("dem.zarr") and gets == []  # unchanged on the bucket: the cached copy is current
    assert write(2.0) == first  # the same root zarr.json: its hash alone cannot tell the two stores apart
    assert reader.fetch_zarr("dem.zarr") and len(gets) == 1
    assert (zarr.open_array(str(reader.root / "dem.zarr" / "elevation"), mode="r")[:] == 2.0).all()
    # a chunk rewritten on the bucket after the commit (as a bucket run's gridding tasks write theirs)
    chunk = next(k for k in sorted(writer.remote.objects("dem.zarr")) if k.startswith("elevation/c/"))
    zarr.open_array(writer.remote.url_of("dem.zarr/elevation"), mode="r+")[:2, :2] = 3.0
    assert reader.fetch_zarr("dem.zarr") and len(gets) == 2, chunk
    assert zarr.open_array(str(reader.root / "dem.zarr" / "elevation"), mode="r")[0, 0] == 3.0
