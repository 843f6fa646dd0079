"""The same run on every execution mode: in-process, LocalCluster, a real dask scheduler with workers.

Serial == distributed: the global solution and network are identical. Also: a
worker killed mid-run does not lose the run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.io.network_store import read_network
from mercury_dem.io.run_store import RunStore
from mercury_dem.pipeline.graph import run_pipeline

from .conftest import tiny_config
from .test_run import global_solution


def assert_same_run(a: Path, b: Path) -> None:
    ids_a, rot_a = global_solution(a)
    ids_b, rot_b = global_solution(b)
    assert (ids_a == ids_b).all()
    assert np.allclose(rot_a, rot_b, rtol=0, atol=1e-12)
    na = read_network(RunStore(a).network_path("global", 0))
    nb = read_network(RunStore(b).network_path("global", 0))
    assert na.n_points == nb.n_points and na.n_measures == nb.n_measures


def test_local_cluster_gives_the_sync_result(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
                                             tmp_path: Path) -> None:
    run, _ = sync_run
    out = tmp_path / "local"
    report = run_pipeline(tiny_mission_path, out, tiny_config(), scheduler="local", workers=2,
                          threads_per_worker=1, stream=None, dem=False)
    assert report["execution"]["mode"] == "local"
    assert "127.0.0.1" in report["execution"]["description"]
    assert (out / "performance.html").is_file()
    assert_same_run(run, out)


def _start(cmd: list[str], log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as fh:  # the child keeps its own descriptor
        return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)


@pytest.mark.slow
def test_real_dask_scheduler_and_workers(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
                                         tmp_path: Path) -> None:
    """`dask scheduler` + two `dask worker` processes on 127.0.0.1, submitted to by scheduler file."""
    run, _ = sync_run
    dask = str(Path(sys.executable).with_name("dask"))
    sched_file = tmp_path / "scheduler.json"
    procs = [_start([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", "127.0.0.1:0",
                     "--scheduler-file", str(sched_file)], tmp_path / "scheduler.log")]
    try:
        for _ in range(200):
            if sched_file.exists() and sched_file.stat().st_size > 0:
                break
            time.sleep(0.1)
        for k in range(2):
            procs.append(_start([dask, "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                                 "--host", "127.0.0.1", "--resources", "adjust_slots=1", "--no-dashboard"],
                                tmp_path / f"worker{k}.log"))
        from distributed import Client

        with Client(scheduler_file=str(sched_file), timeout=30) as c:
            c.wait_for_workers(2, timeout=60)
        out = tmp_path / "cluster"
        report = run_pipeline(tiny_mission_path, out, tiny_config(), scheduler_file=str(sched_file),
                              stream=None, dem=False)
        assert report["execution"]["mode"] == "scheduler-file"
        assert_same_run(run, out)
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert all(p.poll() is not None for p in procs)


@pytest.mark.slow
def test_a_worker_killed_mid_run_loses_nothing(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
                                              tmp_path: Path) -> None:
    from distributed import Client, LocalCluster

    from mercury_dem.compute import ADJUST_RESOURCE, Connection

    run, _ = sync_run
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=":0",
                           resources={ADJUST_RESOURCE: 1}, processes=True)
    client = Client(cluster)
    conn = Connection(client, "local", cluster=cluster, uses_resources=True, description="test cluster")
    out = tmp_path / "killed"
    killed: list[int] = []

    def kill_one_worker() -> None:
        # wait until the first tile unit is written, then SIGKILL one worker process
        for _ in range(600):
            if any((out / "tile").glob("*/.complete")):
                break
            time.sleep(0.05)
        pids = client.run(os.getpid)
        pid = sorted(pids.values())[0]
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    t = threading.Thread(target=kill_one_worker, daemon=True)
    t.start()
    try:
        report = run_pipeline(tiny_mission_path, out, tiny_config(), connection=conn, stream=None, dem=False)
    finally:
        t.join(timeout=60)
        conn.close()
    assert killed, "a worker was killed during the run"
    assert report["levels"]["global"]["ok"]
    assert_same_run(run, out)
