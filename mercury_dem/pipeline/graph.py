"""The run: tiles -> 14 regions -> 2 hemispheres -> globe, then the DEM, on any client.

The whole merge tree is submitted up front: each region task depends on its
tiles' futures, each hemisphere on its regions', the globe on both hemispheres,
so a region starts as soon as its own tiles are done. Tasks pass store paths and
small summaries, never networks or images. Every task is wrapped so an
unexpected exception becomes a failure summary (the run goes on); a lost worker
is retried by Dask (``retries``). Units already complete in the store are
skipped by the runners themselves, which is how a killed run resumes.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from mercury_dem.compute import (
    ADJUST_RESOURCE,
    RUN_STOPPING,
    Connection,
    as_completed,
    connect,
    lost_to_the_cluster,
    performance_report,
    raise_if_run_stopping,
    runs_in_process,
)
from mercury_dem.compute.watchdog import NoWorkerWatchdog, watch_workers
from mercury_dem.config import Config, to_dict
from mercury_dem.exceptions import DiskFullError, SchedulerLostError, StoreError
from mercury_dem.io.atomic import disk_full_cause, disk_full_message, sweep_temporaries, verify_complete
from mercury_dem.io.run_store import DEM_OUTPUTS, DENSE_OUTPUTS, PLAN_DIR, RunStore
from mercury_dem.pipeline.report import build_report, unit_message, versions, write_report
from mercury_dem.pipeline.results import FailureSummary, Summary, summary_from_json
from mercury_dem.pipeline.shard_engine import shard_engine_factory
from mercury_dem.pipeline.stages import failure_summary, plan_run, run_adjust_unit, run_tile, unit_name
from mercury_dem.plan.tree import CHILD_LEVEL, LEVELS, merge_tree

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient

#: Stages in order; ``--force STAGE`` recomputes that stage and every later one.
STAGES = ("plan", *LEVELS, "dem", "dense")


def safe_call(fn: Callable[..., dict[str, Any]], level: str, unit_id: int, *args: Any) -> dict[str, Any]:
    """Run a stage runner; an unexpected exception becomes a failure summary.

    Except a full disk or a corrupt input unit (:func:`~mercury_dem.compute.failures.run_stopping_error`):
    those are raised (as :class:`DiskFullError` / :class:`CorruptUnitError`) and stop the run.
    """
    try:
        return fn(*args)
    except Exception as exc:  # noqa: BLE001 - recorded as a value, see module docstring
        raise_if_run_stopping(exc, unit_name(level, unit_id), args[0] if args else "the run")
        return failure_summary(level, unit_id, exc)


def _tile_task(run_root: str, tile_id: int, config: Config) -> dict[str, Any]:
    return safe_call(run_tile, "tile", tile_id, run_root, tile_id, config)


def _unit_task(run_root: str, level: str, unit_id: int, config: Config, children: list[dict[str, Any]]) -> dict[str, Any]:
    # a blocked adjustment (adjust.blocked_min_measures) of a unit running on a Dask worker spreads its point
    # blocks over the run's workers (shard_engine.worker_shard_engine); in a sync run it stays in this process
    factory = shard_engine_factory(config.adjust.blocked_tree_min_workers) if config.adjust.blocked_on_workers else None
    return safe_call(run_adjust_unit, level, unit_id, run_root, level, unit_id, config, children, factory)


class Progress:
    """Per-level counts, elapsed time and ETAs of the cascade as units finish (:mod:`mercury_dem.progress`).

    Updated from ``as_completed`` on the units' futures (Dask's completion order); a bar on a
    terminal, periodic plain lines otherwise; a failed unit is printed at once with its message.
    """

    def __init__(self, totals: dict[str, int], stream: TextIO | None = sys.stdout, enabled: bool = True,
                 mode: str | None = None):
        from mercury_dem.progress import LevelTask, Reporter

        self.totals = totals
        self.reporter = Reporter(stream if enabled else None, mode)
        self.task = LevelTask(self.reporter, "adjustment cascade", totals)
        self.done = self.task.done
        self.failed = self.task.failed

    def update(self, summary: Summary) -> None:
        msg = "" if summary.ok else f"{summary.name} FAILED: {unit_message(summary.error, summary.name)}"
        self.task.update(summary.level, failed=not summary.ok, message=msg)

    def close(self) -> None:
        self.task.close()


#: Configuration sections that say how a run executes, not what it computes (serial == distributed): a run may
#: resume with other values (more workers, another no-worker timeout).
EXECUTION_ONLY_SECTIONS = frozenset({"execution"})


def changed_sections(before: dict[str, Any], after: dict[str, Any],
                     defaults: dict[str, Any] | None = None) -> list[str]:
    """The configuration sections whose values differ and that change results (execution-only ones skipped).

    ``defaults`` (the default configuration as a dict): a key missing from a section of ``before`` (a parameter
    added since that run was made, e.g. ``adjust.rms_flag_px``) counts as its default value, so a run resumes
    with a newer version as long as the new parameters keep their defaults.
    """
    defaults = defaults or {}
    before = {k: ({**defaults[k], **v} if isinstance(v, dict) and isinstance(defaults.get(k), dict) else v)
              for k, v in before.items()}
    keys = (set(before) | set(after)) - EXECUTION_ONLY_SECTIONS
    return sorted(k for k in keys if before.get(k) != after.get(k))


def prepare_store(mission_path: str | Path, out: str | Path, config: Config, force: str | None) -> RunStore:
    """Create or reopen ``RUN``; a run of another mission is refused; ``force`` clears stages.

    ``out`` and ``mission_path`` may be object-store URLs (:mod:`mercury_dem.io.location`); an
    unsupported scheme or a missing fsspec backend is refused here, before anything is written.
    """
    from mercury_dem.io.location import resolve_location

    store = RunStore(resolve_location(out, "--out"))
    mission_loc = resolve_location(mission_path, "mission")
    mission_abs = mission_loc if isinstance(mission_loc, str) else str(mission_loc.resolve())
    if store.url is not None:
        store.check_writable()
    if store.has_run():
        prev = store.read_run()
        if prev.get("mission") != mission_abs:
            raise StoreError(
                f"{out} holds a run of mission {prev.get('mission')}, not {mission_abs}; choose another --out"
            )
        changed = changed_sections(prev.get("config") or {}, to_dict(config), to_dict(Config()))
        if changed and force is None:
            raise StoreError(
                f"{out} was run with a different configuration (section{'s' if len(changed) > 1 else ''} "
                f"{', '.join(changed)}); resume with the same one, or recompute with --force plan (or a later stage)"
            )
    elif not store.is_empty():
        raise StoreError(f"{out} exists and is not a mercury-dem run; choose an empty or new --out")
    # the a-priori pointing sigma: a mission that declares none, with no override, is refused before RUN is
    # written (a run.json written first would make the corrected configuration a "different configuration")
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.stages import pointing_sigma_urad_for

    pointing_sigma_urad_for(open_mission(mission_path), config)
    store.root.mkdir(parents=True, exist_ok=True)
    # A resumed run: what a killed writer left half-written is removed before anything else runs.
    sweep_temporaries(store.root)
    if force is not None:
        if force not in STAGES:
            raise StoreError(f"--force takes one of {', '.join(STAGES)}, got {force!r}")
        for stage in STAGES[STAGES.index(force):]:
            if stage == "plan":
                store.remove(PLAN_DIR)
            elif stage in LEVELS:
                store.remove_level(stage)
            elif stage == "dem":
                for name in DEM_OUTPUTS:
                    store.remove(name)
            elif stage == "dense":
                for name in DENSE_OUTPUTS:
                    store.remove(name)
    store.write_run({
        "mission": mission_abs,
        "config": to_dict(config),
        "versions": versions(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    })
    return store


def run_pipeline(
    mission_path: str | Path,
    out: str | Path,
    config: Config,
    *,
    scheduler: str | None = None,
    scheduler_file: str | None = None,
    workers: int | None = None,
    threads_per_worker: int | None = None,
    force: str | None = None,
    security: Any = None,
    stream: TextIO | None = sys.stdout,
    connection: Connection | None = None,
    dem: bool = True,
) -> dict[str, Any]:
    """Run (or resume) the whole job; return the report (also written to ``RUN/report.json``).

    A resumed run verifies every finished unit against the checksums in its completion marker
    before trusting it; a unit that fails is named (stream and ``report["integrity"]``), removed
    and recomputed.

    Raises
    ------
    DiskFullError : the run's file system filled up (at any stage); nothing half-written is kept,
        resume once space is freed.
    CorruptUnitError : a unit's files changed during this run, after it was verified (it is withdrawn:
        the next resume recomputes it).
    SchedulerLostError : the Dask scheduler went away and the client could not reconnect.
    NoWorkerError : the Dask cluster had no worker for ``execution.no_worker_timeout_s`` seconds.
    Both are recorded in ``run.json`` (``infrastructure_failure``), never as a unit's failure; the same
    command resumes the run.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    stage = ["preparing the run directory"]  # what is being written, for a full disk's message
    integrity: dict[str, Any] = {"verified_units": 0, "unverifiable_units": 0, "corrupt": [], "verify_seconds": 0.0}
    try:
        return _run_pipeline(mission_path, out, config, scheduler, scheduler_file, workers, threads_per_worker, force,
                             security, stream, connection, dem, t_start, timings, stage, integrity)
    except RUN_STOPPING:
        raise
    except Exception as exc:  # noqa: BLE001 - only a full disk is converted, anything else re-raised as is
        cause = disk_full_cause(exc)
        if cause is None:
            raise
        raise DiskFullError(disk_full_message(stage[0], cause, out)) from exc


