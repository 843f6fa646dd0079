"""Where the tasks run: the in-process client, a LocalCluster, or an existing scheduler.

Every ``distributed.Client`` and ``LocalCluster`` the package opens comes from here: the run's
(:func:`connect`), ``mercury-dem grid --workers``, ``adjust-network --workers``, the synthetic
mission's renderer and the benchmarks (:func:`local_cluster`, :func:`open_client`).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mercury_dem.compute.client import ADJUST_RESOURCE, ComputeClient, SyncClient
from mercury_dem.compute.security import require_tls_settings
from mercury_dem.config.execution import ExecutionConfig

if TYPE_CHECKING:
    from distributed import Client


@dataclass
class Connection:
    """A client and what must be closed with it."""

    client: ComputeClient
    mode: str
    cluster: Any = None
    description: str = ""
    uses_resources: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def scheduler_address(self) -> str:
        """The scheduler's address (``tcp://...``), or the description when there is none (in-process)."""
        scheduler = getattr(self.client, "scheduler", None)  # distributed's; none in process
        address = getattr(scheduler, "address", None)
        return self.description if address is None else str(address)

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()


def default_workers() -> tuple[int, int]:
    """(workers, threads per worker) for this machine: one single-threaded worker per core.

    Tile matching is multi-threaded inside OpenCV and the adjustment inside BLAS, so one
    thread per worker process keeps the cores busy without oversubscription.
    """
    n = os.cpu_count() or 1
    return max(1, n), 1


#: Logged by ``distributed.sizeof`` when the size probe that ``distributed.comm`` runs on every
#: outgoing message (``safe_sizeof(msg, default_size=-1)``) fails.
COMM_SIZE_PROBE_WARNING = "Defaulting to -1 B"


class CommSizeProbeFilter(logging.Filter):
    """Drop distributed's warning that the pre-send size probe of a comm message failed.

    A worker answering the performance report's profile request sends the call-tree
    profile, a dict nested deeper than ``dask.sizeof`` recurses (RecursionError). distributed
    expects this (``distributed/comm/utils.py``): the probe returns -1 and the message
    is serialised off the event loop, nothing is lost. Every run printed two such
    warnings at the end of its cascade; only that exact message is dropped, any other
    sizeof failure (a task result whose size cannot be measured) is still logged.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return COMM_SIZE_PROBE_WARNING not in record.getMessage()


def quiet_comm_size_probe() -> bool:
    """Install :class:`CommSizeProbeFilter` on the ``distributed.sizeof`` logger of this process (idempotent)."""
    logger = logging.getLogger("distributed.sizeof")
    if not any(isinstance(f, CommSizeProbeFilter) for f in logger.filters):
        logger.addFilter(CommSizeProbeFilter())
    return True


def _quiet_workers(client: Client) -> None:
    """The filter in this process and on every worker, present and future (a worker plugin)."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class QuietCommSizeProbe(WorkerPlugin):
        name = "mercury-dem-quiet-comm-size-probe"

        def setup(self, worker: Any) -> None:
            quiet_comm_size_probe()

    quiet_comm_size_probe()
    client.register_plugin(QuietCommSizeProbe())


def _check_tls_of_scheduler_file(path: str, security: Any) -> None:
    """A scheduler file naming a ``tls://`` address needs certificates (see ``require_tls_settings``).

    Only the address is looked at (the file is JSON); a missing or unreadable file is left to
    Dask, which waits for it to appear (launchers write it while the client starts).
    """
    import json
    from pathlib import Path

    try:
        address = json.loads(Path(path).read_text()).get("address", "")
    except (OSError, ValueError, AttributeError):
        return
    require_tls_settings(str(address), security, f"scheduler file {path}")


