"""Benchmark of the hierarchical workflow (issue #6, section 7): a finished run, then the plan past this machine.

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_cascade.py RUN \
        [--workers 32 64] [--hour-seconds 5] [--alpha 1.0] [--pairs-per-image X] [--json OUT.json]

Part 1, the measured run (``RUN/report.json`` and every unit's ``summary.json``):
wall time per level (``report.timings``), the sum of unit times per level, how busy
the workers were (sum of unit seconds / (cascade wall x workers)), the critical
path of the run's own graph with its measured durations, and the scheduler
overhead per task, measured here by submitting 1000 trivial tasks to a
LocalCluster of the run's size (worker processes, as the run uses).

Part 2, the simulation: the run's per-pair tile cost and per-measure adjustment
cost, scaled to the reference (Becker et al. 2016: 100,432 images, 94,745,475
measures, 10 deg tiles -> 648 tiles, 14 regions, 2 hemispheres, 1 globe), replayed
as ``time.sleep`` tasks in the run's graph (submitted up front, tile futures ->
regions -> hemispheres -> globe) on in-process LocalClusters of 32 and 64
single-threaded workers, ``--hour-seconds`` real seconds per simulated hour.
Printed next to it, as the reference of the replay: the critical path and the
greedy list schedule with zero overhead; ratios Dask / ideal.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from cascade_replay import (  # beside this script (workflows/benchmarks/cascade_replay.py)
    ADJUSTED_LEVELS,
    LEVELS,
    TargetSize,
    busy_fraction,
    cascade_graph,
    critical_path,
    level_spans,
    list_schedule,
    n_workers_of,
    read_unit_timings,
    replay_on_dask,
    scale_plan,
    scheduler_overhead,
    sleep_cluster,
)

#: Measured elsewhere in this project (quoted, not re-measured here): adjustment at 5e6 measures,
#: 17-30 s per LM iteration and 4.3 GB peak (/work/shared/ECOSYSTEM-NOTES.md); merge of 5.5e6 input
#: measures, 1.7 GiB peak (docs/benchmarks/network.md).
ANCHOR_MEASURES = 5e6
ANCHOR_S_PER_ITERATION = (17.0, 30.0)
ANCHOR_ADJUST_GB = 4.3
MERGE_GIB_PER_MEASURE = 1.72 / 5.5e6


def measured_part(run: Path, run_workers: int | None = None) -> dict:
    report = json.loads((run / "report.json").read_text())
    timings = read_unit_timings(run)
    nw = run_workers or n_workers_of(report) or 1
    tm = report["timings"]
    cascade_wall = sum(float(tm.get(lvl, 0.0)) for lvl in LEVELS)
    spans = level_spans(timings)
    per_level = {}
    for lvl in LEVELS:
        us = timings[lvl]
        s = float(sum(u.seconds for u in us))
        sp = spans.get(lvl, {"start": np.nan, "end": np.nan, "span": np.nan})
        per_level[lvl] = {"units": len(us), "report_s": float(tm.get(lvl, np.nan)), **sp, "sum_unit_s": s,
                          "max_unit_s": float(max((u.seconds for u in us), default=0.0)),
                          "busy_in_span": s / (sp["span"] * nw) if sp["span"] > 0 else None}
    span_all = max(v["end"] for v in spans.values())
    g = cascade_graph(report["config"]["tiling"]["tile_size_deg"], tiles=[u.id for u in timings["tile"]])
    dur = {u.key: u.seconds for lvl in LEVELS for u in timings[lvl]}
    dur.update({k: 0.0 for k in g.order if k not in dur})
    cp, path = critical_path(g.deps, dur)
    ideal = list_schedule(g, dur, nw).makespan
    return {
        "report_timings": tm, "n_workers": nw, "execution": report.get("execution"),
        "levels": per_level, "cascade_wall_s": cascade_wall, "units_span_s": span_all,
        "busy_fraction": busy_fraction(timings, cascade_wall, nw),
        "busy_fraction_units_span": busy_fraction(timings, span_all, nw),
        "critical_path_s": cp, "critical_path": path, "ideal_list_schedule_s": ideal,
        "pairs_per_image": sum(u.pairs for u in timings["tile"]) / max(1, sum(u.images for u in timings["tile"])),
        "timings": timings,
    }


def overhead_part(n_workers: int, n_tasks: int) -> dict:
    """Per-task overhead on a LocalCluster shaped like the run's (processes, 1 thread each)."""
    from distributed import Client

    from mercury_dem.compute import local_cluster

    with local_cluster(n_workers, 1) as cluster, Client(cluster) as client:
        return scheduler_overhead(client, n_tasks)


