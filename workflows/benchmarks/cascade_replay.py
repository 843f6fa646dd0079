"""Replay of the merge cascade as sleep tasks: measured unit times, scaling, critical path.

Helpers of ``workflows/benchmarks/bench_cascade.py`` (issue #6, section 7): read the
measured duration of every unit of a finished run from its store, take the run's
tile -> region -> hemisphere -> global tree (:func:`mercury_dem.plan.tree.merge_tree`,
the one :mod:`mercury_dem.pipeline.graph` submits) for any tile size, scale measured durations to another mission size, compute the
critical path (longest chain through the merge tree), predict the makespan of a
greedy list schedule, and replay the graph as ``time.sleep`` tasks on a Dask
cluster (submitted up front, dependencies as futures, exactly like the run).

Durations are in *simulated seconds*; :func:`replay_on_dask` compresses them by
``time_scale`` (real seconds per simulated second) so an hours-long plan replays in
seconds. A small discrete-event list scheduler is written here instead of a
scheduling library because it has to mirror one specific policy (Dask's: ready
tasks run in submission order on the first free worker) and is twenty lines.

Benchmark code, not the package's: it lived in ``mercury_dem/pipeline/simulate.py`` until
issue 20 moved it here; ``bench_cascade.py`` imports it from its own directory and the
tests load it by path (``tests/benchmarks/test_cascade_replay.py``).
"""

from __future__ import annotations

import heapq
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.plan.tree import ADJUSTED_LEVELS, CHILD_LEVEL, LEVELS, MergeTree, merge_tree

#: The merge tree as a DAG of keys (``deps``, ``order``, ``keys(level)``): the run's own type.
CascadeGraph = MergeTree


# --------------------------------------------------------------------------- measured run
@dataclass(frozen=True)
class UnitTiming:
    """What a finished unit recorded in its ``summary.json``.

    ``seconds`` is the runner's own wall time inside the task (store reads, work,
    atomic write); ``work`` is the unit's size: matched pairs for a tile, measures
    for an adjustment unit.
    """

    level: str
    id: int
    seconds: float
    ok: bool
    images: int
    pairs: int
    measures: int
    iterations: int
    end: float = float("nan")

    @property
    def start(self) -> float:
        return self.end - self.seconds

    @property
    def key(self) -> str:
        return f"{self.level}-{self.id}"


def read_unit_timings(run_root: str | Path) -> dict[str, list[UnitTiming]]:
    """Every complete unit's timing, per level, from ``RUN/<level>/<id>/summary.json``.

    Raises
    ------
    StoreError
        When the run holds no timed tile (not a finished ``mercury-dem run``).
    """
    root = Path(run_root)
    out: dict[str, list[UnitTiming]] = {lvl: [] for lvl in LEVELS}
    for lvl in LEVELS:
        d = root / lvl
        if not d.is_dir():
            continue
        for p in sorted(d.iterdir(), key=lambda q: (len(q.name), q.name)):
            f = p / "summary.json"
            if not (p.name.isdigit() and f.is_file()):
                continue
            s = json.loads(f.read_text())
            if s.get("seconds") is None:
                continue
            out[lvl].append(UnitTiming(
                level=lvl, id=int(p.name), seconds=float(s["seconds"]), ok=bool(s.get("ok")),
                images=int(s.get("images") or 0), pairs=int(s.get("pairs") or 0),
                measures=int(s.get("measures") or 0), iterations=int(s.get("iterations") or 0),
                end=f.stat().st_mtime,
            ))
    if not out["tile"]:
        raise StoreError(f"{root}: no tile/<id>/summary.json with 'seconds'; point at a finished mercury-dem run")
    return out


def n_workers_of(report: Mapping[str, Any]) -> int | None:
    """Worker count from ``report.json``'s execution description (``LocalCluster N workers x M threads``)."""
    desc = str(report.get("execution", {}).get("description", ""))
    parts = desc.split()
    if "workers" in parts:
        k = parts.index("workers")
        try:
            return int(parts[k - 1])
        except (ValueError, IndexError):
            return None
    return 1 if report.get("execution", {}).get("mode") == "sync" else None


def level_spans(timings: Mapping[str, list[UnitTiming]]) -> dict[str, dict[str, float]]:
    """Per level: first unit start and last unit end (seconds from the first tile's start) and the span."""
    units = [u for lvl in LEVELS for u in timings.get(lvl, [])]
    t0 = min(u.start for u in units)
    out = {}
    for lvl in LEVELS:
        us = timings.get(lvl, [])
        if us:
            a, b = min(u.start for u in us) - t0, max(u.end for u in us) - t0
            out[lvl] = {"start": a, "end": b, "span": b - a}
    return out


