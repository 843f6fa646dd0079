"""Benchmark: peak memory of ``mercury-dem register`` on a global DEM (registered/merged maps block by block).

1. Prepares (once, in this process) a misregistered global ``dem.zarr`` at ``--ppd`` and ``--shots``
   MLA-like shots (``harness.scenarios.make_dem`` / ``make_shots``, as ``bench_register.py``) in ``--out``.
2. Runs ``mercury-dem register OUT --altimetry OUT/shots.parquet --overwrite`` (the CLI module) in a
   child process per ``--pythonpath`` (e.g. the old tree and the new one, side by side) and reports
   its wall time, CPU and peak resident memory (``harness.measure``: the child's ``ru_maxrss`` from
   ``wait4``), appended to ``records/register_memory.jsonl``.

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
import sys
import time
from pathlib import Path

import numpy as np
from harness import append_record, measure
from harness.scenarios import Surface, make_dem, make_shots


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ppd", type=float, default=16.0)
    ap.add_argument("--shots", type=float, default=1e6)
    ap.add_argument("--out", required=True)
    ap.add_argument("--pythonpath", action="append", default=[], help="source tree to run (repeatable)")
    ap.add_argument("--api-block-pixels", type=float, action="append", default=[],
                    help="call register_dem_store(settings=RegistrationConfig(block_pixels=N)) in the child instead of the CLI, one per "
                         "--pythonpath (0: without the argument, for a tree that predates it)")
    ap.add_argument("--extra", action="append", default=[],
                    help="extra arguments for register, one per --pythonpath (e.g. '--no-products' for a tree that has it)")
    args = ap.parse_args()
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
        code = ("import runpy, sys\n"
                f"sys.argv = {argv!r}\n"
                "runpy.run_module('mercury_dem.cli', run_name='__main__')\n")
        if block is not None:  # the stage alone, through its Python API
            kw = f", settings=RegistrationConfig(block_pixels={block!r})" if block else ""
            code = ("import sys, tracemalloc\nimport pandas as pd\n"
                    "from mercury_dem.config.registration import RegistrationConfig\n"
                    "from mercury_dem.pipeline.register_stage import register_dem_store\n"
                    f"shots = pd.read_parquet({str(out / 'shots.parquet')!r})\n"
                    "tracemalloc.start()\n"
                    f"s = register_dem_store({str(out / 'dem.zarr')!r}, shots, "
                    f"{str(out)!r}, overwrite=True{kw})\n"
                    "print('TRACED_PEAK_B', tracemalloc.get_traced_memory()[1], file=sys.stderr)\n"
                    "print('registered', s['tiles_registered'], 'tiles; block_rows', s.get('block_rows'))\n")
        # the harness: wall, CPU and the child's peak resident memory (wait4), one child per tree
        # cwd /tmp: 'python -c' puts the current directory first on sys.path, before PYTHONPATH's tree
        res = measure([sys.executable, "-c", code], label=tree, env={**os.environ, "PYTHONPATH": tree}, cwd="/tmp",
                      check=False)
        traced = [ln.split()[1] for ln in res.stderr.splitlines() if ln.startswith("TRACED_PEAK_B")]
        rows.append({"tree": tree, "args": extra if block is None else f"API block_pixels={block or 'n/a'}",
                     "rc": res.returncode, "seconds": round(res.wall_s, 1), "cpu_seconds": round(res.cpu_s, 1),
                     "peak_rss_gb": round(res.peak_rss_bytes / 1e9, 3),
                     # numpy/Python allocations during the stage alone (tracemalloc; API mode): no import baseline
                     "stage_traced_peak_gb": round(int(traced[-1]) / 1e9, 3) if traced else None,
                     "last_line": (res.stdout.strip().splitlines() or [res.stderr.strip()[-300:]])[-1]})
    append_record("register_memory", {"ppd": args.ppd, "shots": int(args.shots), "out": args.out}, {"runs": rows})
    print(json.dumps({"date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
                      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "ppd": args.ppd,
                      "shots": int(args.shots), "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
