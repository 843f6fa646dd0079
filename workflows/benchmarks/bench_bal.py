"""BAL benchmark: our Schur LM vs scipy.optimize.least_squares vs Ceres (through pycolmap), in one run.

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_bal.py ../shared/data/bal/problem-49-7776-pre.txt

Prints, for each solver, the seconds to reach the goal cost (default 1.3409e+04,
scipy's final cost in the SciPy cookbook), the final cost and the ratios. pycolmap
is a benchmark-only dependency (``make bench-deps``: the ``anchors`` extra); it is skipped when absent.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np
from harness import measure
from harness.scenarios import bal_file

from mercury_dem.adjust.bal import BalProblem, adjust_bal
from mercury_dem.adjust.solver import SolverOptions
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.io.bal import read_bal


def ours(problem: BalProblem, target: float, iterations: int) -> dict:
    _, res = adjust_bal(problem, SolverOptions(max_iterations=iterations, function_tolerance=0.0))
    reach = next((e["elapsed"] for e in res.log if e["cost"] <= target), float("nan"))
    it = next((e["iteration"] for e in res.log if e["cost"] <= target), None)
    return {"solver": "ours (Schur LM)", "seconds_to_target": reach, "iterations_to_target": it,
            "final_cost": res.final_cost, "iterations": res.iterations, "total_seconds": res.seconds,
            "initial_cost": res.initial_cost, "linear": res.linear_method}


def ours_fresh_process(path: str) -> dict:
    """The CLI in a fresh process (numba cache load included in solver seconds)."""
    m = measure([sys.executable, "-m", "mercury_dem.cli", "adjust-bal", path, "--json", "--max-iterations", "5"])
    rec = json.loads(m.stdout)
    return {"solver": "ours, fresh process, 5 iterations (adjust-bal)", "final_cost": rec["final_cost"],
            "solver_seconds": rec["solver_seconds"], "read_seconds": rec["read_seconds"],
            "process_wall_seconds": round(m.wall_s, 3), "process_cpu_seconds": round(m.cpu_s, 3),
            "process_peak_rss_bytes": m.peak_rss_bytes}


def _residuals_numpy(x: np.ndarray, p: BalProblem) -> np.ndarray:
    nc = p.n_cameras
    cams = x[: nc * 9].reshape(nc, 9)
    pts = x[nc * 9 :].reshape(-1, 3)
    c = cams[p.camera_index]
    big = np.einsum("nij,nj->ni", rotation_from_angles(c[:, :3]), pts[p.point_index]) + c[:, 3:6]
    q = -big[:, :2] / big[:, 2:3]
    n2 = np.sum(q * q, axis=1)
    d = 1 + c[:, 7] * n2 + c[:, 8] * n2 * n2
    return ((c[:, 6] * d)[:, None] * q - p.observations).ravel()


def scipy_ls(problem: BalProblem, target: float) -> dict:
    """scipy least_squares as in the SciPy cookbook: trf, jac_sparsity, x_scale='jac', ftol=1e-4."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    p = problem
    m = 2 * p.n_observations
    n = 9 * p.n_cameras + 3 * p.n_points
    a = lil_matrix((m, n), dtype=int)
    i = np.arange(p.n_observations)
    for s in range(9):
        a[2 * i, p.camera_index * 9 + s] = 1
        a[2 * i + 1, p.camera_index * 9 + s] = 1
    for s in range(3):
        a[2 * i, p.n_cameras * 9 + p.point_index * 3 + s] = 1
        a[2 * i + 1, p.n_cameras * 9 + p.point_index * 3 + s] = 1
    x0 = np.concatenate([p.cameras.ravel(), p.points.ravel()])
    t0 = time.perf_counter()
    res = least_squares(_residuals_numpy, x0, jac_sparsity=a, x_scale="jac", ftol=1e-4, method="trf", args=(p,))
    sec = time.perf_counter() - t0
    return {"solver": "scipy least_squares (trf)", "final_cost": float(res.cost), "total_seconds": sec,
            "nfev": int(res.nfev), "seconds_to_target": sec if res.cost <= target * (1 + 1e-9) else float("nan")}