def busy_fraction(timings: Mapping[str, list[UnitTiming]], wall_seconds: float, n_workers: int) -> float:
    """Sum of unit times over (wall time x workers): 1 means every worker busy all the time."""
    total = sum(u.seconds for lvl in LEVELS for u in timings.get(lvl, []))
    return total / (wall_seconds * n_workers)


# --------------------------------------------------------------------------- graph
def cascade_graph(tile_size_deg: float = 10.0, tiles: Sequence[int] | None = None) -> CascadeGraph:
    """The run's graph for a tile grid: every tile (or only ``tiles``) -> regions -> hemispheres -> globe.

    Units without children are left out, as the run does for empty regions. The tiles are
    taken in id order.
    """
    return merge_tree(tile_size_deg, None if tiles is None else sorted(int(t) for t in tiles))


def critical_path(deps: Mapping[str, Sequence[str]], durations: Mapping[str, float]) -> tuple[float, list[str]]:
    """Longest chain of a DAG with task durations: (its length, its keys from first to last).

    ``deps`` must list every key (roots with no dependency map to an empty sequence).
    The makespan of any schedule, on any number of workers, is at least this length.
    """
    finish: dict[str, float] = {}
    via: dict[str, str | None] = {}
    state: dict[str, int] = {}

    def visit(k: str) -> float:
        # iterative depth-first search (the tree is shallow, but keep it stack-safe)
        stack = [(k, False)]
        while stack:
            node, expanded = stack.pop()
            if node in finish:
                continue
            if expanded:
                best, arg = 0.0, None
                for d in deps[node]:
                    if finish[d] > best:
                        best, arg = finish[d], d
                finish[node] = best + float(durations[node])
                via[node] = arg
                continue
            if state.get(node) == 1:
                raise ValueError(f"critical_path: the graph has a cycle through {node!r}")
            state[node] = 1
            stack.append((node, True))
            for d in deps[node]:
                if d not in deps:
                    raise KeyError(f"critical_path: {node!r} depends on {d!r}, which is not in the graph")
                if d not in finish:
                    stack.append((d, False))
        return finish[k]

    for k in deps:
        visit(k)
    end = max(finish, key=lambda k: finish[k])
    path = [end]
    while via[path[-1]] is not None:
        path.append(via[path[-1]])  # type: ignore[arg-type]
    return finish[end], path[::-1]


@dataclass(frozen=True)
class Schedule:
    """Start and finish time of every task, and the makespan."""

    start: Mapping[str, float]
    finish: Mapping[str, float]

    @property
    def makespan(self) -> float:
        return max(self.finish.values()) if self.finish else 0.0

    def level_finish(self, graph: CascadeGraph | SplitGraph) -> dict[str, float]:
        return {lvl: max(self.finish[k] for k in graph.keys(lvl)) for lvl in LEVELS if graph.keys(lvl)}


def list_schedule(graph: CascadeGraph | SplitGraph, durations: Mapping[str, float], n_workers: int,
                  width: Mapping[str, int] | None = None) -> Schedule:
    """Greedy schedule: whenever a worker is free it takes the ready task submitted first.

    This is Dask's behaviour for a graph submitted up front without priorities, with
    zero scheduler overhead; :func:`replay_on_dask` measures the real thing.

    ``width``: tasks that occupy several workers at once (a blocked adjustment whose point
    blocks are spread over the cluster: a gang), at most ``n_workers``; 1 for the others. A
    gang at the head of the ready queue waits until that many workers are free, and nothing
    submitted after it starts meanwhile (no backfilling: the simplest policy that cannot
    starve the gang; it wastes the free workers while the gang waits, so it is pessimistic).
    """
    rank = {k: n for n, k in enumerate(graph.order)}
    waiting = {k: len(graph.deps[k]) for k in graph.order}
    children: dict[str, list[str]] = {k: [] for k in graph.order}
    for k, ds in graph.deps.items():
        for d in ds:
            children[d].append(k)
    wide = {k: max(1, min(int(v), n_workers)) for k, v in (width or {}).items()}
    ready = [rank[k] for k in graph.order if waiting[k] == 0]
    heapq.heapify(ready)
    running: list[tuple[float, int, int]] = []  # (finish time, rank, workers held)
    free, now = n_workers, 0.0
    start: dict[str, float] = {}
    finish: dict[str, float] = {}
    while ready or running:
        while ready and free > 0:
            k = graph.order[ready[0]]
            w = wide.get(k, 1)
            if w > free:
                break  # the gang at the head waits for its workers
            heapq.heappop(ready)
            start[k] = now
            heapq.heappush(running, (now + float(durations[k]), rank[k], w))
            free -= w
        now, r, w = heapq.heappop(running)
        done = graph.order[r]
        finish[done] = now
        free += w
        for c in children[done]:
            waiting[c] -= 1
            if waiting[c] == 0:
                heapq.heappush(ready, rank[c])
    return Schedule(start=start, finish=finish)


