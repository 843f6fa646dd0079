"""The no-worker watchdog on a fake clock (issue 33 item 4): the run's error comes at the timeout, not before."""

from __future__ import annotations

import pytest

from mercury_dem.compute import SyncClient
from mercury_dem.compute.watchdog import NoWorkerWatchdog, watch_workers
from mercury_dem.exceptions import NoWorkerError


class Timeline:
    """Workers and time under the test's control; records what the watchdog cancels."""

    def __init__(self) -> None:
        self.t = 0.0
        self.workers: int | None = 2
        self.cancelled: list[str] = []

    def watchdog(self, timeout_s: float) -> NoWorkerWatchdog:
        w = NoWorkerWatchdog(object(), timeout_s, "tcp://127.0.0.1:8786", workers=lambda c: self.workers,
                             clock=lambda: self.t)
        w.cancel = self.cancelled.append  # type: ignore[method-assign]
        return w


def test_the_error_comes_after_the_timeout_without_worker_and_names_the_cause() -> None:
    tl = Timeline()
    w = tl.watchdog(30.0)
    for t in (0.0, 10.0, 20.0):
        tl.t = t
        assert not w.poll()
    tl.workers, tl.t = 0, 25.0  # every worker gone from t = 25 s
    assert not w.poll()
    tl.t = 54.9
    assert not w.poll() and w.error is None and tl.cancelled == []
    tl.t = 55.0
    assert w.poll()
    assert isinstance(w.error, NoWorkerError)
    msg = str(w.error)
    assert "tcp://127.0.0.1:8786" in msg and "no worker since" in msg and "run the same command" in msg
    assert "no_worker_timeout_s = 30 s" in msg
    assert tl.cancelled == [msg]  # the futures are cancelled with the error's message
    tl.t = 56.0
    assert w.poll() and len(tl.cancelled) == 2  # and again: futures submitted since are cancelled too


def test_a_worker_back_in_time_resets_the_clock_and_an_unknown_count_is_not_time_without_worker() -> None:
    tl = Timeline()
    w = tl.watchdog(10.0)
    tl.workers = 0
    assert not w.poll()
    tl.t, tl.workers = 9.0, 1  # one came back before the timeout
    assert not w.poll() and w.no_worker_since is None
    tl.t, tl.workers = 12.0, 0
    assert not w.poll()
    tl.t, tl.workers = 21.0, None  # the scheduler cannot be asked: the scheduler-loss path decides, not this one
    assert not w.poll()
    tl.t, tl.workers = 21.5, 0
    assert not w.poll()  # 9.5 s without worker since t = 12 s
    tl.t = 22.0
    assert w.poll()


def test_nothing_is_watched_in_process_and_the_timeout_must_be_positive() -> None:
    assert watch_workers(SyncClient(), 5.0, "in-process") is None
    assert watch_workers(object(), 0.0, "tcp://x") is None  # 0: wait for ever (the configuration's off switch)
    with pytest.raises(ValueError):
        NoWorkerWatchdog(object(), 0.0, "tcp://x")


def test_a_real_scheduler_without_workers_cancels_the_waiting_futures() -> None:
    """The watchdog's thread on a LocalCluster with no worker: the future waited on ends, cancelled, in time."""
    import time

    from distributed import Client, LocalCluster

    from mercury_dem.compute import lost_to_the_cluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address="127.0.0.1:0") as cluster, \
            Client(cluster) as client:
        fut = client.submit(sum, [1, 2])
        t0 = time.monotonic()
        with NoWorkerWatchdog(client, 1.0, cluster.scheduler_address, poll_s=0.1) as w:
            with pytest.raises(Exception) as info:
                fut.result(timeout=20)
        elapsed = time.monotonic() - t0
        assert lost_to_the_cluster(info.value), info.value
        assert isinstance(w.error, NoWorkerError) and cluster.scheduler_address in str(w.error)
        assert str(w.error) in str(info.value)  # the cancelled future says why
        assert 1.0 <= elapsed < 5.0, elapsed
