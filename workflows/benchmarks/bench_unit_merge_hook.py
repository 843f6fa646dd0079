"""Benchmark of the run's unit merge with ``adjust.streamed_merge_levels`` on and off (issue 33 item 1, first step).

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python -u workflows/benchmarks/bench_unit_merge_hook.py \
        --measures 1e6 [--repeats 1] [--part-measures 5e5] [--json] [--dir /tmp/unit_merge_hook]

Children: a synthetic network of ``--measures`` measures cut into two overlapping children (as
``bench_streamed_merge.py``: "two hemispheres' stores"). Then, interleaved, each in a forked child (its peak its own):

* ``in_memory``: what a unit did with the key off — every child's network read, ``merge_networks``;
* ``streamed``: what it does with the key on — ``stream_merged_network`` (the merge by parts into a scratch store,
  the merged network read back whole for the adjustment, the scratch removed).

Prints and records (``unit_merge_hook``) each one's wall seconds, peak RSS above the process's start, bytes per
measure, and whether the two merged networks are equal (sha256 over every column's bytes).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
from harness import append_record, interleave, measure
from harness.measure import median


def _digest(net: Any) -> str:
    from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS

    h = hashlib.sha256()
    for name in ("image_ids", "point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
        h.update(np.ascontiguousarray(getattr(net, name)).tobytes())
    return h.hexdigest()[:16]


def in_memory(root: Path) -> dict[str, Any]:
    """The key off: both children read whole, ``merge_networks``."""
    from mercury_dem.io.network_store import read_network
    from mercury_dem.network.merge import merge_networks

    net = merge_networks([read_network(root / "a"), read_network(root / "b")]).network
    return {"digest": _digest(net), "measures": net.n_measures}


def streamed(root: Path, part_measures: int) -> dict[str, Any]:
    """The key on: ``stream_merged_network`` (by parts into a scratch store, read back, removed)."""
    from mercury_dem.io.merged_network_store import stream_merged_network
    from mercury_dem.io.synthetic_network_store import BlockedNetwork

    images = BlockedNetwork(root / "src").images
    net, _ = stream_merged_network("hemisphere 0", [("a", root / "a"), ("b", root / "b")], root / "merged",
                                   lambda ids: images, part_measures=part_measures)
    return {"digest": _digest(net), "measures": net.n_measures}


def main() -> None:
    """Build the children, measure both merges interleaved, print and record the figures."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--measures", type=float, default=1e6)
    ap.add_argument("--part-measures", type=float, default=5e5)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--dir", default="/tmp/unit_merge_hook")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from mercury_dem.io.synthetic_network_store import split_synthetic_network, write_synthetic_network
    from mercury_dem.network.synthetic import SyntheticSpec

    root = Path(args.dir)
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    t0 = time.perf_counter()
    write_synthetic_network(SyntheticSpec(n_measures=int(args.measures), seed=args.seed), root / "src")
    split_synthetic_network(root / "src", [root / "a", root / "b"], overlap_blocks=1, seed=args.seed + 1)
    build_s = time.perf_counter() - t0
    runs = interleave({"in_memory": lambda: measure(in_memory, root, label="in_memory"),
                       "streamed": lambda: measure(streamed, root, int(args.part_measures), label="streamed")},
                      args.repeats)
    n = runs["in_memory"][0].value["measures"]
    rec: dict[str, Any] = {"measures": n, "children_seconds": round(build_s, 1),
                           "equal": runs["in_memory"][0].value["digest"] == runs["streamed"][0].value["digest"]}
    for k, ms in runs.items():
        rec[k] = {"wall_s": round(median(ms), 2), "extra_rss_bytes": int(median(ms, "extra_rss_bytes")),
                  "bytes_per_measure": round(median(ms, "extra_rss_bytes") / n, 1), "runs": [m.as_record() for m in ms]}
    append_record("unit_merge_hook", {"measures": args.measures, "part_measures": args.part_measures,
                                      "repeats": args.repeats, "seed": args.seed}, rec)
    shutil.rmtree(root, ignore_errors=True)
    print(json.dumps(rec) if args.json else "\n".join(f"{k}: {v}" for k, v in rec.items() if k != "runs"))


if __name__ == "__main__":
    main()
