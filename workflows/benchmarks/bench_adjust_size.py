"""Size benchmark of the planetary bundle adjustment on synthetic networks (issue #5, section 6).

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_adjust_size.py [--sizes 1e5 1e6 5e6] [--scipy]

Each size runs in its own child process (``harness.measure``: the peak resident memory is that size's
alone, VmHWM reset when the call starts): generate the network (timed apart),
adjust it with the default configuration (450 urad pointing sigma), and print one
JSON line: iterations, seconds per iteration, total, linear solver, peak RSS, RMS,
outliers/good rejected; each line is also appended to ``records/adjust_size.jsonl``. ``--scipy`` also runs ``scipy.optimize.least_squares``
(trf, jac_sparsity, x_scale='jac') on the smallest size with the same cost function
(no robust loss, no rejection, on a network without outliers) next to ours, for the ratio.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from harness import append_record, measure
from harness.scenarios import least_squares_anchor


def run_one(n: int, seed: int) -> dict:
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.validate.synthetic_network import make_synthetic_network, pointing_errors

    t = time.perf_counter()
    net = make_synthetic_network(n, rng=np.random.default_rng(seed), min_views=3)
    gen = time.perf_counter() - t
    p = net.problem
    cfg = AdjustConfig()
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
    }


def run_scipy(n: int, seed: int) -> dict:
    """Ours and scipy least_squares on the same clean network and cost (no robust loss, no rejection).

    The scipy side is :func:`harness.scenarios.least_squares_anchor` (the one anchor both benchmarks use)."""
    from mercury_dem.adjust.bundle import bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.validate.synthetic_network import make_synthetic_network

    net = make_synthetic_network(n, rng=np.random.default_rng(seed), min_views=3, outlier_fraction=0.0)
    p = net.problem
    cfg = AdjustConfig(robust_loss="none", reject_outliers=False)
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
    ap.add_argument("--headline", action="store_true",
                    help="record the largest size as the headline row of docs/benchmarks.md (then run "
                         "`python -m harness headline`)")
    args = ap.parse_args()
    largest: dict | None = None
    jobs = [(run_one, int(s)) for s in args.sizes]
    if args.scipy:
        jobs.append((run_scipy, int(min(args.sizes))))
    for fn, n in jobs:
        try:
            m = measure(fn, n, args.seed, label=f"{fn.__name__} {n}")
        except RuntimeError as exc:  # the child's traceback, as the subprocess's stderr was printed before
            print(str(exc)[-2000:], flush=True)
            continue
        out = {**m.value, "peak_rss_gb": round(m.peak_rss_bytes / 1024**3, 2), "cpu_seconds": round(m.cpu_s, 2)}
        params = {"function": fn.__name__, "measures": n, "seed": args.seed}
        if args.headline and fn is run_one and n == max(int(s) for s in args.sizes):
            largest = out
        else:
            append_record("adjust_size", params, out)
        print(json.dumps(out), flush=True)
    if largest is not None:
        append_record("adjust_size", {"function": "run_one", "measures": largest["measures"], "seed": args.seed},
                      largest, headline=headline_row(largest, args.sizes))


def headline_row(r: dict, sizes: list[float]) -> dict[str, str]:
    """The headline of docs/benchmarks.md for this benchmark, from the largest size's figures."""
    ok = r["adjust_seconds"] <= 600 and r["peak_rss_gb"] <= 8
    return {"area": "bundle adjustment, size (issue 5)",
            "command": f"`workflows/benchmarks/bench_adjust_size.py --sizes {' '.join(f'{s:g}' for s in sizes)} --headline`",
            "text": (f"{r['measures']:,} measures adjusted in {r['adjust_seconds']:.0f} s ({r['iterations']} iterations, "
                     f"median {r['seconds_per_iteration_median']} s each) at {r['peak_rss_gb']} GiB peak; "
                     f"RMS {r['rms_px']} px, outliers rejected {100 * r['outliers_rejected']:.1f} %"),
            "goal": "≤ 10 min, ≤ 8 GB", "status": "met" if ok else "missed"}


if __name__ == "__main__":
    main()
