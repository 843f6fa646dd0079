"""The cascade replay helpers (``workflows/benchmarks/cascade_replay.py``): critical path, graph shape,
scaling, schedule and Dask replay."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from mercury_dem.exceptions import StoreError
from tests.benchmarks import load_benchmark

_replay = load_benchmark("cascade_replay")
TargetSize = _replay.TargetSize
UnitTiming = _replay.UnitTiming
busy_fraction = _replay.busy_fraction
cascade_graph = _replay.cascade_graph
critical_path = _replay.critical_path
level_spans = _replay.level_spans
list_schedule = _replay.list_schedule
n_workers_of = _replay.n_workers_of
read_unit_timings = _replay.read_unit_timings
replay_on_dask = _replay.replay_on_dask
scale_plan = _replay.scale_plan
scheduler_overhead = _replay.scheduler_overhead
sleep_cluster = _replay.sleep_cluster
BlockedCost = _replay.BlockedCost
InMemoryCost = _replay.InMemoryCost
MergeCost = _replay.MergeCost
SplitGraph = _replay.SplitGraph
with_merge = _replay.with_merge


def test_critical_path_hand_made_graph() -> None:
    # a(3) -> c(2); b(5) -> c; b -> d(1); c -> e(4); d -> e. Longest: b, c, e = 11.
    deps = {"a": (), "b": (), "c": ("a", "b"), "d": ("b",), "e": ("c", "d")}
    dur = {"a": 3.0, "b": 5.0, "c": 2.0, "d": 1.0, "e": 4.0}
    length, path = critical_path(deps, dur)
    assert length == pytest.approx(11.0)
    assert path == ["b", "c", "e"]
    dur["d"] = 7.0  # now b -> d -> e = 16
    assert critical_path(deps, dur) == (pytest.approx(16.0), ["b", "d", "e"])


def test_critical_path_refuses_cycles_and_unknown_keys() -> None:
    with pytest.raises(ValueError, match="cycle"):
        critical_path({"a": ("b",), "b": ("a",)}, {"a": 1.0, "b": 1.0})
    with pytest.raises(KeyError, match="'z'"):
        critical_path({"a": ("z",)}, {"a": 1.0})


def test_cascade_graph_shape_10_degrees() -> None:
    g = cascade_graph(10.0)
    assert [len(g.keys(lvl)) for lvl in ("tile", "region", "hemisphere", "global")] == [648, 14, 2, 1]
    # every tile feeds exactly one region; regions 0-6 north, 7-13 south
    fed = [t for r in g.keys("region") for t in g.deps[r]]
    assert sorted(fed) == sorted(g.keys("tile"))
    assert g.deps["hemisphere-0"] == tuple(f"region-{r}" for r in range(7))
    assert g.deps["global-0"] == ("hemisphere-0", "hemisphere-1")
    # a 10-degree polar cap is 3 rows x 36 columns; a 0-60 deg sector 6 rows x 6 columns
    assert len(g.deps["region-0"]) == 108 and len(g.deps["region-3"]) == 36
    assert g.order[:648] == tuple(g.keys("tile"))


def test_cascade_graph_of_a_subset_leaves_out_empty_units() -> None:
    g = cascade_graph(10.0, tiles=[0, 1, 182])  # south cap; row 5 col 2 (lat -40, lon 20): sector 0-60
    assert g.keys("region") == ["region-7", "region-8"]
    assert g.keys("hemisphere") == ["hemisphere-1"]
    assert g.deps["global-0"] == ("hemisphere-1",)


def test_list_schedule_bounds() -> None:
    g = cascade_graph(30.0)
    dur = {k: 1.0 + (n % 7) / 7.0 for n, k in enumerate(g.order)}
    cp, _ = critical_path(g.deps, dur)
    wide = list_schedule(g, dur, 10_000)
    assert wide.makespan == pytest.approx(cp)
    narrow = list_schedule(g, dur, 2)
    assert narrow.makespan >= max(cp, sum(dur.values()) / 2) - 1e-9
    for k, ds in g.deps.items():  # no task starts before its inputs finish
        assert all(narrow.start[k] >= narrow.finish[d] - 1e-12 for d in ds)


class _Graph:
    """A hand-made DAG with the attributes list_schedule reads."""

    def __init__(self, order: list[str], deps: dict[str, tuple[str, ...]]):
        self.order, self.deps = order, deps


def test_list_schedule_gang_waits_for_its_workers() -> None:
    # a (10 s) and b (1 s) start on the 2 workers; g (needs both) is ready at 1 but waits for a;
    # d (ready from the start, submitted after g) does not jump the queue
    g = _Graph(["a", "b", "g", "d"], {"a": (), "b": (), "g": ("b",), "d": ()})
    dur = {"a": 10.0, "b": 1.0, "g": 3.0, "d": 2.0}
    gang = list_schedule(g, dur, 2, {"g": 2})
    assert gang.start == {"a": 0.0, "b": 0.0, "g": 10.0, "d": 13.0}
    assert gang.makespan == pytest.approx(15.0)
    plain = list_schedule(g, dur, 2)
    assert plain.start == {"a": 0.0, "b": 0.0, "g": 1.0, "d": 4.0}
    # a width above the cluster is capped at the cluster; width 1 everywhere is the plain schedule
    assert list_schedule(g, dur, 2, {"g": 99}).start == gang.start
    assert list_schedule(g, dur, 2, {k: 1 for k in g.order}).finish == plain.finish


def test_blocked_cost_model_scales_as_documented() -> None:
    c = BlockedCost(measures=2e7, images=20_000, points=2_800_000, workers=2, seconds_per_iteration=100.0,
                    worker_seconds_per_iteration=80.0, iterations=10, load_seconds=40.0, worker_peak_bytes=3e9,
                    client_peak_bytes=1e9, call_seconds=0.0)
    # the measured point is reproduced: 10 x 100 s + 40 s load, 3 GB per worker, 1 GB client
    assert c.unit_seconds(2e7, 20_000, 2) == pytest.approx(1040.0)
    assert c.unit_bytes(2e7, 20_000, 2) == pytest.approx((3e9, 1e9))
    # 4x the workers: the workers' share and the load / 4, the client's 20 s stays
    assert c.unit_seconds(2e7, 20_000, 8) == pytest.approx(10 * (20.0 + 20.0) + 10.0)
    # shards are whole blocks: 2.8e6 points / 25,000 = 112 blocks, so 648 workers give 112 shards
    assert c.shards(2e7, 648) == 112
    assert c.unit_seconds(2e7, 20_000, 648) == pytest.approx(c.unit_seconds(2e7, 20_000, 112))
    # the client's share grows with the images, the per-call cost with the shards
    assert c.client_seconds_per_iteration(40_000, 2) == pytest.approx(40.0)
    c2 = BlockedCost(**{**c.__dict__, "call_seconds": 0.01, "calls_per_iteration": 10,
                        "seconds_per_iteration": 100.2})
    assert c2.client_seconds_per_iteration(20_000, 50) == pytest.approx(20.0 + 5.0)
    # from an adjust-network record: the mean iteration (the shards' busy seconds are a total), the slower shard
    rec = {"measures": 2e7, "images": 20_000, "points": 2_800_000, "iterations": 4, "seconds_per_iteration": [1, 1, 1, 9],
           "shard_busy_seconds": [6.0, 8.0], "load_seconds": 3.0, "setup_seconds": 1.0,
           "peak_memory_bytes_shards": [2e9, 3e9], "peak_memory_bytes_client": 1e9}
    r = BlockedCost.from_record(rec, call_seconds=0.0)
    assert (r.seconds_per_iteration, r.worker_seconds_per_iteration, r.load_seconds, r.workers) == (3.0, 2.0, 4.0, 2)
    assert r.worker_peak_bytes == 3e9 and r.client_seconds_per_iteration(20_000, 2) == pytest.approx(1.0)
    m = InMemoryCost(measures=1e6, seconds=100.0, peak_bytes=1e9)
    assert m.unit_seconds(3e6) == pytest.approx(300.0) and m.unit_bytes(3e6) == pytest.approx(3e9)


def _fake_run(root: Path) -> None:
    units = {
        ("tile", 0): {"seconds": 2.0, "ok": True, "images": 2, "pairs": 10, "measures": 100},
        ("tile", 1): {"seconds": 4.0, "ok": True, "images": 2, "pairs": 10, "measures": 100},
        ("region", 7): {"seconds": 3.0, "ok": True, "images": 4, "measures": 300, "iterations": 5},
        ("hemisphere", 1): {"seconds": 6.0, "ok": True, "images": 4, "measures": 300},
        ("global", 0): {"seconds": 9.0, "ok": True, "images": 4, "measures": 300},
    }
    for (lvl, uid), s in units.items():
        d = root / lvl / str(uid)
        d.mkdir(parents=True)
        (d / "summary.json").write_text(json.dumps({"level": lvl, "id": uid, **s}))


def test_read_timings_busy_fraction_and_scaling(tmp_path: Path) -> None:
    _fake_run(tmp_path)
    t = read_unit_timings(tmp_path)
    assert [u.key for u in t["tile"]] == ["tile-0", "tile-1"]
    r = t["region"][0]
    assert r == UnitTiming("region", 7, 3.0, True, 4, 0, 300, 5, end=r.end) and r.start == pytest.approx(r.end - 3.0)
    assert busy_fraction(t, wall_seconds=12.0, n_workers=2) == pytest.approx(24.0 / 24.0)
    # 0.2 and 0.4 s per pair; 100 images x 3 pairs per image spread over the sphere
    target = TargetSize(images=6480, measures=648_000, tile_size_deg=10.0, pairs_per_image=3.0)
    plan = scale_plan(t, target, alpha=1.0)
    assert sum(plan.images[k] for k in plan.graph.keys("tile")) == pytest.approx(6480)
    per_pair = [plan.durations[k] / (plan.images[k] * 3.0) for k in plan.graph.keys("tile")]
    assert set(round(x, 9) for x in per_pair) == {0.2, 0.4}
    # adjustment: 0.01 s per measure at region level, 0.02 hemisphere, 0.03 global
    assert plan.measures["global-0"] == pytest.approx(648_000)
    assert plan.durations["global-0"] == pytest.approx(0.03 * 648_000)
    assert plan.durations["hemisphere-0"] == pytest.approx(0.02 * 324_000)
    assert plan.durations["region-0"] == pytest.approx(0.01 * plan.measures["region-0"])


def test_level_spans_from_summary_times(tmp_path: Path) -> None:
    _fake_run(tmp_path)
    ends = {("tile", 0): 102.0, ("tile", 1): 104.0, ("region", 7): 107.0, ("hemisphere", 1): 113.0, ("global", 0): 122.0}
    for (lvl, uid), end in ends.items():
        os.utime(tmp_path / lvl / str(uid) / "summary.json", (end, end))
    sp = level_spans(read_unit_timings(tmp_path))
    assert sp["tile"] == {"start": 0.0, "end": 4.0, "span": 4.0}  # tile 1: 100 -> 104
    assert sp["region"]["start"] == pytest.approx(4.0) and sp["global"]["end"] == pytest.approx(22.0)


def test_merge_is_a_task_of_its_own_before_its_unit(tmp_path: Path) -> None:
    # the merge of the hemispheres and the globe: a one-worker task on the unit's children, the unit after it
    _fake_run(tmp_path)
    target = TargetSize(images=6480, measures=648_000, tile_size_deg=10.0, pairs_per_image=3.0)
    plan = scale_plan(read_unit_timings(tmp_path), target, alpha=1.0)
    merge = MergeCost(input_measures=1000.0, seconds=1.0, peak_bytes=1e9, peak_exponent=0.0, input_ratio=1.1)
    graph, dur, det = with_merge(plan, ("hemisphere", "global"), plan.durations, merge)
    assert graph.deps["merge:global-0"] == plan.graph.deps["global-0"] and graph.deps["global-0"] == ("merge:global-0",)
    assert graph.order.index("merge:global-0") == graph.order.index("global-0") - 1
    assert graph.keys("global") == ["global-0"] and "merge:region-0" not in dur
    assert dur["merge:global-0"] == pytest.approx(648_000 * 1.1 / 1000.0) and det["global-0"]["bytes"] == 1e9
    # the critical path gains exactly the merges on it; a wide cluster's makespan is the critical path
    cp0, path0 = critical_path(plan.graph.deps, plan.durations)
    cp1, path1 = critical_path(graph.deps, dur)
    assert path1 == [k for p in path0 for k in ((f"merge:{p}", p) if p.split("-")[0] in ("hemisphere", "global") else (p,))]
    assert cp1 == pytest.approx(cp0 + sum(dur[k] for k in path1 if k.startswith("merge:")))
    assert list_schedule(graph, dur, 10_000).makespan == pytest.approx(cp1)
    assert list_schedule(graph, dur, 10_000).level_finish(graph)["global"] == pytest.approx(cp1)
    # the in-memory merge's figures (network.md): 5.5e6 input measures, 8.1 s, 1.72 GB, linear in memory
    mem = MergeCost.in_memory()
    assert mem.unit_bytes(5_500_030 / mem.input_ratio) == pytest.approx(1.72e9)


def test_read_timings_refuses_an_empty_directory(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="finished mercury-dem run"):
        read_unit_timings(tmp_path)


def test_n_workers_of_report() -> None:
    assert n_workers_of({"execution": {"mode": "local", "description": "LocalCluster 2 workers x 1 threads on 127.0.0.1"}}) == 2
    assert n_workers_of({"execution": {"mode": "sync", "description": "in-process, synchronous"}}) == 1


def test_sleep_cluster_workers_are_never_paused_for_memory() -> None:
    # In-process workers measure the whole process's memory; with a limit (the machine's / n) a caller
    # holding more than that share had every worker paused, and the replay below hung for 600 s.
    pytest.importorskip("distributed")
    with sleep_cluster(16) as cluster:
        limits = {w.memory_manager.memory_limit for w in cluster.workers.values()}
    assert limits == {None}


@pytest.mark.slow  # timing-based (sleep tasks on 16 and 3 in-process workers)
def test_replay_on_dask_makespan_near_critical_path() -> None:
    distributed = pytest.importorskip("distributed")
    # 12 tiles of 30 deg over 5 regions of both hemispheres: the run's shape, small enough for 16 threads
    tiles = [0, 1, 2, 3, 14, 15, 48, 49, 50, 51, 60, 70]
    g = cascade_graph(30.0, tiles=tiles)
    assert [len(g.keys(lvl)) for lvl in ("tile", "region", "hemisphere", "global")] == [12, 5, 2, 1]
    dur = {k: 0.3 for k in g.keys("tile")}
    dur.update({k: 0.2 for k in g.order if not k.startswith("tile")})
    cp, path = critical_path(g.deps, dur)
    assert cp == pytest.approx(0.9) and [k.split("-")[0] for k in path] == ["tile", "region", "hemisphere", "global"]
    with sleep_cluster(16) as cluster, distributed.Client(cluster) as client:
        res = replay_on_dask(client, g, dur, time_scale=1.0)
        # plentiful workers: the critical path plus the scheduler's overhead (generous: a loaded 2-core machine)
        assert cp - 0.01 <= res["makespan"] <= cp + 0.6
        lf = res["level_finish"]
        assert lf["tile"] <= lf["region"] <= lf["hemisphere"] <= lf["global"] == res["makespan"]
    narrow = list_schedule(g, dur, 3).makespan
    assert narrow >= max(cp, sum(dur.values()) / 3) > cp
    with sleep_cluster(3) as cluster, distributed.Client(cluster) as client:
        res3 = replay_on_dask(client, g, dur, time_scale=1.0)
        assert res3["makespan"] >= narrow - 0.01  # no schedule beats the work bound here
        assert res3["makespan"] <= narrow + 0.6
        ov = scheduler_overhead(client, n_tasks=200)
        assert 0 < ov["seconds_per_task"] < 0.05
