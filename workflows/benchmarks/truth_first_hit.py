"""Is the matching study's truth right? The same matches scored against two truths (issue 21 §2).

``validate.matching.true_errors`` finds the ground point of a reference keypoint with
``geometry.pose.image_to_ground``: a fixed-point iteration against the true surface, which is
not guaranteed to converge, nor to give the *first* crossing, for oblique rays over steep relief
(session 6 saw 8 % of 65° rays unconverged on a rendered scene). Here every match of a mission is
also scored against the first crossing of the reference ray with the true surface, found by
marching down the ray in 60 m steps from 10 km above the datum to 10 km below and bisecting the
first step that goes under the surface. If the tail of the true errors came from the truth, the
per-class figures would differ between the two.

Every tile of the mission is matched as the pipeline matches it (``bench_match.tracks_study``:
the run's plan, tracks on) and grouped as ``bench_seeds.py`` groups pairs.

    PYTHONPATH=$PWD nice .venv/bin/python workflows/benchmarks/truth_first_hit.py MISSION RUN [--json OUT]

(RUN: a run of MISSION with its plan, e.g. ``bench_seeds.py``'s ``run_<seed>``.)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import bench_match  # beside this script (its directory is first on sys.path)
import bench_seeds
import numpy as np

from mercury_dem.geometry.body import DATUM_RADIUS_M, xyz_to_latlon
from mercury_dem.geometry.pose import image_to_ground, intersect_sphere, pixel_rays, project

GROUPS = ["all", "similar", "incidence", "azimuth", "convergence 0-10", "convergence 10-20", "convergence 20-30",
          "convergence 30-45", "convergence 45-+", "similar WAC-WAC", "similar NAC-WAC", "similar NAC-NAC"]


def first_hit(camera: Any, position: Any, rotation: Any, pixels: np.ndarray, height: Any,
              top_m: float = 10_000.0, bottom_m: float = -10_000.0, step_m: float = 60.0) -> np.ndarray:
    """The first crossing of each pixel's ray with the surface ``height`` (N, 3); NaN where none is found."""
    o, d = pixel_rays(camera, position, rotation, pixels)
    o = np.broadcast_to(o, d.shape)
    top, hit_top = intersect_sphere(o, d, DATUM_RADIUS_M + top_m)
    bot, hit_bot = intersect_sphere(o, d, DATUM_RADIUS_M + bottom_m)
    s0 = np.where(hit_top, np.linalg.norm(top - o, axis=1), 0.0)
    s1 = np.where(hit_bot, np.linalg.norm(bot - o, axis=1), s0 + 4.0 * (top_m - bottom_m))
    s1 = np.where(hit_top, s1, 1.0)
    k_steps = int(np.ceil(np.max(s1 - s0) / step_m)) + 1
    s = s0[:, None] + np.linspace(0.0, 1.0, k_steps)[None, :] * (s1 - s0)[:, None]
    lat, lon, h = xyz_to_latlon((o[:, None, :] + s[..., None] * d[:, None, :]).reshape(-1, 3), datum_radius_m=DATUM_RADIUS_M)
    below = (h - height(lat, lon)).reshape(s.shape) <= 0
    k = np.argmax(below, axis=1)
    ok = hit_top & below.any(axis=1) & (k > 0)
    rows = np.arange(len(k))
    a, b = s[rows, np.maximum(k - 1, 0)], s[rows, k]
    for _ in range(30):  # bisection to 20 km / 2^30
        m = 0.5 * (a + b)
        lat, lon, h = xyz_to_latlon(o + m[:, None] * d, datum_radius_m=DATUM_RADIUS_M)
        above = h - height(lat, lon) > 0
        a, b = np.where(above, m, a), np.where(above, b, m)
    out = o + (0.5 * (a + b))[:, None] * d
    out[~ok] = np.nan
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mission")
    ap.add_argument("run")
    ap.add_argument("--json", help="write both truths' per-group figures here")
    args = ap.parse_args()
    alt_errors: list[np.ndarray] = []
    moved: list[np.ndarray] = []
    fixed_point = bench_match.true_errors

    def both(image_ids: Any, ia: Any, ib: Any, pa: np.ndarray, pb: np.ndarray, truth: Any, height: Any,
             datum_radius_m: float = DATUM_RADIUS_M) -> np.ndarray:
        err = fixed_point(image_ids, ia, ib, pa, pb, truth, height, datum_radius_m=datum_radius_m)
        alt = np.full(err.shape, np.nan)
        ia, ib = np.asarray(ia), np.asarray(ib)
        keys = ia * (len(image_ids) + 1) + ib
        for key in np.unique(keys):
            sel = np.flatnonzero(keys == key)
            ta, tb = truth[image_ids[ia[sel[0]]]], truth[image_ids[ib[sel[0]]]]
            g_fp, _ = image_to_ground(ta.camera, ta.position, ta.rotation, pa[sel], height=height, datum_radius_m=datum_radius_m)
            g = first_hit(ta.camera, ta.position, ta.rotation, pa[sel], height)
            ok = np.isfinite(g).all(axis=1)
            px, depth = project(tb.camera, tb.position, tb.rotation, np.where(ok[:, None], g, 0.0))
            alt[sel] = np.where(ok & (depth > 0), np.linalg.norm(px - pb[sel], axis=1), np.nan)
            moved.append(np.linalg.norm(np.where(ok[:, None], g - g_fp, np.nan), axis=1))
        alt_errors.append(alt)
        return err

    bench_match.true_errors = both  # the study's pair scoring, both truths on the same matches
    res = bench_match.tracks_study(args.mission, args.run, verbose=False)
    err, alt = res["pair_errors"], np.concatenate(alt_errors)
    from mercury_dem.mission import open_mission

    ms = open_mission(args.mission)
    instrument = dict(zip(ms.catalog["image_id"].astype(str), ms.catalog["instrument"].astype(str)))
    groups = bench_seeds.pair_groups(res["pair_rows"], instrument)
    figs = {name: bench_seeds.group_figures(e, res["pair_of_error"], res["pair_rows"], res["pair_overlaps"], groups)
            for name, e in (("fixed_point", err), ("first_hit", alt))}
    mv = np.concatenate(moved)
    mv = mv[np.isfinite(mv)]
    print(f"{args.mission}: {err.size} matches; ground points moved by the first-hit truth: > 1 m {100 * np.mean(mv > 1):.2f} %, "
          f"> 100 m {100 * np.mean(mv > 100):.2f} %, > 1 km {100 * np.mean(mv > 1000):.2f} %")
    for name in GROUPS:
        if name in figs["fixed_point"]:
            a, b = figs["fixed_point"][name], figs["first_hit"][name]
            print(f"{name:20s} n {int(a['n_measures']):7d}  median {a['median_px']:.3f} -> {b['median_px']:.3f}  "
                  f"p95 {a['p95_px']:.3f} -> {b['p95_px']:.3f}  > 2 px {100 * a['outlier_share']:.2f} -> "
                  f"{100 * b['outlier_share']:.2f} %")
    if args.json:
        Path(args.json).write_text(json.dumps(figs, indent=1))


if __name__ == "__main__":
    main()
