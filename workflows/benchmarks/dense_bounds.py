"""Bounds on the dense DEM's accuracy on the tiny mission (issue 31, 'Done when' 1; docs/benchmarks/dense.md).

For a finished dense run (``dense.zarr`` + ``dem_dense.zarr``, e.g. from ``bench_dense_dem.py``), on the pixels the
issue's ratio is measured on (``source`` = dense, the sparse DEM defined), against the truth as the validation samples
it (at each pixel's centre):

* **floor**: a perfect pixel -- the truth's area mean over the pixel (``--supersample``² samples) -- against the
  point sample: what no DEM at this grid can beat with the validation as it is;
* **oracle**: the cloud's points with the truth's height at their own (lat, lon), gridded by the stage's own gridding
  (``grid_dem``, median11 over ``dense.grid_neighbours``, ``dense.max_gap_pixels``): what the gridding allows;
* **window**: the oracle with each point's height the truth averaged over a square of ``dense.refine_window`` x its
  pair's coarser pixel scale about it (a box-window matcher without noise: what the matching window's resolution
  allows; the least-squares window weights by the image gradient, so this is indicative, not exact);
* **noise**: the oracle plus Gaussian disparity noise of ``--noise`` px, each point's height moved by the noise times
  its own ``m_per_px`` (|dh/dd| of its pair): the matching accuracy the ratio needs; independent per point, or with
  ``--correlated`` a field per pair correlated over the matching window (white noise on a grid of the pair's coarser
  pixel scale, box-filtered by ``dense.refine_window``, scaled to the stated sigma), as a window matcher's errors are;
* **actual**: the cloud as it is, regridded the same way (checks this script against the run's report).

``--neighbours`` and ``--smoothing`` grid with other values than the run's (``dense.grid_neighbours``,
``dense.grid_smoothing_passes``) for every column but the run's own.

Run (1-3 min per run on the shared machine; light, no lock needed):
    .venv/bin/python workflows/benchmarks/dense_bounds.py RUN [RUN ...] [--noise 0.1 0.2 0.3] [--correlated]
        [--neighbours 16 --smoothing 0]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np


def rms(x: np.ndarray) -> float:
    """Root mean square of the finite values (NaN: none)."""
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def area_mean(truth: Any, lat: np.ndarray, lon: np.ndarray, ppd: float, n: int) -> np.ndarray:
    """The truth's mean over each pixel, from n x n samples (uniform in lat/lon inside the pixel)."""
    off = (np.arange(n) + 0.5) / n - 0.5
    acc = np.zeros((lat.size, lon.size))
    for a in off:
        for b in off:
            la, lo = np.meshgrid(lat + a / ppd, lon + b / ppd, indexing="ij")
            acc += truth(la, lo)
    return acc / (n * n)


def window_heights(truth: Any, lat: np.ndarray, lon: np.ndarray, width_m: np.ndarray, radius_m: float,
                   step_m: float = 500.0) -> np.ndarray:
    """The truth averaged over a ``width_m`` square about each point: a box filter of the truth sampled every
    ``step_m`` over the points' extent (one filter per distinct width in steps), interpolated bilinearly.
    """
    from scipy.ndimage import map_coordinates, uniform_filter

    deg = step_m / (math.pi * radius_m / 180.0)
    coslat = max(0.2, math.cos(math.radians(float(np.mean(lat)))))
    la0, la1 = float(lat.min()) - 1.0, float(lat.max()) + 1.0
    lo0, lo1 = float(lon.min()) - 1.0, float(lon.max()) + 1.0
    gla = np.arange(la0, la1, deg)
    glo = np.arange(lo0, lo1, deg / coslat)
    fine = np.concatenate([truth(np.full(glo.size, a), glo)[None, :] for a in gla])
    cells = np.maximum(1, np.round(width_m / step_m)).astype(np.int64)
    out = np.empty(lat.size)
    for n in np.unique(cells):
        sel = cells == n
        f = uniform_filter(fine, size=int(n), mode="nearest")
        out[sel] = map_coordinates(f, [(lat[sel] - la0) / deg, (lon[sel] - lo0) / (deg / coslat)], order=1)
    return out


