"""The gridding kernels alone, warm: bucket index build, median11 and Shepard over a map, in this process.

    PYTHONPATH=TREE python workflows/benchmarks/bench_dem_kernels.py [--points 1000000] [--size 1000] [--repeats 5]

Times (wall, seconds; median and minimum of ``--repeats`` after one untimed warm-up call that loads or
compiles numba's cache) of ``build_buckets`` on ``--points`` points over 20 x 20 degrees (the cloud of
``bench_grid.py``: ``write_point_inputs``) and of ``median11_search`` / ``shepard_search`` over a
``--size``-square grid of it (``grid=True``, all numba threads), plus a checksum of each result so two
source trees can be compared (the same bits give the same checksum). Run it once per tree, interleaved,
under ``flock /tmp/mercury_bench.lock`` (session 12 compared the split ``dem/`` with the one-module one).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics

import numpy as np
from harness import interleave, measure_here


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, default=1_000_000)
    p.add_argument("--size", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    from mercury_dem.dem import buckets as B
    from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz

    rng = np.random.default_rng(11)
    n, span = args.points, 20.0
    lat, lon = rng.uniform(-span / 2, span / 2, n), rng.uniform(0.0, span, n)
    pts = latlon_to_xyz(lat, lon, 1000.0 * np.sin(np.radians(lat) * 7) * np.cos(np.radians(lon) * 5)
                        + rng.normal(0, 30.0, n), datum_radius_m=DATUM_RADIUS_M)
    ppd = args.size / span
    rows = span / 2 - (np.arange(args.size) + 0.5) / ppd
    cols = (np.arange(args.size) + 0.5) / ppd
    search_r = 1.4142 * 2 * np.pi * DATUM_RADIUS_M / 360.0 / ppd
    jobs = {
        "build_buckets": lambda: B.build_buckets(pts, DATUM_RADIUS_M),
    }
    b = B.build_buckets(pts, DATUM_RADIUS_M)
    jobs["median11_search"] = lambda: B.median11_search(b, rows, cols, 11, 1.0, search_r, 0.05, grid=True)
    jobs["shepard_search"] = lambda: B.shepard_search(b, rows, cols, 32, 5, search_r, 0.05, grid=True)
    out: dict[str, object] = {"points": n, "grid": [args.size, args.size], "repeats": args.repeats}
    for job in jobs.values():
        job()  # warm-up: numba's cache loaded (or the kernels compiled)
    # harness.interleave of warm in-process calls (harness.measure_here): one round is each kernel once
    ms = interleave({name: (lambda job=job, name=name: measure_here(job, label=name)) for name, job in jobs.items()},
                    args.repeats)
    for name, runs in ms.items():
        times = [m.wall_s for m in runs]
        res = runs[-1].value
        arr = res.xyz if name == "build_buckets" else res["radius"]
        out[name] = {"median_s": round(statistics.median(times), 4), "min_s": round(min(times), 4),
                     "cpu_median_s": round(statistics.median(m.cpu_s for m in runs), 4),
                     "checksum": hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()[:16]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
