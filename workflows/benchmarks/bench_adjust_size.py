"""Size benchmark of the planetary bundle adjustment on synthetic networks (issue #5, section 6).

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_adjust_size.py [--sizes 1e5 1e6 5e6] [--scipy]

Each size runs in its own subprocess (so the peak resident memory, from
``resource.getrusage``, is that size's alone): generate the network (timed apart),
adjust it with the default configuration (450 urad pointing sigma), and print one
JSON line: iterations, seconds per iteration, total, linear solver, peak RSS, RMS,
outliers/good rejected. ``--scipy`` also runs ``scipy.optimize.least_squares``
(trf, jac_sparsity, x_scale='jac') on the smallest size with the same cost function
(no robust loss, no rejection, on a network without outliers) next to ours, for the ratio.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np


def run_one(n: int, seed: int) -> dict:
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.validate.synthetic_network import make_synthetic_network, pointing_errors

    t = time.perf_counter()
    net = make_synthetic_network(n, rng=np.random.default_rng(seed), min_views=3)
    gen = time.perf_counter() - t
    p = net.problem
    cfg = AdjustConfig(pointing_sigma_deg=float(np.degrees(450e-6)))
    res = bundle_adjust(p, cfg)
    raw, _, _ = pointing_errors(res.rotations, net.true_rotations)
    ifov = np.array([p.cameras[k].ifov_rad for k in p.image_camera])
    sel = res.accepted_per_image >= 30
    bore = np.linalg.norm(raw[:, :2], axis=1) / ifov
    its = [e["seconds"] for e in res.log]
    ok = ~res.underdetermined_points
    perr = np.linalg.norm(res.points - net.true_points, axis=1)[ok]
    return {
        "measures": p.n_measures, "images": p.n_images, "points": p.n_points, "generate_seconds": round(gen, 2),
        "iterations": res.iterations, "seconds_per_iteration_median": round(float(np.median(its)), 3),
        "seconds_per_iteration_max": round(float(np.max(its)), 3), "adjust_seconds": round(res.seconds, 2),
        "linear_method": res.linear_method, "pcg_iterations": [e["linear_iterations"] for e in res.log],
        "converged": res.converged, "reason": res.reason, "rms_px": round(res.rms_px, 4), "sigma0": round(res.sigma0, 4),
        "outliers_rejected": round(float(res.rejected[net.outlier].mean()), 4),
        "good_rejected": round(float(res.rejected[~net.outlier].mean()), 4),
        "boresight_rms_ifov_ge30": round(float(np.sqrt(np.mean(bore[sel] ** 2))), 3),
        "boresight_rms_ifov_all": round(float(np.sqrt(np.mean(bore**2))), 3),
        "point_error_m_median_p90": [round(float(np.median(perr)), 1), round(float(np.percentile(perr, 90)), 1)],
        "peak_rss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2, 2),
    }


def run_scipy(n: int, seed: int) -> dict:
    """Ours and scipy least_squares on the same clean network and cost (no robust loss, no rejection).

    The scipy side is :func:`bench_blocked_anchor.least_squares_anchor` (the one anchor both benchmarks use)."""
    from pathlib import Path

    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.validate.synthetic_network import make_synthetic_network

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_blocked_anchor import least_squares_anchor

    net = make_synthetic_network(n, rng=np.random.default_rng(seed), min_views=3, outlier_fraction=0.0)
    p = net.problem
    cfg = AdjustConfig(pointing_sigma_deg=float(np.degrees(450e-6)), robust_loss="none", reject_outliers=False)
    t = time.perf_counter()
    ours = bundle_adjust(p, cfg)
    ours_s = time.perf_counter() - t
    ls = least_squares_anchor(p, cfg)
    return {"measures": p.n_measures, "ours_seconds": round(ours_s, 2), "ours_cost": ours.log[-1]["cost"],
            "ours_iterations": ours.iterations, "scipy_seconds": round(ls["seconds"], 2), "scipy_cost": ls["cost"],
            "scipy_nfev": ls["nfev"], "ratio": round(ls["seconds"] / ours_s, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e5, 1e6, 5e6])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scipy", action="store_true")
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--one-scipy", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(int(args.one), args.seed)))
        return
    if args.one_scipy:
        print(json.dumps(run_scipy(int(args.one_scipy), args.seed)))
        return
    jobs = [["--one", str(s)] for s in args.sizes]
    if args.scipy:
        jobs.append(["--one-scipy", str(min(args.sizes))])
    for job in jobs:
        out = subprocess.run([sys.executable, __file__, *job, "--seed", str(args.seed)], capture_output=True, text=True)
        print(out.stdout.strip() or out.stderr.strip()[-2000:], flush=True)


if __name__ == "__main__":
    main()
