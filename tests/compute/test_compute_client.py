"""The in-process clients implement the whole client interface, with Dask's results (issue 32 item 3)."""

from __future__ import annotations

import errno
import operator
import threading

import pytest

from mercury_dem.compute import (
    ComputeClient,
    SyncClient,
    ThreadPoolClient,
    as_completed,
    client_or_sync,
    lost_to_the_cluster,
    run_stopping_error,
    runs_in_process,
)
from mercury_dem.exceptions import CorruptUnitError, DiskFullError, GridError, NoWorkerError, SchedulerLostError


def _exercise(client: ComputeClient) -> dict[str, object]:
    """Every method of the interface, results only (what a stage relies on)."""
    data = client.scatter([1, 2, 3])
    one = client.scatter({"a": 10})
    total = client.submit(sum, data, key="total")
    mapped = client.map(operator.mul, [1, 2, 3], [4, 5, 6])
    nested = client.submit(lambda d, x: d["a"] + x, one, total)
    done = sorted(f.result() for f in as_completed(client, mapped))
    failing = client.submit(operator.truediv, 1, 0)
    with pytest.raises(ZeroDivisionError):
        failing.result()
    return {"gather": client.gather([total, mapped, nested]), "done": done}


EXPECTED = {"gather": [6, [4, 10, 18], 16], "done": [4, 10, 18]}


@pytest.mark.parametrize("make", [SyncClient, lambda: ThreadPoolClient(2)], ids=["sync", "threads"])
def test_in_process_clients_implement_the_interface(make: object) -> None:
    client = make()  # type: ignore[operator]
    assert isinstance(client, ComputeClient)
    assert runs_in_process(client)
    try:
        assert _exercise(client) == EXPECTED
    finally:
        client.close()


def test_a_dask_client_gives_the_same_results() -> None:
    from distributed import Client

    with Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address="127.0.0.1:0") as client:
        assert isinstance(client, ComputeClient) and not runs_in_process(client)
        assert _exercise(client) == EXPECTED


def test_the_thread_pool_client_runs_tasks_at_once() -> None:
    """Two tasks that each wait for the other to start: only a client running both at once finishes them."""
    barrier = threading.Barrier(2, timeout=10)
    with ThreadPoolClient(2) as client:
        futures = [client.submit(barrier.wait) for _ in range(2)]
        assert sorted(client.gather(futures)) == [0, 1]


def test_the_sync_client_runs_at_submission_and_scatters_like_dask() -> None:
    client = client_or_sync(None)
    seen: list[int] = []
    client.submit(seen.append, 1)
    assert seen == [1]  # ran already
    assert client.gather(client.scatter(5)) == 5
    assert client.gather(client.scatter({"k": [1]})) == {"k": [1]}


def test_run_stopping_errors_are_the_infrastructure_ones() -> None:
    where = "/runs/x"
    for exc in (DiskFullError("d"), CorruptUnitError("c"), SchedulerLostError("s"), NoWorkerError("n")):
        assert run_stopping_error(exc, "tile 3", where) is exc
    full = OSError(errno.ENOSPC, "No space left on device")
    wrapped = RuntimeError("writing failed")
    wrapped.__cause__ = full
    converted = run_stopping_error(wrapped, "tile 3", where)
    assert isinstance(converted, DiskFullError) and "tile 3" in str(converted)
    for own in (GridError("no points"), ValueError("bad pixel"), KeyError("x"), OSError(errno.ENOENT, "gone")):
        assert run_stopping_error(own, "tile 3", where) is None


def test_a_cancelled_future_is_lost_to_the_cluster_not_the_task() -> None:
    import asyncio
    import concurrent.futures

    from distributed.client import FutureCancelledError

    assert lost_to_the_cluster(FutureCancelledError("k", reason="scheduler-connection-lost"))
    assert lost_to_the_cluster(concurrent.futures.CancelledError())
    assert lost_to_the_cluster(asyncio.CancelledError())
    assert not lost_to_the_cluster(ValueError("a chunk's own failure"))
