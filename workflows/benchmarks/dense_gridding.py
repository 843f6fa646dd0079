"""The dense DEM's gridding against alternatives, and its bias before / after the registration (issue 31, 'Done
when' 1; docs/benchmarks/dense.md).

For a finished dense run (``dense.zarr`` + ``dem_dense.zarr``, e.g. from ``bench_dense_dem.py``), on the pixels the
issue's ratio is measured on (``source`` = dense, the sparse DEM of the run's dense DEM defined), against the truth at
each pixel's centre as the validation samples it, RMSE (bias) in metres and the ratio to that sparse DEM's RMSE:

* rows ``oracle``: the cloud's points with the truth's height at their own (lat, lon) (``dense_bounds.py``'s oracle):
  what each gridding allows;
* rows ``real ..., fused``: the same gridded values fused with the sparse DEM by their precisions as the stage fuses
  them (``dense.sparse_sigma_m``, ``dense.fusion_correlation``; the precision layer of the points' sigma_h);
* rows ``real``: the cloud's own heights, moved by the run's registration (``registration/transform.json``,
  :func:`mercury_dem.altimetry.merge.register_points`) when the run has one; ``real, adjusted frame``: not moved
  (the dense DEM before this session's registration hook), for the bias.

Griddings (columns): ``stage`` = the stage's own (``grid_dem``, median11 of ``dense.grid_neighbours`` with
``dense.grid_smoothing_passes``, ``dense.max_gap_pixels``; via ``dense_bounds.grid_heights``); ``stage kN sS`` = the same
with N neighbours and S smoothing passes; ``knn-mean k`` / ``knn-median k`` = mean / median of the k nearest points
of each pixel centre (chord distance, ``scipy.spatial.cKDTree``), no smoothing; ``tin`` = linear interpolation
(``scipy.interpolate.LinearNDInterpolator``) in a tangent plane at the cloud's centre; ``pair-wmedian`` = per pixel
the median of each pair's points inside it, merged across pairs by a median weighted by 1 / (the pair's median
sigma_h)^2 (the issue's "pairs merged by a weighted median"). Each is evaluated on the same mask.

Run (light, no lock; ~1-3 min per run):
    .venv/bin/python workflows/benchmarks/dense_gridding.py RUN [RUN ...] [--k 4 8 16 32] [--stage 16:0 64:0]
        [--no-tin] [--no-adjusted]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from dense_bounds import grid_heights, rms  # noqa: E402


def knn_grid(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, glat: np.ndarray, glon: np.ndarray, k: int,
             radius_m: float, how: str) -> np.ndarray:
    """Mean or median of the k nearest points (chord distance on the datum sphere) at every pixel centre."""
    from scipy.spatial import cKDTree

    from mercury_dem.geometry.body import latlon_to_unit

    tree = cKDTree(latlon_to_unit(lat, lon) * radius_m)
    la, lo = np.meshgrid(glat, glon, indexing="ij")
    _, idx = tree.query(latlon_to_unit(la.ravel(), lo.ravel()) * radius_m, k=k)
    v = h[idx.reshape(la.size, -1)]
    out = v.mean(axis=1) if how == "mean" else np.median(v, axis=1)
    return np.asarray(out).reshape(la.shape)


def tin_grid(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, glat: np.ndarray, glon: np.ndarray,
             mask: np.ndarray) -> np.ndarray:
    """Linear interpolation of the points in a tangent plane at their centre, at the masked pixel centres."""
    from scipy.interpolate import LinearNDInterpolator

    from mercury_dem.altimetry.register import enu_frame
    from mercury_dem.geometry.body import latlon_to_unit

    E = enu_frame(float(np.median(lat)), float(np.median(lon)))

    def plane(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        u = latlon_to_unit(a, b) @ E
        return u[:, :2] / u[:, 2:3]  # gnomonic: straight lines stay straight

    f = LinearNDInterpolator(plane(lat, lon), h)
    la, lo = np.meshgrid(glat, glon, indexing="ij")
    out = np.full(la.shape, np.nan)
    out[mask] = f(plane(la[mask], lo[mask]))
    return out


def pair_wmedian_grid(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, sigma: np.ndarray, pair: np.ndarray,
                      glat: np.ndarray, glon: np.ndarray, ppd: float) -> np.ndarray:
    """Per pixel: each pair's median inside it, merged across pairs by a 1/sigma^2-weighted median."""
    import pandas as pd

    H, W = glat.size, glon.size
    i = np.floor((float(glat[0]) + 0.5 / ppd - lat) * ppd).astype(np.int64)
    j = np.floor(np.mod(lon - (float(glon[0]) - 0.5 / ppd), 360.0) * ppd).astype(np.int64)
    ok = (i >= 0) & (i < H) & (j >= 0) & (j < W) & np.isfinite(h)
    df = pd.DataFrame({"px": i[ok] * W + j[ok], "pair": pair[ok], "h": h[ok], "s": sigma[ok]})
    g = df.groupby(["px", "pair"]).median().reset_index()
    g["w"] = 1.0 / np.maximum(g["s"].to_numpy(), 1.0) ** 2
    g = g.sort_values(["px", "h"])
    g["cw"] = g.groupby("px")["w"].cumsum()
    g["tw"] = g.groupby("px")["w"].transform("sum")
    med = g[g["cw"] >= 0.5 * g["tw"]].groupby("px")["h"].first()
    out = np.full(H * W, np.nan)
    out[med.index.to_numpy()] = med.to_numpy()
    return out.reshape(H, W)