# --------------------------------------------------------------------------- scaling
@dataclass(frozen=True)
class TargetSize:
    """The mission to plan for (defaults: Becker et al. 2016, MESSENGER MDIS)."""

    images: int = 100_432
    measures: int = 94_745_475
    tile_size_deg: float = 10.0
    pairs_per_image: float = 15.0


@dataclass(frozen=True)
class ScaledPlan:
    """Durations (simulated seconds) of every unit of the target graph and how they were derived."""

    graph: CascadeGraph
    durations: Mapping[str, float]
    images: Mapping[str, float]
    measures: Mapping[str, float]
    notes: Mapping[str, Any] = field(default_factory=dict)


def images_per_tile(grid: TileGrid, total: int) -> np.ndarray:
    """Images of every tile when ``total`` image centres are spread uniformly over the sphere.

    A tile's share is its area, sin(lat_max) - sin(lat_min) over the sphere's 2 x n_cols.
    """
    t = np.arange(grid.n_tiles)
    lat0, lat1, _, _ = grid.bounds(t)
    w = np.sin(np.radians(lat1)) - np.sin(np.radians(lat0))
    return total * w / w.sum()


def scale_plan(timings: Mapping[str, list[UnitTiming]], target: TargetSize, alpha: float = 1.0,
               seed: int = 0) -> ScaledPlan:
    """Durations of the target mission's cascade from a measured run.

    Tiles: a target tile of ``n`` images matches ``n x pairs_per_image`` pairs; its
    time is that count times a measured seconds-per-pair, drawn (seeded) from the
    measured tiles, so the spread of the measured per-pair costs is kept. Adjustment
    units: time = ``k_level x measures**alpha``, ``k_level`` the median over the
    measured units of the level (``seconds / measures**alpha``); a unit's measures
    are its images' share of ``target.measures``. A level with no measured unit
    borrows the nearest lower level's coefficient.
    """
    grid = TileGrid(target.tile_size_deg)
    rng = np.random.default_rng(seed)
    graph = cascade_graph(target.tile_size_deg)
    deps = graph.deps
    n_img = images_per_tile(grid, target.images)
    tiles = [u for u in timings["tile"] if u.ok and u.pairs > 0]
    if not tiles:
        raise StoreError("scale_plan: no successful tile with pairs to take a per-pair time from")
    per_pair = np.array([u.seconds / u.pairs for u in tiles])
    draw = per_pair[rng.integers(0, per_pair.size, grid.n_tiles)]
    durations: dict[str, float] = {}
    images: dict[str, float] = {}
    measures: dict[str, float] = {}
    mpi = target.measures / target.images
    for t in range(grid.n_tiles):
        k = f"tile-{t}"
        durations[k] = float(draw[t] * n_img[t] * target.pairs_per_image)
        images[k] = float(n_img[t])
    coef: dict[str, float] = {}
    for lvl in ADJUSTED_LEVELS:
        units = [u for u in timings.get(lvl, []) if u.ok and u.measures > 0]
        if units:
            coef[lvl] = float(np.median([u.seconds / u.measures ** alpha for u in units]))
        else:  # the level below's coefficient (regions have none below: NaN)
            coef[lvl] = coef.get(CHILD_LEVEL[lvl], np.nan)
        for k in graph.keys(lvl):
            images[k] = float(sum(images[d] for d in deps[k]))
            measures[k] = images[k] * mpi
            durations[k] = coef[lvl] * measures[k] ** alpha
    notes = {
        "seconds_per_pair": {"median": float(np.median(per_pair)), "min": float(per_pair.min()),
                             "max": float(per_pair.max()), "tiles": int(per_pair.size)},
        "adjust_coefficient_s_per_measure_pow_alpha": coef,
        "alpha": alpha,
        "measures_per_image": mpi,
        "images_per_tile": {"mean": float(n_img.mean()), "max": float(n_img.max()), "min": float(n_img.min())},
    }
    return ScaledPlan(graph=graph, durations=durations, images=images, measures=measures, notes=notes)


