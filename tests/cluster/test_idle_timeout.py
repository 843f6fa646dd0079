"""mercury_dem/cluster/idle_timeout.py: the idle clock of a throw-away scheduler starts at the first join.

In-process schedulers (no worker processes): a few seconds in all. The scripts' end-to-end check is
``test_local_scripts.py::test_idle_timeout_ends_a_deployment_whose_caller_is_gone``.
"""

from __future__ import annotations

import asyncio
import time

import pytest
from distributed import Client, Scheduler

from mercury_dem.cluster.idle_timeout import IdleAfterJoin


async def _closed_within(s: Scheduler, seconds: float) -> float | None:
    """Seconds until ``s`` closed, or None if it is still open after ``seconds``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if s.status.name in ("closing", "closed"):
            return time.monotonic() - t0
        await asyncio.sleep(0.05)
    return None


def test_the_idle_clock_starts_at_the_first_join_not_at_the_start() -> None:
    async def main() -> None:
        plugin = IdleAfterJoin(idle=0.5, join_bound=30, interval=0.1)
        async with Scheduler(host="127.0.0.1", port=0, dashboard=False, dashboard_address="127.0.0.1:0") as s:
            s.add_plugin(plugin)
            await plugin.start(s)  # added after the start: the plugin starts its own callback
            # Nobody has joined: 4 x the idle time passes and the scheduler stays up (Dask's own
            # --idle-timeout would have closed it, as on a cold machine whose first worker imports slowly).
            assert await _closed_within(s, 2.0) is None
            async with Client(s.address, asynchronous=True) as c:
                # A connected client, even doing nothing, keeps it up.
                assert await _closed_within(s, 1.5) is None
                assert plugin.joined and c.status == "running"
            # The client left: closed about ``idle`` later.
            took = await _closed_within(s, 5.0)
            assert took is not None and took >= 0.4, took
    asyncio.run(main())


def test_a_scheduler_nobody_joins_ends_after_the_bound() -> None:
    async def main() -> None:
        plugin = IdleAfterJoin(idle=0.3, join_bound=1.0, interval=0.1)
        async with Scheduler(host="127.0.0.1", port=0, dashboard=False, dashboard_address="127.0.0.1:0") as s:
            s.add_plugin(plugin)
            await plugin.start(s)
            took = await _closed_within(s, 5.0)
            assert took is not None and 0.7 <= took <= 3.0, took
            assert not plugin.joined
    asyncio.run(main())


def test_timeouts_must_be_positive() -> None:
    with pytest.raises(ValueError, match="must be positive"):
        IdleAfterJoin(idle=0, join_bound=10)
