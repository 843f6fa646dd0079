"""The one rule for "does this error stop the run, or is it the unit's own failure".

A task's exception is either a fact about its unit (a bug, bad data: recorded as that unit's
failure, the run goes on) or a fact about the run's infrastructure (a full disk, a corrupt input
unit, no worker left, the scheduler gone): recording that as the unit's failure would commit a unit
without its data and silently drop it downstream, so it stops the run with its own exception,
whose message says how to resume. Every place that catches a task's exception asks
:func:`run_stopping_error` (or :func:`raise_if_run_stopping`).
"""

from __future__ import annotations

from typing import Any

from mercury_dem.exceptions import (
    CorruptUnitError,
    DiskFullError,
    MercuryDemError,
    NoWorkerError,
    SchedulerLostError,
)
from mercury_dem.io.atomic import disk_full_cause, disk_full_message

#: Errors that are facts about the run's infrastructure, never about the unit that raised or waited.
RUN_STOPPING = (DiskFullError, CorruptUnitError, SchedulerLostError, NoWorkerError)


def run_stopping_error(exc: BaseException, name: str, where: Any) -> MercuryDemError | None:
    """The run-stopping error ``exc`` is, or None when it is the unit's own failure.

    Parameters
    ----------
    exc : what a task (or the wait for it) raised
    name : the unit, for a full disk's message ("tile 17", "region 3")
    where : the run's location (path or URL), for that message

    Returns
    -------
    ``exc`` itself when it is already one of :data:`RUN_STOPPING`; a :class:`DiskFullError` when an
    ENOSPC/EDQUOT is anywhere in its chain; otherwise None.
    """
    if isinstance(exc, RUN_STOPPING):
        return exc
    cause = disk_full_cause(exc)
    if cause is not None:
        return DiskFullError(disk_full_message(name, cause, where))
    return None


def raise_if_run_stopping(exc: BaseException, name: str, where: Any) -> None:
    """Raise the run-stopping error ``exc`` is (:func:`run_stopping_error`); return when it is the unit's own."""
    fatal = run_stopping_error(exc, name, where)
    if fatal is exc:
        raise exc
    if fatal is not None:
        raise fatal from exc


def lost_to_the_cluster(exc: BaseException) -> bool:
    """Whether a task's future failed because the cluster dropped it (cancelled: its scheduler went away),
    not because of anything the task computed. Such an error is the run's, never the task's unit's.
    """
    import asyncio
    import concurrent.futures

    # distributed's FutureCancelledError is a concurrent.futures.CancelledError
    return isinstance(exc, (asyncio.CancelledError, concurrent.futures.CancelledError))
