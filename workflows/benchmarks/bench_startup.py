"""Start-up time of small commands, each a fresh process, for one or more source trees.

    python workflows/benchmarks/bench_startup.py [--mission DIR] [--repeats 5] TREE [TREE ...]

Each TREE is a directory holding ``mercury_dem/`` (e.g. this checkout, or ``git archive REV mercury_dem``
unpacked elsewhere), put first on ``PYTHONPATH``; runs happen in ``/tmp`` so the current directory
does not shadow it. Every command of every tree is one :func:`harness.measure` of a child process, the rounds
interleaved by :func:`harness.interleave` (a load burst hits every tree alike). Prints median and minimum wall
seconds, median CPU seconds and peak memory per tree and command; ``--json`` appends a harness record.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from harness import Measurement, append_record, interleave, measure
from harness.measure import median


def _runner(tree: str, argv: list[str], label: str) -> Callable[[], Measurement]:
    env = dict(os.environ, PYTHONPATH=tree)
    return lambda: measure([sys.executable, "-m", "mercury_dem.cli", *argv], label=label, env=env, cwd="/tmp")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("trees", nargs="+")
    p.add_argument("--mission", help="a small mission for 'mercury-dem info'")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json", action="store_true", help="append a record to records/bench_startup.jsonl")
    args = p.parse_args()
    cmds = {"--help": ["--help"], "config --template": ["config", "--template"]}
    if args.mission:
        cmds["info"] = ["info", args.mission]
    runs = {f"{tree} | {name}": _runner(tree, argv, f"{tree} | {name}")
            for tree in args.trees for name, argv in cmds.items()}
    res = interleave(runs, args.repeats)
    rows = []
    for label, ms in res.items():
        tree, name = label.split(" | ")
        row = {"tree": tree, "command": name, "wall_median_s": round(median(ms), 4),
               "wall_min_s": round(min(m.wall_s for m in ms), 4), "cpu_median_s": round(median(ms, "cpu_s"), 4),
               "peak_rss_mib": round(max(m.peak_rss_bytes for m in ms) / 2**20, 1)}
        rows.append(row)
        print(f"{tree:30s} {name:18s} median {row['wall_median_s']:.3f} s  min {row['wall_min_s']:.3f} s  "
              f"CPU {row['cpu_median_s']:.3f} s  peak {row['peak_rss_mib']:.0f} MiB")
    if args.json:
        append_record("bench_startup", {"repeats": args.repeats, "trees": args.trees}, {"rows": rows})


if __name__ == "__main__":
    main()
