"""Exceptions of mercury_dem.

Expected failures (a tile with no images, a pair with no matches) are recorded as
values in reports; the exceptions below are for inputs or states a caller must
fix. Every message names the thing at fault (image, tile, file, key) and says
what to do.
"""

from __future__ import annotations


class MercuryDemError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(MercuryDemError, ValueError):
    """A configuration key has a bad value or is unknown."""


class GeometryError(MercuryDemError, ValueError):
    """Geometry of an image (position, rotation, camera) is missing or invalid."""


class IsdError(GeometryError):
    """A CSM/ALE image support data (ISD) file lacks a key or has a bad value."""


class CubeError(GeometryError):
    """An ISIS3 cube is unreadable, truncated, or lacks what is asked of it (a table, SPICE)."""


class StoreError(MercuryDemError):
    """A mission or run store is missing, incomplete or would be overwritten."""


class NetworkError(MercuryDemError, ValueError):
    """A control network is inconsistent (dangling ids, bad measures, bad file)."""


class AdjustmentError(MercuryDemError):
    """A bundle adjustment cannot be solved (islands, under-determined unknowns)."""


class GridError(MercuryDemError, ValueError):
    """A DEM cannot be gridded as asked (no points, grid too large for memory)."""


class ReferenceDataError(MercuryDemError, ValueError):
    """A reference-height file (altimetry shots, shape harmonics, reference DEM) is unreadable.

    The message names the file and the fault (line, column, value) so the user can
    fetch a fresh copy or fix the column mapping.
    """


class CorruptUnitError(StoreError):
    """A committed unit's files differ from the checksums written into its completion marker.

    The message names the unit and each file ("checksum mismatch", "missing", ...). The unit
    is not trusted: a resumed run recomputes it (``mercury-dem verify RUN`` lists them all).
    """


class DiskFullError(StoreError):
    """The run's file system is full (ENOSPC/EDQUOT) while a stage writes.

    Fatal for the run (never recorded as a per-unit failure, which would silently drop the
    unit's data downstream): nothing half-written is kept; the message names the stage or
    unit, the path, and says to free space (or move the run) and resume.
    """


class SchedulerLostError(MercuryDemError):
    """The Dask scheduler of a run went away (killed, its machine lost) and the client could not reconnect.

    The units finished so far are committed; the message says to start a scheduler and workers
    again and resume with the same command.
    """


class NoWorkerError(MercuryDemError):
    """The run's Dask cluster has had no worker for longer than ``execution.no_worker_timeout_s``.

    A fact about the infrastructure, never about the unit that was waiting: the units finished so
    far are committed; the message names the scheduler and since when it has had no worker, and
    says to start workers (or fix what kills them) and run the same command to resume.
    """