def local_cluster(n_workers: int, threads_per_worker: int = 1, *, host: str = "127.0.0.1",
                  processes: bool = True, resources: dict[str, float] | None = None, security: Any = None,
                  memory_limit: str | float | None = None, nanny_environ: dict[str, str | None] | None = None) -> Any:
    """A ``distributed.LocalCluster``: the one place the package starts one.

    Everything it opens listens on ``host`` (loopback by default; ``execution.host``
    widens it): the scheduler, the workers and the dashboard (on a free port,
    ``dashboard_address=host:0``; Dask's default ``:8787`` binds all interfaces). In-process
    workers (``processes=False``) talk over the inproc transport; they still start an HTTP
    server each, bound to ``host`` here (``worker_dashboard_address``; with Dask's default
    they listened on 0.0.0.0 and ::).

    Parameters
    ----------
    n_workers, threads_per_worker : the cluster's shape
    host : the address every server binds to
    processes : worker processes (the default) or threads of this process
    resources : worker resources, e.g. ``{ADJUST_RESOURCE: 1}``
    security : a ``distributed.Security`` for TLS, or None
    memory_limit : per worker; None keeps Dask's default (the machine's memory / workers)
    nanny_environ : changes to the environment the nannies give their workers
        (``distributed.nanny.pre-spawn-environ``): a value None removes that variable

    Returns
    -------
    distributed.LocalCluster, started; close it (or use it as a context manager).
    """
    import dask
    from distributed import LocalCluster

    kw: dict[str, Any] = {"n_workers": n_workers, "threads_per_worker": threads_per_worker,
                          "dashboard_address": f"{host}:0", "processes": processes}
    if processes:
        kw["host"] = host
    else:  # inproc transport (a host would make Dask try tcp://); only the HTTP servers bind
        kw["worker_dashboard_address"] = f"{host}:0"
    if resources is not None:
        kw["resources"] = resources
    if security is not None:
        kw["security"] = security
    if memory_limit is not None:
        kw["memory_limit"] = memory_limit
    if not nanny_environ:
        return LocalCluster(**kw)
    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    for k, v in nanny_environ.items():
        if v is None:
            env.pop(k, None)
        else:
            env[k] = v
    with dask.config.set({"distributed.nanny.pre-spawn-environ": env}):
        return LocalCluster(**kw)


def dask_client(target: Any, security: Any = None, source: str = "the scheduler address") -> Any:
    """A ``distributed.Client`` of a cluster object or a scheduler address (checked for TLS first)."""
    from distributed import Client

    if isinstance(target, str):
        require_tls_settings(target, security, source)
    return Client(target, security=security)


@contextlib.contextmanager
def open_client(workers: int = 0, scheduler: str | None = None, *, host: str = "127.0.0.1",
                source: str = "--scheduler", nanny_environ: dict[str, str | None] | None = None) -> Iterator[Any]:
    """A client for a command's own tasks, closed (with its cluster) on exit.

    ``scheduler``: an existing scheduler's address; else ``workers`` > 0: a temporary LocalCluster of
    that many single-threaded workers on ``host``; else the in-process :class:`SyncClient`.
    """
    if scheduler is not None:
        client = dask_client(scheduler, None, source)  # TLS only through Dask's config (env.sh)
        try:
            yield client
        finally:
            client.close()
        return
    if workers <= 0:
        yield SyncClient()
        return
    with local_cluster(workers, 1, host=host, nanny_environ=nanny_environ) as cluster, \
            dask_client(cluster) as client:
        yield client


def connect(
    cfg: ExecutionConfig,
    scheduler: str | None = None,
    scheduler_file: str | None = None,
    workers: int | None = None,
    threads_per_worker: int | None = None,
    security: Any = None,
) -> Connection:
    """Open the execution backend named by the CLI or the configuration.

    ``scheduler``: ``"sync"``, ``"local"`` (a LocalCluster bound to ``cfg.host``),
    or an address such as ``tcp://127.0.0.1:8786``; ``scheduler_file`` a Dask
    scheduler file (how HPC launchers publish the address).
    """
    target = scheduler or cfg.scheduler
    if scheduler_file:
        from distributed import Client

        _check_tls_of_scheduler_file(scheduler_file, security)
        client = Client(scheduler_file=scheduler_file, security=security)
        _quiet_workers(client)
        return Connection(client, "scheduler-file", description=f"scheduler file {scheduler_file}")
    if target == "sync":
        return Connection(SyncClient(), "sync", description="in-process, synchronous")
    if target == "local":
        nw, nt = default_workers()
        nw = workers or cfg.workers or nw
        nt = threads_per_worker or cfg.threads_per_worker or nt
        cluster = local_cluster(nw, nt, host=cfg.host, resources={ADJUST_RESOURCE: 1}, security=security)
        client = dask_client(cluster, security)
        _quiet_workers(client)
        return Connection(
            client, "local", cluster=cluster, uses_resources=True,
            description=f"LocalCluster {nw} workers x {nt} threads on {cfg.host}",
        )
    client = dask_client(target, security, "--scheduler or execution.scheduler")
    _quiet_workers(client)
    return Connection(client, "scheduler", description=f"scheduler {target}")


def performance_report(conn: Connection, path: str) -> Any:
    """Dask's performance report of what runs in the block, written to ``path``; nothing in process."""
    if conn.mode == "sync":
        return contextlib.nullcontext()
    from distributed import performance_report as _performance_report

    return _performance_report(filename=path)


def in_dask_worker() -> bool:
    """Whether this code runs inside a Dask worker's task."""
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return False
    return True


def worker_client() -> Any:
    """Dask's ``worker_client()``: the run's client from inside a task, the task seceded from its slot."""
    from distributed import worker_client as _worker_client

    return _worker_client()


def versions() -> dict[str, str]:
    """The versions of the execution libraries (recorded in the run's report)."""
    import dask
    import distributed

    return {"dask": dask.__version__, "distributed": distributed.__version__}
