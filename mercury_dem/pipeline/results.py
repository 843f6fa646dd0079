"""Typed results of the stage runners: unit summaries and the files of a unit, serialized in one place.

A unit's ``summary.json`` (and the dict a runner returns to the task graph, the same thing) is the
JSON form of one of these dataclasses; :meth:`to_json` writes it and :func:`summary_from_json` reads
it back (:func:`read_summary` from a run store). Every reader (the task graph's bookkeeping,
``report.json``, ``viz.status`` and so the dashboard, ``viz.tables``, the commands) takes the typed
summary and reads attributes; :func:`summary_from_json` accepts the summaries of older runs that lack
fields, as the readers did when they read dicts (``.get`` with a default). The JSON is the contract the readers rely on (``report.json``'s levels, ``mercury-dem
report``, the dashboard, ``viz.status``, the notebooks): its keys and their values are exactly those
of the dicts the runners built before these types existed; the key order is kept stable for people
reading the files but no reader depends on it (``tests/pipeline/test_results.py`` compares with
hand-written JSON and a round trip on a run's summaries, not the order).

:class:`UnitFiles` replaces the ``"_files"`` key the runners once smuggled through the summary dict:
a runner's computation returns its summary fields and the files to write side by side, and
:meth:`mercury_dem.io.run_store.RunStore.write_unit` writes them (names from the run store).

Why dataclasses of our own and not a schema library (pydantic, attrs): the package's configuration
and results are frozen standard-library dataclasses already, and these only need stable keys
and a pass-through for the adjustment's open-ended summary.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mercury_dem.exceptions import (
    AdjustmentError,
    ConfigError,
    GeometryError,
    GridError,
    NetworkError,
    ReferenceDataError,
    StoreError,
)
from mercury_dem.io.run_store import (
    BUNDLEOUT_FILE,
    NETWORK_FILE,
    PAIRS_FILE,
    SOLUTION_FILE,
    RunStore,
    unit_name,
    write_solution,
)

if TYPE_CHECKING:  # numpy only in annotations: the readers of summaries ('mercury-dem report') load no numpy
    import numpy as np
    from numpy.typing import NDArray

    from mercury_dem.network.model import ControlNetwork

__all__ = ["FailureSummary", "Summary", "TileCounts", "TileSummary", "UnitFailure", "UnitFiles", "UnitSolution",
           "UnitSummary", "UnitTiming", "failure_of", "read_summary", "summary_from_json"]

_TIMING_KEYS = ("seconds", "finished_at", "started_at")


class UnitFailure(StrEnum):
    """Why a unit (tile, region, hemisphere, globe) failed: ``failure`` in its ``summary.json`` beside the
    human-readable ``error``, set where the failure is found (from the exception's type,
    :func:`failure_of`); the report counts failed units by it and nothing parses ``error``. A summary of an
    older run has none (read as None, counted as ``unrecorded``).
    """

    NO_PAIRS = "no_pairs"  # a tile without overlapping image pairs: nothing to match
    NO_MATCH = "no_match"  # a tile whose pairs gave no control point
    NO_INPUT = "no_input"  # a merged unit without a successful child network, or no measures once merged
    CORRUPT_INPUT = "corrupt_input"  # a store or unit file it reads is missing, cut or fails its checksums
    BAD_INPUT = "bad_input"  # unusable geometry, network, reference data or configuration for this unit
    ADJUSTMENT_FAILED = "adjustment_failed"  # the bundle adjustment cannot be solved (AdjustmentError)
    OTHER = "other"  # another of the package's own errors
    UNEXPECTED = "unexpected"  # the task died with an unexpected exception (FailureSummary: a bug, a lost worker)


#: The failure kind of an exception's type, first match wins (an exception may also carry its own ``failure``).
_FAILURE_OF_TYPE: tuple[tuple[type[BaseException] | tuple[type[BaseException], ...], UnitFailure], ...] = (
    (StoreError, UnitFailure.CORRUPT_INPUT),
    (AdjustmentError, UnitFailure.ADJUSTMENT_FAILED),
    ((GeometryError, NetworkError, ReferenceDataError, ConfigError, GridError), UnitFailure.BAD_INPUT),
)


def failure_of(exc: BaseException) -> UnitFailure:
    """The :class:`UnitFailure` of an exception a unit caught: its own ``failure`` attribute when it has one,
    else by its type (:data:`_FAILURE_OF_TYPE`), else ``OTHER``.
    """
    own = getattr(exc, "failure", None)
    if isinstance(own, UnitFailure):
        return own
    for types, kind in _FAILURE_OF_TYPE:
        if isinstance(exc, types):
            return kind
    return UnitFailure.OTHER


def _failure_from_json(d: Mapping[str, Any]) -> UnitFailure | None:
    """A summary's ``failure``; None when it has none (an older run, or a unit that did not fail) or an unknown one."""
    v = d.get("failure")
    try:
        return None if v is None else UnitFailure(v)
    except ValueError:
        return None


