"""A cluster that cannot hang (issue 33 item 4): a run that has had no worker for
``execution.no_worker_timeout_s`` ends with :class:`NoWorkerError`, recorded as the run's infrastructure
failure (``run.json``), never as a unit's; the store stays resumable and the same command finishes it
equal to a clean run.

- fast: a scheduler that never had a worker, through the CLI (exit code 2, the message on stderr);
- slow (``.ci/run``): every worker of a LocalCluster killed mid-run (their nannies gave up), and every
  ``dask worker`` (nanny and worker processes) of a ``dask scheduler`` cluster killed mid-run; each resumed.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from mercury_dem.cli import main
from mercury_dem.exceptions import NoWorkerError
from mercury_dem.io.run_store import LEVELS, RunStore
from mercury_dem.pipeline.graph import run_pipeline

from .conftest import tiny_config
from .test_execution import _start, assert_same_run
from .test_faults import assert_nothing_corrupt

pytestmark = pytest.mark.integration

TIMEOUT_S = 3.0
#: What the watchdog may take beyond the timeout: its poll (0.3 s here), the scheduler noticing the dead
#: workers, the cancelled futures reaching the loop, a loaded 2-core machine.
SLACK_S = 12.0


def _config() -> Any:
    return tiny_config(execution={"no_worker_timeout_s": TIMEOUT_S})


def _assert_infrastructure_failure(out: Path, exc: NoWorkerError, scheduler: str) -> None:
    msg = str(exc)
    assert "no worker since" in msg and scheduler in msg and "run the same command" in msg, msg
    failure = json.loads((out / "run.json").read_text())["infrastructure_failure"]
    assert failure["kind"] == "infrastructure" and failure["error"] == "NoWorkerError", failure
    assert failure["scheduler"] == scheduler and failure["no_worker_timeout_s"] == TIMEOUT_S
    assert "no_worker_since" in failure
    store = RunStore(out)
    for level in LEVELS:  # every committed unit is a real result: none was written as a failure for want of a worker
        for uid in store.completed_units(level):
            err = store.read_summary(level, uid).get("error") or ""
            assert "ancel" not in err and "worker" not in err, (level, uid, err)


def test_a_scheduler_without_any_worker_ends_the_run_with_the_named_error(tiny_mission_path: Path,
                                                                         tmp_path: Path) -> None:
    from distributed import LocalCluster

    out = tmp_path / "run"
    cfg = tmp_path / "config.yaml"
    cfg.write_text(f"execution:\n  no_worker_timeout_s: {TIMEOUT_S}\n")
    with LocalCluster(n_workers=0, processes=False, dashboard_address="127.0.0.1:0") as cluster:
        err = io.StringIO()
        t0 = time.monotonic()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["run", str(tiny_mission_path), "--out", str(out), "--config", str(cfg),
                         "--scheduler", cluster.scheduler_address])
        elapsed = time.monotonic() - t0
        assert code == 2
        assert "NoWorkerError" in err.getvalue() or "no worker since" in err.getvalue(), err.getvalue()
        assert cluster.scheduler_address in err.getvalue()
        failure = json.loads((out / "run.json").read_text())["infrastructure_failure"]
        assert failure["error"] == "NoWorkerError"
    assert not (out / "report.json").exists()  # not a finished run
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["report", str(out)]) == 2
    assert "it stopped: NoWorkerError" in err.getvalue(), err.getvalue()
    assert not any((out / "tile").glob("*/summary.json")) if (out / "tile").exists() else True
    assert elapsed < 120, elapsed  # the plan, then the timeout: never a hang


def _kill_all_when_a_tile_is_done(out: Path, kill: Any, killed_at: list[float]) -> threading.Thread:
    def run() -> None:
        for _ in range(6000):
            if any((out / "tile").glob("*/.complete")):
                break
            time.sleep(0.05)
        kill()
        killed_at.append(time.monotonic())

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


@pytest.mark.slow
def test_every_local_cluster_worker_killed_mid_run_ends_in_time_and_resumes_to_the_clean_result(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    from distributed import Client

    from mercury_dem.compute import ADJUST_RESOURCE, Connection, local_cluster

    ref, _ = sync_run
    out = tmp_path / "killed"
    cluster = local_cluster(2, 1, resources={ADJUST_RESOURCE: 1})
    client = Client(cluster)
    conn = Connection(client, "local", cluster=cluster, uses_resources=True, description="test cluster")
    killed_at: list[float] = []

    def kill_every_worker() -> None:
        pids = client.run(os.getpid)
        for nanny in list(cluster.workers.values()):
            nanny.close_gracefully()  # the nannies give up: a killed worker is not restarted
        for pid in pids.values():
            os.kill(pid, signal.SIGKILL)

    t = _kill_all_when_a_tile_is_done(out, kill_every_worker, killed_at)
    try:
        with pytest.raises(NoWorkerError) as info:
            run_pipeline(tiny_mission_path, out, _config(), connection=conn, stream=None, dem=False)
        ended = time.monotonic()
        t.join(timeout=60)
        assert killed_at, "the workers were killed during the run"
        print(f"the run ended {ended - killed_at[0]:.1f} s after its last worker was killed (timeout {TIMEOUT_S} s)")
        assert ended - killed_at[0] < TIMEOUT_S + SLACK_S, ended - killed_at[0]
        assert ended - killed_at[0] >= TIMEOUT_S - 0.5
        _assert_infrastructure_failure(out, info.value, cluster.scheduler_address)
    finally:
        conn.close()
    assert_nothing_corrupt(out, temporaries_allowed=True)
    report = run_pipeline(tiny_mission_path, out, _config(), scheduler="local", workers=2, threads_per_worker=1,
                          stream=None, dem=False)  # the same command on a fresh cluster
    assert report["levels"]["global"]["ok"]
    assert "infrastructure_failure" not in json.loads((out / "run.json").read_text())
    assert_nothing_corrupt(out)
    assert_same_run(ref, out)


@pytest.mark.slow
def test_every_dask_worker_killed_mid_run_ends_in_time_and_resumes_to_the_clean_result(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    from .test_faults import _dask_cluster, _stop

    ref, _ = sync_run
    out = tmp_path / "killed"
    procs: list[subprocess.Popen[bytes]] = []
    killed_at: list[float] = []
    try:
        sched_file = _dask_cluster(tmp_path, "a", procs)
        scheduler = json.loads(sched_file.read_text())["address"]
        workers = procs[1:]

        def kill_every_worker() -> None:
            for p in workers:  # nanny and worker: the whole process group of each `dask worker`
                os.killpg(p.pid, signal.SIGKILL)

        t = _kill_all_when_a_tile_is_done(out, kill_every_worker, killed_at)
        with pytest.raises(NoWorkerError) as info:
            run_pipeline(tiny_mission_path, out, _config(), scheduler_file=str(sched_file), stream=None, dem=False)
        ended = time.monotonic()
        t.join(timeout=60)
        for p in workers:
            p.wait(timeout=30)
        assert killed_at, "the workers were killed during the run"
        print(f"the run ended {ended - killed_at[0]:.1f} s after its last worker was killed (timeout {TIMEOUT_S} s)")
        assert ended - killed_at[0] < TIMEOUT_S + SLACK_S, ended - killed_at[0]
        assert ended - killed_at[0] >= TIMEOUT_S - 0.5
        _assert_infrastructure_failure(out, info.value, scheduler)
        assert_nothing_corrupt(out, temporaries_allowed=True)
        # workers again on the same scheduler, and the same command
        dask_exe = str(Path(sys.executable).with_name("dask"))
        for k in range(2):
            procs.append(_start([dask_exe, "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                                 "--host", "127.0.0.1", "--resources", "adjust_slots=1", "--no-dashboard"],
                                tmp_path / f"again-worker{k}.log"))
        from distributed import Client

        with Client(scheduler_file=str(sched_file), timeout=30) as c:
            c.wait_for_workers(2, timeout=90)  # else the resumed run would start without a worker
        report = run_pipeline(tiny_mission_path, out, _config(), scheduler_file=str(sched_file), stream=None,
                              dem=False)
    finally:
        _stop(procs)
    assert report["levels"]["global"]["ok"]
    assert "infrastructure_failure" not in json.loads((out / "run.json").read_text())
    assert_nothing_corrupt(out)
    assert_same_run(ref, out)