def _run_pipeline(mission_path: str | Path, out: str | Path, config: Config, scheduler: str | None,
                  scheduler_file: str | None, workers: int | None, threads_per_worker: int | None,
                  force: str | None, security: Any, stream: TextIO | None, connection: Connection | None,
                  dem: bool, t_start: float, timings: dict[str, float], stage: list[str],
                  integrity: dict[str, Any]) -> dict[str, Any]:
    from mercury_dem.mission import open_mission
    store = prepare_store(mission_path, out, config, force)
    mission = open_mission(mission_path)
    t = time.perf_counter()
    stage[0] = "the plan (RUN/plan)"
    if store.plan_complete() and not _plan_corrupt(store, integrity, stream):
        plan = store.read_plan_info()
    else:
        plan = plan_run(store, mission, config)
    timings["plan"] = time.perf_counter() - t

    own = connection is None
    conn = connection or connect(config.execution, scheduler, scheduler_file, workers, threads_per_worker, security)
    _announce(store, conn, stream)
    perf = performance_report(conn, str(store.performance_html))
    watchdog = watch_workers(conn.client, config.execution.no_worker_timeout_s, conn.scheduler_address)
    try:
        with _cluster_loss(conn, out, watchdog, store), perf, watchdog or contextlib.nullcontext():
            stage[0] = "the adjustment cascade"
            summaries, level_seconds = _run_cascade(conn.client, conn, store, config, plan, stream, integrity)
            timings.update(level_seconds)
            glob = summaries["global"][0] if summaries["global"] else None
            products = _products(store, mission, config, conn.client, stream, timings, stage,
                                 dem and glob is not None and glob.ok)
            validation = _validation_on_worker(store, mission, conn.client, glob)
            if watchdog is not None and watchdog.error is not None:  # a stage that took its cancelled tasks
                raise watchdog.error                                   # for failures of its own must not finish
    finally:
        if own:
            conn.close()
        if conn.mode != "sync":
            store.commit_performance_report()
    timings["total"] = time.perf_counter() - t_start
    stage[0] = "the report (RUN/report.json)"
    dem_summary, dense_summary = products
    report = build_report(store, mission, config, plan, summaries, timings, conn, dem_summary, validation)
    report["integrity"] = integrity
    if dense_summary is not None:
        report["dense"] = dense_summary
    write_report(store, report)
    return report


