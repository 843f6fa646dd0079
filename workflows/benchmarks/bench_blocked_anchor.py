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
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np


def least_squares_anchor(p: Any, cfg: Any) -> dict[str, Any]:
    """``scipy.optimize.least_squares`` on ``bundle_adjust``'s cost (no robust loss): seconds, cost, nfev, pointing."""
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    from mercury_dem.adjust.bundle import make_model
    from mercury_dem.adjust.framing import FramingState

    model = make_model(p, cfg)
    ni, npt, m = p.n_images, p.n_points, p.n_measures
    zeros = np.zeros((ni, 3))

    def fun(x: np.ndarray) -> np.ndarray:
        st = FramingState(x[: 3 * ni].reshape(ni, 3), zeros, x[3 * ni:].reshape(npt, 3))
        parts = [model.residuals(st).ravel(), model.camera_prior(st)[0].ravel()]
        pp = model.point_prior(st)
        if pp is not None:
            parts.append(pp[0].ravel())
        return np.concatenate(parts)

    rows, cols = [], []
    mi, mp = p.measure_image, p.measure_point
    for k in range(2):
        for s in range(3):
            rows += [2 * np.arange(m) + k, 2 * np.arange(m) + k]
            cols += [3 * mi + s, 3 * ni + 3 * mp + s]
    for s in range(3):
        for s2 in range(3):
            rows.append(2 * m + 3 * np.arange(ni) + s)
            cols.append(3 * np.arange(ni) + s2)
    pp0 = model.point_prior(model.initial_state())
    npp = 0 if pp0 is None else pp0[0].shape[1]
    for s in range(npp):
        for s2 in range(3):
            rows.append(2 * m + 3 * ni + npp * np.arange(npt) + s)
            cols.append(3 * ni + 3 * np.arange(npt) + s2)
    r, c = np.concatenate(rows), np.concatenate(cols)
    nres = 2 * m + 3 * ni + npp * npt
    sparsity = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(nres, 3 * ni + 3 * npt)).tocsr()
    sparsity.data[:] = 1
    x0 = np.concatenate([np.zeros(3 * ni), p.points.ravel()])
    t = time.perf_counter()
    ls = least_squares(fun, x0, jac_sparsity=sparsity, x_scale="jac", ftol=1e-4, method="trf")
    return {"seconds": time.perf_counter() - t, "cost": float(ls.cost), "nfev": int(ls.nfev),
            "omega": ls.x[: 3 * ni].reshape(ni, 3)}


def clean_store(directory: str | Path, measures: float, seed: int) -> Path:
    """A ``synth-network`` store without gross outliers under ``directory`` (made once, then reused)."""
    store = Path(directory) / f"clean_{measures:.0e}_s{seed}"
    if not store.exists():
        subprocess.run([sys.executable, "-m", "mercury_dem.cli", "synth-network", str(store), "--measures",
                        str(int(measures)), "--seed", str(seed), "--outlier-fraction", "0", "--progress",
                        "none"], check=True, capture_output=True)
    return store


def problem_from_store(store: Path) -> Any:
    """The whole stored network as one AdjustmentProblem (small stores only)."""
    from mercury_dem.adjust.problem import AdjustmentProblem
    from mercury_dem.io.synthetic_network_store import BlockedNetwork

    net = BlockedNetwork(store)
    im = net.images
    blocks = [net.read_block(b) for b in range(net.n_blocks)]
    cat = np.concatenate
    return AdjustmentProblem(
        cameras=tuple(im.cameras), image_camera=im.image_camera, positions=im.positions, rotations=im.rotations,
        points=cat([b.apriori_points for b in blocks]), measure_image=cat([b.measure_image for b in blocks]),
        measure_point=cat([b.measure_point + b.point_start for b in blocks]), measures=cat([b.measures for b in blocks]),
        measure_sigma=cat([b.sigma for b in blocks]), held_points=cat([b.held_points for b in blocks]))


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
    cfg = AdjustConfig(pointing_sigma_deg=float(np.degrees(450e-6)), robust_loss="none", reject_outliers=False)
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
    out["peak_rss_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2, 2)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