def ceres_pycolmap(problem: BalProblem, iterations: int, threads: int = 2) -> dict:
    """Ceres SPARSE_SCHUR through pycolmap. BAL cameras look down -Z: flipping Y and Z of the camera
    frame (and the sign of the observed y) gives COLMAP's RADIAL camera with the same residuals."""
    import pycolmap

    p = problem
    rec = pycolmap.Reconstruction()
    flip = np.diag([1.0, -1.0, -1.0])
    rot = rotation_from_angles(p.cameras[:, :3])
    by_cam = [np.flatnonzero(p.camera_index == k) for k in range(p.n_cameras)]
    for k in range(p.n_cameras):
        f, k1, k2 = p.cameras[k, 6:9]
        cam = pycolmap.Camera(model="RADIAL", width=2000, height=2000, params=[f, 0.0, 0.0, k1, k2], camera_id=k + 1)
        rec.add_camera_with_trivial_rig(cam)
        obs = p.observations[by_cam[k]] * [1.0, -1.0]
        img = pycolmap.Image(name=f"cam{k}", keypoints=obs, camera_id=k + 1, image_id=k + 1)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(flip @ rot[k]), flip @ p.cameras[k, 3:6])
        rec.add_image_with_trivial_frame(img, pose)
    obs_index = np.empty(p.n_observations, np.int64)
    for k in range(p.n_cameras):
        obs_index[by_cam[k]] = np.arange(len(by_cam[k]))
    order = np.argsort(p.point_index, kind="stable")
    splits = np.cumsum(np.bincount(p.point_index, minlength=p.n_points))[:-1]
    for j, ms in enumerate(np.split(order, splits)):
        track = pycolmap.Track()
        for mm in ms:
            track.add_element(int(p.camera_index[mm] + 1), int(obs_index[mm]))
        rec.add_point3D(p.points[j], track)
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_principal_point = False
    opts.refine_focal_length = True
    opts.refine_extra_params = True
    ceres = opts.ceres
    ceres.auto_select_solver_type = False
    so = ceres.solver_options
    so.linear_solver_type = type(so.linear_solver_type).SPARSE_SCHUR
    so.max_num_iterations = iterations
    so.num_threads = threads
    so.function_tolerance = 0.0
    so.gradient_tolerance = 0.0
    so.parameter_tolerance = 0.0
    config = pycolmap.BundleAdjustmentConfig()
    for k in range(p.n_cameras):
        config.add_image(k + 1)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    t0 = time.perf_counter()
    summary = adjuster.solve()
    sec = time.perf_counter() - t0
    cs = summary.ceres_summary if hasattr(summary, "ceres_summary") else summary
    return {"solver": f"Ceres SPARSE_SCHUR via pycolmap ({threads} threads, {iterations} iterations)",
            "total_seconds": sec, "final_cost": float(getattr(cs, "final_cost", np.nan)),
            "initial_cost": float(getattr(cs, "initial_cost", np.nan)),
            "residual_blocks": int(getattr(cs, "num_residual_blocks", -1))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", help="a BAL file, or the name of one under ../shared/data/bal")
    ap.add_argument("--target", type=float, default=1.3409e04)
    ap.add_argument("--skip-scipy", action="store_true")
    args = ap.parse_args()
    t = time.perf_counter()
    args.file = str(bal_file(args.file))
    problem = read_bal(args.file)
    print(f"# {args.file}: {problem.n_cameras} cameras, {problem.n_points} points, {problem.n_observations} obs; "
          f"read {time.perf_counter() - t:.2f} s; {platform.processor() or platform.machine()}, {os.cpu_count()} cpus")
    rows = []
    ours(problem, args.target, 3)  # warm-up (numba cache load, page faults)
    rows.append(ours(problem, args.target, 20))
    rows.append(ours_fresh_process(args.file))
    try:
        rows.append(ceres_pycolmap(problem, 5))
        rows.append(ceres_pycolmap(problem, 20))
    except ImportError:
        print("# pycolmap not installed: Ceres skipped")
    if not args.skip_scipy:
        rows.append(scipy_ls(problem, args.target))
    for r in rows:
        print(json.dumps(r))
    ref = rows[0]["seconds_to_target"]
    for r in rows[1:]:
        sec = r.get("seconds_to_target", r.get("total_seconds", r.get("solver_seconds")))
        print(f"{r['solver']}: {sec:.3f} s, final cost {r['final_cost']:.6e}; ratio to ours-to-target {sec / ref:.1f}x")
    print(f"ours: cost <= {args.target:g} after {rows[0]['iterations_to_target']} iterations in {ref:.3f} s "
          f"(final {rows[0]['final_cost']:.6e} after {rows[0]['iterations']} in {rows[0]['total_seconds']:.2f} s)")


if __name__ == "__main__":
    main()
