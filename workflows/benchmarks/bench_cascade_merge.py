"""The reference's cascade with the merge of the hemispheres and the globe in the model (issue 33, done-when 5).

Usage::

    .venv/bin/python workflows/benchmarks/bench_cascade_merge.py RUN --adjust-json ADJ.json \
        [--workers 64 256 648] [--json OUT.json]

As ``bench_cascade_blocked.py`` (``RUN``: a finished run whose tiles' per-pair times and adjustment units'
seconds per measure are scaled to the reference, Becker et al. 2016: 100,432 images, 94.7 M measures, 648
tiles; ``ADJ.json``: an ``adjust-network --workers N --json`` record of the blocked adjustment), but every
hemisphere and the globe is two tasks: its merge (:class:`cascade_replay.MergeCost`; serial in the unit's
process, one worker, as the pipeline's units run it) and then its blocked adjustment over min(workers,
blocks) workers (:class:`cascade_replay.BlockedCost`, a gang in the list schedule). Three merges: none (the
figures of section 4, where the merge was left out of the "after" model), the streamed merge
(``io/merged_network_store.stream_merge``: 82.65 s for 2.5*10^7 measures, 0.97 GB) and the in-memory merge
(``merge_networks``: 8.1 s for 5.5*10^6 input measures, 1.72 GB, linear). Regions keep the run's own model
(A: the demo's seconds per measure, merge included) or the in-memory adjuster at size (B). No Dask replay:
the list schedule and the critical path are computed directly (the replay matched the list schedule to
3-10 % on this machine, docs/benchmarks/cascade.md).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

from cascade_replay import (  # beside this script (its directory is first on sys.path)
    BlockedCost,
    InMemoryCost,
    MergeCost,
    TargetSize,
    critical_path,
    list_schedule,
    read_unit_timings,
    scale_plan,
    with_adjustment,
    with_merge,
)

TOP = ("hemisphere", "global")


def evaluate(graph: Any, durations: dict[str, float], width: dict[str, int], n_workers: int) -> dict[str, Any]:
    """Critical path, list-schedule makespan and the shares of the critical path (merge, top adjustment, tile)."""
    cp, path = critical_path(graph.deps, durations)
    sched = list_schedule(graph, durations, n_workers, width)
    lf = sched.level_finish(graph)
    merge = sum(durations[k] for k in path if k.startswith("merge:"))
    top = sum(durations[k] for k in path if k.split("-")[0] in TOP)
    tiles = sum(durations[k] for k in path if k.startswith("tile-"))
    return {"critical_path_h": cp / 3600, "critical_path": path, "makespan_h": sched.makespan / 3600,
            "merge_share_of_critical_path": merge / cp, "adjust_top_share_of_critical_path": top / cp,
            "tile_share_of_critical_path": tiles / cp,
            "level_finish_h": {k: v / 3600 for k, v in lf.items()}, "work_h": sum(durations.values()) / 3600}


def main() -> int:
    """Every worker count x region model x merge model: critical path, makespan, what they are made of."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--adjust-json", required=True, help="adjust-network --workers N --json record")
    ap.add_argument("--workers", type=int, nargs="+", default=[64, 256, 648])
    ap.add_argument("--call-seconds", type=float, default=0.00355,
                    help="client cost per actor call per shard (measured per-task overhead, cascade.md)")
    ap.add_argument("--per-pair-median", type=float,
                    help="scale the tiles' drawn seconds per pair so that the run's median is this (e.g. 0.32 s, "
                         "the demo run behind cascade.md section 4, when RUN is a smaller mission's)")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()
    blocked = BlockedCost.from_record(json.loads(Path(args.adjust_json).read_text()), call_seconds=args.call_seconds)
    plan = scale_plan(read_unit_timings(args.run), TargetSize())
    if args.per_pair_median:
        f = args.per_pair_median / plan.notes["seconds_per_pair"]["median"]
        plan = replace(plan, durations={k: v * (f if k.startswith("tile-") else 1.0) for k, v in plan.durations.items()},
                       notes={**plan.notes, "tile_scale": f})
    base_b, _, _ = with_adjustment(plan, ("region", *TOP), InMemoryCost())
    merges = {"none": None, "streamed": MergeCost(), "in memory": MergeCost.in_memory()}
    out: dict[str, Any] = {"blocked_cost": blocked.__dict__, "merge_costs": {k: v.__dict__ for k, v in merges.items() if v},
                           "plan_notes": plan.notes, "rows": []}
    print(f"blocked, measured: {blocked}", flush=True)
    for n in args.workers:
        for model, base in (("A", dict(plan.durations)), ("B", base_b)):
            adj, width, det = with_adjustment(plan, TOP, blocked, n)
            adj = {k: (adj[k] if k in width else base[k]) for k in base}
            for name, merge in merges.items():
                if merge is None:
                    graph, d, mdet = plan.graph, adj, {}
                else:
                    graph, d, mdet = with_merge(plan, TOP, adj, merge)
                row = {"workers": n, "regions": model, "merge": name, **evaluate(graph, d, width, n),
                       "adjust": {k: det[k] for k in ("hemisphere-0", "hemisphere-1", "global-0")}, "merges": mdet}
                out["rows"].append(row)
                lf = row["level_finish_h"]
                g = mdet.get("global-0", {})
                print(f"{n:4d} workers, regions {model}, merge {name:9s}: critical path {row['critical_path_h']:.2f} h "
                      f"(merge {100 * row['merge_share_of_critical_path']:.0f} %, top adjustment "
                      f"{100 * row['adjust_top_share_of_critical_path']:.0f} %, tile "
                      f"{100 * row['tile_share_of_critical_path']:.0f} %), makespan {row['makespan_h']:.2f} h; "
                      f"level finish {lf['tile']:.2f}/{lf['region']:.2f}/{lf['hemisphere']:.2f}/{lf['global']:.2f} h"
                      + (f"; global merge {g['seconds'] / 3600:.3f} h, {g['bytes'] / 1e9:.1f} GB" if g else "")
                      + f"; global adjustment {det['global-0']['seconds'] / 3600:.3f} h", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