@dataclass(frozen=True)
class UnitTiming:
    """When a unit ran: its duration and wall-clock end and start (s since the epoch: level spans across workers)."""

    seconds: float
    finished_at: float | None = None
    started_at: float | None = None

    @classmethod
    def since(cls, t0: float) -> UnitTiming:
        """The timing of a unit that started at ``t0`` (``time.perf_counter()``) and ends now."""
        seconds = time.perf_counter() - t0
        finished = time.time()
        return cls(seconds=seconds, finished_at=finished, started_at=finished - seconds)

    def to_json(self) -> dict[str, float]:
        out = {"seconds": self.seconds, "finished_at": self.finished_at, "started_at": self.started_at}
        return {k: v for k, v in out.items() if v is not None}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> UnitTiming | None:
        """The timing keys of a summary; None without ``seconds`` (a unit not written yet). The wall-clock
        ``finished_at``/``started_at`` may be missing (older runs): None then.
        """
        if d.get("seconds") is None:
            return None
        return cls(**{k: d[k] for k in _TIMING_KEYS if k in d})


@dataclass(frozen=True)
class TileCounts:
    """What a tile's matching and network building gave (the keys of a tile's summary after ``error``)."""

    images: int
    images_involved: int
    pairs: int
    pairs_matched: int
    routes: dict[str, int]
    pair_failures: dict[str, int]
    image_errors: dict[str, str]
    points: int
    measures: int
    #: pairs not matched because a narrower route joins their images (``match.redundant_convergence_deg``):
    #: neither matched nor failed
    pairs_redundant: int = 0

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> TileCounts | None:
        """The counts of a tile's summary; None when it has none (the tile failed before matching). A count an
        older run did not record reads as empty (0, ``{}``), as the readers of the dicts had it.
        """
        if "images" not in d:
            return None
        empty: dict[str, Any] = {"routes": {}, "pair_failures": {}, "image_errors": {}}
        return cls(**{f.name: d.get(f.name, empty.get(f.name, 0)) for f in dataclasses.fields(cls)})


@dataclass(frozen=True)
class TileSummary:
    """A tile's ``summary.json``.

    ``counts`` is None when the tile failed before matching (its ``error`` says why); ``timing`` is
    None until the unit is written.
    """

    id: int
    ok: bool = False
    error: str | None = None
    counts: TileCounts | None = None
    timing: UnitTiming | None = None
    failure: UnitFailure | None = None
    level: str = field(default="tile", init=False)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"level": "tile", "id": int(self.id), "ok": self.ok, "error": self.error}
        if self.failure is not None:
            out["failure"] = self.failure.value
        if self.counts is not None:
            out.update(self.counts.to_json())
        if self.timing is not None:
            out.update(self.timing.to_json())
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> TileSummary:
        return cls(id=int(d["id"]), ok=bool(d.get("ok")), error=d.get("error"), counts=TileCounts.from_json(d),
                   timing=UnitTiming.from_json(d), failure=_failure_from_json(d))

    @property
    def name(self) -> str:
        return unit_name("tile", self.id)

    @property
    def seconds(self) -> float | None:
        return None if self.timing is None else self.timing.seconds

    @property
    def images(self) -> int | None:
        return None if self.counts is None else self.counts.images

    @property
    def points(self) -> int | None:
        return None if self.counts is None else self.counts.points

    @property
    def measures(self) -> int | None:
        return None if self.counts is None else self.counts.measures

    @property
    def image_errors(self) -> dict[str, str]:
        """Images whose pixels could not be used (id -> reason); empty without counts."""
        return {} if self.counts is None else dict(self.counts.image_errors or {})