# --------------------------------------------------------------------------- adjustment cost models
@dataclass(frozen=True)
class InMemoryCost:
    """The in-memory adjuster (one process per unit) measured at one size, scaled linearly in measures.

    Defaults: ``bundle_adjust`` on 4,946,512 measures, 342.3 s (10 iterations) and 4.11 GB peak
    (docs/benchmarks/adjust.md, "Synthetic planetary networks", 2026-11-22).
    """

    measures: float = 4_946_512
    seconds: float = 342.3
    peak_bytes: float = 4.11e9

    def unit_seconds(self, measures: float) -> float:
        return self.seconds * measures / self.measures

    def unit_bytes(self, measures: float) -> float:
        return self.peak_bytes * measures / self.measures


@dataclass(frozen=True)
class BlockedCost:
    """The blocked distributed adjustment measured on ``workers`` workers, and its model on ``P`` shards.

    Measured (``adjust-network --workers 2 --json`` on one store): ``seconds_per_iteration``
    (mean), ``worker_seconds_per_iteration`` (the slowest shard's seconds in its blocks'
    computations over the run / iterations: ``shard_busy_seconds``), ``iterations``,
    ``load_seconds`` (actors reading their blocks), the peak memory of the largest worker and
    of the client, at ``measures`` measures and ``images`` images. Modelled (not measured at
    other sizes or shard counts):

    - the workers' share of an iteration is linear in the measures a shard holds
      (``measures / P``; measured exponent 0.91 between 10^7 and 2.5*10^7 on 2 workers, so
      linear is pessimistic);
    - the client's share (the rest of the iteration: summing the shards' camera-pair blocks,
      the PCG solve of the camera system, messages) is linear in the unit's images (a PCG
      iteration is linear in the system's nonzero blocks; the CG iteration count is assumed
      not to grow);
    - every actor call costs the client ``call_seconds`` per shard (``calls_per_iteration``
      calls an iteration; ``call_seconds`` is the measured per-task Dask overhead on this
      machine, docs/benchmarks/cascade.md: 3.55-8.7 ms);
    - ``P`` = min(workers, blocks): a shard holds whole blocks of ``block_points`` points
      (``points_per_measure`` of the measured network);
    - the largest worker's memory: the measured peak plus ``worker_bytes_per_measure`` (242 B,
      the measured growth 10^7 -> 2.5*10^7) per measure more or less than the measured shard
      held; the client's: measured peak scaled linearly with the images.
    """

    measures: float = 25_948_126
    images: int = 26_596
    points: int = 3_571_151
    workers: int = 2
    seconds_per_iteration: float = 89.0
    worker_seconds_per_iteration: float = float("nan")
    iterations: int = 9
    load_seconds: float = float("nan")
    worker_peak_bytes: float = 3.73e9
    client_peak_bytes: float = 1.33e9
    worker_bytes_per_measure: float = 242.0
    block_points: int = 25_000
    call_seconds: float = 0.00355
    calls_per_iteration: int = 12

    @classmethod
    def from_record(cls, rec: Mapping[str, Any], **kw: Any) -> BlockedCost:
        """From an ``adjust-network --json`` record (with ``shard_busy_seconds`` and ``log``)."""
        its = int(rec["iterations"])
        return cls(measures=float(rec["measures"]), images=int(rec["images"]), points=int(rec["points"]),
                   workers=len(rec["peak_memory_bytes_shards"]),
                   # the mean, not the median: the shards' busy seconds are a total over the same iterations
                   seconds_per_iteration=float(np.sum(rec["seconds_per_iteration"])) / its,
                   worker_seconds_per_iteration=float(max(rec["shard_busy_seconds"])) / its, iterations=its,
                   load_seconds=float(rec["load_seconds"]) + float(rec["setup_seconds"]),
                   worker_peak_bytes=float(max(rec["peak_memory_bytes_shards"])),
                   client_peak_bytes=float(rec["peak_memory_bytes_client"]), **kw)

    def shards(self, measures: float, n_workers: int) -> int:
        blocks = max(1, int(np.ceil(measures * self.points / self.measures / self.block_points)))
        return max(1, min(int(n_workers), blocks))

    def client_seconds_per_iteration(self, images: float, n_shards: int) -> float:
        fixed = max(0.0, self.seconds_per_iteration - self.worker_seconds_per_iteration
                    - self.calls_per_iteration * self.workers * self.call_seconds)
        return fixed * images / self.images + self.calls_per_iteration * n_shards * self.call_seconds

    def unit_seconds(self, measures: float, images: float, n_workers: int) -> float:
        p = self.shards(measures, n_workers)
        share = measures / self.measures * self.workers / p
        per_it = self.worker_seconds_per_iteration * share + self.client_seconds_per_iteration(images, p)
        return self.iterations * per_it + self.load_seconds * share

    def unit_bytes(self, measures: float, images: float, n_workers: int) -> tuple[float, float]:
        """(largest worker, client) peak bytes."""
        p = self.shards(measures, n_workers)
        w = self.worker_peak_bytes + self.worker_bytes_per_measure * (measures / p - self.measures / self.workers)
        return max(w, 0.0), self.client_peak_bytes * images / self.images


