"""The Ceres anchor of the blocked adjustment (issue #17 §4.5): the same stored network, ours and Ceres side by side.

Usage::

    make bench-deps     # pyceres + pycolmap (the `anchors` extra) into the project's venv
    flock /tmp/mercury_bench.lock .venv/bin/python -u workflows/benchmarks/bench_ceres_anchor.py \
        --measures 1e5 [--dir /tmp/anchor] [--seed 0] [--threads 2]

Ceres is reached through COLMAP's bundle adjuster (pycolmap 4.2: ``create_pose_prior_bundle_adjuster``, Ceres'
sparse Schur/Cholesky solvers chosen by COLMAP from the problem size, its analytic pinhole reprojection cost in C++):
a fair speed anchor needs compiled residuals, and pyceres alone only takes Python cost callbacks (one Python call
per residual block per evaluation, which would measure CPython, not Ceres).

What is solved, by both, on the same measures:

* pointing only: the camera centres are held (ours never moves them; COLMAP gets a position prior of
  ``--position-sigma-m`` = 1 mm on every image, so its centres move by < 1 mm), every rotation and every point free;
* no robust loss, no rejection (``synth-network --outlier-fraction 0``), no point radius prior;
* ours keeps a pointing prior, set to ``--pointing-sigma-urad`` = 174533 urad (10 deg) per axis: 0.2 % of a 450 urad correction's
  weight, so in effect none (COLMAP has no rotation prior);
* COLMAP's cameras are PINHOLE: the MDIS-NAC's distortion is removed from the measures first (each measure mapped
  exactly through the camera's own ``undistort``); the measure weights then differ from ours by the distortion's
  local scale (< 0.1 % for the NAC).

Both are scored against the network's truth (``pointing_errors`` of the adjusted rotations vs the true ones, in
pixels of each image's camera) and against each other; one JSON line: seconds (wall, and this process's CPU),
iterations, pointing error RMS, the largest rotation difference between the two solutions in pixels, the ratio.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import time
from typing import Any

import numpy as np
from harness import peak_rss_bytes
from harness.scenarios import clean_store, problem_from_store


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def ideal_pixels(p: Any) -> np.ndarray:
    """Each measure as an undistorted pinhole pixel of its camera (same focal length and boresight)."""
    out = np.empty_like(p.measures)
    for k, cam in enumerate(p.cameras):
        sel = p.image_camera[p.measure_image] == k
        if not sel.any():
            continue
        px = p.measures[sel]
        if cam.focal_plane_map:
            raise SystemExit(f"camera {cam.name}: a general focal-plane map is not converted here")
        ps = cam.pixel_size_mm
        x, y = cam.undistort((px[:, 0] - cam.boresight_sample) * ps, (px[:, 1] - cam.boresight_line) * ps)
        out[sel, 0] = cam.boresight_sample + x / ps
        out[sel, 1] = cam.boresight_line + y / ps
    return out


def colmap_adjust(p: Any, threads: int, position_sigma_m: float, max_iterations: int,
                  function_tolerance: float = 1e-6) -> dict[str, Any]:
    """COLMAP/Ceres pointing-only adjustment of ``p`` (centres held by a tight prior): rotations, seconds, summary."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    for k, cam in enumerate(p.cameras):
        f = cam.focal_length_mm / cam.pixel_size_mm
        c = pycolmap.Camera(camera_id=k + 1, model="PINHOLE", width=cam.samples, height=cam.lines,
                            params=[f, f, cam.boresight_sample + 0.5, cam.boresight_line + 0.5])
        rec.add_camera_with_trivial_rig(c)
    uv = ideal_pixels(p) + 0.5  # COLMAP's pixel centres are at +0.5 (ours 0-based centres)
    order = np.argsort(p.measure_image, kind="stable")
    starts = np.searchsorted(p.measure_image[order], np.arange(p.n_images + 1))
    point2d_index = np.empty(p.n_measures, np.int64)
    priors = []
    for i in range(p.n_images):
        ms = order[starts[i]:starts[i + 1]]
        point2d_index[ms] = np.arange(len(ms))
        r = p.rotations[i]
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(r), -r @ p.positions[i])
        im = pycolmap.Image(image_id=i + 1, name=str(i), camera_id=int(p.image_camera[i]) + 1,
                            keypoints=np.ascontiguousarray(uv[ms]))
        rec.add_image_with_trivial_frame(im, pose)
        priors.append(pycolmap.PosePrior(corr_data_id=rec.image(i + 1).data_id, position=p.positions[i],
                                         position_covariance=np.eye(3) * position_sigma_m**2,
                                         coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN))
    morder = np.argsort(p.measure_point, kind="stable")
    pstarts = np.searchsorted(p.measure_point[morder], np.arange(p.n_points + 1))
    for j in range(p.n_points):
        track = pycolmap.Track()
        for m in morder[pstarts[j]:pstarts[j + 1]]:
            track.add_element(int(p.measure_image[m]) + 1, int(point2d_index[m]))
        rec.add_point3D(p.points[j], track)
    opts = pycolmap.BundleAdjustmentOptions(refine_focal_length=False, refine_principal_point=False,
                                            refine_extra_params=False, refine_sensor_from_rig=False,
                                            print_summary=False)
    so = opts.ceres.solver_options
    so.num_threads = threads
    so.max_num_iterations = max_iterations
    so.function_tolerance = function_tolerance  # Ceres' own defaults for the other two
    so.gradient_tolerance = 1e-10
    so.parameter_tolerance = 1e-8
    config = pycolmap.BundleAdjustmentConfig()
    for i in range(p.n_images):
        config.add_image(i + 1)
    prior_opts = pycolmap.PosePriorBundleAdjustmentOptions()
    prior_opts.alignment_ransac.max_error = 0.0  # no similarity alignment to the priors: the frame is the body's
    t, c = time.perf_counter(), _cpu()
    adjuster = pycolmap.create_pose_prior_bundle_adjuster(opts, prior_opts, config, priors, rec)
    summary = adjuster.solve()
    seconds, cpu = time.perf_counter() - t, _cpu() - c
    rot = np.stack([rec.image(i + 1).cam_from_world().rotation.matrix() for i in range(p.n_images)])
    cen = np.stack([rec.image(i + 1).projection_center() for i in range(p.n_images)])
    return {"rotations": rot, "seconds": seconds, "cpu_seconds": cpu, "centre_shift_m_max":
            float(np.linalg.norm(cen - p.positions, axis=1).max()), "summary": summary}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--measures", type=float, default=1e5)
    ap.add_argument("--dir", default="/tmp/anchor")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2, help="threads for both (numba's and Ceres')")
    ap.add_argument("--pointing-sigma-urad", type=float, default=174_533.0, help="our pointing prior (10 deg)")
    ap.add_argument("--position-sigma-m", type=float, default=1e-3)
    ap.add_argument("--max-iterations", type=int, default=100)
    ap.add_argument("--function-tolerance", type=float, default=1e-6, help="Ceres' (its default 1e-6)")
    ap.add_argument("--sigma0-tolerance", type=float, action="append",
                    help="ours (adjust.sigma0_tolerance; default the project's); repeat to run ours at several")
    args = ap.parse_args()
    os.environ.setdefault("NUMBA_NUM_THREADS", str(args.threads))
    from threadpoolctl import threadpool_limits

    from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.io.synthetic_network_store import BlockedNetwork
    from mercury_dem.validate.synthetic_network import pointing_errors

    store = clean_store(args.dir, args.measures, args.seed)
    p = problem_from_store(store, args.pointing_sigma_urad)
    truth = BlockedNetwork(store).truth_images()
    ifov = np.array([p.cameras[k].ifov_rad for k in p.image_camera])

    def score(rot: np.ndarray) -> float:
        raw, _, _ = pointing_errors(rot, truth)
        return float(np.sqrt(np.mean((np.linalg.norm(raw[:, :2], axis=1) / ifov) ** 2)))

    base = AdjustConfig(robust_loss="none", reject_outliers=False,
                        radius_sigma_m=None, max_iterations=args.max_iterations)
    tolerances = args.sigma0_tolerance or [base.sigma0_tolerance]
    out: dict[str, Any] = {"measures": p.n_measures, "images": p.n_images, "points": p.n_points,
                           "threads": args.threads, "apriori_pointing_px_rms": score(p.rotations)}
    runs = []
    with threadpool_limits(limits=args.threads):
        for tol in tolerances:
            t, c = time.perf_counter(), _cpu()
            blk = blocked_bundle_adjust(p, dataclasses.replace(base, sigma0_tolerance=tol))
            runs.append((blk, {"sigma0_tolerance": tol, "seconds": round(time.perf_counter() - t, 2),
                               "cpu_seconds": round(_cpu() - c, 2), "iterations": blk.iterations,
                               "solver": blk.linear_method, "pointing_px_rms": score(blk.rotations)}))
        col = colmap_adjust(p, args.threads, args.position_sigma_m, args.max_iterations, args.function_tolerance)
    s = col["summary"].ceres_summary
    ceres = {"seconds": round(col["seconds"], 2), "cpu_seconds": round(col["cpu_seconds"], 2),
             "iterations": int(s.num_successful_steps + s.num_unsuccessful_steps),
             "termination": str(s.termination_type), "linear_solver": str(s.linear_solver_type_used),
             "pointing_px_rms": score(col["rotations"]), "centre_shift_m_max": col["centre_shift_m_max"]}
    for blk, ours in runs:
        diff, _, _ = pointing_errors(col["rotations"], blk.rotations)
        ours.update(ceres_vs_ours_px_max=float((np.linalg.norm(diff, axis=1) / ifov).max()),
                    ratio_ceres_to_ours_wall=round(col["seconds"] / ours["seconds"], 2),
                    ratio_ceres_to_ours_cpu=round(col["cpu_seconds"] / max(ours["cpu_seconds"], 1e-9), 2))
    out.update(ours=[r for _, r in runs], ceres=ceres,
               peak_rss_gb=round(peak_rss_bytes() / 1024**3, 2))
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