@dataclass(frozen=True)
class UnitSummary:
    """The ``summary.json`` of a merged unit (region, hemisphere, globe).

    Attributes
    ----------
    children : ids of the children merged; None when the unit failed before merging.
    adjustment : the adjustment's summary (:attr:`mercury_dem.adjust.unit.UnitAdjustment.summary`:
        images, points, rms_px, sigma0, ..., and the optional ``blocked``, ``altimetry``, ``levelling``,
        ``point_prior``), with ``images_without_measures`` covering the merge's too; open-ended, kept in order.
    single_measure_points : count and first ids (:func:`mercury_dem.network.check.singular_parts`).
    """

    level: str
    id: int
    ok: bool = False
    error: str | None = None
    children: list[int] | None = None
    adjustment: dict[str, Any] = field(default_factory=dict)
    single_measure_points: dict[str, Any] | None = None
    timing: UnitTiming | None = None
    failure: UnitFailure | None = None

    @property
    def name(self) -> str:
        return unit_name(self.level, self.id)

    @property
    def seconds(self) -> float | None:
        return None if self.timing is None else self.timing.seconds

    # the adjustment's figures the readers show (None when the unit has none: it failed, or an older run)
    @property
    def images(self) -> int | None:
        return self.adjustment.get("images")

    @property
    def points(self) -> int | None:
        return self.adjustment.get("points")

    @property
    def measures(self) -> int | None:
        return self.adjustment.get("measures")

    @property
    def rms_px(self) -> float | None:
        return self.adjustment.get("rms_px")

    @property
    def sigma0(self) -> float | None:
        return self.adjustment.get("sigma0")

    @property
    def iterations(self) -> int | None:
        return self.adjustment.get("iterations")

    @property
    def sigma0_history(self) -> list[float]:
        return list(self.adjustment.get("sigma0_history") or [])

    @property
    def flagged_images(self) -> list[dict[str, Any]]:
        """Images flagged for their residuals: ``{"image", "rms_px", ...}`` each."""
        return list(self.adjustment.get("flagged_images") or [])

    @property
    def weak_images(self) -> list[str]:
        return list(self.adjustment.get("weak_images") or [])

    @property
    def levelling(self) -> dict[str, Any] | None:
        """The levelling decision of the unit (:func:`mercury_dem.adjust.datum.levelling_decision`), if any."""
        lev = self.adjustment.get("levelling")
        return lev if isinstance(lev, dict) else None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"level": self.level, "id": int(self.id), "name": self.name, "ok": self.ok,
                               "error": self.error}
        if self.failure is not None:
            out["failure"] = self.failure.value
        if self.children is not None:
            out["children"] = self.children
            out.update(self.adjustment)
            if self.single_measure_points is not None:
                out["single_measure_points"] = self.single_measure_points
        if self.timing is not None:
            out.update(self.timing.to_json())
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> UnitSummary:
        own = {"level", "id", "name", "ok", "error", "failure", "children", "single_measure_points", *_TIMING_KEYS}
        return cls(level=str(d["level"]), id=int(d["id"]), ok=bool(d.get("ok")), error=d.get("error"),
                   children=d.get("children"), adjustment={k: v for k, v in d.items() if k not in own},
                   single_measure_points=d.get("single_measure_points"), timing=UnitTiming.from_json(d),
                   failure=_failure_from_json(d))


