"""cluster/local/: start.sh starts a real scheduler and workers on 127.0.0.1, stop.sh stops every process."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

from distributed import Client

from mercury_dem.compute import ADJUST_RESOURCE
from tests.cluster.conftest import (
    LOCAL,
    REPO,
    LocalDeployment,
    alive,
    listening_addresses,
    refused,
    script_env,
    start_local,
)


def _square(x: int) -> int:
    return x * x


def test_start_compute_stop(local_deployment: LocalDeployment) -> None:
    dep = local_deployment
    assert set(dep.leaders) == {"scheduler", "worker-1", "worker-2"}
    # Leaders plus at least one child per worker (the nanny's worker process).
    assert len(dep.processes) >= 5
    with Client(scheduler_file=str(dep.scheduler_file), timeout=20) as client:
        info = client.scheduler_info(n_workers=-1)
        assert info["address"].startswith("tcp://127.0.0.1:")
        workers = info["workers"]
        assert len(workers) == 2
        for addr, w in workers.items():
            assert addr.startswith("tcp://127.0.0.1:"), addr
            assert w["resources"] == {ADJUST_RESOURCE: 1}  # the resource the pipeline asks for
            assert w["nthreads"] == 1
        assert client.dashboard_link.startswith("http://127.0.0.1:")
        # A small computation, with and without the adjustment resource.
        futures = client.map(_square, range(20))
        assert sum(client.gather(futures)) == sum(i * i for i in range(20))
        constrained = [client.submit(_square, i, resources={ADJUST_RESOURCE: 1}, pure=False) for i in range(4)]
        assert client.gather(constrained) == [0, 1, 4, 9]
    # The scheduler file names the loopback address and a dashboard.
    sched = json.loads(dep.scheduler_file.read_text())
    assert sched["address"].startswith("tcp://127.0.0.1:") and "dashboard" in sched["services"]
    # A second start on the same state directory is refused, and leaves the running one alone.
    again = subprocess.run([str(LOCAL / "start.sh"), "--state-dir", str(dep.state), "--port", "0"],
                           capture_output=True, text=True, timeout=60, env=script_env())
    assert again.returncode != 0 and "already has a running process" in again.stderr
    assert len(alive(dep.processes)) == len(dep.processes)
    # Nothing the scripts started listens beyond the loopback interface.
    socks = listening_addresses(dep.processes)
    assert socks, "no listening sockets found"
    assert {ip for _, ip, _ in socks} == {"127.0.0.1"}, socks

    res = dep.stop()
    assert res.returncode == 0, res.stderr
    deadline = time.monotonic() + 10
    while alive(dep.processes) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert alive(dep.processes) == [], [p.pid for p in alive(dep.processes)]
    assert list((dep.state / "pids").glob("*.pid")) == []
    assert not dep.scheduler_file.exists()


def test_stop_skips_a_stale_pid_that_is_not_dask(tmp_path: Path) -> None:
    """A PID file pointing at an unrelated live process (here: this test) must not be signalled."""
    import os

    pids = tmp_path / "pids"
    pids.mkdir()
    (pids / "worker-1.pid").write_text(str(os.getpid()))
    res = subprocess.run([str(LOCAL / "stop.sh"), "--state-dir", str(tmp_path)], capture_output=True, text=True,
                         timeout=60, env=script_env())
    assert res.returncode == 0, res.stderr
    assert not (pids / "worker-1.pid").exists()


def test_idle_timeout_ends_a_deployment_whose_caller_is_gone(tmp_path: Path) -> None:
    """A deployment started with ``--idle-timeout`` ends by itself when nobody uses it (as after a killed
    pytest, which runs no teardown): the scheduler closes, then its workers after their death timeout."""
    dep = start_local(tmp_path / "dask", workers=1, idle_timeout=2)
    try:
        scheduler = [p for p in dep.processes if p.pid == dep.leaders["scheduler"]]
        deadline = time.monotonic() + 30
        while alive(scheduler) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert alive(scheduler) == [], "the idle scheduler did not close"
        assert "idle" in (dep.state / "logs" / "scheduler.log").read_text()
    finally:
        dep.stop()
    bad = subprocess.run([str(LOCAL / "start.sh"), "--state-dir", str(tmp_path / "bad"), "--idle-timeout", "soon"],
                         capture_output=True, text=True, timeout=60, env=script_env())
    assert bad.returncode == 2 and "--idle-timeout must be a positive number of seconds, got soon" in bad.stderr


def test_tls_deployment_refuses_plain_tcp_and_foreign_certificates(tmp_path: Path) -> None:
    from distributed.security import Security

    from mercury_dem.compute.security import TlsFiles, tls_environment, tls_security
    from tests.cluster.conftest import make_certs

    dep = start_local(tmp_path / "dask", workers=1, tls=True)
    try:
        address = dep.address
        assert address.startswith("tls://127.0.0.1:")
        # 1. plain TCP to the TLS port: the scheduler drops the connection.
        refused(lambda: Client(address.replace("tls://", "tcp://"), timeout=10), "reset|closed")
        # 2. TLS with a certificate from another CA: refused during the handshake.
        other = TlsFiles.in_directory(make_certs(tmp_path / "other-ca"))
        refused(lambda: Client(address, security=tls_security(other), timeout=10), "certificate")
        # 3. The deployment's own certificates: accepted, and the work runs on the TLS worker.
        own = TlsFiles.in_directory(dep.state / "tls")
        with Client(address, security=tls_security(own), timeout=20) as client:
            assert client.submit(_square, 7).result() == 49
            (w,) = client.scheduler_info(n_workers=-1)["workers"]
            assert w.startswith("tls://127.0.0.1:")
        # env.sh names the same files that tls_environment() would export.
        env_sh = (dep.state / "env.sh").read_text()
        for key, value in tls_environment(own).items():
            if "SCHEDULER" in key or "WORKER" in key:
                continue
            assert f'{key}="{value}"' in env_sh or f"{key}={value}" in env_sh, key
        assert isinstance(tls_security(own), Security)
        assert {ip for _, ip, _ in listening_addresses(dep.processes)} == {"127.0.0.1"}
    finally:
        res = dep.stop()
    assert res.returncode == 0, res.stderr
    deadline = time.monotonic() + 10
    while alive(dep.processes) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert alive(dep.processes) == []


_CONNECT_FROM_CONFIG = """
import sys
from mercury_dem.config import load_config
from mercury_dem.compute import connect
conn = connect(load_config(sys.argv[1]).execution)
try:
    print(conn.mode, conn.client.submit(sum, [20, 22]).result())
