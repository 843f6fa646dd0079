"""Benchmark of dense chip matching beside the bare OpenCV StereoSGBM floor (issue 31, 'Done when' 3).

One rendered stereo pair (MDIS-WAC, nadir and 25 deg north, 200 m/pixel, the truth Surface of seed 42,
Lambert photometry) is rectified per chip (:func:`mercury_dem.dense.rectify.rectify_chip`). On the same
rectified chips, interleaved repetitions time:

* ``floor``: the bare OpenCV StereoSGBM -- the 8-bit stretch and ``StereoSGBM.compute`` with the same
  parameters (its built-in left--right check and speckle filter included);
* ``window_fit``: :func:`mercury_dem.dense.disparity.dense_disparity` with ``refine_method="window_fit"`` (SGBM,
  then the compiled per-pixel least-squares window fit in two passes, scores, precision, holes);
* ``dense_lk``: the same with ``refine_method="dense_lk"`` (the whole-image Lucas--Kanade, ``refine_iterations``
  as given, default 2);
* ``triangulate``: :func:`mercury_dem.dense.triangulate.triangulate_chip` of ``dense_lk``'s disparities.

Wall (``perf_counter``) and CPU (``process_time``) seconds (``harness.measure_here``, rounds by
``harness.interleave``), medians over the repetitions, and the
ratios to the floor; points per second of matching + triangulation. OpenCV's threads as configured
(``cv2.getNumThreads()``).

Run (heavy; take the lock):
    flock /tmp/mercury_bench.lock nice -n 10 .venv/bin/python workflows/benchmarks/bench_dense.py [--reps 7] [--threads 1]
        [--margin-m 3000] [--iterations 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
from typing import Any

import cv2
import numpy as np
from harness import append_record, interleave, measure_here

from mercury_dem.dense.disparity import MatcherSettings, dense_disparity, sgbm_disparity, to_8bit
from mercury_dem.dense.rectify import Chip, rectify_chip
from mercury_dem.dense.triangulate import triangulate_chip
from mercury_dem.geometry.body import MERCURY, latlon_to_unit, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.match.pretransform import ImageGeometry


def rendered_pair(samples: int, gsd_m: float = 200.0) -> tuple[Any, list[np.ndarray], list[ImageGeometry]]:
    """The nadir / 25-deg-north pair at ``samples``^2 (sun 45 deg from the east, Lambert photometry)."""
    from mercury_dem.synth.render import RenderSettings, render_image
    from mercury_dem.synth.terrain import Surface, SurfaceParams

    surface = Surface(SurfaceParams(seed=42))
    lat, lon = 5.0, 3.0
    up = latlon_to_unit(lat, lon)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    centre = latlon_to_xyz(lat, lon, 0.0, MERCURY.datum_radius_m)
    sun = centre + 5.8e10 * (np.cos(np.radians(45)) * up + np.sin(np.radians(45)) * east)
    cam = mdis_wac(samples)
    alt = gsd_m / cam.ifov_rad
    rng = np.random.default_rng(3)
    images, geom = [], []
    for tilt in (0.0, 25.0):
        c = centre + alt * (np.cos(np.radians(tilt)) * up + np.sin(np.radians(tilt)) * north)
        r = look_at_rotation(c, centre, east)
        images.append(render_image(surface, cam, c, r, sun, rng, RenderSettings(lambert_weight=1.0)).astype(np.float32))
        geom.append(ImageGeometry.of(cam, c, r, sun, MERCURY.datum_radius_m))
    return surface, images, geom


def timed(fn: Any, label: str, keep: dict[str, Any] | None = None) -> Any:
    """``fn`` as one of ``harness.interleave``'s runs: timed in this process (``harness.measure_here``: wall and
    CPU, ``process_time``); its result goes to ``keep[label]`` (the last round's), not into the measurement.
    """
    def once() -> Any:
        m = measure_here(fn, label=label)
        if keep is not None:
            keep[label] = m.value
        m.value = None
        return m
    return once


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--margin-m", type=float, default=800.0, help="height margin of the search range, metres")
    ap.add_argument("--threads", type=int, default=0,
                    help="OpenCV threads (cv2.setNumThreads; 0: OpenCV's default). On a loaded machine the floor's "
                         "CPU time varies ~2x with how its threads are scheduled; 1 is the quieter control")
    ap.add_argument("--iterations", type=int, default=2, help="refine_iterations of dense_lk")
    args = ap.parse_args(argv)
    if args.threads > 0:
        cv2.setNumThreads(args.threads)
    print(f"# bench_dense: {platform.node()}, {platform.processor() or platform.machine()}, "
          f"OpenCV {cv2.__version__} threads {cv2.getNumThreads()}, numpy {np.__version__}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    settings = MatcherSettings(min_score=0.8, max_sigma_px=0.3, refine_method="window_fit")
    lk = dataclasses.replace(settings, refine_method="dense_lk", refine_iterations=args.iterations)
    print("| chip (collar 16) | disparities | SGM memory | floor wall / CPU s | window_fit wall / CPU s | ratio wall / CPU "
          "| dense_lk wall / CPU s | ratio wall / CPU | triangulate s | points | points/s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        surface, (img_l, img_r), (gl, gr) = rendered_pair(n)
        chip = Chip(16, 16, n - 32, n - 32, 16)
        rect = rectify_chip(img_l, img_r, gl, gr, chip, surface_height=lambda a, b: surface.height(a, b, 1000.0),
                            height_margin_m=args.margin_m)
        both = rect.left_valid & rect.right_valid

        def floor() -> Any:
            l8, r8 = to_8bit(rect.left, rect.right, both)
            return sgbm_disparity(l8, r8, rect.disparity_min_px, rect.disparity_max_px, settings)

        def ours(s: MatcherSettings = settings) -> Any:
            return dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid,
                                   rect.disparity_min_px, rect.disparity_max_px, s)

        last: dict[str, Any] = {"lk": ours(lk)}

        def tri() -> Any:
            dm = last["lk"]  # the disparities of this round's dense_lk
            return triangulate_chip(rect, gl, gr, dm.disparity, dm.sigma_px, dm.score)

        res = interleave({"floor": timed(floor, "floor"), "window_fit": timed(ours, "window_fit"),
                          "lk": timed(lambda: ours(lk), "lk", last), "tri": timed(tri, "tri", last)}, args.reps)
        pts = last["tri"]
        med = {k: np.median(np.array([(m.wall_s, m.cpu_s) for m in ms]), axis=0) for k, ms in res.items()}
        f, o, q, t = med["floor"], med["window_fit"], med["lk"], med["tri"]
        print(f"| {n - 32}^2 ({n}^2) | {rect.disparity_count} | {rect.sgm_memory_bytes / 2**20:.1f} MiB "
              f"| {f[0]:.4f} / {f[1]:.4f} | {o[0]:.4f} / {o[1]:.4f} | {o[0] / f[0]:.1f} / {o[1] / f[1]:.1f} "
              f"| {q[0]:.4f} / {q[1]:.4f} | {q[0] / f[0]:.1f} / {q[1] / f[1]:.1f} | {t[0]:.4f} | {len(pts)} "
              f"| {len(pts) / (q[0] + t[0]):.0f} |")
        append_record("dense_refine", {"chip": n, "disparities": rect.disparity_count, "reps": args.reps,
                                       "threads": cv2.getNumThreads(), "iterations": args.iterations,
                                       "margin_m": args.margin_m},
                      {k: {"wall_s": float(v[0]), "cpu_s": float(v[1])} for k, v in med.items()}
                      | {"ratio_window_fit": [float(o[0] / f[0]), float(o[1] / f[1])],
                         "ratio_dense_lk": [float(q[0] / f[0]), float(q[1] / f[1])], "points": len(pts),
                         "load_average": list(os.getloadavg())})


if __name__ == "__main__":
    main()