@dataclass(frozen=True)
class FailureSummary:
    """The summary of a task that died with an unexpected exception (a bug, a lost worker); not written."""

    level: str
    id: int
    error: str
    traceback: str
    ok: bool = field(default=False, init=False)
    timing: UnitTiming | None = field(default=None, init=False)
    failure: UnitFailure = field(default=UnitFailure.UNEXPECTED, init=False)

    @property
    def name(self) -> str:
        return unit_name(self.level, self.id)

    @property
    def seconds(self) -> float | None:
        return None

    @classmethod
    def of(cls, level: str, unit_id: int, exc: BaseException) -> FailureSummary:
        return cls(level=level, id=int(unit_id),
                   error=f"{unit_name(level, unit_id)}: unexpected {type(exc).__name__}: {exc}",
                   traceback="".join(traceback.format_exception(exc))[-4000:])

    def to_json(self) -> dict[str, Any]:
        return {"level": self.level, "id": int(self.id), "name": unit_name(self.level, self.id), "ok": False,
                "error": self.error, "failure": self.failure.value, "traceback": self.traceback}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FailureSummary:
        return cls(level=str(d["level"]), id=int(d["id"]), error=str(d["error"]), traceback=str(d["traceback"]))


#: A unit's summary, whatever its level and outcome (the readers use ``level``, ``id``, ``name``, ``ok``,
#: ``error``, ``failure``, ``timing`` and ``seconds`` of each).
Summary = TileSummary | UnitSummary | FailureSummary


def summary_from_json(d: Mapping[str, Any]) -> Summary:
    """The typed summary of a unit's JSON (``summary.json``, or a summary a runner returned)."""
    if "traceback" in d:
        return FailureSummary.from_json(d)
    if d.get("level") == "tile":
        return TileSummary.from_json(d)
    return UnitSummary.from_json(d)


def read_summary(store: RunStore, level: str, unit_id: int) -> Summary:
    """The typed ``summary.json`` of a unit of a run (:meth:`RunStore.read_summary` reads its JSON).

    The unit's level and id come from where it is stored when its JSON lacks them (a damaged or foreign
    file is then judged by the unit's checksums where it is merged, as the dict readers left it, not by a
    ``KeyError`` here).
    """
    d = dict(store.read_summary(level, unit_id))
    d.setdefault("level", level)
    d.setdefault("id", unit_id)
    return summary_from_json(d)


@dataclass(frozen=True)
class UnitSolution:
    """A merged unit's adjusted pointing (its ``solution.parquet``): per image, rotation, position, extra columns."""

    image_ids: NDArray[Any]
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    extra: dict[str, NDArray[Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class UnitFiles:
    """The data files of a unit, next to its summary; each None is not written."""

    network: ControlNetwork | None = None  # -> network.zarr
    pairs: Any = None  # pandas.DataFrame, one row per matched pair -> pairs.parquet (tiles)
    solution: UnitSolution | None = None  # -> solution.parquet (merged units)
    bundleout: str | None = None  # jigsaw-like report -> bundleout.txt (merged units)
    #: a complete network store already written (a unit adjusted from its merged store) -> moved to network.zarr
    network_dir: Path | None = None

    def writers(self) -> dict[str, Callable[[Path], object]]:
        """For :meth:`~mercury_dem.io.run_store.RunStore.write_unit`: file name -> a function writing it at a path."""
        out: dict[str, Callable[[Path], object]] = {}
        if self.bundleout is not None:
            text = self.bundleout
            out[BUNDLEOUT_FILE] = lambda p: p.write_text(text)
        if self.network is not None:
            from mercury_dem.io.network_store import write_network

            net = self.network
            out[NETWORK_FILE] = lambda p: write_network(net, p)
        elif self.network_dir is not None:
            src = self.network_dir
            out[NETWORK_FILE] = lambda p: shutil.move(str(src), str(p))  # a rename on one file system
        if self.pairs is not None:
            pairs = self.pairs
            out[PAIRS_FILE] = lambda p: pairs.to_parquet(p, index=False)
        if self.solution is not None:
            sol = self.solution
            out[SOLUTION_FILE] = lambda p: write_solution(p, sol.image_ids, sol.rotations, sol.positions, sol.extra)
        return out
