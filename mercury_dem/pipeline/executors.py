"""Where the tasks run: an in-process synchronous client, a LocalCluster, or an existing scheduler.

The graph code (:mod:`mercury_dem.pipeline.graph`) only calls ``submit``,
``gather`` and ``result`` on what :func:`connect` returns, so the synchronous
mode runs the same graph, in the same order of dependencies, in this process.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from mercury_dem.config.execution import ExecutionConfig

#: Worker resource that bounds memory-heavy adjustments to one at a time per worker.
ADJUST_RESOURCE = "adjust_slots"


class SyncFuture:
    """A finished computation, shaped like a ``distributed.Future`` for what the graph uses."""

    def __init__(self, key: str, fn: Callable[..., Any], args: tuple[Any, ...], kwargs: dict[str, Any]):
        self.key = key
        self._exc: BaseException | None = None
        self._value: Any = None
        try:
            self._value = fn(*[_resolve(a) for a in args], **{k: _resolve(v) for k, v in kwargs.items()})
            self.status = "finished"
        except Exception as exc:  # recorded, re-raised by result() like a distributed future
            self._exc = exc
            self.status = "error"

    def result(self) -> Any:
        if self._exc is not None:
            raise self._exc
        return self._value

    def done(self) -> bool:
        return True


def _resolve(x: Any) -> Any:
    if isinstance(x, SyncFuture):
        return x.result()
    if isinstance(x, list):
        return [_resolve(v) for v in x]
    if isinstance(x, tuple):
        return tuple(_resolve(v) for v in x)
    if isinstance(x, dict):
        return {k: _resolve(v) for k, v in x.items()}
    return x


class SyncClient:
    """In-process stand-in for ``distributed.Client`` (``--scheduler sync``), for debugging and tests."""

    dashboard_link = None
    synchronous = True

    def submit(self, fn: Callable[..., Any], *args: Any, key: str | None = None, **kwargs: Any) -> SyncFuture:
        for k in ("retries", "resources", "pure", "priority", "workers", "allow_other_workers"):
            kwargs.pop(k, None)
        return SyncFuture(key or getattr(fn, "__name__", "task"), fn, args, kwargs)

    def gather(self, futures: Any) -> Any:
        return _resolve(futures)

    def close(self) -> None:
        pass


def as_completed(client: Any, futures: list[Any]) -> Iterator[Any]:
    """Futures in the order they finish (submission order for the synchronous client)."""
    if getattr(client, "synchronous", False):
        yield from futures
        return
    from distributed import as_completed as _as_completed

    yield from _as_completed(futures)


def runs_in_process(client: Any) -> bool:
    """True when tasks given to ``client`` run in this process: None or the synchronous client.

    The stages take the run's one client (the cascade's, :func:`connect`) and ask this, rather
    than each deciding from the connection's mode, where to run a loop of their own tasks.
    """
    return client is None or bool(getattr(client, "synchronous", False))


@dataclass
class Connection:
    """A client and what must be closed with it."""

    client: Any
    mode: str
    cluster: Any = None
    description: str = ""
    uses_resources: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

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


class _CommSizeProbeFilter(logging.Filter):
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
    """Install :class:`_CommSizeProbeFilter` on the ``distributed.sizeof`` logger of this process (idempotent)."""
    logger = logging.getLogger("distributed.sizeof")
    if not any(isinstance(f, _CommSizeProbeFilter) for f in logger.filters):
        logger.addFilter(_CommSizeProbeFilter())
    return True


def _quiet_workers(client: Any) -> None:
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

    from mercury_dem.pipeline.security import require_tls_settings

    try:
        address = json.loads(Path(path).read_text()).get("address", "")
    except (OSError, ValueError, AttributeError):
        return
    require_tls_settings(str(address), security, f"scheduler file {path}")


def local_cluster(n_workers: int, threads_per_worker: int = 1, *, host: str = "127.0.0.1",
                  processes: bool = True, resources: dict[str, float] | None = None, security: Any = None,
                  memory_limit: str | float | None = None) -> Any:
    """A ``distributed.LocalCluster``: the one place the package starts one.

    Used by the run (:func:`connect`), ``mercury-dem grid --workers``, ``adjust-network --workers``,
    the synthetic mission's renderer (``synth.parallel.render_all``) and the cascade benchmark's
    replay. Everything it opens listens on ``host`` (loopback by default; ``execution.host``
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

    Returns
    -------
    distributed.LocalCluster, started; close it (or use it as a context manager).
    """
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
    return LocalCluster(**kw)


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
        from distributed import Client

        nw, nt = default_workers()
        nw = workers or cfg.workers or nw
        nt = threads_per_worker or cfg.threads_per_worker or nt
        cluster = local_cluster(nw, nt, host=cfg.host, resources={ADJUST_RESOURCE: 1}, security=security)
        client = Client(cluster, security=security)
        _quiet_workers(client)
        return Connection(
            client, "local", cluster=cluster, uses_resources=True,
            description=f"LocalCluster {nw} workers x {nt} threads on {cfg.host}",
        )
    from distributed import Client

    from mercury_dem.pipeline.security import require_tls_settings

    require_tls_settings(target, security, "--scheduler or execution.scheduler")
    client = Client(target, security=security)
    _quiet_workers(client)
    return Connection(client, "scheduler", description=f"scheduler {target}")


#: From this many shard actors on, the blocked adjustment's sums are merged on the workers (a tree)
#: rather than at the client (``adjust.blocked_tree_min_workers``).
TREE_MIN_WORKERS = 4


class DaskShardEngine:
    """The distributed engine of the blocked adjustment: one ``BlockShard`` Dask actor per worker.

    Each actor loads its point blocks from the store itself (nothing goes through the
    client) and keeps them in its worker's memory across iterations; every call runs
    one ``BlockShard`` method on all actors at once and returns their results in
    worker order (see :mod:`mercury_dem.adjust.blocked`). Blocks are dealt in
    contiguous runs: neighbouring blocks share images, so a worker's partial sum of the
    reduced camera system (the first level of the reduction tree) stays small.

    Parameters
    ----------
    client : a ``distributed.Client``
    store : the network store path (the workers must see it: a shared file system)
    n_blocks : point blocks in the store
    setup, opt : ``CameraSetup`` and ``SolverOptions`` (sent once to every actor)
    tree_min_workers : from this many actors on, the sums are merged on the workers (:meth:`summed`)
    """

    def __init__(self, client: Any, store: str, n_blocks: int, setup: Any, opt: Any,
                 tree_min_workers: int = TREE_MIN_WORKERS):
        import numpy as np

        from mercury_dem.adjust.blocked import BlockShard
        from mercury_dem.exceptions import AdjustmentError
        from mercury_dem.io.synthetic_network_store import StoredBlocks

        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise AdjustmentError("the Dask cluster has no workers: start some, or use --sync")
        runs = list(np.array_split(np.arange(n_blocks), len(workers)))
        pairs = [(w, tuple(int(x) for x in r)) for w, r in zip(workers, runs) if len(r)]
        futures = [client.submit(BlockShard, StoredBlocks(str(store), ids), setup, opt, actor=True, workers=[w],
                                 allow_other_workers=False, pure=False) for w, ids in pairs]
        self.workers = [w for w, _ in pairs]
        self.actors = [f.result() for f in futures]
        self._futures = futures  # the actors live as long as these futures
        self.client = client
        self.tree_min_workers = tree_min_workers
        self.description = f"dask ({len(self.actors)} workers)"

    @classmethod
    def from_blocks(cls, client: Any, blocks: list[Any], setup: Any, opt: Any,
                    tree_min_workers: int = TREE_MIN_WORKERS) -> DaskShardEngine:
        """The engine over ``blocks`` held by the caller (a run's unit): scattered to the workers, not read there.

        Contiguous runs of blocks, one per worker (at most one per block); each run is scattered
        straight to its worker and its actor built there from it; the scattered copies are then
        released (the actor's block states are what stays). The caller's own process keeps
        nothing of the blocks once it drops them.
        """
        import numpy as np

        from mercury_dem.adjust.blocked import BlockShard
        from mercury_dem.exceptions import AdjustmentError

        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise AdjustmentError("the Dask cluster has no workers for the blocked adjustment's point blocks")
        runs = [r for r in np.array_split(np.arange(len(blocks)), min(len(workers), max(1, len(blocks)))) if len(r)]
        self = cls.__new__(cls)
        self.client = client
        self.tree_min_workers = tree_min_workers
        self.workers, futures = [], []
        for w, r in zip(workers, runs):
            data = client.scatter([blocks[int(k)] for k in r], workers=[w], hash=False)
            futures.append(client.submit(BlockShard, data, setup, opt, actor=True, workers=[w],
                                         allow_other_workers=False, pure=False))
            self.workers.append(w)
        self.actors = [f.result() for f in futures]
        self._futures = futures
        self.description = f"dask ({len(self.actors)} workers)"
        return self

    def call(self, method: str, *args: Any) -> list[Any]:
        pending = [getattr(a, method)(*args) for a in self.actors]
        return [p.result() for p in pending]

    def summed(self, method: str, *args: Any) -> list[Any]:
        """The shards' sums of ``method`` (``linearize``/``reduce``): one partial a shard, or one in all by a tree.

        Below ``tree_min_workers`` actors every shard's partial comes to the client (which adds them in
        shard order). From it on, the partials are merged on the workers in ceil(log2 N) rounds, actor
        ``i`` absorbing actor ``i + 2^k``'s (moved worker to worker), so the client receives one
        partial instead of N and its memory and network share stay those of one shard's.
        """
        if len(self.actors) < self.tree_min_workers:
            return self.call("partial", method, *args)
        for p in [a.hold(method, *args) for a in self.actors]:
            p.result()
        from mercury_dem.adjust.blocked import tree_rounds

        for merges in tree_rounds(len(self.actors)):
            for p in [self.actors[i].absorb(self.actors[j]) for i, j in merges]:
                p.result()
        return [self.actors[0].take().result()]

    def close(self) -> None:
        """Release the actors (their workers free the blocks).

        Cancelled rather than only released: the actor handles keep their own references to the
        keys, and a unit's later passes (re-centring, altimetry) make new actors on the same workers.
        """
        futures, self._futures, self.actors = self._futures, [], []
        if futures:
            self.client.cancel(futures, force=True)


@contextlib.contextmanager
def worker_shard_engine(blocks: list[Any], setup: Any, opt: Any,
                        tree_min_workers: int = TREE_MIN_WORKERS) -> Iterator[DaskShardEngine]:
    """The run's blocked adjustment on the run's own Dask workers, from inside a unit's task.

    For :func:`~mercury_dem.adjust.blocked_bundle.blocked_bundle_adjust`'s ``engine_factory``. The
    unit's task leaves the worker's thread pool (``worker_client`` secedes it, and rejoins at the
    end) while it drives the loop: its worker's slot can then run the actors' construction and
    the other units' tasks, and a task that blocked on tasks it submitted could deadlock a
    cluster whose slots are all taken by such tasks. Called outside a Dask worker (a sync run, a
    test), ``worker_client`` raises ``ValueError``: use ``engine_factory=None`` there
    (:func:`shard_engine_factory` decides).
    """
    from distributed import worker_client

    with worker_client() as client:
        engine = DaskShardEngine.from_blocks(client, blocks, setup, opt, tree_min_workers)
        try:
            yield engine
        finally:
            engine.close()


def shard_engine_factory(tree_min_workers: int = TREE_MIN_WORKERS) -> Any:
    """:func:`worker_shard_engine` when called inside a Dask worker's task, else None (one process)."""
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return None
    return functools.partial(worker_shard_engine, tree_min_workers=tree_min_workers)
