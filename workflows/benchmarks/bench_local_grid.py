r"""Benchmark (issue 30 item 5): the grid of a local block of altimeter shots, ours vs gdal_grid on the same canvas.

The user's case: 52,363 LOLA shots over 0.8 deg x 0.75 deg of the Moon near 25 N, 3 E,
``mercury-dem grid --body moon``. Before, the canvas was 6 x 5 deg (30x the data's
area, 48 % no value) and the grid took 52 s at 64 pixel/deg; at 256 it was still on its
first chunk after 8 minutes. Here the shots are simulated
(:func:`mercury_dem.synth.altimeter_block.altimeter_block`: 45 near-polar tracks, 1 m noise, over
:class:`~mercury_dem.synth.altimeter_block.BlockSurface`: a regional slope, long waves, six craters).

Reported:

* the canvas our code chooses (``dem.extent.points_extent``) against the data's bounding
  box, by area on the sphere, at 64 and 256 pixel/deg (goal: within 1.2x);
* the 256 pixel/deg grid's wall time, as the user runs it: ``mercury-dem grid POINTS.npy
  --body moon --ppd 256`` in a fresh process, coverage included (goal: under 20 s), and
  the DEM stage in-process (``grid_dem``, warm: numba's cache loaded, imports done;
  coverage off), as ``bench_grid.py`` times it;
* ours against ``gdal_grid -a invdistnn`` on the SAME canvas (``-txe/-tye`` = our bounds,
  ``-outsize`` = our shape) and search radius (gdal's ``radius`` = our no-value distance,
  in degrees of latitude: a pixel with no shot within it has no value on both sides;
  ``max_points=11`` = median11's neighbours, power 2), reading FlatGeobuf, 2 threads.
  Repetitions interleaved (ours warm, gdal_grid, ours CLI cold, then again), medians and
  minimums, ratio of medians (goal: ours warm >= 3x faster); the CPU time (user + system)
  of the two subprocesses too, less sensitive than wall time to a loaded machine. Accuracy of both against
  the surface on the canvas, and their filled fractions.

gdal_grid works in lon/lat degrees: at 25 N its radius is 0.906 x as long east-west as
north-south in metres (the same canvas in degrees, a slightly narrower search east-west).
The helpers that write gdal_grid's FlatGeobuf and run it are ``bench_grid.py``'s.

Usage (heavy: run under the lock; the machine is shared)::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_local_grid.py \\
        [--repeats 5] [--before]

``--before`` also grids, once, the old canvas (6 x 5 deg, 50 km no-value distance) at 64
pixel/deg in-process, for the before/after on the same machine and run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import interleave, measure, measure_here
from harness.scenarios import gdal_grid, median_and_min, write_cloud_files  # gdal_grid's inputs and call, shared

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.extent import box_area_ratio, points_box, points_extent
from mercury_dem.geometry.body import MOON
from mercury_dem.pipeline.dem_stage import grid_dem, open_dem
from mercury_dem.synth.altimeter_block import BlockSurface, altimeter_block

BODY = MOON
LAT = (24.6, 25.35)
LON = (2.6, 3.4)
N_PROFILES = 45
N_SHOTS = 52_363
NOISE_M = 1.0
PPD = 256.0
#: The canvas the code chose before this change for this block (6 x 5 deg at 64 ppd, 50 km).
OLD_BOUNDS = {"lat_min": 23.0, "lat_max": 28.0, "lon_min": 0.0, "lon_max": 6.0}


def simulate(seed: int = 30):
    """The block of shots and its truth surface."""
    surf = BlockSurface(0.5 * sum(LAT), 0.5 * sum(LON), BODY.datum_radius_m)
    block = altimeter_block(np.random.default_rng(seed), BODY.datum_radius_m, surf, lat_range=LAT, lon_range=LON,
                            n_profiles=N_PROFILES, n_shots=N_SHOTS, noise_m=NOISE_M)
    return block, surf


def rmse_filled(elev, lat, lon, surf):
    """RMSE (m) of a grid against the surface where it has values, and the fraction with values."""
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    e = elev - surf(la, lo)
    return float(np.sqrt(np.nanmean(e**2))), float(np.isfinite(elev).mean())


def run_ours(npy, cfg, out):
    """The DEM stage in this process (reading the .npy, writing dem.zarr; coverage off), timed by the harness
    (``harness.measure_here``): (the measurement, the stage's summary)."""
    m = measure_here(lambda: grid_dem(np.load(npy), cfg, out, coverage=False, body=BODY), label="ours (in-process, warm)")
    return m, m.value


def run_cli(npy, ppd, out):
    """``mercury-dem grid`` as the user runs it (coverage included), a fresh process measured from outside
    (``harness.measure``): (the measurement, the command, its output)."""
    exe = Path(sys.executable).with_name("mercury-dem")
    cmd = [str(exe), "grid", str(npy), "--out", str(out), "--body", "moon", "--ppd", f"{ppd:g}"]
    m = measure(cmd, cwd="/tmp", env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    return m, " ".join(cmd[1:]), m.stdout.strip()


def main():
    """Run the comparison and print the table, the goals and a JSON record."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=5, help="interleaved repetitions of ours / gdal_grid / ours CLI")
    p.add_argument("--before", action="store_true", help="also grid the old 6 x 5 deg canvas once (64 ppd, 50 km)")
    args = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_local_grid_"))
    try:
        block, surf = simulate()
        pts = block.xyz
        npy, _, _, fgb = write_cloud_files(work, pts, BODY.datum_radius_m)
        box = points_box(pts)
        canvases = {}
        for ppd in (64.0, PPD):
            ext = points_extent(pts, ppd, margin_pixels=DemConfig().canvas_margin_pixels)
            canvases[ppd] = {"bounds": ext, "area_vs_box": box_area_ratio(ext, box)}
        cfg = DemConfig(pixels_per_degree=PPD, query_threads=2)
        # warm-up: numba's cache, lazy imports; and the canvas / no-value distance the timed runs use
        _, warm = run_ours(npy, cfg, work / "warm.zarr")
        lat_min, lat_max, lon_min, lon_max = warm["grid_bounds_deg"]
        ny, nx = warm["shape"]
        radius_m = warm["no_value_distance_m"]
        radius_deg = math.degrees(radius_m / BODY.datum_radius_m)
        algo = f"invdistnn:power=2.0:radius={radius_deg:.8f}:max_points=11:min_points=1:nodata=nan"
        extent = (lon_min, lon_max, lat_min, lat_max)
        quality = {}
        last = {}  # the commands and the CLI's output, as the last round ran them

        def ours():
            m, _ = run_ours(npy, cfg, work / "ours.zarr")
            if "ours (in-process, warm)" not in quality:
                ds = open_dem(work / "ours.zarr")
                quality["ours (in-process, warm)"] = rmse_filled(ds.elevation.values, ds.lat.values, ds.lon.values,
                                                                 surf)
            shutil.rmtree(work / "ours.zarr")
            m.value = None
            return m

        def gdal():
            m, elev, last["gdal"] = gdal_grid(fgb, algo, (nx, ny), extent, work)
            if "gdal_grid invdistnn (fgb)" not in quality:
                glat = lat_max - (np.arange(ny) + 0.5) / PPD
                glon = lon_min + (np.arange(nx) + 0.5) / PPD
                quality["gdal_grid invdistnn (fgb)"] = rmse_filled(elev, glat, glon, surf)
            return m

        def cli():
            m, last["cli"], last["cli_out"] = run_cli(npy, PPD, work / "cli")
            shutil.rmtree(work / "cli")
            return m

        t_start = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
        load_start = Path("/proc/loadavg").read_text().split()[:3]
        res = interleave({"ours (in-process, warm)": ours, "gdal_grid invdistnn (fgb)": gdal,
                          "ours: mercury-dem grid (cold CLI)": cli}, args.repeats)
        times = {k: [m.wall_s for m in ms] for k, ms in res.items()}
        cpu = {k: [m.cpu_s for m in ms] for k, ms in res.items() if k != "ours (in-process, warm)"}
        gdal_cmd, cli_cmd, cli_out = last["gdal"], last["cli"], last["cli_out"]
        quality["ours: mercury-dem grid (cold CLI)"] = quality["ours (in-process, warm)"]
        before = None
        if args.before:
            old = DemConfig(pixels_per_degree=64.0, max_distance_m=50_000.0, query_threads=2, **OLD_BOUNDS)
            m_old, s_old = run_ours(npy, old, work / "before.zarr")
            before = {"seconds": m_old.wall_s, "shape": s_old["shape"], "no_value_fraction": s_old["no_value_fraction"],
                      "area_vs_box": box_area_ratio((23.0, 28.0, 0.0, 6.0), box)}
        t_end = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
        load_end = Path("/proc/loadavg").read_text().split()[:3]

        ref_med, ref_min = median_and_min(times["gdal_grid invdistnn (fgb)"])
        print(f"\n{pts.shape[0]} shots, {N_PROFILES} tracks, lat {LAT[0]}..{LAT[1]}, lon {LON[0]}..{LON[1]} "
              f"(Moon, noise {NOISE_M:g} m); data box lat {box[0]:.4f}..{box[1]:.4f}, lon {box[2]:.4f}..{box[3]:.4f}")
        print(f"run {t_start} .. {t_end}, load average {' '.join(load_start)} .. {' '.join(load_end)}, "
              f"{args.repeats} interleaved repetitions, shared machine")
        for ppd, c in canvases.items():
            print(f"canvas at {ppd:g} px/deg: lat {c['bounds'][0]:g}..{c['bounds'][1]:g}, lon {c['bounds'][2]:g}.."
                  f"{c['bounds'][3]:g}: {c['area_vs_box']:.3f} x the data's box (goal < 1.2)")
        print(f"256 px/deg grid: {ny} x {nx}, no-value distance {radius_m:.0f} m "
              f"(gdal_grid radius {radius_deg:.6f} deg), no value {100 * warm['no_value_fraction']:.2f} %")
        print(f"{'method':36s} {'median s':>8s} {'min s':>7s} {'gdal/ours med':>13s} {'min/min':>7s} "
              f"{'RMSE m':>7s} {'filled':>7s}  all runs (s)")
        for name, ts in times.items():
            med, mn = median_and_min(ts)
            rmse, filled = quality[name]
            print(f"{name:36s} {med:8.3f} {mn:7.3f} {ref_med / med:12.2f}x {ref_min / mn:6.2f}x {rmse:7.2f} "
                  f"{100 * filled:6.1f}%  {' '.join(f'{t:.3f}' for t in ts)}")
        for name, cs in cpu.items():
            print(f"{name}: CPU (user + system) median {np.median(cs):.2f} s: {' '.join(f'{c:.2f}' for c in cs)}")
        paired = np.asarray(times["gdal_grid invdistnn (fgb)"]) / np.asarray(times["ours (in-process, warm)"])
        print(f"ours warm vs gdal_grid per repetition: {' '.join(f'{r:.2f}' for r in paired)}")
        if before is not None:
            print(f"before (old canvas 6 x 5 deg, 50 km, 64 px/deg, in-process): {before['seconds']:.1f} s, "
                  f"{before['shape'][0]} x {before['shape'][1]}, {before['area_vs_box']:.1f} x the box, "
                  f"{100 * before['no_value_fraction']:.1f} % no value")
        cold_med = median_and_min(times["ours: mercury-dem grid (cold CLI)"])[0]
        warm_med = median_and_min(times["ours (in-process, warm)"])[0]
        goals = {"canvas within 1.2x of the box (256 ppd)": canvases[PPD]["area_vs_box"] < 1.2,
                 "canvas within 1.2x of the box (64 ppd)": canvases[64.0]["area_vs_box"] < 1.2,
                 "256 ppd grid under 20 s (cold CLI, median)": cold_med < 20.0,
                 "ours warm >= 3x gdal_grid (ratio of medians)": ref_med / warm_med >= 3.0}
        for goal, ok in goals.items():
            print(f"  {'MET   ' if ok else 'MISSED'} {goal}")
        print(f"  ours: mercury-dem {cli_cmd}\n    -> {cli_out}")
        print(f"  gdal: {gdal_cmd}")
        record = {"date": t_start, "load": [load_start, load_end], "shots": int(pts.shape[0]),
                  "canvases": {str(k): v for k, v in canvases.items()}, "shape_256": [ny, nx],
                  "no_value_distance_m": radius_m, "times": times, "cpu_children": cpu, "quality": quality, "before": before,
                  "goals": goals}
        print(json.dumps(record))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