def correlated_noise(lat: np.ndarray, lon: np.ndarray, pair: np.ndarray, scale_m: np.ndarray, window: int,
                     radius_m: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance noise per point, one field per pair correlated over ``window`` of its pixels (see the module
    docstring).
    """
    from scipy.ndimage import map_coordinates, uniform_filter

    out = np.zeros(lat.size)
    for p in np.unique(pair):
        sel = pair == p
        deg = scale_m[p] / (math.pi * radius_m / 180.0)
        la, lo = lat[sel], lon[sel]
        coslat = max(0.2, math.cos(math.radians(float(np.mean(la)))))
        la0, lo0 = float(la.min()) - 2 * window * deg, float(lo.min()) - 2 * window * deg / coslat
        n0 = int((float(la.max()) - la0) / deg) + 4 * window
        n1 = int((float(lo.max()) - lo0) / (deg / coslat)) + 4 * window
        f = uniform_filter(rng.standard_normal((n0, n1)), size=window, mode="wrap")
        f /= f.std()
        out[sel] = map_coordinates(f, [(la - la0) / deg, (lo - lo0) / (deg / coslat)], order=1)
    return out


def grid_heights(lat: np.ndarray, lon: np.ndarray, height: np.ndarray, config: Any, ppd: float,
                 bounds: tuple[float, ...], body: Any) -> np.ndarray:
    """The cloud gridded as ``pipeline.dense_dem.grid_dense_dem`` grids it; (H, W) elevation (NaN: no dense value)."""
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

    xyz = latlon_to_xyz(lat, lon, height_m=height, datum_radius_m=body.datum_radius_m)
    cfg = replace(config.dem, pixels_per_degree=ppd, lat_min=bounds[0], lat_max=bounds[1], lon_min=bounds[2],
                  lon_max=bounds[3], method="median11", neighbours=config.dense.grid_neighbours,
                  smoothing_passes=(config.dem.smoothing_passes if config.dense.grid_smoothing_passes is None
                                    else config.dense.grid_smoothing_passes),
                  max_distance_m=config.dense.max_gap_pixels * 2 * math.pi * body.datum_radius_m / 360.0 / ppd)
    tmp = Path(tempfile.mkdtemp(prefix="dense_bounds_"))
    try:
        grid_dem(xyz, cfg, tmp / "g.zarr", None, coverage=False, body=body)
        g = open_dem(tmp / "g.zarr").load()
        return g["elevation"].transpose("lat", "lon").values.astype(np.float64)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv: list[str] | None = None) -> None:
    """One table row per run (module docstring)."""
    from mercury_dem.config import load_config
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.pipeline.dense_stage import read_cloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--noise", type=float, nargs="*", default=[0.1, 0.2, 0.3])
    ap.add_argument("--supersample", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0, help="random seed of the disparity noise")
    ap.add_argument("--correlated", action="store_true", help="noise correlated over the matching window, per pair")
    ap.add_argument("--neighbours", type=int, default=None, help="grid with this dense.grid_neighbours")
    ap.add_argument("--smoothing", type=int, default=None, help="grid with this dem.smoothing_passes")
    args = ap.parse_args(argv)
    print("| run | pixels | sparse RMSE m | dense RMSE m (ratio) | floor: area mean vs point m (ratio) "
          "| oracle m (ratio) | window m (ratio) | " + " | ".join(f"noise {s:g} px m (ratio)" for s in args.noise) + " |")
    print("|---" * (7 + len(args.noise)) + "|")
    for run in args.runs:
        info = json.loads((run / "run.json").read_text())
        mission = open_mission(Path(info["mission"]))
        config = load_config(overrides=info["config"])
        run_config = config
        if args.neighbours is not None:
            config = replace(config, dense=replace(config.dense, grid_neighbours=args.neighbours))
        if args.smoothing is not None:
            config = replace(config, dense=replace(config.dense, grid_smoothing_passes=args.smoothing))
        body = mission.body
        truth = mission.need_truth().surface().height
        ds = open_dem(run / "dem_dense.zarr").load()
        lat, lon = ds["lat"].values, ds["lon"].values
        ppd = float(ds.attrs["pixels_per_degree"])
        half = 0.5 / ppd
        bounds = (float(lat.min()) - half, float(lat.max()) + half, float(lon.min()) - half, float(lon.max()) + half)
        src = ds["source"].transpose("lat", "lon").values
        sparse = ds["sparse_on_grid"].transpose("lat", "lon").values.astype(np.float64)
        dense = ds["elevation"].transpose("lat", "lon").values.astype(np.float64)
        mask = (src == 1) & np.isfinite(sparse)
        la2, lo2 = np.meshgrid(lat, lon, indexing="ij")
        t_pt = truth(la2, lo2)
        t_area = area_mean(truth, lat, lon, ppd, args.supersample)
        s_rmse = rms(np.where(mask, sparse - t_pt, np.nan))
        d_rmse = rms(np.where(mask, dense - t_pt, np.nan))
        floor = rms(np.where(mask, t_area - t_pt, np.nan))
        cloud = read_cloud(run / "dense.zarr")
        h_true = truth(cloud["lat"], cloud["lon"])
        row = [f"{run}", f"{int(mask.sum())}", f"{s_rmse:.0f}", f"{d_rmse:.0f} ({d_rmse / s_rmse:.2f})",
               f"{floor:.0f} ({floor / s_rmse:.2f})"]
        oracle = grid_heights(cloud["lat"], cloud["lon"], h_true, config, ppd, bounds, body)
        o = rms(np.where(mask, oracle - t_pt, np.nan))
        row.append(f"{o:.0f} ({o / s_rmse:.2f})")
        import zarr

        pairs = zarr.open_group(str(run / "dense.zarr"), mode="r").attrs["pairs"]
        coarser = np.array([max(p["pixel_scale_left_m"], p["pixel_scale_right_m"]) for p in pairs])
        width = config.dense.refine_window * coarser[cloud["pair"]]
        h_win = window_heights(truth, cloud["lat"], cloud["lon"], width, body.datum_radius_m)
        wg = grid_heights(cloud["lat"], cloud["lon"], h_win, config, ppd, bounds, body)
        e = rms(np.where(mask, wg - t_pt, np.nan))
        row.append(f"{e:.0f} ({e / s_rmse:.2f})")
        rng = np.random.default_rng(args.seed)
        mpp = cloud["m_per_px"].astype(np.float64)
        unit = (correlated_noise(cloud["lat"], cloud["lon"], cloud["pair"], coarser, config.dense.refine_window,
                                 body.datum_radius_m, rng) if args.correlated else rng.standard_normal(mpp.size))
        for s in args.noise:
            g = grid_heights(cloud["lat"], cloud["lon"], h_true + s * mpp * unit, config, ppd, bounds, body)
            e = rms(np.where(mask, g - t_pt, np.nan))
            row.append(f"{e:.0f} ({e / s_rmse:.2f})")
        print("| " + " | ".join(row) + " |", flush=True)
        actual = grid_heights(cloud["lat"], cloud["lon"], cloud["height"], config, ppd, bounds, body)
        a = rms(np.where(mask, actual - t_pt, np.nan))
        same = "" if config is run_config else " with --neighbours/--smoothing"
        print(f"#   actual cloud regridded here{same}: {a:.0f} m, ratio {a / s_rmse:.2f} (run's dense {d_rmse:.0f} m); "
              "median m_per_px "
              f"{np.median(mpp):.0f} m (p10 {np.percentile(mpp, 10):.0f}, p90 {np.percentile(mpp, 90):.0f})",
              flush=True)


if __name__ == "__main__":
    main()