def simulate_part(timings: dict, target: TargetSize, alpha: float, workers: list[int], hour_seconds: float,
                  replay: bool) -> dict:
    from distributed import Client

    plan = scale_plan(timings, target, alpha=alpha)
    g, dur = plan.graph, plan.durations
    cp, path = critical_path(g.deps, dur)
    total = float(sum(dur.values()))
    by_level = {lvl: {"units": len(g.keys(lvl)), "sum_h": sum(dur[k] for k in g.keys(lvl)) / 3600,
                      "max_h": max(dur[k] for k in g.keys(lvl)) / 3600} for lvl in LEVELS}
    out = {"notes": plan.notes, "levels": by_level, "critical_path_h": cp / 3600,
           "critical_path": [(k, dur[k] / 3600) for k in path], "total_work_h": total / 3600, "runs": {}}
    scale = hour_seconds / 3600.0
    for n in sorted(set(workers) | {8, 16, 128, 256, 648}):
        ls = list_schedule(g, dur, n)
        row = {"list_schedule_h": ls.makespan / 3600, "work_bound_h": total / n / 3600,
               "list_level_finish_h": {k: v / 3600 for k, v in ls.level_finish(g).items()}}
        if replay and n in workers:
            with sleep_cluster(n) as cluster, Client(cluster) as client:
                res = replay_on_dask(client, g, dur, scale)
            row["dask_h"] = res["makespan"] / 3600
            row["dask_level_finish_h"] = {k: v / 3600 for k, v in res["level_finish"].items()}
            row["dask_over_list"] = res["makespan"] / ls.makespan
            row["real_seconds"] = res["makespan"] * scale
        out["runs"][n] = row
    # Cross-check of the adjustment levels with the large-size anchor (per-iteration cost x iterations).
    its = {lvl: int(np.median([u.iterations for u in timings[lvl] if u.iterations] or [15]))
           for lvl in ADJUSTED_LEVELS}
    anchor = {}
    for lvl in ADJUSTED_LEVELS:
        m = max(plan.measures[k] for k in g.keys(lvl))
        anchor[lvl] = {
            "largest_unit_measures": m, "iterations_measured": its[lvl],
            "anchor_hours": [its[lvl] * s * m / ANCHOR_MEASURES / 3600 for s in ANCHOR_S_PER_ITERATION],
            "replayed_hours": max(dur[k] for k in g.keys(lvl)) / 3600,
            "adjust_memory_gb": ANCHOR_ADJUST_GB * m / ANCHOR_MEASURES,
            "merge_memory_gib": MERGE_GIB_PER_MEASURE * m,
        }
    out["anchor"] = anchor
    # The same schedule with the anchor's (faster, large-size) adjustment times, for the bound.
    dur2 = dict(dur)
    for lvl in ADJUSTED_LEVELS:
        for k in g.keys(lvl):
            dur2[k] = its[lvl] * float(np.mean(ANCHOR_S_PER_ITERATION)) * plan.measures[k] / ANCHOR_MEASURES
    cp2, _ = critical_path(g.deps, dur2)
    out["anchor_schedule"] = {"critical_path_h": cp2 / 3600,
                              "list_schedule_h": {n: list_schedule(g, dur2, n).makespan / 3600 for n in workers}}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--workers", type=int, nargs="+", default=[32, 64])
    ap.add_argument("--hour-seconds", type=float, default=5.0, help="real seconds per simulated hour")
    ap.add_argument("--alpha", type=float, default=1.0, help="adjustment time ~ measures**alpha")
    ap.add_argument("--pairs-per-image", type=float, default=None, help="default: the run's own")
    ap.add_argument("--images", type=int, default=TargetSize.images)
    ap.add_argument("--measures", type=int, default=TargetSize.measures)
    ap.add_argument("--run-workers", type=int, default=None,
                    help="workers of the measured run (default: from report.json's execution description)")
    ap.add_argument("--overhead-tasks", type=int, default=1000)
    ap.add_argument("--no-replay", action="store_true", help="list schedule only, no Dask replay")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    print(f"date {datetime.now(timezone.utc).isoformat(timespec='seconds')}; {platform.node()} "
          f"{os.cpu_count()} cores; load {os.getloadavg()}; python {platform.python_version()}")
    m = measured_part(a.run, a.run_workers)
    timings = m.pop("timings")
    print(f"\n== measured run {a.run} ({m['execution']}) ==")
    print("report.timings = time from the previous level's last completion to this level's last; start/end/span "
          "from each unit's summary.json (mtime = end, minus its seconds = start), s from the first tile's start")
    print(f"{'level':<11}{'units':>6}{'report s':>9}{'start':>8}{'end':>8}{'span':>8}{'sum s':>9}{'max s':>8}{'busy':>7}")
    for lvl, r in m["levels"].items():
        busy = "-" if r["busy_in_span"] is None else f"{r['busy_in_span']:.2f}"
        print(f"{lvl:<11}{r['units']:>6}{r['report_s']:>9.1f}{r['start']:>8.1f}{r['end']:>8.1f}{r['span']:>8.1f}"
              f"{r['sum_unit_s']:>9.1f}{r['max_unit_s']:>8.1f}{busy:>7}")
    print(f"cascade wall (report) {m['cascade_wall_s']:.1f} s, units' span {m['units_span_s']:.1f} s, on "
          f"{m['n_workers']} workers; busy fraction {m['busy_fraction']:.2f} of the cascade wall "
          f"({m['busy_fraction_units_span']:.2f} of the units' span); critical path {m['critical_path_s']:.1f} s ({' -> '.join(m['critical_path'])}); "
          f"ideal list schedule of the measured units {m['ideal_list_schedule_s']:.1f} s "
          f"(wall / ideal {m['cascade_wall_s'] / m['ideal_list_schedule_s']:.2f})")
    if abs(m["units_span_s"] - m["cascade_wall_s"]) > 0.1 * m["cascade_wall_s"]:
        print(f"WARNING: the units span {m['units_span_s']:.0f} s but the report's cascade took "
              f"{m['cascade_wall_s']:.0f} s: this run was resumed (units reused from an earlier invocation keep "
              "their first times); the busy fraction of the report's wall is meaningless, read the per-level spans")
    t = time.perf_counter()
    ov = overhead_part(m["n_workers"], a.overhead_tasks)
    print(f"scheduler overhead: {ov['tasks']} trivial tasks on a LocalCluster of {m['n_workers']} worker processes: "
          f"{ov['seconds']:.2f} s, {1e3 * ov['seconds_per_task']:.2f} ms per task "
          f"(x {sum(r['units'] for r in m['levels'].values())} units = "
          f"{ov['seconds_per_task'] * sum(r['units'] for r in m['levels'].values()):.2f} s of the run) "
          f"[{time.perf_counter() - t:.1f} s with start-up]")
    ppi = a.pairs_per_image or m["pairs_per_image"]
    target = TargetSize(images=a.images, measures=a.measures, tile_size_deg=10.0, pairs_per_image=ppi)
    s = simulate_part(timings, target, a.alpha, a.workers, a.hour_seconds, not a.no_replay)
    n = s["notes"]
    print(f"\n== simulation: {a.images} images, {a.measures} measures, 10 deg tiles, {ppi:.1f} pairs per image, "
          f"alpha {a.alpha}; 1 simulated hour = {a.hour_seconds} s ==")
    print(f"tile cost {n['seconds_per_pair']['median']:.2f} s/pair (median; {n['seconds_per_pair']['min']:.2f}-"
          f"{n['seconds_per_pair']['max']:.2f} over {n['seconds_per_pair']['tiles']} tiles); images per tile "
          f"{n['images_per_tile']['min']:.0f}-{n['images_per_tile']['max']:.0f} (mean {n['images_per_tile']['mean']:.0f}); "
          f"adjustment s/measure^alpha {json.dumps({k: float(f'{v:.3g}') for k, v in n['adjust_coefficient_s_per_measure_pow_alpha'].items()})}")
    for lvl, r in s["levels"].items():
        print(f"  {lvl:<11}{r['units']:>5} units, work {r['sum_h']:9.2f} h, longest unit {r['max_h']:7.2f} h")
    print(f"total work {s['total_work_h']:.1f} h; critical path {s['critical_path_h']:.2f} h: "
          + " -> ".join(f"{k} {h:.2f} h" for k, h in s["critical_path"]))
    print(f"{'workers':>8}{'work/n h':>10}{'list h':>9}{'dask h':>9}{'dask/list':>10}{'dask/CP':>9}{'real s':>8}   level finish (dask or list) h")
    for w, r in s["runs"].items():
        d = r.get("dask_h")
        lf = r.get("dask_level_finish_h", r["list_level_finish_h"])
        cols = ["-"] * 4 if d is None else [f"{d:.2f}", f"{r['dask_over_list']:.3f}",
                                             f"{d / s['critical_path_h']:.3f}", f"{r['real_seconds']:.1f}"]
        print(f"{w:>8}{r['work_bound_h']:>10.2f}{r['list_schedule_h']:>9.2f}{cols[0]:>9}{cols[1]:>10}{cols[2]:>9}"
              f"{cols[3]:>8}   " + ", ".join(f"{k} {v:.2f}" for k, v in lf.items()))
    print("largest adjustment unit per level (replayed vs anchor 17-30 s/iteration at 5e6 measures, linear):")
    for lvl, r in s["anchor"].items():
        print(f"  {lvl:<11}{r['largest_unit_measures']:>12.3g} measures, {r['iterations_measured']} it: replayed "
              f"{r['replayed_hours']:.2f} h, anchor {r['anchor_hours'][0]:.2f}-{r['anchor_hours'][1]:.2f} h; memory "
              f"adjust ~{r['adjust_memory_gb']:.0f} GB, merge ~{r['merge_memory_gib']:.0f} GiB")
    print(f"with the anchor's adjustment times: critical path {s['anchor_schedule']['critical_path_h']:.2f} h, list schedule "
          + ", ".join(f"{w} workers {h:.2f} h" for w, h in s["anchor_schedule"]["list_schedule_h"].items()))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"measured": m, "overhead": ov, "simulation": s}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
