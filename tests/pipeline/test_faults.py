"""Faults injected into whole runs of the tiny mission, each compared with the clean run (issue 19 §2).

- a corrupted chunk in a finished unit: named (unit, file, "checksum mismatch"), recomputed, same result;
- a full disk (a small tmpfs mounted here, as root) during matching and during the DEM: a clear
  DiskFullError naming the stage, nothing corrupt left, the resumed run identical once space is freed;
- >= 10 random worker SIGKILLs in one run on a LocalCluster, and a scheduler killed mid-run then
  resumed on a fresh scheduler and workers: identical (slow; ``.ci/run``).

The random choices come from ``MERCURY_DEM_FAULT_SEED`` (default 19; the tests were written on 19
and checked on 5). Figures: docs/benchmarks/faults.md.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.cli import main
from mercury_dem.exceptions import DiskFullError, SchedulerLostError
from mercury_dem.io.atomic import COMPLETE_MARKER, verify_complete
from mercury_dem.io.network_store import read_network
from mercury_dem.io.run_store import LEVELS, RunStore, read_solution
from mercury_dem.pipeline.graph import run_pipeline
from mercury_dem.products.make import open_dem

from .conftest import tiny_config
from .test_execution import _start, assert_same_run

pytestmark = pytest.mark.integration

SEED = int(os.environ.get("MERCURY_DEM_FAULT_SEED", "19"))


def _rng(salt: int) -> np.random.Generator:
    return np.random.default_rng([SEED, salt])


def assert_nothing_corrupt(run: Path, *, temporaries_allowed: bool = False) -> int:
    """No temporary sibling left; every unit directory committed and matching its checksums. Returns the units.

    ``temporaries_allowed``: right after a process was killed mid-write, its ``.NAME.tmp-*`` siblings may remain
    (a SIGKILL runs no clean-up); they are never read as units, and the next run sweeps them
    (``io.atomic.sweep_temporaries``), which the strict check after the resume confirms."""
    leftovers = [str(p.relative_to(run)) for p in run.rglob("*") if ".tmp-" in p.name]
    if not temporaries_allowed:
        assert leftovers == [], leftovers[:10]
    n = 0
    for level in LEVELS:
        for unit in sorted((run / level).iterdir()) if (run / level).exists() else ():
            if temporaries_allowed and ".tmp-" in unit.name:
                continue
            assert (unit / COMPLETE_MARKER).is_file(), f"{unit} has no completion marker"
            assert verify_complete(unit) == [], unit
            n += 1
    return n


def assert_same_dem(a: Path, b: Path) -> None:
    x = open_dem(a / "dem.zarr")["elevation"].values
    y = open_dem(b / "dem.zarr")["elevation"].values
    assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True)


def _flip_one_bit(path: Path, rng: np.random.Generator) -> int:
    data = bytearray(path.read_bytes())
    k = int(rng.integers(len(data)))
    data[k] ^= 1 << int(rng.integers(8))
    path.write_bytes(bytes(data))
    return k


# ------------------------------------------------------------------------------------------ corrupted chunk
@pytest.mark.timeout(900)  # the session's clean run (sync_run) may be built by this test
def test_a_corrupted_chunk_is_named_recomputed_and_the_run_goes_on(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    ref, _ = sync_run
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    rng = _rng(1)
    # one bit of a network chunk of a matched tile, one bit of a region's adjusted pointing
    tiles = [int(p.parent.name) for p in sorted((run / "tile").glob("*/network.zarr"))]
    tile = tiles[int(rng.integers(len(tiles)))]
    chunks = sorted(p for p in (run / "tile" / str(tile) / "network.zarr").rglob("*")
                    if p.is_file() and "/c/" in p.as_posix())
    chunk = chunks[int(rng.integers(len(chunks)))]
    _flip_one_bit(chunk, rng)
    regions = sorted(int(p.parent.name) for p in (run / "region").glob("*/solution.parquet"))
    region = regions[int(rng.integers(len(regions)))]
    _flip_one_bit(run / "region" / str(region) / "solution.parquet", rng)
    chunk_rel = chunk.relative_to(run / "tile" / str(tile)).as_posix()

    assert main(["verify", str(run)]) == 1
    said = capsys.readouterr().out
    assert f"CORRUPT tile {tile} (tile/{tile})" in said and f"{chunk_rel}: checksum mismatch" in said, said
    assert "solution.parquet: checksum mismatch" in said and "2 corrupt" in said, said

    log = io.StringIO()
    report = run_pipeline(tiny_mission_path, run, tiny_config(), scheduler="sync", stream=log, dem=False)
    corrupt = {(c["level"], c["id"]): c for c in report["integrity"]["corrupt"]}
    assert set(corrupt) == {("tile", tile), ("region", region)}, corrupt
    assert corrupt[("tile", tile)]["problems"] == [f"{chunk_rel}: checksum mismatch (sha256 differs from the "
                                                   "committed one)"]
    assert f"tile {tile}: checksum verification failed ({chunk_rel}: checksum mismatch" in log.getvalue()
    assert report["integrity"]["verified_units"] == assert_nothing_corrupt(run)
    # recomputed as the clean run computed them: the tile's network, the region's pointing, the globe
    a = read_network(RunStore(ref).network_path("tile", tile))
    b = read_network(RunStore(run).network_path("tile", tile))
    assert np.array_equal(a.sample, b.sample) and np.array_equal(a.line, b.line)
    assert np.array_equal(a.point_ids, b.point_ids) and np.array_equal(a.apriori_xyz, b.apriori_xyz, equal_nan=True)
    ids_a, rot_a, pos_a, _ = read_solution(RunStore(ref).solution_path("region", region))
    ids_b, rot_b, pos_b, _ = read_solution(RunStore(run).solution_path("region", region))
    assert (ids_a == ids_b).all() and np.array_equal(rot_a, rot_b) and np.array_equal(pos_a, pos_b)
    assert_same_run(ref, run)
    assert main(["verify", str(run)]) == 0


# ------------------------------------------------------------------------------------------ full disk
@contextlib.contextmanager
def tmpfs(where: Path, size_kb: int) -> Iterator[Path]:
    """A tmpfs of ``size_kb`` mounted at ``where`` (root only; skips otherwise), unmounted on exit."""
    where.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {r.stderr.strip() or r.returncode}")
    try:
        yield where
    finally:
        if subprocess.run(["umount", str(where)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(where)], capture_output=True)


def resize(where: Path, size_kb: int) -> None:
    """Grow (or shrink, not below what is used) the tmpfs at ``where``: space freed or taken."""
    subprocess.run(["mount", "-o", f"remount,size={size_kb}k", str(where)], check=True, capture_output=True)


def used_kb(where: Path) -> int:
    return shutil.disk_usage(where).used // 1024


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_full_disk_during_matching_and_during_the_dem_stops_cleanly_and_resumes_identically(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    ref, _ = sync_run
    cfg = tiny_config()
    with tmpfs(tmp_path / "fs", 1024) as fs:
        run = fs / "run"
        # 1. a 1 MiB file system: the plan fits, the tiles (~0.4 MB each) fill it
        with pytest.raises(DiskFullError) as err:
            run_pipeline(tiny_mission_path, run, cfg, scheduler="sync", stream=None)
        msg = str(err.value)
        assert msg.startswith("tile ") and "no space left on device" in msg and "resume" in msg, msg
        done_a = assert_nothing_corrupt(run)
        assert 0 < done_a < 14 and not (run / "dem.zarr").exists()
        # space freed: the cascade finishes
        resize(fs, 64 * 1024)
        report = run_pipeline(tiny_mission_path, run, cfg, scheduler="sync", stream=None, dem=False)
        assert report["levels"]["global"]["ok"] and report["integrity"]["verified_units"] == done_a
        # 2. the DEM stage on a disk with ~300 kB left (dem.zarr alone is ~0.7 MB)
        resize(fs, used_kb(fs) + 300)
        with pytest.raises(DiskFullError) as err:
            run_pipeline(tiny_mission_path, run, cfg, scheduler="sync", stream=None)
        msg = str(err.value)
        assert msg.startswith("the DEM stage") and "no space left on device" in msg, msg
        assert not (run / "dem.zarr").exists()  # nothing half-written trusted
        assert_nothing_corrupt(run)
        resize(fs, 64 * 1024)
        report = run_pipeline(tiny_mission_path, run, cfg, scheduler="sync", stream=None)
        assert report["levels"]["global"]["ok"] and not report["integrity"]["corrupt"]
        assert_nothing_corrupt(run)
        assert_same_run(ref, run)
        assert_same_dem(ref, run)
        shutil.copy(run / "report.json", tmp_path / "report.json")


# ------------------------------------------------------------------------------------------ killed workers
KILLS = 10
MAX_KILLS, TILE_KILLS = 14, 9  # at most 9 during matching: the rest wait for adjustments to hit


def _same_levels(ref: Path, report: dict[str, Any]) -> None:
    """Every unit ended as in the clean run (the same tiles failed for the same reasons, the rest ok)."""
    clean = json.loads((ref / "report.json").read_text())
    assert report["tiles"]["failed"] == clean["tiles"]["failed"]
    for level in ("region", "hemisphere"):
        assert [(r["id"], r["ok"]) for r in report["levels"][level]] == \
            [(r["id"], r["ok"]) for r in clean["levels"][level]]
    assert report["levels"]["global"]["ok"]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_ten_random_worker_kills_in_one_run_lose_nothing(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    """SIGKILL a worker process (LocalCluster, nanny-restarted) >= 10 times during matching and the
    adjustments, each time one that is running a unit: the run finishes, equal to the clean run."""
    import dask
    from distributed import Client, LocalCluster

    from mercury_dem.compute import ADJUST_RESOURCE, Connection

    ref, _ = sync_run
    # a unit may lose its worker several times: let the scheduler retry it (default 3 deaths per task)
    with dask.config.set({"distributed.scheduler.allowed-failures": 50}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=":0",
                               resources={ADJUST_RESOURCE: 1}, processes=True)
    client = Client(cluster)
    conn = Connection(client, "local", cluster=cluster, uses_resources=True, description="test cluster")
    out = tmp_path / "killed"
    rng = _rng(2)
    kills: list[dict[str, Any]] = []
    stop = threading.Event()

    pid_of: dict[str, Any] = {}

    def worker_pids() -> dict[str, int]:
        """Address -> pid of the workers running and registered with the scheduler. Never one a nanny is
        still starting: killing a worker before it registers makes its nanny give up (no real fault does
        that alone, and the cluster would be left without workers). A new worker's pid is asked once."""
        info = client.scheduler_info(n_workers=-1).get("workers", {})
        live = [a for a, w in info.items() if w.get("status") == "running"]
        new = [a for a in live if a not in pid_of]
        if new:
            pid_of.update(client.run(os.getpid, workers=new, on_error="return"))
        out_: dict[str, int] = {}
        for addr in live:
            pid = pid_of.get(addr)
            if isinstance(pid, int):
                try:
                    os.kill(pid, 0)
                    out_[addr] = pid
                except ProcessLookupError:
                    pid_of.pop(addr, None)
        return out_

    replaced: list[float] = []

    missing_since: dict[str, float] = {}

    def replace_lost_workers() -> None:
        """What an adaptive cluster or a job array does: a worker that stays gone is replaced. On this loaded
        machine a nanny sometimes gives up after its worker was killed (its new worker registered under the
        name of the dead one before the scheduler removed it, and was refused). Counted in the figures."""
        from distributed.core import Status

        registered = {str(w.get("name")) for w in client.scheduler_info(n_workers=-1).get("workers", {}).values()}
        now = time.monotonic()
        lost = []
        for n, w in list(cluster.workers.items()):
            gone = getattr(w, "status", None) in (Status.closed, Status.closing, Status.failed) \
                or str(n) not in registered
            if not gone:
                missing_since.pop(str(n), None)
            elif now - missing_since.setdefault(str(n), now) > 20:  # a restart takes ~1-5 s
                lost.append(n)
        for n in lost:
            cluster.worker_spec.pop(n, None)
            missing_since.pop(str(n), None)
            replaced.append(round(now - t0, 1))
        if lost:
            cluster.scale(2)

    def killer() -> None:
        # the first kills hit workers matching tiles; any adjustment seen running is hit at once
        while not stop.is_set() and not (out / "global" / "0" / COMPLETE_MARKER).exists():
            with contextlib.suppress(Exception):
                replace_lost_workers()
            if len(kills) >= MAX_KILLS:
                stop.wait(0.5)
                continue
            try:
                running = client.processing()
                pids = worker_pids()
            except Exception:  # noqa: BLE001 - a worker went away while asked: look again
                stop.wait(0.1)
                continue
            adjusting = {w: k for w, ks in running.items() for k in ks
                         if str(k).split("-")[0] in ("region", "hemisphere", "global") and w in pids}
            matching = {w: k for w, ks in running.items() for k in ks if str(k).startswith("tile-") and w in pids}
            pool = adjusting or (matching if sum(k["unit"].startswith("tile") for k in kills) < TILE_KILLS else {})
            if not pool:
                stop.wait(0.1)
                continue
            w = sorted(pool)[int(rng.integers(len(pool)))]
            with contextlib.suppress(ProcessLookupError):
                os.kill(pids[w], signal.SIGKILL)
                kills.append({"unit": str(pool[w]), "after_s": round(time.monotonic() - t0, 1)})
            # a random pause (the nanny brings a new worker up in ~1-3 s) before the next kill
            stop.wait(float(rng.uniform(1.5, 4.0)))

    t0 = time.monotonic()
    t = threading.Thread(target=killer, daemon=True)
    t.start()
    result: dict[str, Any] = {}

    def go() -> None:
        try:
            result["report"] = run_pipeline(tiny_mission_path, out, tiny_config(), connection=conn, stream=None,
                                            dem=False)
        except BaseException as exc:  # noqa: BLE001 - re-raised below
            result["error"] = exc

    runner = threading.Thread(target=go, daemon=True)
    runner.start()
    try:
        runner.join(timeout=900)  # a cluster left without workers would wait for ever: fail instead
        assert not runner.is_alive(), f"the run did not finish in 15 min; kills: {kills}"
    finally:
        stop.set()
        t.join(timeout=60)
        conn.close()
    if "error" in result:
        raise result["error"]
    report = result["report"]
    seconds = time.monotonic() - t0
    print(f"{len(kills)} worker SIGKILLs in {seconds:.0f} s, {len(replaced)} lost workers replaced at {replaced}: "
          f"{kills}")
    (tmp_path / "kills.json").write_text(json.dumps({"kills": kills, "seconds": seconds, "replaced": replaced}))
    assert len(kills) >= KILLS, kills
    assert any(k["unit"].startswith("tile") for k in kills) and \
        any(not k["unit"].startswith("tile") for k in kills), kills
    _same_levels(ref, report)
    # a worker SIGKILLed while it wrote a unit leaves that unit's temporary sibling (never read; the unit was
    # recomputed elsewhere, and the next run of the store sweeps it)
    assert_nothing_corrupt(out, temporaries_allowed=True)
    assert_same_run(ref, out)  # the global pointing to 1e-12 rad, the same points and measures