def main(argv: list[str] | None = None) -> None:
    """One table per run (module docstring)."""
    from mercury_dem.altimetry.merge import register_points
    from mercury_dem.config import load_config
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.io.run_store import read_registration_transform
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.pipeline.dense_stage import read_cloud

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--k", type=int, nargs="*", default=[4, 8, 16, 32])
    ap.add_argument("--stage", nargs="*", default=["16:0", "32:0", "64:0"], metavar="N:S",
                    help="the stage's gridding with N neighbours and S smoothing passes")
    ap.add_argument("--no-tin", action="store_true")
    ap.add_argument("--no-adjusted", action="store_true", help="without the rows of the cloud in the adjusted frame")
    args = ap.parse_args(argv)
    for run in args.runs:
        info = json.loads((run / "run.json").read_text())
        mission = open_mission(Path(info["mission"]))
        config = load_config(overrides=info["config"])
        body = mission.body
        R = body.datum_radius_m
        truth = mission.need_truth().surface().height
        ds = open_dem(run / "dem_dense.zarr").load()
        glat, glon = ds["lat"].values, ds["lon"].values
        ppd = float(ds.attrs["pixels_per_degree"])
        half = 0.5 / ppd
        bounds = (float(glat.min()) - half, float(glat.max()) + half, float(glon.min()) - half,
                  float(glon.max()) + half)
        src = ds["source"].transpose("lat", "lon").values
        sparse = ds["sparse_on_grid"].transpose("lat", "lon").values.astype(np.float64)
        mask = (src == 1) & np.isfinite(sparse)
        la2, lo2 = np.meshgrid(glat, glon, indexing="ij")
        t_pt = truth(la2, lo2)
        s_err = np.where(mask, sparse - t_pt, np.nan)
        s_rmse = rms(s_err)
        cloud = read_cloud(run / "dense.zarr")
        lat, lon = cloud["lat"].astype(np.float64), cloud["lon"].astype(np.float64)
        h_adj = cloud["height"].astype(np.float64)
        t = read_registration_transform(run / "registration")
        frame = ds.attrs.get("frame", "adjusted")
        heights: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {"oracle": (lat, lon, truth(lat, lon))}
        if t is not None:
            xyz = latlon_to_xyz(lat, lon, height_m=h_adj, datum_radius_m=R)
            rla, rlo, rh = register_points(xyz, lat, lon, R, t["table"], TileGrid(float(t["tile_size_deg"])),
                                           t.get("level_offset_m"))
            heights["real, registered"] = (rla, rlo, rh)
        if t is None or not args.no_adjusted:
            heights["real, adjusted frame"] = (lat, lon, h_adj)
        print(f"\n# {run}: {int(mask.sum())} pixels at {ppd:g} pixel/deg, {lat.size} points; the run's dense DEM "
              f"frame: {frame}; sparse DEM there {s_rmse:.0f} m RMSE (bias {np.nanmean(s_err):+.0f} m); "
              f"registration transform {'stored' if t is not None else 'none'}", flush=True)
        cols: list[tuple[str, Any]] = [("stage", None)]
        cols += [(f"stage k{n} s{s}", (int(n), int(s))) for n, s in (x.split(":") for x in args.stage)]
        cols += [(f"knn-{how} {k}", (how, k)) for k in args.k for how in ("mean", "median")]
        cols += [("pair-wmedian", None)] + ([] if args.no_tin else [("tin", None)])
        print("| cloud | " + " | ".join(c for c, _ in cols) + " |")
        print("|---" * (len(cols) + 1) + "|")
        sig = cloud["sigma_h_m"].astype(np.float64)
        pair = cloud["pair"].astype(np.int64)
        from mercury_dem.dem.dense_grid import fuse_with_prior, pixel_precision

        d = config.dense
        for name, (a, b, h) in list(heights.items()):
            fused = name.startswith("real") and d.sparse_sigma_m is not None
            prec = (pixel_precision({"lat": a, "lon": b, "sigma_h_m": sig, "pair": pair}, glat, glon, ppd,
                                    int(d.grid_neighbours)) if fused else None)
            rows: dict[str, list[str]] = {name: []}
            if fused:
                rows[name + ", fused"] = []
            for col, arg in cols:
                if col == "stage":
                    g = grid_heights(a, b, h, config, ppd, bounds, body)
                elif col.startswith("stage k"):
                    cfg = replace(config, dense=replace(config.dense, grid_neighbours=arg[0],
                                                        grid_smoothing_passes=arg[1]))
                    g = grid_heights(a, b, h, cfg, ppd, bounds, body)
                elif col.startswith("knn"):
                    g = knn_grid(a, b, h, glat, glon, arg[1], R, arg[0])
                elif col == "pair-wmedian":
                    g = pair_wmedian_grid(a, b, h, sig, pair, glat, glon, ppd)
                else:
                    g = tin_grid(a, b, h, glat, glon, mask)
                outs = {name: g}
                if fused:
                    outs[name + ", fused"] = fuse_with_prior(g, prec, sparse, float(d.sparse_sigma_m),
                                                             float(d.fusion_correlation))[0]
                for key, gg in outs.items():
                    e = np.where(mask, gg - t_pt, np.nan)
                    miss = int((mask & ~np.isfinite(gg)).sum())
                    r = rms(e)
                    rows[key].append(f"{r:.0f} ({np.nanmean(e):+.0f}) {r / s_rmse:.2f}"
                                     + (f" [{miss} px none]" if miss else ""))
            for key, row in rows.items():
                print(f"| {key} | " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
