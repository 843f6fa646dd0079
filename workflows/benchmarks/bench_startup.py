"""Start-up time of small commands, each a fresh process, for one or more source trees.

    python workflows/benchmarks/bench_startup.py [--mission DIR] [--repeats 5] TREE [TREE ...]

Each TREE is a directory holding ``mercury_dem/`` (e.g. this checkout, or ``git archive REV mercury_dem``
unpacked elsewhere), put first on ``PYTHONPATH``; runs happen in ``/tmp`` so the current directory
does not shadow it. Prints median and minimum seconds per tree and command.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("trees", nargs="+")
    p.add_argument("--mission", help="a small mission for 'mercury-dem info'")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    cmds = {"--help": ["--help"], "config --template": ["config", "--template"]}
    if args.mission:
        cmds["info"] = ["info", args.mission]
    res: dict[tuple[str, str], list[float]] = {}
    for _ in range(args.repeats):  # interleaved: a load burst hits every tree alike
        for tree in args.trees:
            env = dict(os.environ, PYTHONPATH=tree)
            for name, argv in cmds.items():
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "mercury_dem.cli", *argv], env=env, cwd="/tmp",
                               stdout=subprocess.DEVNULL, check=True)
                res.setdefault((tree, name), []).append(time.perf_counter() - t0)
    for (tree, name), v in res.items():
        print(f"{tree:30s} {name:18s} median {statistics.median(v):.3f} s  min {min(v):.3f} s")


if __name__ == "__main__":
    main()