# ------------------------------------------------------------------------------------------ scheduler restart
def _dask_cluster(tmp_path: Path, name: str, procs: list[subprocess.Popen[bytes]]) -> Path:
    """`dask scheduler` + two nanny `dask worker` processes on 127.0.0.1 (appended to ``procs``); the scheduler file."""
    from distributed import Client

    dask_exe = str(Path(sys.executable).with_name("dask"))
    sched_file = tmp_path / f"{name}-scheduler.json"
    procs.append(_start([dask_exe, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                         "127.0.0.1:0", "--scheduler-file", str(sched_file)], tmp_path / f"{name}-scheduler.log"))
    for _ in range(300):
        if sched_file.exists() and sched_file.stat().st_size > 0:
            break
        time.sleep(0.1)
    for k in range(2):
        procs.append(_start([dask_exe, "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                             "--host", "127.0.0.1", "--resources", "adjust_slots=1", "--no-dashboard"],
                            tmp_path / f"{name}-worker{k}.log"))
    with Client(scheduler_file=str(sched_file), timeout=30) as c:
        c.wait_for_workers(2, timeout=90)
    return sched_file


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_scheduler_killed_mid_run_then_resumed_on_a_fresh_one_gives_the_clean_result(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    ref, _ = sync_run
    out = tmp_path / "run"
    rng = _rng(3)
    procs: list[subprocess.Popen[bytes]] = []
    result: dict[str, Any] = {}
    try:
        first = _dask_cluster(tmp_path, "first", procs)

        def go() -> None:
            try:
                result["report"] = run_pipeline(tiny_mission_path, out, tiny_config(), scheduler_file=str(first),
                                                stream=None, dem=False)
            except BaseException as exc:  # noqa: BLE001 - inspected below
                result["error"] = exc

        th = threading.Thread(target=go, daemon=True)
        th.start()
        target = int(rng.integers(2, 8))  # tiles finished before the scheduler dies
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and th.is_alive():
            if sum(1 for _ in (out / "tile").glob(f"*/{COMPLETE_MARKER}")) >= target:
                break
            time.sleep(0.05)
        assert th.is_alive(), f"the run ended before the scheduler could be killed: {result}"
        os.killpg(procs[0].pid, signal.SIGKILL)
        procs[0].wait()
        killed_after = sum(1 for _ in (out / "tile").glob(f"*/{COMPLETE_MARKER}"))
        th.join(timeout=240)
        assert not th.is_alive(), "the run hung after losing its scheduler"
        _stop(procs)
        procs.clear()
        print(f"scheduler SIGKILLed after {killed_after} tiles; the run ended with {result!r:.300}")
        err = result.get("error")
        assert isinstance(err, SchedulerLostError), result
        assert "lost the Dask scheduler" in str(err) and "run the same command to resume" in str(err)
        # a worker may have been writing a unit when the scheduler died (its temporary stays until the resume)
        assert_nothing_corrupt(out, temporaries_allowed=True)
        second = _dask_cluster(tmp_path, "second", procs)
        report = run_pipeline(tiny_mission_path, out, tiny_config(), scheduler_file=str(second), stream=None,
                              dem=False)
    finally:
        _stop(procs)
    _same_levels(ref, report)
    assert report["integrity"]["verified_units"] >= killed_after
    assert_nothing_corrupt(out)
    assert_same_run(ref, out)
