"""Cold ``mercury-dem grid`` of 10^6 points against ``gdal_grid``: each a fresh process, timed from outside.

    python workflows/benchmarks/bench_grid_cli_cold.py [--points 1000000] [--repeats 3] [--tree DIR ...]

What a user sees at the command line: ``mercury-dem grid points.npy --out DIR`` (a new
interpreter: Python start-up, imports, numba's compiled-kernel cache load, the gridding,
the ``dem.zarr`` write; ``--no-coverage``) against ``gdal_grid -a invdistnn`` (11 nearest,
the same search radius) on the same cloud as FlatGeobuf and as CSV. 1000 x 1000 grid over
20 deg x 20 deg, as ``bench_grid.py``; the runs are interleaved (``harness.interleave``) so load bursts hit
both.
Also timed: ``mercury-dem --help`` and the bare import of the gridding stage, cold.
``--tree DIR`` (repeatable) runs ``mercury-dem`` from each source tree (first on ``PYTHONPATH``),
interleaved with the others and gdal_grid: before/after side by side in the same minutes.
Wall and CPU seconds (user + system of the child process, including any process it forked and
waited for, e.g. the ``dem.zarr`` writer of mercury_dem.pipeline.store_writer) are both recorded, and each
command's peak resident size (``harness.measure``). Prints the record and appends it to
``records/grid_cli_cold.jsonl`` (``harness.append_record``). Run under ``flock /tmp/mercury_bench.lock``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from harness import Measurement, append_record, interleave, measure
from harness.scenarios import gdal_grid, write_point_inputs  # the same cloud and gdal_grid call as bench_grid.py


def command(cmd: list[str], env: dict[str, str], label: str) -> Callable[[], Measurement]:
    """One of :func:`harness.interleave`'s runs: ``cmd`` measured by ``harness.measure`` (wall, CPU of the child
    and its children, peak resident size)."""
    # cwd /tmp: 'python -m'/'-c' put the current directory first on sys.path, before PYTHONPATH's tree
    return lambda: measure(cmd, env=env, cwd="/tmp", label=label)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, default=1_000_000)
    p.add_argument("--size", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--tree", action="append", default=[],
                   help="source tree to time (repeatable; default: as installed); DIR,VAR=VALUE also sets VAR "
                        "for it (e.g. /src,MERCURY_DEM_GRID_WRITER=inprocess)")
    args = p.parse_args()
    size, span = args.size, 20.0
    ppd = size / span
    extent = (0.0, span, -span / 2, span / 2)
    exe = [sys.executable, "-m", "mercury_dem.cli"]
    env = dict(os.environ, MERCURY_DEM_PROGRESS="none")
    work = Path(tempfile.mkdtemp(prefix="bench_grid_cold_"))
    try:
        _, npy, _, vrt, fgb = write_point_inputs(work, args.points, span)
        cfg = work / "grid.yaml"
        cfg.write_text(f"dem:\n  pixels_per_degree: {ppd}\n  lat_min: {extent[2]}\n  lat_max: {extent[3]}\n"
                       f"  lon_min: {extent[0]}\n  lon_max: {extent[1]}\n  chunk_size: 512\n  max_distance_m: 10000000.0\n"
                       "  query_threads: 2\n")
        radius_deg = 1.4142 / ppd
        algo = f"invdistnn:power=2.0:radius={radius_deg:.8f}:max_points=11:min_points=1:nodata=nan"
        grid_cmd = exe + ["grid", str(npy), "--out", str(work / "ours"), "--config", str(cfg), "--no-coverage",
                          "--overwrite"]
        trees = args.tree or [None]
        envs = {t: (env if t is None else dict(env, PYTHONPATH=t.split(",")[0],
                                                 **dict(kv.split("=", 1) for kv in t.split(",")[1:])))
                for t in trees}

        def name(what: str, t: str | None) -> str:
            return what if t is None else f"{what} [{t}]"

        for t in trees:
            measure(grid_cmd, env=envs[t], cwd="/tmp")  # numba's on-disk cache filled (a first run compiles; not timed)
        # harness.interleave: one round is each tree's grid, gdal_grid FlatGeobuf and CSV, each tree's --help and import
        runs = {name("mercury-dem grid (cold process)", t): command(grid_cmd, envs[t], name("grid", t)) for t in trees}
        for k, src in (("gdal_grid invdistnn FlatGeobuf", fgb), ("gdal_grid invdistnn CSV", vrt)):
            runs[k] = lambda src=src: gdal_grid(src, algo, size, extent, work)[0]
        for t in trees:
            runs[name("mercury-dem --help", t)] = command(exe + ["--help"], envs[t], name("help", t))
            runs[name("import mercury_dem.pipeline.dem_stage (cold)", t)] = command(
                [sys.executable, "-c", "import mercury_dem.pipeline.dem_stage"], envs[t], name("import", t))
        ms = interleave(runs, args.repeats)
        times = {k: [m.wall_s for m in v] for k, v in ms.items()}
        cpu = {k: [m.cpu_s for m in v] for k, v in ms.items()}
        med = {k: statistics.median(v) for k, v in times.items()}
        record: dict[str, object] = {
            "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
            "load_average": os.getloadavg(),
            "points": args.points, "grid": [size, size], "repeats": args.repeats,
            "median_s": {k: round(v, 3) for k, v in med.items()},
            "all_s": {k: [round(x, 3) for x in v] for k, v in times.items()},
            "cpu_median_s": {k: round(statistics.median(v), 3) for k, v in cpu.items()},
            "cpu_all_s": {k: [round(x, 3) for x in v] for k, v in cpu.items()},
            "peak_rss_median_bytes": {k: int(statistics.median(m.peak_rss_bytes for m in v)) for k, v in ms.items()},
        }
        for t in trees:
            ours = med[name("mercury-dem grid (cold process)", t)]
            record[name("gdal_fgb_over_ours", t)] = round(med["gdal_grid invdistnn FlatGeobuf"] / ours, 2)
            record[name("gdal_csv_over_ours", t)] = round(med["gdal_grid invdistnn CSV"] / ours, 2)
            ours_cpu = statistics.median(cpu[name("mercury-dem grid (cold process)", t)])
            record[name("cpu_gdal_fgb_over_ours", t)] = round(
                statistics.median(cpu["gdal_grid invdistnn FlatGeobuf"]) / ours_cpu, 2)
            # per repetition (adjacent runs, the same load): gdal_grid FlatGeobuf wall / ours wall
            record[name("per_repeat_gdal_fgb_over_ours", t)] = [
                round(g / o, 2) for g, o in zip(times["gdal_grid invdistnn FlatGeobuf"],
                                                 times[name("mercury-dem grid (cold process)", t)])]
        append_record("grid_cli_cold", {"points": args.points, "size": size, "repeats": args.repeats,
                                         "trees": args.tree}, record)
        print(json.dumps(record, indent=2))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
