"""Benchmark: registration of a global DEM onto up to 10⁷ altimetry shots (issue 16 §4.5).

One run:

1. A synthetic global Mercury surface (plane waves, 50–300 km wavelengths by default, ~1 km relief), gridded
   at ``--ppd`` pixels/degree into a ``dem.zarr`` that is *misregistered*: the surface sampled
   ``--shift-lat``/``--shift-lon`` degrees away and ``--shift-up`` metres low.
2. ``--shots`` MLA-like shots of the true surface: near-polar profiles pole to pole, ~400 m apart
   along track, 1 m noise, a 3-D error per profile (σ 30 m horizontal, 3 m vertical).
3. The whole stage, :func:`mercury_dem.pipeline.register_stage.register_dem_store` (synchronous
   client, one process: the tile fits, the registered DEM, the merge, the stores), timed: cost
   per shot and per tile.
4. Side by side on the same tile and shots: our tile fit (:func:`register_tile`, transform only
   and with the profile offsets) and a plain ``scipy.optimize.least_squares`` reference of the
   same transform (the similarity model the tiles use here; Huber loss at 2 x our registered RMS; the
   residuals from the same DEM sampling; Jacobian by finite differences, scipy's default): time,
   ratio and the difference of the two translations.

Usage (heavy: run under the lock)::

    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_register.py \\
        [--shots 10000000] [--ppd 8] [--tile LAT,LON]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from harness import interleave, measure_here, peak_rss_bytes
from harness.scenarios import R, Surface, make_dem, make_shots


def scipy_reference(win, shots: pd.DataFrame, centre: tuple[float, float], scale: float) -> tuple[float, np.ndarray]:
    """Plain scipy least_squares of the similarity transform on one tile: seconds, translation of T (ENU)."""
    from scipy.optimize import least_squares

    from mercury_dem.altimetry import register as rg
    from mercury_dem.geometry.body import latlon_to_unit

    x = latlon_to_unit(shots["lat"].to_numpy(), shots["lon"].to_numpy()) * shots["radius_m"].to_numpy()[:, None]
    sampler = rg._Sampler(win)
    E = rg.enu_frame(*centre)
    c = R * E[:, 2]
    q = (x - c) @ E
    L = max(10_000.0, float(np.max(np.hypot(q[:, 0], q[:, 1]))))
    P = rg._model_basis("similarity", np.array([L, L, L]))

    def fun(phi: np.ndarray) -> np.ndarray:
        th = P @ phi
        B = th[:9].reshape(3, 3) / L
        r, _ = rg._residuals(c + (q @ (np.eye(3) + B).T + th[9:]) @ E.T, sampler, R)
        return np.nan_to_num(r, nan=0.0)

    t0 = time.perf_counter()
    r0, _ = rg._residuals(x, sampler, R)
    phi0 = np.zeros(7)
    phi0[6] = -float(np.nanmedian(r0))
    sol = least_squares(fun, phi0, loss="huber", f_scale=2.0 * scale, method="trf", x_scale=np.full(7, 100.0))
    # f_scale: 2 x the RMS our fit reached (ours uses 2 x the current NMAD), the same order
    secs = time.perf_counter() - t0
    th = P @ sol.x
    M = np.linalg.inv(np.eye(3) + th[:9].reshape(3, 3) / L)
    return secs, -M @ th[9:]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shots", type=float, default=1e7)
    ap.add_argument("--ppd", type=float, default=8.0)
    ap.add_argument("--shift-lat", type=float, default=0.02)
    ap.add_argument("--shift-lon", type=float, default=0.03)
    ap.add_argument("--shift-up", type=float, default=300.0)
    ap.add_argument("--tile", default="", help="lat,lon of the tile of the side-by-side comparison (default: the "
                    "registered tile with the median number of used shots, |lat| < 60)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--min-wavelength-km", type=float, default=50.0,
                    help="shortest wavelength of the surface (its DEM must resolve it: 8 ppd is 5.3 km pixels)")
    ap.add_argument("--out", help="working directory (default: a temporary one)")
    ap.add_argument("--no-profile-nuisance", action="store_true",
                    help="the stage's tile fits without step 1's profile nuisance (RegisterOptions.profile_nuisance=False)")
    args = ap.parse_args()

    from mercury_dem.altimetry.register import RegisterOptions, register_tile, tile_window
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.pipeline.register_stage import register_dem_store
    from mercury_dem.products.make import open_dem

    rng = np.random.default_rng(args.seed)
    surf = Surface(rng, min_wavelength_m=1e3 * args.min_wavelength_km)
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_register_"))
    t0 = time.perf_counter()
    make_dem(surf, args.ppd, work / "dem.zarr", (args.shift_lat, args.shift_lon, args.shift_up))
    shots = make_shots(surf, int(args.shots), rng)
    t_setup = time.perf_counter() - t0
    print(f"setup {t_setup:.1f} s: {len(shots)} shots in {shots['profile_id'].nunique()} profiles, "
          f"DEM {int(180 * args.ppd)} x {int(360 * args.ppd)}", flush=True)

    t0 = time.perf_counter()
    stage_opt = RegisterOptions(profile_nuisance=not args.no_profile_nuisance)
    summary = register_dem_store(work / "dem.zarr", shots, work, overwrite=True, source="bench", options=stage_opt)
    t_stage = time.perf_counter() - t0
    tiles = pd.DataFrame(summary["tiles"])
    ok = tiles[tiles["ok"]]
    n_tiles = len(tiles)

    # side by side on one tile
    tg = TileGrid(10.0)
    if args.tile:
        la, lo = (float(v) for v in args.tile.split(","))
        tid = int(tg.tile_of(la, lo))
    else:
        mid = ok[(ok["centre_lat"].abs() < 60) & ok["model"].isin(["similarity", "affine"])].sort_values("n_used")
        if mid.empty:
            mid = ok.sort_values("n_used")
        tid = int(mid["tile_id"].iloc[len(mid) // 2])
    centre = tuple(float(v) for v in tg.centre(tid))
    ds = open_dem(work / "dem.zarr")
    win = tile_window(ds["elevation"].values, ds["lat"].values, ds["lon"].values,
                      tuple(float(v) for v in tg.bounds(tid)), R, 1.0)
    sel = shots[tg.tile_of(shots["lat"].to_numpy(), shots["lon"].to_numpy()) == tid]
    args_t = (win, sel["lat"].to_numpy(), sel["lon"].to_numpy(), sel["radius_m"].to_numpy(), sel["profile_id"].to_numpy())
    opt_sim = RegisterOptions(models=("similarity",), profile_nuisance=not args.no_profile_nuisance)
    from mercury_dem.altimetry import register as rg

    x = rg.latlon_to_unit(args_t[1], args_t[2]) * args_t[3][:, None]
    E = rg.enu_frame(*centre)
    c = R * E[:, 2]
    q = (x - c) @ E
    L = max(10_000.0, float(np.max(np.hypot(q[:, 0], q[:, 1]))))
    # harness.interleave of warm in-process calls (harness.measure_here): the whole tile, then the fit alone
    ms = interleave({
        "register_tile": lambda: measure_here(register_tile, *args_t, tile_id=tid, centre=centre, options=opt_sim),
        "fit_only": lambda: measure_here(lambda: rg._fit_transform(x, q, E, c, rg._Sampler(win), R, "similarity",
                                                                   np.array([L, L, L]), opt_sim))}, 3)
    res = ms["register_tile"][-1].value
    times_ours_prof = [m.wall_s for m in ms["register_tile"]]
    times_ours = [m.wall_s for m in ms["fit_only"]]
    scale = res.rms_registered_m if np.isfinite(res.rms_registered_m) else 5.0
    t_scipy, tr_scipy = scipy_reference(win, sel, centre, scale)
    tr_ours = np.asarray(res.transform.translation_enu_m)

    rss_gb = peak_rss_bytes() / 1e9
    out = {
        "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()), "machine": platform.processor() or platform.machine(),
        "shots": len(shots), "profiles": int(shots["profile_id"].nunique()), "dem_shape": list(ds["elevation"].shape),
        "setup_seconds": t_setup, "stage_seconds": t_stage, "tile_fits_seconds": summary["seconds_tiles"],
        "tiles_with_shots": n_tiles, "tiles_registered": len(ok),
        "us_per_shot_stage": 1e6 * t_stage / len(shots), "ms_per_tile_stage": 1e3 * t_stage / n_tiles,
        "us_per_shot_tiles": 1e6 * summary["seconds_tiles"] / len(shots),
        "ms_per_tile_tiles": 1e3 * summary["seconds_tiles"] / n_tiles,
        "models": ok["model"].value_counts().to_dict(),
        "median_translation_enu_m": [float(ok[f"translation_{a}_m"].median()) for a in "enu"],
        "median_rms_before_after_m": [float(ok["rms_before_m"].median()), float(ok["rms_registered_m"].median()),
                                      float(ok["rms_after_m"].median())],
        "statistics": {k: {m: v[m] for m in ("bias_m", "rmse_m", "n")} for k, v in summary["statistics"].items()},
        "side_by_side": {
            "tile_id": tid, "model": res.transform.model, "shots": len(sel), "ours_fit_s": min(times_ours), "ours_fit_and_profiles_s": min(times_ours_prof),
            "scipy_least_squares_s": t_scipy, "ratio_scipy_over_ours_fit": t_scipy / min(times_ours),
            "translation_ours_enu_m": tr_ours.tolist(), "translation_scipy_enu_m": tr_scipy.tolist(),
            "max_translation_difference_m": float(np.max(np.abs(tr_ours - tr_scipy))),
        },
        "peak_rss_gb": rss_gb,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