@dataclass(frozen=True)
class MergeCost:
    """The merge of a unit's children, measured at one size and scaled linearly in the input measures.

    Run serially in the unit's own process before its adjustment (as the pipeline's units do: the merge in
    the unit, the adjustment over the workers), so it occupies one worker. ``input_ratio``: the children's
    measures over the merged unit's (their border copies, joined by the merge), measured on the streamed
    merge's two overlapping children (26,311,820 / 23,846,511 = 1.103). Defaults: the streamed merge,
    2.5*10^7 measures in 82.65 s, 0.97 GB in the unit's process (docs/benchmarks/cascade.md section 5; its
    parts on 2 workers, at most 3 in flight, so more workers would not shorten it: ``peak_exponent`` 0.08,
    the measured growth of its peak from 10^7 to 2.5*10^7). :meth:`in_memory`: ``merge_networks``,
    5,500,030 input measures in 6.9-9.4 s (8.1 s), 1.72 GB (docs/benchmarks/network.md), linear in memory.
    """

    input_measures: float = 26_311_820
    seconds: float = 82.65
    peak_bytes: float = 0.967e9
    peak_exponent: float = 0.08
    input_ratio: float = 26_311_820 / 23_846_511
    name: str = "streamed"

    @classmethod
    def in_memory(cls) -> MergeCost:
        return cls(input_measures=5_500_030, seconds=8.1, peak_bytes=1.72e9, peak_exponent=1.0, name="in memory")

    def unit_seconds(self, measures: float) -> float:
        return self.seconds * measures * self.input_ratio / self.input_measures

    def unit_bytes(self, measures: float) -> float:
        return self.peak_bytes * (measures * self.input_ratio / self.input_measures) ** self.peak_exponent


@dataclass(frozen=True)
class SplitGraph:
    """A cascade graph in which some units' merge is a task of its own (``merge:<key>``) before the unit.

    Same interface as :class:`CascadeGraph` for :func:`critical_path`, :func:`list_schedule` and
    :meth:`Schedule.level_finish` (``order``, ``deps``, ``keys(level)``); a merge task comes right before
    its unit in the submission order, takes the unit's children as its dependencies and is the unit's one.
    """

    order: tuple[str, ...]
    deps: Mapping[str, tuple[str, ...]]
    base: CascadeGraph

    def keys(self, level: str) -> list[str]:
        return self.base.keys(level)

    @classmethod
    def of(cls, graph: CascadeGraph, merged: Sequence[str]) -> SplitGraph:
        deps = dict(graph.deps)
        order: list[str] = []
        for k in graph.order:
            if k in merged:
                m = f"merge:{k}"
                deps[m], deps[k] = tuple(graph.deps[k]), (m,)
                order.append(m)
            order.append(k)
        return cls(order=tuple(order), deps=deps, base=graph)


def with_merge(plan: ScaledPlan, levels: Sequence[str], durations: Mapping[str, float], merge: MergeCost,
               ) -> tuple[SplitGraph, dict[str, float], dict[str, dict[str, float]]]:
    """The plan's graph with ``levels``' merges as tasks of their own (:class:`SplitGraph`), costed by ``merge``;
    ``durations`` (of the units, their adjustment only) extended with the merges'; each merge's
    ``{"measures", "seconds", "bytes"}``.
    """
    keys = [k for lvl in levels for k in plan.graph.keys(lvl)]
    graph = SplitGraph.of(plan.graph, keys)
    out = dict(durations)
    detail: dict[str, dict[str, float]] = {}
    for k in keys:
        m = plan.measures[k]
        out[f"merge:{k}"] = merge.unit_seconds(m)
        detail[k] = {"measures": m, "seconds": out[f"merge:{k}"], "bytes": merge.unit_bytes(m)}
    return graph, out, detail


