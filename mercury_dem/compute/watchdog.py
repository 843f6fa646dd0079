"""A run whose cluster has had no worker for too long ends, with :class:`NoWorkerError`, instead of waiting for ever.

Dask never fails a task for want of a worker: with every worker gone (killed, their nannies given
up, their batch jobs ended) the scheduler keeps the tasks and the client waits on their futures
for ever. :class:`NoWorkerWatchdog` looks at the scheduler's workers from a thread of the client's
process; when there has been none for ``timeout_s`` it records the error and cancels the
client's futures (with the error's message), so whatever the run is waiting on (the cascade's
``as_completed``, a stage's ``gather`` or ``result``) returns at once; the run then raises
:attr:`NoWorkerWatchdog.error`. Nothing is written by the cancellation: the units committed so far
stay, and the same command resumes the run. The in-process client has no workers to lose: no watch.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, cast

from mercury_dem.compute.client import ComputeClient, runs_in_process
from mercury_dem.exceptions import NoWorkerError

if TYPE_CHECKING:
    from distributed import Client


def count_workers(client: Client) -> int | None:
    """Workers the client's scheduler has now, or None when it cannot be asked (scheduler gone, closing)."""
    if getattr(client, "status", "running") != "running":
        return None
    try:
        return len(client.nthreads())
    except Exception:  # noqa: BLE001 - an unreachable scheduler is the scheduler-loss path's, not ours
        return None


def cancel_all_futures(client: Client, message: str) -> int:
    """Cancel every future the client holds (``message`` in their ``FutureCancelledError``); their number."""
    from distributed import Future

    futures: list[Any] = [Future(k, client) for k in list(client.futures)]
    if futures:
        client.cancel(futures, reason="no-worker", msg=message)
    return len(futures)


class NoWorkerWatchdog:
    """Ends a run whose cluster has had no worker for ``timeout_s`` seconds.

    Parameters
    ----------
    client : the run's ``distributed.Client``
    timeout_s : seconds without any worker before the run ends (``execution.no_worker_timeout_s``)
    scheduler : the scheduler's address or description, for the message
    resume_hint : how to resume, for the message (the run's command)
    poll_s : how often the scheduler is asked (default: a tenth of the timeout, 0.2-5 s)
    workers : how to count workers (for tests; default :func:`count_workers`)
    clock : monotonic seconds (for tests)

    Use as a context manager (a daemon thread polls while the block runs) or call :meth:`poll`.
    """

    def __init__(self, client: Client, timeout_s: float, scheduler: str, resume_hint: str = "run the same command",
                 poll_s: float | None = None, workers: Callable[[Client], int | None] = count_workers,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self.client = client
        self.timeout_s = float(timeout_s)
        self.scheduler = scheduler
        self.resume_hint = resume_hint
        self.poll_s = float(poll_s) if poll_s is not None else min(5.0, max(0.2, self.timeout_s / 10))
        self._workers = workers
        self._clock = clock
        self.no_worker_since: float | None = None  # monotonic
        self.no_worker_since_utc: datetime | None = None
        self.error: NoWorkerError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def poll(self) -> bool:
        """Look once; True when the run must end (the error is set and the futures cancelled)."""
        n = self._workers(self.client)
        if n is None:  # cannot tell: not counted as time without a worker
            return self.error is not None
        if n > 0:
            self.no_worker_since = self.no_worker_since_utc = None
            return self.error is not None
        now = self._clock()
        if self.no_worker_since is None:
            self.no_worker_since, self.no_worker_since_utc = now, datetime.now(UTC)
        if self.error is None and now - self.no_worker_since >= self.timeout_s:
            self.error = NoWorkerError(self.message())
        if self.error is not None:  # again at each look: futures submitted since are cancelled too
            self.cancel(str(self.error))
        return self.error is not None

    def cancel(self, message: str) -> None:
        cancel_all_futures(self.client, message)

    def message(self) -> str:
        since = self.no_worker_since_utc.isoformat(timespec="seconds") if self.no_worker_since_utc else "?"
        return (f"the Dask cluster (scheduler {self.scheduler}) has had no worker since {since} "
                f"(more than execution.no_worker_timeout_s = {self.timeout_s:g} s): every worker was lost and none "
                f"came back. The units finished so far are committed; start workers (or find what kills them: "
                f"memory limits, the batch system's wall time) and {self.resume_hint} to resume")

    def _loop(self) -> None:
        while not self._stop.wait(self.poll_s):
            try:
                self.poll()
            except Exception:  # noqa: BLE001 - a failed look must not kill the watch; the next one retries
                continue

    def __enter__(self) -> NoWorkerWatchdog:
        self._thread = threading.Thread(target=self._loop, name="mercury-dem-no-worker-watchdog", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=min(5.0, self.poll_s + 1.0))  # a daemon: a look stuck on a dead scheduler is left


def watch_workers(client: ComputeClient | None, timeout_s: float, scheduler: str,
                  resume_hint: str = "run the same command") -> NoWorkerWatchdog | None:
    """A :class:`NoWorkerWatchdog` for ``client``, or None for the in-process client (nothing to watch)."""
    if runs_in_process(client) or timeout_s <= 0:
        return None
    return NoWorkerWatchdog(cast("Client", client), timeout_s, scheduler, resume_hint)  # not in process: distributed's
