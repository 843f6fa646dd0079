"""The scipy anchor of the blocked adjustment (issue #17 §4.5): the same stored network, side by side in one run.

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python -u workflows/benchmarks/bench_blocked_anchor.py \
        --measures 1e5 [--dir /tmp/anchor] [--seed 0]

``mercury-dem synth-network`` writes a network without gross outliers (``--outlier-fraction 0``: scipy has no
rejection); it is read whole into one :class:`~mercury_dem.adjust.problem.AdjustmentProblem`, then, in this
process, one after the other, on the same cost (no robust loss, no rejection, the 450 urad pointing prior and the
default radius prior): the blocked adjustment (:func:`~mercury_dem.adjust.blocked_bundle.blocked_bundle_adjust`,
float32 storage, blocks of 25,000 points), the in-memory adjuster (``bundle_adjust``) and
``scipy.optimize.least_squares`` (trf, finite-difference Jacobian with its sparsity, LSMR, x_scale='jac',
ftol=1e-4: :func:`least_squares_anchor`). Prints one JSON line: seconds, final cost and iterations of each, the
ratios, and the largest pointing difference from ours in pixels.

Ceres: ``pip download pyceres pycolmap`` succeeds from this machine's index (pyceres 2.6, pycolmap 4.2.1), but
neither is in the project's environment, and pycolmap's camera models have no MDIS distortion (a Ceres cost for our
framing camera would be a Python callback per residual through pyceres); not run here.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np
from harness import peak_rss_bytes
from harness.scenarios import clean_store, least_squares_anchor, problem_from_store


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--measures", type=float, default=1e5)
    ap.add_argument("--dir", default="/tmp/anchor")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from threadpoolctl import threadpool_limits

    from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig

    p = problem_from_store(clean_store(args.dir, args.measures, args.seed))
    cfg = AdjustConfig(robust_loss="none", reject_outliers=False)
    ifov = min(c.pixel_size_mm / c.focal_length_mm for c in p.cameras)
    out: dict[str, Any] = {"measures": p.n_measures, "images": p.n_images, "points": p.n_points}
    t = time.perf_counter()
    blk = blocked_bundle_adjust(p, cfg)
    out["blocked"] = {"seconds": round(time.perf_counter() - t, 2), "cost": blk.log[-1]["cost"],
                      "iterations": blk.iterations, "solver": blk.linear_method}
    t = time.perf_counter()
    mem = bundle_adjust(p, cfg)
    out["in_memory"] = {"seconds": round(time.perf_counter() - t, 2), "cost": mem.log[-1]["cost"],
                        "iterations": mem.iterations}
    with threadpool_limits(limits=1, user_api="blas"):  # scipy's LSMR on one core, like ours
        sc = least_squares_anchor(p, cfg)
    out["scipy"] = {"seconds": round(sc["seconds"], 2), "cost": sc["cost"], "nfev": sc["nfev"],
                    "pointing_vs_ours_px_max": float(np.abs(sc["omega"] - blk.pointing_corrections).max() / ifov)}
    out["ratio_scipy_to_blocked"] = round(sc["seconds"] / out["blocked"]["seconds"], 1)
    out["ratio_scipy_to_in_memory"] = round(sc["seconds"] / out["in_memory"]["seconds"], 1)
    out["peak_rss_gb"] = round(peak_rss_bytes() / 1024**3, 2)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
