"""The reference's cascade before and after the blocked distributed adjustment (issue #17, item 4.4).

Usage::

    .venv/bin/python workflows/benchmarks/bench_cascade_blocked.py RUN --adjust-json ADJ.json \
        [--workers 64 256 648] [--json OUT.json]

``RUN``: a finished ``mercury-dem run`` (its tiles' measured per-pair times and its
adjustment units' seconds per measure, as ``bench_cascade.py`` scales them to the
reference: Becker et al. 2016, 100,432 images, 94.7 M measures, 648 tiles).
``ADJ.json``: an ``adjust-network --workers N --json`` record (the blocked adjustment's
measured per-iteration time, the workers' share of it, iterations, load time, peak
memory of the workers and the client).

Two "before" models of the hemisphere and global units, each a single process:
(A) the run's own seconds per measure (the demo's small units, as in
docs/benchmarks/cascade.md section 2) and (B) the in-memory adjuster measured at
4.9 M measures (342 s, 4.1 GB; docs/benchmarks/adjust.md), linear in measures. "After":
the same plan with the hemisphere and global units costed by
:class:`cascade_replay.BlockedCost` on the run's workers (their point blocks spread over
min(workers, blocks) workers, which the unit occupies as a gang in the list schedule);
regions keep the "before" model (they stay below ``adjust.blocked_min_measures``).
No Dask replay: the list schedule of the same graph (the replay matched it to 3-10 % on
this machine, docs/benchmarks/cascade.md) and the critical path are computed directly.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cascade_replay import (  # beside this script (its directory is first on sys.path)
    BlockedCost,
    InMemoryCost,
    TargetSize,
    critical_path,
    list_schedule,
    read_unit_timings,
    scale_plan,
    with_adjustment,
)

TOP = ("hemisphere", "global")


def evaluate(plan, durations, width, n_workers):  # noqa: ANN001, ANN201 - benchmark helper
    cp, path = critical_path(plan.graph.deps, durations)
    sched = list_schedule(plan.graph, durations, n_workers, width)
    lf = sched.level_finish(plan.graph)
    top = sum(durations[k] for k in path if k.split("-")[0] in TOP)
    return {"critical_path_h": cp / 3600, "critical_path": path, "top_share_of_critical_path": top / cp,
            "makespan_h": sched.makespan / 3600, "level_finish_h": {k: v / 3600 for k, v in lf.items()},
            "work_h": sum(durations.values()) / 3600}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--adjust-json", required=True, help="adjust-network --workers N --json record")
    ap.add_argument("--workers", type=int, nargs="+", default=[64, 256, 648])
    ap.add_argument("--call-seconds", type=float, default=0.00355,
                    help="client cost per actor call per shard (measured per-task overhead, cascade.md)")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()
    rec = json.loads(Path(args.adjust_json).read_text())
    blocked = BlockedCost.from_record(rec, call_seconds=args.call_seconds)
    inmem = InMemoryCost()
    plan = scale_plan(read_unit_timings(args.run), TargetSize())
    out = {"blocked_cost": blocked.__dict__, "in_memory_cost": inmem.__dict__, "rows": []}
    print(f"blocked, measured: {blocked}", flush=True)
    base_b, _, det_b = with_adjustment(plan, ("region", *TOP), inmem)
    for n in args.workers:
        row = {"workers": n}
        for name, base in (("A", dict(plan.durations)), ("B", base_b)):
            before = evaluate(plan, base, {}, n)
            after_d, width, det = with_adjustment(plan, TOP, blocked, n)
            after_d = {k: (after_d[k] if k in width else base[k]) for k in base}
            after = evaluate(plan, after_d, width, n)
            after["units"] = {k: det[k] for k in ("hemisphere-0", "hemisphere-1", "global-0")}
            row[name] = {"before": before, "after": after}
            print(f"{n:4d} workers, model {name}: critical path {before['critical_path_h']:.2f} -> "
                  f"{after['critical_path_h']:.2f} h, makespan {before['makespan_h']:.2f} -> {after['makespan_h']:.2f} h; "
                  f"after: global {det['global-0']['seconds'] / 3600:.3f} h on {int(det['global-0']['shards'])} shards "
                  f"(worker {det['global-0']['worker_bytes'] / 1e9:.2f} GB, client {det['global-0']['client_bytes'] / 1e9:.2f} GB), "
                  f"hemispheres {det['hemisphere-0']['seconds'] / 3600:.3f}/{det['hemisphere-1']['seconds'] / 3600:.3f} h",
                  flush=True)
        out["rows"].append(row)
    out["before_memory_bytes"] = {k: {"measures": det_b[k]["measures"], "bytes": det_b[k]["worker_bytes"]}
                                  for k in ("hemisphere-0", "hemisphere-1", "global-0")}
    print("before, in memory: " + ", ".join(f"{k} {v['measures'] / 1e6:.1f} M measures {v['bytes'] / 1e9:.0f} GB"
                                            for k, v in out["before_memory_bytes"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
