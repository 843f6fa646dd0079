"""The one execution layer: where the package's tasks run, and the only package that imports Dask.

- :mod:`~mercury_dem.compute.client`: the client interface every stage submits to
  (:class:`ComputeClient`) and the in-process :class:`SyncClient` that implements all of it;
- :mod:`~mercury_dem.compute.clusters`: :func:`connect` (the run's client), :func:`local_cluster`
  (every LocalCluster the package starts), :func:`open_client` (a command's own tasks);
- :mod:`~mercury_dem.compute.security`: TLS from certificate files and the ``tls://`` check;
- :mod:`~mercury_dem.compute.failures`: the one rule for "this error stops the run";
- :mod:`~mercury_dem.compute.watchdog`: a run whose cluster has had no worker for too long ends.

``pipeline/`` and ``synth/`` use it; the stage graph (``pipeline/graph.py``) drives it.
"""

from mercury_dem.compute.client import (
    ADJUST_RESOURCE,
    ComputeClient,
    SyncClient,
    SyncFuture,
    ThreadPoolClient,
    as_completed,
    client_or_sync,
    runs_in_process,
)
from mercury_dem.compute.clusters import (
    Connection,
    connect,
    dask_client,
    default_workers,
    in_dask_worker,
    local_cluster,
    open_client,
    performance_report,
    quiet_comm_size_probe,
    worker_client,
)
from mercury_dem.compute.failures import RUN_STOPPING, lost_to_the_cluster, raise_if_run_stopping, run_stopping_error

__all__ = [
    "ADJUST_RESOURCE", "ComputeClient", "SyncClient", "SyncFuture", "ThreadPoolClient", "as_completed", "client_or_sync",
    "runs_in_process", "Connection", "connect", "dask_client", "default_workers", "in_dask_worker",
    "local_cluster", "open_client", "performance_report", "quiet_comm_size_probe", "worker_client",
    "RUN_STOPPING", "lost_to_the_cluster", "raise_if_run_stopping", "run_stopping_error",
]