def with_adjustment(plan: ScaledPlan, levels: Sequence[str], model: InMemoryCost | BlockedCost,
                    n_workers: int = 1) -> tuple[dict[str, float], dict[str, int], dict[str, dict[str, float]]]:
    """The plan's durations with ``levels``' units costed by ``model``; their widths and memory.

    Returns (durations, width: workers each unit of ``levels`` occupies, per unit
    ``{"measures", "seconds", "worker_bytes", "client_bytes", "shards"}``).
    """
    durations = dict(plan.durations)
    width: dict[str, int] = {}
    detail: dict[str, dict[str, float]] = {}
    for lvl in levels:
        for k in plan.graph.keys(lvl):
            m, n = plan.measures[k], plan.images[k]
            if isinstance(model, BlockedCost):
                durations[k] = model.unit_seconds(m, n, n_workers)
                width[k] = model.shards(m, n_workers)
                wb, cb = model.unit_bytes(m, n, n_workers)
            else:
                durations[k] = model.unit_seconds(m)
                wb, cb = model.unit_bytes(m), 0.0
            detail[k] = {"measures": m, "seconds": durations[k], "worker_bytes": wb, "client_bytes": cb,
                         "shards": float(width.get(k, 1))}
    return durations, width, detail


# --------------------------------------------------------------------------- Dask replay
def _sleep(seconds: float, *deps: Any) -> float:
    time.sleep(seconds)
    return time.perf_counter()


def sleep_cluster(n_workers: int) -> Any:
    """An in-process LocalCluster of single-threaded workers (inproc transport, HTTP on loopback only).

    Sleep tasks release the GIL, so threads stand in for worker processes. The workers have no
    memory limit: in-process workers each measure the whole process's memory against their 1/n
    share of the machine's (1.5 GiB for 16 workers on 24 GiB), so a caller already holding more (a
    test session after other tests) had every worker paused and the replay hung.

    Even an inproc cluster starts HTTP servers (the scheduler's health/metrics routes and one per
    worker): with ``dashboard_address=None`` Dask bound the scheduler's to port 8787 and every one
    of them to all interfaces (0.0.0.0 and ::). Both addresses are therefore given as loopback.
    """
    from mercury_dem.compute import local_cluster

    return local_cluster(n_workers, 1, host="127.0.0.1", processes=False, memory_limit=0)


def replay_on_dask(client: Any, graph: CascadeGraph, durations: Mapping[str, float],
                   time_scale: float) -> dict[str, Any]:
    """Submit the graph up front as sleep tasks (``durations x time_scale`` real seconds); time it.

    Returns ``makespan`` and ``level_finish`` (simulated seconds, i.e. real seconds
    divided by ``time_scale``), measured from the first submission to each
    completion as seen by the client.
    """
    from distributed import as_completed

    t0 = time.perf_counter()
    futs: dict[str, Any] = {}
    for k in graph.order:
        futs[k] = client.submit(_sleep, float(durations[k]) * time_scale, *[futs[d] for d in graph.deps[k]],
                                key=f"sim-{k}-{t0}", pure=False)
    key_of = {f.key: k for k, f in futs.items()}
    done_at: dict[str, float] = {}
    for f in as_completed(list(futs.values())):
        f.result()
        done_at[key_of[f.key]] = (time.perf_counter() - t0) / time_scale
    level_finish = {lvl: max(done_at[k] for k in graph.keys(lvl)) for lvl in LEVELS if graph.keys(lvl)}
    return {"makespan": max(done_at.values()), "level_finish": level_finish, "finish": done_at}


def _noop(x: int) -> int:
    return x


def scheduler_overhead(client: Any, n_tasks: int = 1000) -> dict[str, float]:
    """Seconds per trivial task, submitted in one batch and gathered (after a warm-up batch)."""
    client.gather(client.map(_noop, range(50), pure=False))
    t = time.perf_counter()
    client.gather(client.map(_noop, range(n_tasks), pure=False))
    total = time.perf_counter() - t
    return {"tasks": n_tasks, "seconds": total, "seconds_per_task": total / n_tasks}
