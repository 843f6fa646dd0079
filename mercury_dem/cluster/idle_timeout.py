"""An idle timeout for throw-away Dask schedulers that starts counting only once somebody has joined.

Dask's own ``dask scheduler --idle-timeout N`` counts from the scheduler's start and ignores clients: on a
fresh machine a worker can need more than N s just to import, so a scheduler with a short timeout closes
before its first worker joins (``cluster/local/start.sh --idle-timeout 2`` then failed every time with
"the workers did not all join"). This plugin closes the scheduler instead

- after ``idle`` seconds with no task queued, processing or waiting for a worker and no client
  connected, counted from the first worker or client that joined (and from the last activity after that);
- or, if no worker and no client has joined at all, ``join_bound`` seconds after the scheduler started,
  so a deployment nobody ever uses (its launcher killed before the workers came up) still ends.

Use it as a scheduler preload, by module name or by file path (``cluster/local/start.sh`` uses the path, so the
interpreter running the scheduler needs only ``distributed``)::

    dask scheduler --preload mercury_dem/cluster/idle_timeout.py --idle-after-join 60 --join-bound 660

This module imports nothing from ``mercury_dem`` for that reason.
"""

from __future__ import annotations

import asyncio
import logging
from time import monotonic
from typing import Any

import click
from distributed.diagnostics.plugin import SchedulerPlugin
from tornado.ioloop import PeriodicCallback

logger = logging.getLogger("distributed.scheduler")

#: The pseudo-client every scheduler has from its start; it is nobody joining.
_SCHEDULER_OWN_CLIENTS = frozenset({"fire-and-forget"})


class IdleAfterJoin(SchedulerPlugin):
    """Close the scheduler after ``idle`` s unused, counted from the first join; ``join_bound`` s if nobody joins.

    ``interval`` is how often (s) the scheduler is looked at.
    """

    name = "mercury-dem-idle-after-join"

    def __init__(self, idle: float, join_bound: float, interval: float = 0.5) -> None:
        if idle <= 0 or join_bound <= 0:
            raise ValueError(f"idle ({idle}) and join_bound ({join_bound}) must be positive")
        self.idle = float(idle)
        self.join_bound = float(join_bound)
        self.interval = float(interval)
        self.scheduler: Any = None
        self.started = monotonic()
        self.joined = False
        self.idle_since: float | None = None
        self._transitions = -1
        self._closing = False

    async def start(self, scheduler: Any) -> None:
        self.scheduler = scheduler
        self.started = monotonic()
        pc = PeriodicCallback(self.check, self.interval * 1000)
        # The scheduler starts the callbacks it holds after its plugins, and stops them when it closes.
        scheduler.periodic_callbacks[self.name] = pc
        if getattr(scheduler.status, "name", "") == "running" and not pc.is_running():
            pc.start()  # added to a scheduler already running

    def add_worker(self, scheduler: Any, worker: str) -> None:
        self._join()

    def add_client(self, scheduler: Any, client: str) -> None:
        if client not in _SCHEDULER_OWN_CLIENTS:
            self._join()

    def _join(self) -> None:
        if not self.joined:
            self.joined = True
            self.idle_since = monotonic()

    def _clients(self) -> int:
        return sum(1 for c in self.scheduler.clients if c not in _SCHEDULER_OWN_CLIENTS)

    def _busy(self) -> bool:
        s = self.scheduler
        if self._clients() or getattr(s, "_active_graph_updates", 0):
            return True
        if s.queued or s.unrunnable or any(ws.processing for ws in s.workers.values()):
            return True
        counter = getattr(s, "transition_counter", 0)  # any task transition since the last look is activity
        changed = counter != self._transitions
        self._transitions = counter
        return changed

    def check(self) -> None:
        """One look at the scheduler (every ``interval`` s): close it when the time is up."""
        s = self.scheduler
        if s is None or self._closing or getattr(s.status, "name", "") in ("closing", "closed"):
            return
        now = monotonic()
        if not self.joined and (s.workers or self._clients()):
            self._join()  # joined before this plugin started
        if not self.joined:
            if now - self.started > self.join_bound:
                self._close(f"no worker or client joined within {self.join_bound:g} s of its start "
                            "(idle timeout bound)")
            return
        if self._busy():
            self.idle_since = now
            return
        if self.idle_since is None:
            self.idle_since = now
        elif now - self.idle_since > self.idle:
            self._close(f"being idle for {self.idle:g} s (no task and no client since the first join)")

    def _close(self, why: str) -> None:
        self._closing = True
        logger.info("Scheduler closing after %s", why)
        asyncio.ensure_future(self.scheduler.close(reason="idle-timeout-exceeded"))


@click.command()
@click.option("--idle-after-join", "idle", type=float, required=True,
              help="Close after this many seconds with no task and no client, counted from the first join.")
@click.option("--join-bound", type=float, default=None,
              help="Close this many seconds after the start if no worker or client ever joined "
                   "(default: 600 s plus --idle-after-join).")
def dask_setup(scheduler: Any, idle: float, join_bound: float | None) -> None:
    """The preload's entry point: add :class:`IdleAfterJoin` to the scheduler."""
    bound = join_bound if join_bound is not None else 600.0 + idle
    scheduler.add_plugin(IdleAfterJoin(idle, bound))
    logger.info("Idle timeout: %g s counted from the first worker or client; %g s if nobody joins", idle, bound)
