"""The blocked adjustment's distributed engine: one ``BlockShard`` Dask actor per worker of the run's cluster.

Only the client's methods are used here (``submit(..., actor=True)``, ``scatter``, ``cancel``,
``scheduler_info``); the client, and the run's client from inside a task, come from
:mod:`mercury_dem.compute`.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from mercury_dem.compute import in_dask_worker, worker_client

if TYPE_CHECKING:
    from mercury_dem.compute.client import DaskClient

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

    def __init__(self, client: DaskClient, store: str, n_blocks: int, setup: Any, opt: Any,
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
        self.actors: list[Any] = [f.result() for f in futures]  # Actor proxies: their calls return futures
        self._futures = futures  # the actors live as long as these futures
        self.client = client
        self.tree_min_workers = tree_min_workers
        self.description = f"dask ({len(self.actors)} workers)"

    @classmethod
    def from_blocks(cls, client: DaskClient, blocks: Any, setup: Any, opt: Any,
                    tree_min_workers: int = TREE_MIN_WORKERS) -> DaskShardEngine:
        """The engine over ``blocks`` held by the caller (a run's unit): scattered to the workers, not read there;
        or, ``blocks`` a :class:`~mercury_dem.io.synthetic_network_store.StoredBlocks` (a unit adjusted from its
        merged store), each worker's actor reads its run of them from the store.

        Contiguous runs of blocks, one per worker (at most one per block); each run is scattered
        straight to its worker and its actor built there from it; the scattered copies are then
        released (the actor's block states are what stays). The caller's own process keeps
        nothing of the blocks once it drops them.
        """
        import numpy as np

        from mercury_dem.adjust.blocked import BlockShard
        from mercury_dem.exceptions import AdjustmentError
        from mercury_dem.io.synthetic_network_store import StoredBlocks

        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise AdjustmentError("the Dask cluster has no workers for the blocked adjustment's point blocks")
        runs = [r for r in np.array_split(np.arange(len(blocks)), min(len(workers), max(1, len(blocks)))) if len(r)]
        self = cls.__new__(cls)
        self.client = client
        self.tree_min_workers = tree_min_workers
        self.workers, futures = [], []
        for w, r in zip(workers, runs):
            if isinstance(blocks, StoredBlocks):  # a stored unit's blocks: each worker reads its own run
                data: Any = blocks.subset(tuple(blocks.ids[int(k)] for k in r))
            else:
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
    with worker_client() as client:
        engine = DaskShardEngine.from_blocks(client, blocks, setup, opt, tree_min_workers)
        try:
            yield engine
        finally:
            engine.close()


def shard_engine_factory(tree_min_workers: int = TREE_MIN_WORKERS) -> Any:
    """:func:`worker_shard_engine` when called inside a Dask worker's task, else None (one process)."""
    if not in_dask_worker():
        return None
    return functools.partial(worker_shard_engine, tree_min_workers=tree_min_workers)
