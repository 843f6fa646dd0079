"""distributed's benign comm size-probe warning is filtered, other sizeof warnings are not."""

from __future__ import annotations

import logging

import pytest

from mercury_dem.config.execution import ExecutionConfig
from mercury_dem.compute.clusters import CommSizeProbeFilter, connect, quiet_comm_size_probe


def _filter_installed() -> bool:
    return any(isinstance(f, CommSizeProbeFilter) for f in logging.getLogger("distributed.sizeof").filters)


def test_only_the_comm_probe_message_is_dropped() -> None:
    f = CommSizeProbeFilter()

    def rec(msg: object) -> logging.LogRecord:
        return logging.LogRecord("distributed.sizeof", logging.WARNING, __file__, 1, msg, None, None)

    # distributed logs a one-element tuple (its message ends with a comma)
    assert not f.filter(rec(("Sizeof calculation for object of type 'dict' failed. Defaulting to -1 B",)))
    assert f.filter(rec(("Sizeof calculation for object of type 'Foo' failed. Defaulting to 0.95 MiB",)))
    assert f.filter(rec("anything else"))
    quiet_comm_size_probe()
    quiet_comm_size_probe()
    assert sum(isinstance(x, CommSizeProbeFilter) for x in logging.getLogger("distributed.sizeof").filters) == 1


@pytest.mark.integration  # starts a LocalCluster
def test_local_cluster_workers_get_the_filter() -> None:
    conn = connect(ExecutionConfig(), "local", workers=1, threads_per_worker=1)
    try:
        assert all(conn.client.run(_filter_installed).values())
    finally:
        conn.close()
