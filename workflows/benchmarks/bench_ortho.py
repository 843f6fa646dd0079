"""Matching on DEM-orthorectified images against the datum pre-transform (issue 21 item 2).

Each pair is matched twice or more: with today's datum-sphere pre-transform (``match_tile``, one
pair, no track propagation) and with the DEM pre-transform of :mod:`mercury_dem.match.ortho` (the
partner resampled onto the base through a height model with ``cv2.remap``, matches mapped back
through the map), for several height models and map poses:

    truth_true     the true surface and the true poses (the upper bound)
    truth_adj      the true surface, poses with an adjusted-like pointing error (0.3 px per axis)
    truth_apriori  the true surface, the a-priori poses
    sphere_remap   the datum sphere and a-priori poses through the same path (remap, identity geometry, edge
                   cut, no dense flow): the control that isolates what the surface changes
    rundem_adj / rundem_apriori   a run's dem.zarr (``dem=PATH``: the first pass's DEM)
    lpK_adj / lpK_true   the true surface Gaussian-low-passed with sigma K km on a local lat/lon grid
                   (RMSE against the truth printed), adjusted-like / true poses

True errors are split along / across the epipolar line (``true_error_components``) and summarized
per convergence band. Scenes: ``scene`` (``validate.matching.convergent_views``: nadir vs 30 / 50 /
65 deg, surface seeds 42 and 11, both pair orders; renderer options ``lambert=1 quiet=1``) or
``mission PATH N`` (N seeded similar-illumination pairs of a synthetic mission).

Run (accuracy only; deterministic; a few minutes):
    STRIDE=1 .venv/bin/python workflows/benchmarks/bench_ortho.py scene variants=truth_true,lp2_adj
    STRIDE=1 .venv/bin/python workflows/benchmarks/bench_ortho.py mission MISSION 24 variants=truth_true,truth_adj,lp2_adj
    STRIDE=1 .venv/bin/python workflows/benchmarks/bench_ortho.py mission MISSION 24 dem=RUN/dem.zarr \
        variants=truth_true,rundem_adj,rundem_apriori   # the run's own (first-pass) DEM
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import gaussian_filter

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M, xyz_to_latlon
from mercury_dem.geometry.pose import image_to_ground, rotation_from_angles
from mercury_dem.match import ImageGeometry, match_tile
from mercury_dem.match.ortho import match_pair_on_surface
from mercury_dem.match.pretransform import pair_geometry
from mercury_dem.validate.matching import TruePose, illumination_class, true_error_components

CFG = MatchConfig(threads=2)
STRIDE = int(os.environ.get("STRIDE", "1"))
VARIANTS: dict[str, tuple[Any, Any]] = {
    "truth_true": ("truth", "true"),
    "truth_adj": ("truth", 0.3),
    "truth_apriori": ("truth", "apriori"),
    "lp0.5_true": (500.0, "true"),
    "lp1_true": (1000.0, "true"),
    "lp2_true": (2000.0, "true"),
    "lp2_adj": (2000.0, 0.3),
    "lp5_adj": (5000.0, 0.3),
    "rundem_adj": ("run", 0.3),
    "sphere_remap": ("sphere", "apriori"),
    "rundem_apriori": ("run", "apriori"),
}
RUN_DEM: list[Any] = []  # the height function of dem=PATH (a run's dem.zarr), set by main


def run_dem_height(path: str) -> Any:
    """A run's ``dem.zarr`` (elevation above the datum on a lat/lon grid) as a height function; the datum
    (0 m) where the grid has no value or outside it.
    """
    import xarray as xr

    d = xr.open_zarr(path, consolidated=False)
    lat = np.asarray(d["lat"].values, float)
    lon = np.asarray(d["lon"].values, float)
    elev = np.asarray(d["elevation"].values, float)
    if lat[0] > lat[-1]:
        lat, elev = lat[::-1], elev[::-1]
    elev = np.where(np.isfinite(elev), elev, 0.0)
    f = RegularGridInterpolator((lat, lon), elev, bounds_error=False, fill_value=0.0)
    lon0 = float(lon[0])

    def fn(lat_: Any, lon_: Any) -> Any:
        lat_ = np.asarray(lat_, float)
        lo = (np.asarray(lon_, float) - lon0) % 360.0 + lon0
        return f(np.stack([lat_.ravel(), lo.ravel()], -1)).reshape(lat_.shape)

    return fn



def lowpass_height(height: Any, g: ImageGeometry, sigma_m: float, margin_px: float = 40.0) -> tuple[Any, float, float]:
    """The truth sampled on a local lat/lon grid over the base footprint and Gaussian-low-passed.

    Returns (height function, RMSE of the low-pass against the truth at the grid nodes, truth's std there).
    """
    cam = g.camera
    ss, ll = np.meshgrid(np.linspace(-margin_px, cam.samples + margin_px, 9), np.linspace(-margin_px, cam.lines + margin_px, 9))
    gr, hit = image_to_ground(cam, g.position, g.rotation, np.stack([ss.ravel(), ll.ravel()], -1), datum_radius_m=DATUM_RADIUS_M)
    lat, lon, _ = xyz_to_latlon(gr[hit], datum_radius_m=DATUM_RADIUS_M)
    lon = np.where(lon > 180, lon - 360, lon)
    spacing = min(sigma_m / 3.0, 600.0)
    dlat = spacing / (np.radians(1.0) * 2439.4e3)
    la = np.arange(lat.min() - 0.5, lat.max() + 0.5, dlat)
    lo = np.arange(lon.min() - 0.5, lon.max() + 0.5, dlat / max(np.cos(np.radians(np.abs(la).max())), 0.2))
    grid_la, grid_lo = np.meshgrid(la, lo, indexing="ij")
    h = height(grid_la, grid_lo)
    hl = gaussian_filter(h, sigma_m / spacing, mode="nearest")
    f = RegularGridInterpolator((la, lo), hl, bounds_error=False, fill_value=None)

    def fn(lat_: Any, lon_: Any) -> Any:
        lat_ = np.asarray(lat_, float)
        lon_ = np.where(np.asarray(lon_, float) > 180, np.asarray(lon_, float) - 360, lon_)
        return f(np.stack([lat_.ravel(), lon_.ravel()], -1)).reshape(lat_.shape)

    return fn, float(np.sqrt(np.mean((hl - h) ** 2))), float(h.std())


def _errors(pair: tuple[str, str], pa: np.ndarray, pb: np.ndarray, truth: Any, height: Any) -> tuple[np.ndarray, np.ndarray]:
    ids = list(pair)
    ia, ib = np.zeros(len(pa), np.int64), np.ones(len(pa), np.int64)
    return true_error_components(ids, ia, ib, pa, pb, truth, height, datum_radius_m=DATUM_RADIUS_M)


def run_pairs(images: Any, geom: Any, truth: Any, pairs: Any, height_true: Any, variants: Any, tag: str) -> list[Any]:
    """Match every pair with the sphere and each variant; print one line per pair; rows for :func:`summary`."""
    rows = []
    for a, b in pairs:
        t0 = time.time()
        m, reps = match_tile({a: images[a], b: images[b]}, geom, [(a, b)], CFG, tracks=False, pointing_sigma_urad=450.0)
        rep = reps[0]
        pa, pb = np.stack([m.sample_a, m.line_a], -1), np.stack([m.sample_b, m.line_b], -1)
        cls = illumination_class(abs(rep.incidence_ref_deg - rep.incidence_match_deg), rep.sun_azimuth_difference_deg)
        res: dict[str, Any] = {"sphere": _errors((a, b), pa, pb, truth, height_true)}
        rmse: dict[str, tuple[float, float]] = {}
        for name in variants:
            hspec, poses = VARIANTS[name]
            if hspec == "truth":
                h = height_true
            elif hspec == "run":
                h = RUN_DEM[0]
            elif hspec == "sphere":
                h = None
            else:
                h, r, s = lowpass_height(height_true, geom[a], hspec)
                rmse[name] = (r, s)
            if poses == "true":
                mg = {k: ImageGeometry.of(truth[k].camera, truth[k].position, truth[k].rotation, geom[k].sun_position, datum_radius_m=DATUM_RADIUS_M) for k in (a, b)}
            elif poses == "apriori":
                mg = geom
            else:
                rng = np.random.default_rng(sum(map(ord, a + b)))
                mg = {k: ImageGeometry.of(truth[k].camera, truth[k].position,
                                          rotation_from_angles(rng.normal(0, poses * truth[k].camera.ifov_rad, 3)) @ truth[k].rotation,
                                          geom[k].sun_position, datum_radius_m=DATUM_RADIUS_M) for k in (a, b)}
            qa, qb = match_pair_on_surface(images, geom, mg, (a, b), h, CFG, stride=STRIDE, pointing_sigma_urad=450.0)
            res[name] = _errors((a, b), qa, qb, truth, height_true)
        line = f"{tag} {a}->{b} conv {rep.convergence_deg:5.1f} {cls:9s}"
        for k, (al, ac) in res.items():
            e = np.hypot(al, ac)
            line += (f" | {k}: n {len(e)} p95 {np.nanpercentile(e, 95):.3f} along {np.nanmedian(al):+.3f}" if len(e)
                     else f" | {k}: n 0")
        if rmse:
            line += " | DEM rmse/relief std m " + " ".join(f"{k}={v[0]:.0f}/{v[1]:.0f}" for k, v in rmse.items())
        print(line + f" ({time.time() - t0:.0f}s)", flush=True)
        rows.append((rep.convergence_deg, cls, res))
    return rows


def summary(rows: Any, names: Any, bands: Any = ((0, 20), (20, 40), (40, 60), (60, 180))) -> None:
    """Markdown table of the true errors per convergence band and variant."""
    print("\n| convergence deg | pairs | variant | measures | median px | p95 px | along-line median px | across p95 px | > 2 px |")
    print("|---|---|---|---|---|---|---|---|---|")
    for lo, hi in [*bands, (0, 180)]:
        sel = [r for r in rows if lo <= r[0] < hi]
        if not sel:
            continue
        for k in names:
            al = np.concatenate([r[2][k][0] for r in sel])
            ac = np.concatenate([r[2][k][1] for r in sel])
            e = np.hypot(al, ac)
            f = np.isfinite(e)
            if not f.any():
                continue
            print(f"| {lo}-{hi if hi < 180 else '+'} | {len(sel)} | {k} | {f.sum()} | {np.median(e[f]):.3f} | "
                  f"{np.percentile(e[f], 95):.3f} | {np.median(al[f]):+.3f} | {np.percentile(ac[f], 95):.3f} | "
                  f"{100 * np.mean(e[f] > 2):.2f} % |", flush=True)


def main() -> None:
    """Command line: ``scene [lambert=1] [quiet=1]`` or ``mission PATH N``, ``variants=a,b``."""
    args = sys.argv[1:]
    opts = dict(x.split("=", 1) for x in args if "=" in x)
    pos = [x for x in args if "=" not in x]
    variants = opts.get("variants", "truth_true,lp2_adj").split(",")
    if "dem" in opts:
        RUN_DEM.append(run_dem_height(opts["dem"]))
    if pos[0] == "scene":
        from mercury_dem.synth.render import RenderSettings
        from mercury_dem.synth.terrain import Surface, SurfaceParams
        from mercury_dem.validate.matching import convergent_views

        kw: dict[str, Any] = {}
        if opts.get("lambert") == "1":
            kw["lambert_weight"] = 1.0
        if opts.get("quiet") == "1":
            kw.update(gain_e_per_dn=1e6, read_noise_dn=0.0)
        rows = []
        for sseed in (42, 11):
            base = Surface(SurfaceParams(seed=sseed))
            for em in (30, 50, 65):
                images, geom, truth = convergent_views(base, (0.0, float(em)), np.random.default_rng(7),
                                                       RenderSettings(**kw) if kw else None)
                for pair in (("v0", "v1"), ("v1", "v0")):
                    rows += run_pairs(images, geom, truth, [pair], base.height, variants, f"surface {sseed} emission {em}")
        summary(rows, ["sphere", *variants], bands=((0, 40), (40, 60), (60, 90)))
        return
    from harness.scenarios import a_priori_overlaps

    from mercury_dem.mission import open_mission

    path, n_pairs = pos[1], int(pos[2])
    ms = open_mission(path)
    ids, cams, p, r, overlaps = a_priori_overlaps(ms)
    geom = {i: ImageGeometry.of(c, pp, rr, ms.sun_position(i), datum_radius_m=DATUM_RADIUS_M) for i, c, pp, rr in zip(ids, cams, p, r)}
    similar = []
    for a, b in overlaps:
        pg = pair_geometry(geom[a], geom[b])
        if not isinstance(pg, str) and illumination_class(
                abs(pg.incidence_ref_deg - pg.incidence_match_deg), pg.sun_azimuth_difference_deg) == "similar":
            similar.append((a, b))
    pick = sorted(np.random.default_rng(1).permutation(len(similar))[:n_pairs])
    sel = [similar[k] for k in pick]
    used = sorted({x for q in sel for x in q})
    images = {i: ms.read_image(i) for i in used}
    truth = {i: TruePose(ms.camera(i), *ms.need_truth().true_pose(i)) for i in used}
    print(f"{path}: {len(similar)} similar-illumination pairs, {len(sel)} sampled (seeded)", flush=True)
    rows = run_pairs(images, geom, truth, sel, ms.need_truth().surface().height, variants, os.path.basename(path))
    summary(rows, ["sphere", *variants])


if __name__ == "__main__":
    main()
