"""The client interface every stage submits to, and the in-process client that implements all of it.

A stage takes "the run's client" and calls only what :class:`ComputeClient` lists: ``submit``,
``map``, ``scatter``, ``gather``, ``cancel``, ``close`` (and :func:`as_completed` on its futures).
A ``distributed.Client`` has all of these; :class:`SyncClient` runs each task at submission, in
this process, in the order of its dependencies, so a stage has one code path for both (the
synchronous mode is for tests and debugging: ``--scheduler sync``).
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

#: Worker resource that bounds memory-heavy adjustments to one at a time per worker.
ADJUST_RESOURCE = "adjust_slots"

#: Dask's scheduling options, accepted and ignored by the in-process client.
_DASK_ONLY = ("retries", "resources", "pure", "priority", "workers", "allow_other_workers", "actor", "hash",
              "broadcast", "direct", "fifo_timeout", "batch_size")


if TYPE_CHECKING:
    #: Dask's own client, for annotating code that needs more than :class:`ComputeClient` (actors, the
    #: scheduler's state); imported here so that such code outside compute/ names no Dask module.
    from distributed import Client as DaskClient  # noqa: F401


@runtime_checkable
class ComputeClient(Protocol):
    """What a stage may call on the run's client (``distributed.Client`` and :class:`SyncClient`)."""

    # The signatures name only what the stages pass, so that ``distributed.Client`` (whose methods take their
    # own keywords, not ``**kwargs``) is one of these for the type checker too.
    def submit(self, fn: Callable[..., Any], /, *args: Any, key: str | None = ..., pure: bool = ...,
               retries: int | None = ..., resources: dict[str, Any] | None = ..., workers: Any = ...,
               actor: bool = ..., allow_other_workers: bool = ...) -> Any: ...

    def map(self, fn: Callable[..., Any], /, *iterables: Any, key: Any = ..., pure: bool = ...) -> Any: ...

    def scatter(self, data: Any, /, *, workers: Any = ..., broadcast: bool = ..., hash: bool = ...) -> Any: ...

    def gather(self, futures: Any, /) -> Any: ...

    def cancel(self, futures: Any, /, *, force: bool = ..., reason: str | None = ..., msg: str | None = ...) -> Any: ...

    def close(self) -> Any: ...


class SyncFuture:
    """A finished computation, shaped like a ``distributed.Future`` (``key``, ``status``, ``result``)."""

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

    @classmethod
    def of_value(cls, key: str, value: Any) -> SyncFuture:
        """A future holding ``value`` (what :meth:`SyncClient.scatter` returns)."""
        return cls(key, lambda: value, (), {})

    def result(self) -> Any:
        if self._exc is not None:
            raise self._exc
        return self._value

    def exception(self) -> BaseException | None:
        return self._exc

    def done(self) -> bool:
        return True

    def cancel(self) -> None:
        """Nothing to stop: the task ran at submission."""


def _resolve(x: Any) -> Any:
    """``x`` with every in-process future inside (lists, tuples, dicts) replaced by its result."""
    if isinstance(x, (SyncFuture, concurrent.futures.Future)):
        return x.result()
    if isinstance(x, list):
        return [_resolve(v) for v in x]
    if isinstance(x, tuple):
        return tuple(_resolve(v) for v in x)
    if isinstance(x, dict):
        return {k: _resolve(v) for k, v in x.items()}
    return x