def _validation_on_worker(store: RunStore, mission: Any, client: ComputeClient, glob: Any) -> dict[str, Any] | None:
    """A bucket run's validation of the global solution against the truth, as a task on a worker (issue 33: the
    client stays light; it was the client's peak after the DEM stage); None elsewhere: the report computes it here.
    """
    if store.url is None or mission.truth is None or glob is None or not glob.ok or runs_in_process(client):
        return None
    from mercury_dem.pipeline.report import validate_global_task

    return dict(client.submit(validate_global_task, store.url, pure=False).result())


def _announce(store: RunStore, conn: Connection, stream: TextIO | None) -> None:
    """Record how the run executes in ``run.json`` (the run dashboard links to the Dask dashboard from there)
    and say it on ``stream``.
    """
    link = getattr(conn.client, "dashboard_link", None)
    info = store.read_run()
    info["execution"] = {"mode": conn.mode, "description": conn.description}
    info["dashboard_link"] = link
    store.write_run(info)
    if stream is not None:
        print(f"mercury-dem run: {conn.description}" + (f"; dashboard {link}" if link else ""), file=stream, flush=True)


def _products(store: RunStore, mission: Any, config: Config, client: ComputeClient, stream: TextIO | None,
              timings: dict[str, float], stage: list[str], run_dem: bool,
              ) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The DEM stage, then the dense stage when configured, on the cascade's client (when ``run_dem``: asked
    for and the global adjustment succeeded); their summaries (None: not run).
    """
    if not run_dem:
        return None, None
    from mercury_dem.pipeline.dem_run import run_dem_stage

    t = time.perf_counter()
    stage[0] = "the DEM stage (dem.zarr, coverage.zarr, products)"
    dem_summary = run_dem_stage(store, mission, config, client, stream)
    timings["dem"] = time.perf_counter() - t
    dense_summary: dict[str, Any] | None = None
    if config.dense.enabled:
        stage[0] = "the dense stage (dense.zarr, dem_dense.zarr)"
        t = time.perf_counter()
        dense_summary = _dense_stage(store, mission, config, client, stream, dem_summary)
        timings["dense"] = time.perf_counter() - t
    return dem_summary, dense_summary


def _dense_stage(store: RunStore, mission: Any, config: Config, client: ComputeClient, stream: TextIO | None,
                 dem_summary: dict[str, Any]) -> dict[str, Any]:
    """The dense stage (:mod:`mercury_dem.pipeline.dense_stage`) after the DEM stage; its validation entries
    join the DEM's (``validation.dem``). A failure of the whole stage is recorded as a value: the run's other
    products stand. Not on a bucket run yet (its tasks read ``dem.zarr`` and write ``dense.zarr`` locally).
    """
    from mercury_dem.exceptions import MercuryDemError

    if store.url is not None:
        return {"error": "the dense stage does not run on a bucket run yet (dense.enabled is ignored)"}
    from mercury_dem.pipeline.dense_stage import run_dense_stage

    try:
        out = run_dense_stage(store, mission, config, client, stream)
    except RUN_STOPPING:
        raise
    except (MercuryDemError, OSError, ValueError) as exc:
        if disk_full_cause(exc) is not None:
            raise
        return {"error": f"dense stage: {type(exc).__name__}: {exc}"}
    if "validation" in out:
        dem_summary.setdefault("validation", {}).update(out.pop("validation"))
    return out


@contextlib.contextmanager
def _cluster_loss(conn: Connection, out: str | Path, watchdog: NoWorkerWatchdog | None,
                  store: RunStore) -> Iterator[None]:
    """Turn what the Dask client raises when its cluster is gone into the run-stopping error saying how to resume.

    No worker for ``execution.no_worker_timeout_s`` (the watchdog cancelled the futures): :class:`NoWorkerError`;
    the scheduler gone (a connect timeout, cancelled futures, the client not running): :class:`SchedulerLostError`.
    Either is recorded in ``run.json`` as the run's infrastructure failure (:func:`record_infrastructure_failure`).
    Other errors pass unchanged.
    """
    import asyncio

    try:
        yield
    except (Exception, asyncio.CancelledError) as exc:
        error: Exception | None = None
        if watchdog is not None and watchdog.error is not None:
            error = watchdog.error
        elif isinstance(exc, RUN_STOPPING) or conn.mode == "sync" or getattr(conn.client, "status", "running") == "running":
            raise
        else:
            error = SchedulerLostError(
                f"lost the Dask scheduler ({conn.description}) during the run ({type(exc).__name__}: {exc}); the "
                f"units finished so far are committed in {out}: start a scheduler and workers again (or use the "
                "default LocalCluster) and run the same command to resume")
        record_infrastructure_failure(store, error, conn, watchdog)
        if error is exc:
            raise
        raise error from exc


def record_infrastructure_failure(store: RunStore, error: Exception, conn: Connection,
                                  watchdog: NoWorkerWatchdog | None) -> None:
    """Write the run-stopping infrastructure failure into ``run.json`` (``infrastructure_failure``).

    Never a unit's failure: no unit is written for it, and the next run of the same command (which
    rewrites ``run.json``) resumes from the committed units. A failure to write it is not allowed to
    hide the error itself.
    """
    entry: dict[str, Any] = {"kind": "infrastructure", "error": type(error).__name__, "message": str(error),
                             "scheduler": conn.scheduler_address,
                             "at": datetime.now(UTC).isoformat(timespec="seconds")}
    if watchdog is not None and watchdog.no_worker_since_utc is not None:
        entry["no_worker_since"] = watchdog.no_worker_since_utc.isoformat(timespec="seconds")
        entry["no_worker_timeout_s"] = watchdog.timeout_s
    try:
        info = store.read_run()
        info["infrastructure_failure"] = entry
        store.write_run(info)
    except (OSError, ValueError, StoreError) as exc:
        # the run's own error is raised by the caller either way; say why run.json does not carry it
        print(f"mercury-dem: could not record the infrastructure failure in {store.run_json}: {exc}", file=sys.stderr)


def _plan_corrupt(store: RunStore, integrity: dict[str, Any], stream: TextIO | None) -> bool:
    """Whether the committed plan fails its checksums (then it is recomputed; named in the report)."""
    problems = verify_complete(store.plan_dir)
    if not problems:
        return False
    integrity["corrupt"].append({"level": "plan", "id": None, "name": "plan", "problems": problems})
    if stream is not None:
        print(f"mercury-dem run: plan: checksum verification failed ({'; '.join(problems[:3])}); recomputing it",
              file=stream, flush=True)
    return True


def _run_cascade(client: ComputeClient, conn: Connection, store: RunStore, config: Config, plan: dict[str, Any],
                 stream: TextIO | None, integrity: dict[str, Any] | None = None,
                 ) -> tuple[dict[str, list[Summary]], dict[str, float]]:
    """Submit the whole merge tree (units a previous run finished and that pass their checksums are read, not
    resubmitted), record each unit's summary as it finishes, and return the summaries of each level in id
    order with each level's seconds (:func:`level_seconds`).
    """
    integrity = integrity if integrity is not None else {"verified_units": 0, "unverifiable_units": 0,
                                                         "corrupt": [], "verify_seconds": 0.0}
    heavy = {"resources": {ADJUST_RESOURCE: 1}} if use_adjust_resource(conn, config, stream) else {}
    tree = merge_tree(config.tiling.tile_size_deg, [int(t) for t in plan["non_empty_tiles"]])
    cascade = _Cascade(client, store, Progress(tree.totals(), stream), integrity, stream)
    try:
        cascade.run(tree, config, heavy)
    finally:
        cascade.progress.close()
    for lvl in cascade.out:
        cascade.out[lvl].sort(key=lambda s: s.id)
    return cascade.out, level_seconds(cascade.out, cascade.done, cascade.sync)


class _Cascade:
    """The bookkeeping of one cascade: the units finished before (``done``), the summaries recorded (``out``),
    the progress, and the checksums verified on resume (``integrity``).
    """

    def __init__(self, client: ComputeClient, store: RunStore, progress: Progress, integrity: dict[str, Any],
                 stream: TextIO | None):
        self.client, self.store, self.progress, self.integrity, self.stream = client, store, progress, integrity, stream
        self.done: dict[str, dict[int, Summary]] = {k: {} for k in LEVELS}
        self.out: dict[str, list[Summary]] = {k: [] for k in progress.totals}
        self.recorded: set[str] = set()
        self.sync = getattr(client, "synchronous", False)

    def run(self, tree: Any, config: Config, heavy: dict[str, Any]) -> None:
        """Submit the whole tree up front (a unit waits on its children's futures or their stored summaries) and
        record the units as Dask reports them finished; a run-stopping error cancels what is not started.
        """
        root = self.store.location  # tasks open the run from it: the bucket URL of a bucket run
        retries = config.execution.retries
        all_f: list[Any] = []
        try:
            levels: dict[str, dict[int, Any]] = {"tile": {
                t: self.submit(_tile_task, "tile", t, retries, root, t, config) for t in tree.units["tile"]}}
            for lvl in LEVELS[1:]:
                levels[lvl] = {}
                for uid in tree.units[lvl]:
                    deps = [levels[CHILD_LEVEL[lvl]][c] for c in tree.children[(lvl, uid)]]
                    levels[lvl][uid] = self.submit(_unit_task, lvl, uid, retries, root, lvl, uid, config, deps, **heavy)
            level_of = {f.key: (lvl, uid) for lvl, fs in levels.items() for uid, f in fs.items()
                        if uid not in self.done[lvl]}
            all_f += [f for lvl, fs in levels.items() for uid, f in fs.items()
                      if uid not in self.done[lvl] and f.key not in self.recorded]
            for fut in as_completed(self.client, all_f):  # Dask's own completion events drive the counts
                self.record(*level_of[fut.key], fut)
        except RUN_STOPPING:
            if not self.sync:
                self.client.cancel(all_f)  # the run stops: nothing more is started (running units finish atomically)
            raise

    def submit(self, fn: Callable[..., dict[str, Any]], level: str, uid: int, retries: int, *args: Any,
               **kw: Any) -> Any:
        """A future, or the stored summary of a unit a previous run finished (not resubmitted)."""
        if self.trusted(level, uid):
            raw = self.store.read_summary(level, uid)
            self.done[level][uid] = summary_from_json(raw)
            self.out[level].append(self.done[level][uid])
            self.progress.update(self.done[level][uid])
            return raw  # a parent's argument, in the JSON form its task's results have (it only orders the work)
        fut = self.client.submit(fn, *args, key=f"{level}-{uid}", retries=retries, pure=False, **kw)
        if self.sync:  # the synchronous client ran it already: count it now, so progress is live
            self.record(level, uid, fut)
            self.recorded.add(fut.key)
        return fut

    def record(self, level: str, uid: int, fut: Any) -> None:
        """The unit's summary from its future; a task that died (after the retries) is the unit's failure."""
        try:
            s = summary_from_json(fut.result())
        except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker after the retries
            raise_if_run_stopping(exc, unit_name(level, uid), self.store.location)  # stops the run (see safe_call)
            if lost_to_the_cluster(exc):
                raise  # cancelled by the cluster (no worker, the scheduler gone): the run's failure, not the unit's
            s = FailureSummary.of(level, uid, exc)
        self.out[level].append(s)
        self.progress.update(s)

    def trusted(self, level: str, uid: int) -> bool:
        """A finished unit whose files match its checksums; a corrupt one is named and withdrawn."""
        store, integrity = self.store, self.integrity
        if not store.unit_complete(level, uid):
            return False
        if store.url is not None:
            # a bucket run: verifying here would download every finished unit on each resume; a unit is
            # verified when it is fetched to be read (a region's children) and by 'mercury-dem verify'
            return True
        t = time.perf_counter()
        problems = store.verify_unit(level, uid)
        integrity["verify_seconds"] += time.perf_counter() - t
        if problems is None:
            integrity["unverifiable_units"] += 1  # a marker without checksums (an older run): trusted
            return True
        integrity["verified_units"] += 1
        if not problems:
            return True
        name = unit_name(level, uid)
        integrity["corrupt"].append({"level": level, "id": int(uid), "name": name, "problems": problems,
                                     "action": "recomputed"})
        if self.stream is not None:
            print(f"mercury-dem run: {name}: checksum verification failed ({'; '.join(problems[:3])}); "
                  "recomputing it", file=self.stream, flush=True)
        store.invalidate_unit(level, uid)
        return False


def level_seconds(out: dict[str, list[Summary]], done: dict[str, dict[int, Summary]],
                  sync: bool) -> dict[str, float]:
    """Each level's seconds: in-process (every unit ran at submission) the sum of its units'; distributed, its
    span from its first unit's start to its last unit's end (units of this run only; wall clock written by the
    workers), which overlaps the next level; 0 for a level every unit of which an earlier run finished.
    """
    seconds: dict[str, float] = {}
    if sync:
        for lvl in LEVELS:
            seconds[lvl] = float(sum(s.seconds or 0.0 for s in out[lvl]))
        return seconds
    for lvl in LEVELS:
        spans = [(s.timing.started_at, s.timing.finished_at) for s in out[lvl] if s.id not in done[lvl]
                 and s.timing is not None and s.timing.started_at is not None and s.timing.finished_at is not None]
        if spans:
            seconds[lvl] = float(max(f for _, f in spans) - min(st for st, _ in spans))
        elif out[lvl]:
            seconds[lvl] = 0.0  # every unit was finished by an earlier run
    return seconds


def use_adjust_resource(conn: Connection, config: Config, stream: TextIO | None = None) -> bool:
    """Whether adjustments ask for the ``adjust`` worker resource (one at a time per worker).

    ``auto``: on a LocalCluster (we start its workers with the resource) and on a
    scheduler where at least one connected worker advertises it. Workers that join
    later (an adaptive cluster) are not seen here: set ``execution.adjust_resource: on``.
    """
    mode = config.execution.adjust_resource
    if mode == "off" or conn.mode == "sync":
        return False
    if mode == "on" or conn.uses_resources:
        return True
    try:
        workers = conn.client.scheduler_info().get("workers", {})
    except Exception:  # noqa: BLE001 - no scheduler info: behave as without the resource
        workers = {}
    has = any(ADJUST_RESOURCE in (w.get("resources") or {}) for w in workers.values())
    if not has and stream is not None:
        print(f"mercury-dem run: no worker advertises the '{ADJUST_RESOURCE}' resource; adjustments are not "
              f"limited to one per worker (start workers with --resources {ADJUST_RESOURCE}=1)",
              file=stream, flush=True)
    return has
