"""Benchmark: peak memory of ``mercury-dem register`` on a global DEM (registered/merged maps block by block).

1. Prepares (once, in this process) a misregistered global ``dem.zarr`` at ``--ppd`` and ``--shots``
   MLA-like shots (``bench_register.make_dem`` / ``make_shots``) in ``--out``.
2. Runs ``mercury-dem register OUT --altimetry OUT/shots.parquet --overwrite`` (the CLI module) in a
   child process per ``--pythonpath`` (e.g. the old tree and the new one, side by side) and reports
   its wall time and peak resident memory (the child's own ``getrusage(RUSAGE_SELF).ru_maxrss``,
   printed by the child as it exits).

Usage (heavy: run under the lock)::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_register_memory.py \\
        --ppd 16 --shots 1e6 --out /tmp/bench_reg_mem --pythonpath OLD_TREE --pythonpath NEW_TREE \\
        --extra= --extra=--no-products
    # the stage alone, smaller blocks than the default 4e6 pixels (0: an old tree without the argument):
    ... --ppd 8 --shots 2e5 --pythonpath OLD_TREE --pythonpath NEW_TREE --api-block-pixels 0 --api-block-pixels 5e5
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ppd", type=float, default=16.0)
    ap.add_argument("--shots", type=float, default=1e6)
    ap.add_argument("--out", required=True)
    ap.add_argument("--pythonpath", action="append", default=[], help="source tree to run (repeatable)")
    ap.add_argument("--api-block-pixels", type=float, action="append", default=[],
                    help="call register_dem_store(block_pixels=N) in the child instead of the CLI, one per "
                         "--pythonpath (0: without the argument, for a tree that predates it)")
    ap.add_argument("--extra", action="append", default=[],
                    help="extra arguments for register, one per --pythonpath (e.g. '--no-products' for a tree that has it)")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_register import Surface, make_dem, make_shots

    out = Path(args.out)
    if not (out / "shots.parquet").exists():
        out.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(3)
        surf = Surface(rng, min_wavelength_m=50e3)
        make_dem(surf, args.ppd, out / "dem.zarr", (0.02, 0.03, 300.0))
        make_shots(surf, int(args.shots), rng).to_parquet(out / "shots.parquet")
    rows = []
    trees = args.pythonpath or [str(Path(__file__).resolve().parents[2])]
    extras = args.extra + [""] * (len(trees) - len(args.extra))
    blocks = args.api_block_pixels + [None] * (len(trees) - len(args.api_block_pixels))
    for tree, extra, block in zip(trees, extras, blocks):
        argv = ["mercury-dem", "register", str(out), "--altimetry", str(out / "shots.parquet"), "--overwrite",
                *extra.split()]
        code = ("import resource, runpy, sys\n"
                f"sys.argv = {argv!r}\n"
                "try:\n    runpy.run_module('mercury_dem.cli', run_name='__main__')\n"
                "finally:\n    print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n")
        if block is not None:  # the stage alone, through its Python API
            kw = f", block_pixels={block!r}" if block else ""
            code = ("import resource, sys, tracemalloc\nimport pandas as pd\n"
                    "from mercury_dem.pipeline.register_stage import register_dem_store\n"
                    f"shots = pd.read_parquet({str(out / 'shots.parquet')!r})\n"
                    "tracemalloc.start()\n"
                    f"s = register_dem_store({str(out / 'dem.zarr')!r}, shots, "
                    f"{str(out)!r}, overwrite=True{kw})\n"
                    "print('TRACED_PEAK_B', tracemalloc.get_traced_memory()[1], file=sys.stderr)\n"
                    "print('registered', s['tiles_registered'], 'tiles; block_rows', s.get('block_rows'))\n"
                    "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n")
        t0 = time.perf_counter()
        # cwd /tmp: 'python -c' puts the current directory first on sys.path, before PYTHONPATH's tree
        res = subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": tree},
                             capture_output=True, text=True, cwd="/tmp")
        secs = time.perf_counter() - t0
        peak = [ln.split()[1] for ln in res.stderr.splitlines() if ln.startswith("PEAK_RSS_KB")]
        traced = [ln.split()[1] for ln in res.stderr.splitlines() if ln.startswith("TRACED_PEAK_B")]
        rows.append({"tree": tree, "args": extra if block is None else f"API block_pixels={block or 'n/a'}",
                     "rc": res.returncode, "seconds": round(secs, 1),
                     "peak_rss_gb": round(int(peak[-1]) / 1e6, 3) if peak else None,
                     # numpy/Python allocations during the stage alone (tracemalloc; API mode): no import baseline
                     "stage_traced_peak_gb": round(int(traced[-1]) / 1e9, 3) if traced else None,
                     "last_line": (res.stdout.strip().splitlines() or [res.stderr.strip()[-300:]])[-1]})
    print(json.dumps({"date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
                      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "ppd": args.ppd,
                      "shots": int(args.shots), "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