class SyncClient:
    """The in-process client (``--scheduler sync``): every method of :class:`ComputeClient`, no Dask.

    Tasks run when submitted; Dask's scheduling options (``retries``, ``resources``, ``workers``,
    ``pure``, ...) are accepted and ignored. A task's exception is kept in its future and raised by
    ``result``/``gather``, as with Dask.
    """

    dashboard_link = None
    synchronous = True
    status = "running"

    def __init__(self) -> None:
        self._count = 0

    def _key(self, fn: Any, key: str | None) -> str:
        self._count += 1
        return key or f"{getattr(fn, '__name__', 'task')}-{self._count}"

    def submit(self, fn: Callable[..., Any], /, *args: Any, key: str | None = None, **kwargs: Any) -> SyncFuture:
        for k in _DASK_ONLY:
            kwargs.pop(k, None)
        return SyncFuture(self._key(fn, key), fn, args, kwargs)

    def map(self, fn: Callable[..., Any], /, *iterables: Iterable[Any], key: str | list[str] | None = None,
            **kwargs: Any) -> list[SyncFuture]:
        """One future per element of the zipped ``iterables``, like ``distributed.Client.map``."""
        for k in _DASK_ONLY:
            kwargs.pop(k, None)
        out = []
        for i, args in enumerate(zip(*iterables)):
            name = key[i] if isinstance(key, list) else (f"{key}-{i}" if key else None)
            out.append(SyncFuture(self._key(fn, name), fn, tuple(args), dict(kwargs)))
        return out

    def scatter(self, data: Any, **kwargs: Any) -> Any:
        """Futures holding ``data``: a list gives a list, a dict a dict, anything else one future (as Dask)."""
        if isinstance(data, list):
            return [SyncFuture.of_value(self._key(None, None), v) for v in data]
        if isinstance(data, dict):
            return {k: SyncFuture.of_value(str(k), v) for k, v in data.items()}
        return SyncFuture.of_value(self._key(None, None), data)

    def gather(self, futures: Any, **kwargs: Any) -> Any:
        return _resolve(futures)

    def cancel(self, futures: Any, **kwargs: Any) -> None:
        """Nothing runs later than its submission: nothing to cancel."""

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        """The futures in submission order (each finished when submitted)."""
        yield from futures

    def scheduler_info(self) -> dict[str, Any]:
        return {"type": "in-process", "workers": {}}

    def close(self) -> None:
        """Nothing to release: tasks ran in this process when they were submitted."""

    def __enter__(self) -> SyncClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ThreadPoolClient(SyncClient):
    """An in-process client whose tasks run on ``max_workers`` threads of this process (FIFO).

    For work whose tasks release the GIL (compiled kernels, compression) and write to shared
    in-process objects: a stage uses it where the run's client runs in this process, to keep
    ``max_workers`` tasks in flight. A task's arguments may be futures of tasks submitted before it
    (the pool starts tasks in submission order, so it never waits on a task not yet started).
    """

    def __init__(self, max_workers: int = 2) -> None:
        super().__init__()
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=max_workers)

    def submit(self, fn: Callable[..., Any], /, *args: Any, key: str | None = None, **kwargs: Any) -> Any:
        for k in _DASK_ONLY:
            kwargs.pop(k, None)
        fut = self._pool.submit(lambda: fn(*[_resolve(a) for a in args], **{k: _resolve(v) for k, v in kwargs.items()}))
        fut.key = self._key(fn, key)  # type: ignore[attr-defined]
        return fut

    def map(self, fn: Callable[..., Any], /, *iterables: Iterable[Any], key: str | list[str] | None = None,
            **kwargs: Any) -> list[Any]:
        return [self.submit(fn, *args, key=key[i] if isinstance(key, list) else None, **kwargs)
                for i, args in enumerate(zip(*iterables))]

    def cancel(self, futures: Any, **kwargs: Any) -> None:
        for f in futures if isinstance(futures, list) else [futures]:
            f.cancel()

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        """The futures as they finish."""
        from concurrent.futures import as_completed as _as_completed

        yield from _as_completed(list(futures))

    def close(self) -> None:
        self._pool.shutdown(wait=True)


def as_completed(client: ComputeClient | None, futures: list[Any]) -> Iterator[Any]:
    """Futures in the order they finish (submission order for the synchronous client)."""
    if runs_in_process(client):
        yield from (client.as_completed(futures) if isinstance(client, SyncClient) else futures)
        return
    from distributed import as_completed as _as_completed

    yield from _as_completed(futures)


def runs_in_process(client: ComputeClient | None) -> bool:
    """True when tasks given to ``client`` run in this process: None or the in-process client.

    A stage takes the run's one client and asks this where its own loop of tasks runs, rather
    than deciding from the connection's mode.
    """
    return client is None or bool(getattr(client, "synchronous", False))


def client_or_sync(client: ComputeClient | None) -> ComputeClient:
    """``client``, or a :class:`SyncClient` for None (a stage called without a client runs in this process)."""
    return SyncClient() if client is None else client
