"""Size benchmark of the blocked (out-of-core, distributed) adjustment (issue #17).

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python -u workflows/benchmarks/bench_blocked_adjust.py \
        --sizes 1e6 1e7 --modes sync 2 --dir /tmp/bigadj_bench [--keep]

For each size: ``mercury-dem synth-network`` (time, peak memory of the generating
process), then ``mercury-dem adjust-network --json`` per mode (``sync`` = in process,
a number = LocalCluster with that many single-threaded workers), each in its own
subprocess. Prints one JSON line per run and, at the end, the growth exponent of the
per-iteration time and of the peak memory between the sizes.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
from pathlib import Path

from harness import append_record, measure


def _run(cmd: list[str]) -> dict:
    """The command's JSON, with its wall and CPU seconds and the command process's own peak resident bytes
    (``harness.measure``; a LocalCluster's workers are its children: their CPU counts once they were reaped)."""
    m = measure(cmd)
    rec = json.loads(m.stdout)
    rec["wall_seconds"] = round(m.wall_s, 2)
    rec["cpu_seconds"] = round(m.cpu_s, 2)
    rec["process_peak_rss_bytes"] = m.peak_rss_bytes
    return rec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e6, 1e7])
    ap.add_argument("--modes", nargs="+", default=["sync", "2"])
    ap.add_argument("--dir", default="/tmp/bigadj_bench")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="reuse existing networks and keep them")
    ap.add_argument("--config", default=str(Path(__file__).with_name("bigadj.yaml")), help="adjust-network --config")
    args = ap.parse_args()
    exe = [sys.executable, "-m", "mercury_dem.cli"]
    root = Path(args.dir)
    rows = []
    for n in args.sizes:
        store = root / f"net_{n:.0e}"
        if not (args.keep and store.exists()):
            shutil.rmtree(store, ignore_errors=True)
            gen = _run(exe + ["synth-network", str(store), "--measures", str(n), "--seed", str(args.seed), "--json",
                              "--progress", "none"])
            print(json.dumps({"generate": gen}), flush=True)
        for mode in args.modes:
            where = ["--sync"] if mode == "sync" else ["--workers", mode]
            rec = _run(exe + ["adjust-network", str(store), *where, "--json", "--progress", "none",
                              "--config", args.config])
            rec.pop("log", None)
            print(json.dumps(rec), flush=True)
            rows.append((n, mode, rec))
            append_record("blocked_adjust", {"measures": n, "mode": mode, "seed": args.seed, "config": args.config},
                          rec)
        if not args.keep:
            shutil.rmtree(store, ignore_errors=True)
    for mode in args.modes:
        pts = [(r["measures"], sorted(r["seconds_per_iteration"])[len(r["seconds_per_iteration"]) // 2],
                r["peak_memory_bytes"]) for n, m, r in rows if m == mode]
        for (m0, t0, p0), (m1, t1, p1) in zip(pts, pts[1:]):
            k = math.log(m1 / m0)
            print(json.dumps({"mode": mode, "from": m0, "to": m1, "time_per_iteration_exponent": round(math.log(t1 / t0) / k, 3),
                              "peak_memory_exponent": round(math.log(p1 / p0) / k, 3)}), flush=True)


if __name__ == "__main__":
    main()
