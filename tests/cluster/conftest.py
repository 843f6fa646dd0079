"""Shared helpers of the cluster/ tests: paths, running the launch scripts, watching process trees."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import psutil
import pytest

from tests.process_guard import run_in_own_group

REPO = Path(__file__).resolve().parents[2]
CLUSTER = REPO / "cluster"
LOCAL = CLUSTER / "local"


def script_env(**extra: str) -> dict[str, str]:
    """Environment for the launch scripts: this interpreter, no inherited Dask/TLS settings."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    env["PYTHON"] = sys.executable
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.update(extra)
    return env


def make_certs(directory: Path, hosts: str = "127.0.0.1,localhost") -> Path:
    subprocess.run([str(LOCAL / "make-certs.sh"), str(directory), "--hosts", hosts, "--days", "2"],
                   check=True, capture_output=True, text=True, timeout=60)
    return directory


@dataclass
class LocalDeployment:
    """What ``cluster/local/start.sh`` started: its state directory and every process (leaders and children)."""

    state: Path
    leaders: dict[str, int]
    processes: list[psutil.Process]

    @property
    def scheduler_file(self) -> Path:
        return self.state / "scheduler.json"

    @property
    def address(self) -> str:
        return json.loads(self.scheduler_file.read_text())["address"]

    def stop(self) -> subprocess.CompletedProcess[str]:
        return run_in_own_group([str(LOCAL / "stop.sh"), "--state-dir", str(self.state), "--timeout", "20"],
                                timeout=120, env=script_env())


def start_local(state: Path, workers: int = 2, tls: bool = False, idle_timeout: int = 900) -> LocalDeployment:
    cmd = [str(LOCAL / "start.sh"), "--state-dir", str(state), "--workers", str(workers), "--threads", "1",
           "--port", "0", "--dashboard-port", "0", "--memory-limit", "1GiB", "--timeout", "60",
           # a killed pytest runs no teardown: the deployment then ends itself
           "--idle-timeout", str(idle_timeout)]
    if tls:
        cmd.append("--tls")
    try:
        # start.sh's own helpers die with it on a timeout (its scheduler and workers are setsid'd: stop.sh's)
        res = run_in_own_group(cmd, timeout=180, env=script_env())
    except BaseException:
        if (state / "pids").is_dir():
            LocalDeployment(state, {}, []).stop()
        raise
    leaders = {p.stem: int(p.read_text()) for p in sorted((state / "pids").glob("*.pid"))}
    procs: list[psutil.Process] = []
    for pid in leaders.values():
        try:
            p = psutil.Process(pid)
            procs += [p, *p.children(recursive=True)]
        except psutil.NoSuchProcess:
            pass
    dep = LocalDeployment(state, leaders, procs)
    if res.returncode != 0:
        dep.stop()
        raise AssertionError(f"start.sh failed ({res.returncode}):\n{res.stdout}\n{res.stderr}")
    return dep


def alive(procs: list[psutil.Process]) -> list[psutil.Process]:
    """Processes of ``procs`` still running (a zombie, already exited, counts as gone)."""
    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def listening_addresses(procs: list[psutil.Process]) -> list[tuple[int, str, int]]:
    """(pid, ip, port) of every listening TCP socket of ``procs``."""
    out = []
    for p in procs:
        try:
            conns = p.net_connections(kind="inet")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        out += [(p.pid, c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN]
    return out


def refused(connect: Callable[[], object], reason: str) -> None:
    """``connect`` fails with an OSError whose message matches ``reason``, well before its timeout
    (so a slow machine's timeout cannot pass for a refusal)."""
    t0 = time.monotonic()
    with pytest.raises(OSError, match=reason):
        connect()
    assert time.monotonic() - t0 < 5.0


@pytest.fixture
def local_deployment(tmp_path: Path) -> Iterator[LocalDeployment]:
    """A plain-TCP scheduler and two workers from start.sh; stopped (and checked gone) afterwards."""
    dep = start_local(tmp_path / "dask", workers=2)
    try:
        yield dep
    finally:
        dep.stop()
