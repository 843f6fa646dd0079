"""Every Dask cluster the package creates outside ``connect()`` listens on 127.0.0.1 only.

``connect()`` (the run's LocalCluster) is checked in ``test_security_defaults.py``, the
scripts in ``test_local_scripts.py``, the run dashboard in ``tests/dashboard``. Here: the
LocalCluster of ``mercury-dem grid --workers N``, the one ``synth`` renders on
(``synth.parallel.render_all``), and the in-process replay cluster of the cascade benchmark (``workflows/benchmarks/cascade_replay.py``).
Each is inspected *while it runs* (from inside the function that receives its client): the
scheduler's, workers' and dashboard's addresses, and every listening socket of this
process and its children.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import psutil

from tests.cluster.conftest import listening_addresses


def _tree_sockets() -> list[tuple[int, str, int]]:
    me = psutil.Process()
    return listening_addresses([me, *me.children(recursive=True)])


def _assert_loopback(client: Any, n_workers: int) -> dict[str, Any]:
    """Scheduler, workers, dashboard and all listening sockets of the process tree on 127.0.0.1."""
    info = client.scheduler_info(n_workers=-1)
    assert info["address"].startswith("tcp://127.0.0.1:"), info["address"]
    workers = info["workers"]
    assert len(workers) == n_workers
    assert all(a.startswith("tcp://127.0.0.1:") for a in workers), list(workers)
    assert all(w.get("nanny") is None or w["nanny"].startswith("tcp://127.0.0.1:") for w in workers.values())
    assert client.dashboard_link.startswith("http://127.0.0.1:"), client.dashboard_link
    socks = _tree_sockets()
    # scheduler + dashboard + each worker (+ nanny): more than two listening sockets
    assert len(socks) >= 2 + n_workers, socks
    assert {ip for _, ip, _ in socks} == {"127.0.0.1"}, socks
    return info


def test_grid_command_cluster_binds_to_loopback(tmp_path: Path, monkeypatch) -> None:
    """``mercury-dem grid --workers 2``: the cluster it starts is on loopback (its dashboard was on
    every interface before: ``dashboard_address=":0"``)."""
    import pytest

    from mercury_dem.cli import main
    from mercury_dem.pipeline import dem_stage

    seen: dict[str, Any] = {}

    class Inspected(Exception):
        """Stops the command once its cluster was inspected (the gridding itself is tested elsewhere)."""

    def inspecting_grid_dem(points, dem, path, client=None, **kw):
        assert client is not None, "grid --workers 2 gave no client"
        seen["info"] = _assert_loopback(client, 2)
        raise Inspected

    monkeypatch.setattr(dem_stage, "grid_dem", inspecting_grid_dem)
    rng = np.random.default_rng(3)
    lat = rng.uniform(-2, 2, 400)
    lon = rng.uniform(10, 14, 400)
    r = 2439400.0 + rng.normal(0, 50, 400)
    pd.DataFrame({"lat": lat, "lon": lon, "radius": r}).to_csv(tmp_path / "pts.csv", index=False)
    with pytest.raises(Inspected):
        main(["grid", str(tmp_path / "pts.csv"), "--out", str(tmp_path / "out"), "--ppd", "8", "--workers", "2",
              "--no-coverage"])
    assert "info" in seen


def test_synth_render_cluster_binds_to_loopback(tmp_path: Path, monkeypatch) -> None:
    from mercury_dem.synth import parallel

    seen: dict[str, Any] = {}

    def inspecting_run_on(client, *args, **kw):
        seen["info"] = _assert_loopback(client, 2)
        return []

    monkeypatch.setattr(parallel, "_run_on", inspecting_run_on)
    plan = pd.DataFrame({c: [] for c in parallel.RENDER_COLUMNS})
    assert parallel.render_all(tmp_path, plan, {}, 2439400.0, None, 0, workers=2) == []
    assert "info" in seen


def test_simulation_replay_cluster_listens_on_loopback_only() -> None:
    """``cascade_replay.sleep_cluster`` (workflows/benchmarks): inproc transport; the HTTP servers Dask still starts (scheduler
    and each worker) on 127.0.0.1 (with ``dashboard_address=None`` they were on 0.0.0.0 and ::)."""
    from distributed import Client

    from tests.benchmarks import load_benchmark

    sleep_cluster = load_benchmark("cascade_replay").sleep_cluster

    before = set(_tree_sockets())
    with sleep_cluster(2) as cluster, Client(cluster) as client:
        info = client.scheduler_info(n_workers=-1)
        assert info["address"].startswith("inproc://"), info["address"]
        assert all(a.startswith("inproc://") for a in info["workers"])
        assert len(info["workers"]) == 2
        new = set(_tree_sockets()) - before
        assert new and {ip for _, ip, _ in new} == {"127.0.0.1"}, new


def test_synth_on_a_tls_scheduler_without_certificates_says_so(tmp_path: Path, monkeypatch) -> None:
    """``render_all(scheduler="tls://...")`` with no certificate in Dask's configuration: ConfigError naming
    the scheduler and how to give them (not Dask's TypeError about an ssl_context); nothing is contacted."""
    import pytest

    from mercury_dem.config import ConfigError
    from mercury_dem.synth import parallel

    for key in [k for k in __import__("os").environ if k.startswith("DASK_DISTRIBUTED__COMM__TLS")]:
        monkeypatch.delenv(key)
    plan = pd.DataFrame({c: [] for c in parallel.RENDER_COLUMNS})
    with pytest.raises(ConfigError, match=r"scheduler tls://127\.0\.0\.1:9 \(synth --scheduler\) requires TLS.*env\.sh"):
        parallel.render_all(tmp_path, plan, {}, 2439400.0, None, 0, scheduler="tls://127.0.0.1:9")