finally:
    conn.close()
"""


def test_project_client_joins_a_tls_deployment_through_its_configuration(tmp_path: Path) -> None:
    """The project's own client path, not a bare ``Client``: ``connect()`` with ``--scheduler tls://...`` and
    the ``--tls-*`` flags of ``mercury-dem run``; and ``execution.scheduler: tls://...`` in a YAML with the
    certificates from ``start.sh``'s ``env.sh`` only (how the launchers hand TLS to ``mercury-dem run``).
    The same two routes without certificates are refused."""
    import argparse
    import os
    import shlex
    import sys

    import pytest

    from mercury_dem.config import ConfigError, load_config
    from mercury_dem.compute import connect
    from mercury_dem.compute.security import add_tls_arguments, security_from_args

    dep = start_local(tmp_path / "dask", workers=1, tls=True)
    try:
        address = dep.address
        assert address.startswith("tls://127.0.0.1:")
        tls = dep.state / "tls"
        # 1. the run command's flags, parsed as `mercury-dem run` parses them, into connect()
        p = argparse.ArgumentParser()
        add_tls_arguments(p)
        args = p.parse_args(["--tls-ca-file", str(tls / "ca.pem"), "--tls-cert", str(tls / "cert.pem"),
                             "--tls-key", str(tls / "key.pem")])
        conn = connect(load_config().execution, scheduler=address, security=security_from_args(args))
        try:
            assert conn.mode == "scheduler"
            assert conn.client.submit(_square, 9).result() == 81
            (w,) = conn.client.scheduler_info(n_workers=-1)["workers"]
            assert w.startswith("tls://127.0.0.1:")
        finally:
            conn.close()
        # ... and without them: refused (the scheduler requires encryption and a certificate of its CA)
        with pytest.raises(ConfigError, match=rf"scheduler {address} .*requires TLS.*--tls-ca-file.*env\.sh"):
            connect(load_config().execution, scheduler=address, security=None)
        with pytest.raises(ConfigError, match=r"scheduler file .*scheduler\.json.*requires TLS"):
            connect(load_config().execution, scheduler_file=str(dep.scheduler_file), security=None)
        # 2. execution.scheduler in the configuration, certificates from env.sh only, in a fresh process
        cfg = tmp_path / "cfg.yaml"
        cfg.write_text(f"execution:\n  scheduler: {address}\n")
        env = script_env(PYTHONPATH=str(REPO))
        for line in (dep.state / "env.sh").read_text().splitlines():
            if line.startswith("export "):
                key, _, value = line[len("export "):].partition("=")
                env[key] = shlex.split(value)[0] if value else ""
        assert env["DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION"] in ("True", "true", "1")
        res = subprocess.run([sys.executable, "-c", _CONNECT_FROM_CONFIG, str(cfg)], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=60)
        assert res.returncode == 0 and res.stdout.split() == ["scheduler", "42"], res.stderr[-2000:]
        bare = {k: v for k, v in env.items() if not k.startswith("DASK_")}
        t0 = time.monotonic()
        res = subprocess.run([sys.executable, "-c", _CONNECT_FROM_CONFIG, str(cfg)], env=bare, cwd=tmp_path,
                             capture_output=True, text=True, timeout=60)
        assert res.returncode != 0 and "42" not in res.stdout, res.stdout
        assert "ConfigError" in res.stderr and "requires TLS" in res.stderr, res.stderr[-2000:]
        assert time.monotonic() - t0 < 30
        assert os.environ.get("DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION") is None
    finally:
        res = dep.stop()
    assert res.returncode == 0, res.stderr
