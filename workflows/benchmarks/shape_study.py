"""Why the adjusted block bends: re-adjust a finished run's global network with variants.

Reads a finished run (its hemisphere networks and solutions) and its synthetic mission, rebuilds
the global merged network exactly as the global stage does, adjusts it with each variant of the
adjustment configuration / start, and reports (1) the adjusted tie points' height error against the
true surface below them and their distance to their true positions (the first measure's pixel through
the true pose onto the true surface, as validation does), by latitude band and as the RMS of each
spherical-harmonic degree 0..4; (2) the same points gridded as the DEM stage grids them, on the truth
DEM's grid, against the truth (area-weighted bias, RMSE, bands, degrees: ``dem`` in the JSON); (3) the
pointing error in pixels. Nothing is written into the run.

    PYTHONPATH=. python workflows/benchmarks/shape_study.py RUN [--variants base cold r1km ...] [--json OUT]

Variants: ``stored`` (the run's own global points, no adjustment), ``hemi`` (the hemisphere
networks' points), ``base`` (the run's configuration), ``noalt`` (without altimetry), ``cold``
(no warm start from the hemispheres), ``recentre`` (the radius constraints re-centred on the
block's own surface, ``adjust.point_prior_recentre_levels``; every other variant has them on the
datum), ``r1km``/``r3km``/``r100km``/``rnone`` (datum radius sigma), ``pos`` (spacecraft positions solved too), ``truepos`` (a-priori positions replaced by
the true ones), ``iter`` (100 iterations, tighter tolerance), ``network`` (constraints centred on the
a-priori intersections), and ``+`` combinations like ``noalt+cold``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np


def _bands(lat, err, edges=(-90, -60, -30, -10, 10, 30, 60, 90)):
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = (lat >= a) & (lat < b) if b < 90 else (lat >= a)
        out.append({"lat_min": a, "lat_max": b, "n": int(m.sum()),
                    "mean_m": float(np.mean(err[m])) if m.any() else None,
                    "rms_m": float(np.sqrt(np.mean(err[m] ** 2))) if m.any() else None})
    return out


def evaluate(xyz, truth, surface, lmax=4):
    """Height error of points against the true surface below them (what a DEM gridded from them
    sees): overall, per band, per SH degree; and the distance to their true positions."""
    from mercury_dem.dem.accuracy import low_degree_shape

    ok = np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(truth), axis=1)
    x, t = xyz[ok], truth[ok]
    r = np.linalg.norm(x, axis=1)
    plat = np.degrees(np.arcsin(x[:, 2] / r))
    plon = np.degrees(np.arctan2(x[:, 1], x[:, 0])) % 360
    h_true = surface.height(plat, plon)
    err = r - 2439400.0 - h_true
    horiz = np.linalg.norm(x / np.linalg.norm(x, axis=1)[:, None] - t / np.linalg.norm(t, axis=1)[:, None], axis=1) * 2439400.0
    lat = np.degrees(np.arcsin(t[:, 2] / np.linalg.norm(t, axis=1)))
    lon = np.degrees(np.arctan2(t[:, 1], t[:, 0])) % 360
    # Robust: drop gross points (|err| > 5 km) from the shape fit, count them.
    good = np.abs(err) < 5000
    shape = low_degree_shape(err[good], lat[good], lon[good], np.ones(good.sum()), lmax)
    # How much of the true height the points lose toward the datum: err ~ a + k h_true.
    k, a = np.polyfit(h_true[good], err[good], 1)
    return {
        "n": int(ok.sum()), "gross": int((~good).sum()),
        "mean_m": float(err[good].mean()), "rms_m": float(np.sqrt(np.mean(err[good] ** 2))),
        "median_abs_m": float(np.median(np.abs(err))), "horizontal_median_m": float(np.median(horiz)),
        "bands": _bands(lat[good], err[good]),
        "slope_vs_true_height": float(k), "mean_true_height_m": float(h_true[good].mean()),
        "degree_rms_m": shape["degree_rms_m"], "zonal_m": shape["zonal_m"],
    }


def dem_proxy(xyz, truth_dem, dem_cfg, datum_radius_m):
    """Grid the points as the DEM stage does (its gridding and smoothing), on the truth DEM's grid,
    and compare (:func:`mercury_dem.dem.accuracy.dem_accuracy`, area-weighted)."""
    from mercury_dem.dem.accuracy import dem_accuracy
    from mercury_dem.dem.grid import GridSpec, build_point_index, grid_chunk

    ppd = float(truth_dem.attrs["ppd"])
    cfg = dataclasses.replace(dem_cfg, pixels_per_degree=ppd)
    n_lat, n_lon = truth_dem.shape
    lat_max, lon_min = float(truth_dem.attrs["lat_max"]), float(truth_dem.attrs["lon_min"])
    grid = GridSpec(ppd, lat_max - n_lat / ppd, lat_max, lon_min, lon_min + n_lon / ppd, datum_radius_m=datum_radius_m)
    ok = np.all(np.isfinite(xyz), axis=1)
    index = build_point_index(xyz[ok], datum_radius_m)
    nr, nc = grid.shape
    elev = grid_chunk(index, grid, (0, nr, 0, nc), cfg)["elevation"]
    lat, lon = grid.lat_centres(np.arange(nr)), grid.lon_centres(np.arange(nc))
    t = np.asarray(truth_dem.values, np.float64)
    assert t.shape == elev.shape and np.allclose(truth_dem.lat.values, lat), "truth grid differs"
    acc = dem_accuracy(elev, lat, lon, lambda la, lo: t)
    return {"bias_m": acc["bias_m"], "rmse_m": acc["rmse_m"],
            "bands": [(b["lat_min"], b["bias_m"]) for b in acc["error_vs_latitude"]],
            "degree_rms_m": acc["low_degree"]["degree_rms_m"] if acc["low_degree"] else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--variants", nargs="+", default=["stored", "base", "noalt", "cold", "r1km", "pos"])
    ap.add_argument("--json")
    args = ap.parse_args(argv)

    from mercury_dem.adjust.unit import adjust_unit_network
    from mercury_dem.altimetry.unit_terms import AltimetryTerms
    from mercury_dem.config import Config
    from mercury_dem.config.base import from_dict
    from mercury_dem.io.network_store import read_network
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.mission.store import open_mission
    from mercury_dem.network.merge import merge_networks
    from mercury_dem.pipeline.stages import pointing_sigma_urad_for, reconcile_solutions, unit_altimetry
    from mercury_dem.validate.run import per_image_pointing, true_point_positions

    store = RunStore(args.run)
    run = store.read_run()
    config = from_dict(Config, run["config"])
    mission = open_mission(run["mission"])
    kids = [0, 1]
    nets = []
    for c in kids:
        net = read_network(store.network_path("hemisphere", c))
        nets.append(net)
    hemi_nets = list(nets)
    nets = [n.replace(measure_rejected=np.zeros_like(n.measure_rejected),
                      point_rejected=np.zeros_like(n.point_rejected)) for n in nets]
    merged = merge_networks(nets, tolerance_px=config.network.merge_tolerance_px).network.drop_unused_images()
    ids = [str(x) for x in merged.image_ids]
    cameras = [mission.camera(i) for i in ids]
    positions = np.array([mission.a_priori_pose(i)[0] for i in ids]).reshape(-1, 3)
    rotations = np.array([mission.a_priori_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    start_rot, _ = reconcile_solutions(store, "hemisphere", kids, ids, rotations, positions)
    base_cfg = config.adjust
    sigma_urad = pointing_sigma_urad_for(mission, config)
    shots = unit_altimetry(mission, merged, "global", base_cfg)
    surface = mission.need_truth().surface()
    truth_dem = mission.need_truth().dem()
    truth_c = np.array([mission.need_truth().true_pose(i)[0] for i in ids]).reshape(-1, 3)
    results = {}
    for variant in args.variants:
        t0 = time.perf_counter()
        parts = set(variant.split("+"))
        if "stored" in parts:
            net = read_network(store.network_path("global", 0))
            pts = np.flatnonzero(~net.point_rejected)
            xyz = net.adjusted_xyz[pts]
            truth = true_point_positions(net, mission, pts)
            results[variant] = evaluate(xyz, truth, surface)
            results[variant]["dem"] = dem_proxy(xyz, truth_dem, config.dem, mission.body.datum_radius_m)
            print(variant, json.dumps({k: v for k, v in results[variant].items() if k != "bands"}), flush=True)
            continue
        if "hemi" in parts:
            xyzs, truths = [], []
            for net in hemi_nets:
                pts = np.flatnonzero(~net.point_rejected)
                xyzs.append(net.adjusted_xyz[pts])
                truths.append(true_point_positions(net, mission, pts))
            results[variant] = evaluate(np.concatenate(xyzs), np.concatenate(truths), surface)
            print(variant, json.dumps({k: v for k, v in results[variant].items() if k != "bands"}), flush=True)
            continue
        cfg = base_cfg
        pos = positions
        alt = None if "noalt" in parts else shots
        start = None if "cold" in parts else start_rot
        if "r1km" in parts:
            cfg = dataclasses.replace(cfg, radius_sigma_m=1000.0)
        if "r3km" in parts:
            cfg = dataclasses.replace(cfg, radius_sigma_m=3000.0)
        if "r100km" in parts:
            cfg = dataclasses.replace(cfg, radius_sigma_m=100000.0)
        if "rnone" in parts:
            cfg = dataclasses.replace(cfg, radius_sigma_m=None)
        if "pos" in parts:
            cfg = dataclasses.replace(cfg, solve_positions=True)
        if "truepos" in parts:
            pos = truth_c
        if "iter" in parts:
            cfg = dataclasses.replace(cfg, max_iterations=100, sigma0_tolerance=1e-8)
        if "network" in parts:
            cfg = dataclasses.replace(cfg, point_prior_center="network")
        adj = adjust_unit_network(merged, cameras, pos, rotations, cfg, pointing_sigma_urad=sigma_urad,
                                  initial_rotations=start, datum_radius_m=mission.body.datum_radius_m,
                                  heights=AltimetryTerms(alt), recentre_point_priors="recentre" in parts)
        net = adj.network
        pts = np.flatnonzero(~net.point_rejected)
        truth = true_point_positions(net, mission, pts)
        r = evaluate(net.adjusted_xyz[pts], truth, surface)
        pp = per_image_pointing(ids, adj.rotations, mission, adj.positions)
        r["summary"] = {k: adj.summary[k] for k in ("rms_px", "sigma0", "iterations", "converged", "reason")}
        r["pointing_px_rms"] = float(np.sqrt(np.nanmean(pp["adjusted_px"] ** 2)))
        r["seconds"] = time.perf_counter() - t0
        r["dem"] = dem_proxy(net.adjusted_xyz[pts], truth_dem, config.dem, mission.body.datum_radius_m)
        results[variant] = r
        print(variant, json.dumps({k: v for k, v in r.items() if k != "bands"}), flush=True)
    for v, r in results.items():
        print(f"{v:>16}: mean {r['mean_m']:7.0f} rms {r['rms_m']:6.0f} | "
              + " ".join(f"{b['mean_m']:6.0f}" if b["mean_m"] is not None else "     -" for b in r["bands"])
              + " | deg " + " ".join(f"{d:5.0f}" for d in r["degree_rms_m"])
              + f" | k {r['slope_vs_true_height']:+.3f} px {r.get('pointing_px_rms', float('nan')):.3f}")
        if r.get("dem"):
            d = r["dem"]
            print(f"{'DEM':>16}: bias {d['bias_m']:7.0f} rmse {d['rmse_m']:6.0f} | "
                  + " ".join(f"{b:6.0f}" if b is not None else "     -" for _, b in d["bands"]) + " | deg "
                  + " ".join(f"{x:5.0f}" for x in (d["degree_rms_m"] or [])))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
