"""Are the dense DEM's seams at the chip's epipolar parts? (issue 31; docs/benchmarks/dense.md "Seams").

A diagnostic, not a timing benchmark: for a finished run with a dense cloud, each pair's chips are split
again exactly as the dense stage split them (:func:`mercury_dem.dense.chip.rectify_split`, same inputs:
the adjusted geometry, the sparse surface, the tile's height margin), every left-image pixel gets the
label of the part that kept it, and the stored points' heights are compared:

* adjacent-pixel height steps |dh| across a part boundary against those within a part;
* with a truth (synthetic missions): each part's median error (a per-part offset), the error about it
  against the distance from the part's centre (0 centre .. 1 edge, Chebyshev), and the error against
  the part's own rectification error ``vertical_rms_px``;
* the error field's (or, without truth, the height minus a 24-px Gaussian's) correlation at lags along
  the rectified x (epipolar) and y directions: a seam or streak across the epipolar lines shows as a
  correlation along y much longer than along x.

    PYTHONPATH=. .venv/bin/python workflows/benchmarks/diag_dense_part_seams.py RUN [--tiles N] [--swap]

``--swap``: the pair with most points in the first tile is matched again in-process both ways (left/right, then
right/left: other reference pixels, other parts), both clouds binned on one lat/lon grid, and their
high-passed heights correlated: structure both directions give is fixed on the ground (relief, or a
systematic of the two images' geometry, or a matching error driven by the images' content: on tiny,
with truth, the two directions' errors correlate as well), not the reference image's columns or its parts.

RUN is a run directory (run.json, report.json, dense.zarr). Reads only.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from scipy import ndimage

from mercury_dem.config import Config
from mercury_dem.config.base import from_dict
from mercury_dem.dense.chip import chip_grid, dense_chip, rectify_split
from mercury_dem.io.run_store import RunStore
from mercury_dem.mission import open_mission
from mercury_dem.pipeline.dense_inputs import adjusted_geometry, matcher_of, open_sparse_surface


def lag_corr(e: np.ndarray, dx: int, dy: int) -> float:
    """Correlation of a NaN-holed field with itself shifted by (dx, dy) pixels."""
    m = np.isfinite(e)
    z = np.where(m, e - np.nanmean(e), 0.0)
    h, w = z.shape
    ys, xs = slice(max(0, -dy), h - max(0, dy)), slice(max(0, -dx), w - max(0, dx))
    yt, xt = slice(max(0, dy), h - max(0, -dy)), slice(max(0, dx), w - max(0, -dx))
    k = m[ys, xs] & m[yt, xt]
    return float(np.corrcoef(z[ys, xs][k], z[yt, xt][k])[0, 1]) if k.sum() > 100 else float("nan")


def high_pass(img: np.ndarray, sigma: float = 24.0) -> np.ndarray:
    """``img`` minus its NaN-aware Gaussian (the relief the sparse DEM also has removed)."""
    m = np.isfinite(img)
    w = ndimage.gaussian_filter(m.astype(float), sigma)
    v = ndimage.gaussian_filter(np.where(m, img, 0.0), sigma)
    return np.where(m, img - v / np.maximum(w, 1e-9), np.nan)


def nmad(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (NaN when empty)."""
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else float("nan")


def swap_check(mission: Any, geometry: Any, surface: Any, config: Config, row: dict[str, Any], margin: float,
               truth: Any = None) -> None:
    """Print how well the pair's two matching directions agree on the ground (module docstring, ``--swap``)."""
    d = config.dense
    settings, limits = matcher_of(config)
    clouds = []
    for a, b in ((row["left"], row["right"]), (row["right"], row["left"])):
        la, lb = (np.asarray(mission.read_image(i), np.float32) for i in (a, b))
        ga, gb = geometry[a], geometry[b]
        pts = []
        for chip in chip_grid(ga.camera.samples, ga.camera.lines, d.chip_size, d.chip_collar)[:d.max_chips_per_pair]:
            p = dense_chip(la, lb, ga, gb, chip, surface, margin, settings, limits, sigma_floor_px=d.sigma_floor_px,
                           max_vertical_px=d.max_vertical_px, min_chip_px=d.min_chip_px,
                           sigma_scale=d.sigma_scale).points
            keep = np.abs(p.height - surface(p.lat, p.lon)) <= d.max_height_offset_factor * margin
            err = p.height - truth(p.lat, p.lon) if truth is not None else np.full(len(p), np.nan)
            pts.append(np.c_[p.lat, p.lon, p.height, err][keep])
        clouds.append(np.concatenate(pts))
    n = 300
    lat0, lat1 = np.min(clouds[0][:, 0]), np.max(clouds[0][:, 0])
    lon0, lon1 = np.min(clouds[0][:, 1]), np.max(clouds[0][:, 1])
    def grid(c: np.ndarray, col: int) -> np.ndarray:
        i = np.rint((c[:, 0] - lat0) / (lat1 - lat0) * (n - 1)).astype(int)
        j = np.rint((c[:, 1] - lon0) / (lon1 - lon0) * (n - 1)).astype(int)
        k = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        total = np.bincount(i[k] * n + j[k], c[k, col], n * n)
        count = np.bincount(i[k] * n + j[k], None, n * n)
        return np.where(count > 0, total / np.maximum(count, 1), np.nan).reshape(n, n)

    print(f"swap: {row['left']} / {row['right']}, {len(clouds[0])} / {len(clouds[1])} points, one {n} x {n} "
          f"lat/lon grid ({(lat1 - lat0) / n:.4f} deg cells)")
    for col, what in ((2, "heights"), (3, "errors")) if truth is not None else ((2, "heights"),):
        for sigma in (24, 12, 6):
            hf, hs = high_pass(grid(clouds[0], col), sigma), high_pass(grid(clouds[1], col), sigma)
            k = np.isfinite(hf) & np.isfinite(hs)
            print(f"  {what} - gauss {sigma} cells: std {np.std(hf[k]):.0f} / {np.std(hs[k]):.0f} m, correlation "
                  f"{np.corrcoef(hf[k], hs[k])[0, 1]:.2f}, std of the difference {np.std(hf[k] - hs[k]):.0f} m")


def main(argv: list[str] | None = None) -> int:
    """Print the figures of the module docstring for one run."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--tiles", type=int, default=1000, help="at most this many tiles (sorted by name)")
    ap.add_argument("--swap", action="store_true", help="also match the first pair both ways (module docstring)")
    a = ap.parse_args(argv)
    run: Path = a.run
    config = from_dict(Config, json.loads((run / "run.json").read_text())["config"])
    report = json.loads((run / "report.json").read_text())
    margins = report["dense"]["height_margin_m"]["per_tile"]
    store = RunStore(run)
    mission = open_mission(store.read_run()["mission"])
    geometry = adjusted_geometry(store, mission)
    surface = open_sparse_surface(store.dem_path)
    truth = mission.truth.surface().height if mission.truth is not None else None
    d = config.dense
    cloud = zarr.open_group(str(run / "dense.zarr"), mode="r")
    if a.swap:
        first = sorted(cloud.group_keys())[0]
        g0 = cloud[first]
        table = dict(g0.attrs)["summary"]["pairs_table"]
        swap_check(mission, geometry, surface, config, max(table, key=lambda r: r["points"]),
                   float(margins[first.split("_")[1]]), truth)
    acc: dict[str, list[Any]] = {k: [] for k in ("across", "within", "offset", "nmad", "rn", "err", "vrms", "lags", "steps", "control")}
    lags = (2, 4, 8, 16, 32)
    for name in sorted(cloud.group_keys())[:a.tiles]:
        margin = float(margins[name.split("_")[1]])
        g = cloud[name]
        cols = {k: np.asarray(g[k][:]) for k in ("left_px", "height", "pair", "lat", "lon")}
        for row in dict(g.attrs)["summary"]["pairs_table"]:
            sel = cols["pair"] == row["pair"]
            if sel.sum() < 1000:
                continue
            left, right = geometry[row["left"]], geometry[row["right"]]
            li = np.asarray(mission.read_image(row["left"]), np.float32)
            ri = np.asarray(mission.read_image(row["right"]), np.float32)
            label = np.full(li.shape, -1, int)
            parts: list[Any] = []
            for chip in chip_grid(left.camera.samples, left.camera.lines, d.chip_size, d.chip_collar)[
                    :d.max_chips_per_pair]:
                try:
                    kept, _ = rectify_split(li, ri, left, right, chip, surface, margin, d.max_vertical_px,
                                            d.min_chip_px)
                except Exception:  # noqa: BLE001 - a chip the stage also failed: no points to label
                    continue
                for c, r in kept:
                    label[c.y0:c.y0 + c.height, c.x0:c.x0 + c.width] = len(parts)
                    parts.append((c, r))
            h = cols["height"][sel]
            err = h - truth(cols["lat"][sel], cols["lon"][sel]) if truth is not None else None
            ix = np.clip(np.rint(cols["left_px"][sel]).astype(int), 0, [li.shape[1] - 1, li.shape[0] - 1])
            field = np.full(li.shape, np.nan)
            field[ix[:, 1], ix[:, 0]] = err if err is not None else h
            for axis in (0, 1):
                dv = np.diff(field, axis=axis)
                edge = np.diff(label, axis=axis) != 0
                ok = np.isfinite(dv)
                acc["across"].append(np.abs(dv[ok & edge]))
                acc["within"].append(np.abs(dv[ok & ~edge]))
                # per boundary (two parts): the mean signed step from the lower label to the higher one
                la = label[:-1, :] if axis == 0 else label[:, :-1]
                lb = label[1:, :] if axis == 0 else label[:, 1:]
                k = ok & edge
                sign = np.where(la[k] < lb[k], 1.0, -1.0)
                key = np.minimum(la[k], lb[k]) * 100000 + np.maximum(la[k], lb[k]) + row["pair"] * 10**10
                acc["steps"].append((key, sign * dv[k]))
                # control: the same boundaries moved 5 px into the parts (a mean step there is the relief's slope)
                sh = np.roll(label, (5, 5), axis=(0, 1))
                sa = sh[:-1, :] if axis == 0 else sh[:, :-1]
                sb = sh[1:, :] if axis == 0 else sh[:, 1:]
                k = ok & (sa != sb) & ~edge
                sign = np.where(sa[k] < sb[k], 1.0, -1.0)
                key = np.minimum(sa[k], sb[k]) * 100000 + np.maximum(sa[k], sb[k]) + row["pair"] * 10**10
                acc["control"].append((key, sign * dv[k]))
            rect = parts[len(parts) // 2][1] if parts else None
            if rect is not None:
                ex, ey = rect.to_left[:2, 0], rect.to_left[:2, 1]
                e = field if err is not None else high_pass(field)
                acc["lags"].append([(lag_corr(e, *np.rint(ex * n).astype(int)), lag_corr(e, *np.rint(ey * n).astype(int)))
                                    for n in lags])
            if err is None:
                continue
            lab = label[ix[:, 1], ix[:, 0]]
            for k, (c, r) in enumerate(parts):
                s = lab == k
                if s.sum() < 50:
                    continue
                ee = err[s]
                med = float(np.median(ee))
                acc["offset"].append(med)
                acc["nmad"].append(nmad(ee))
                acc["vrms"].append(r.vertical_rms_px)
                acc["rn"].append(np.max(np.abs((ix[s] - c.centre) / [c.width / 2.0, c.height / 2.0]), axis=1))
                acc["err"].append(ee - med)
    if not acc["across"]:
        return 0  # --tiles 0: the swap check only
    across, within = np.concatenate(acc["across"]), np.concatenate(acc["within"])
    what = "error" if truth is not None else "height"
    print(f"adjacent-pixel |d {what}|: across a part boundary median {np.median(across):.1f} m (n {across.size}), "
          f"within a part {np.median(within):.1f} m (n {within.size})")
    for name, label_ in (("steps", "part boundaries"), ("control", "the same lines 5 px inside the parts")):
        keys = np.concatenate([k for k, _ in acc[name]])
        steps = np.concatenate([v for _, v in acc[name]])
        _, inv = np.unique(keys, return_inverse=True)
        n = np.bincount(inv)
        mean = np.bincount(inv, steps) / n
        sd = np.sqrt(np.maximum(np.bincount(inv, steps**2) / n - mean**2, 0.0))
        big = n >= 10
        print(f"{label_} (>= 10 adjacent pixel pairs each): {big.sum()}; mean signed step across each: RMS "
              f"{np.sqrt(np.mean(mean[big] ** 2)):.1f} m (noise of a mean "
              f"{np.sqrt(np.mean((sd[big] / np.sqrt(n[big])) ** 2)):.1f} m)")
    lag = np.nanmean(np.array(acc["lags"]), axis=0)
    print(f"{what}{'' if truth is not None else ' - gauss24'} correlation at lag (px) along rectified x / y: "
          + "; ".join(f"{n}: {x:.2f} / {y:.2f}" for n, (x, y) in zip(lags, lag)))
    if truth is not None:
        off, nm, vr = np.array(acc["offset"]), np.array(acc["nmad"]), np.array(acc["vrms"])
        print(f"parts (>= 50 points): {off.size}; per-part median error: std {off.std():.1f} m, NMAD {nmad(off):.1f} m; "
              f"error NMAD within a part (median over parts) {np.median(nm):.1f} m")
        rn, er = np.concatenate(acc["rn"]), np.concatenate(acc["err"])
        for lo, hi in ((0, .25), (.25, .5), (.5, .75), (.75, .9), (.9, 1.01)):
            s = (rn >= lo) & (rn < hi)
            print(f"  distance from the part's centre {lo:.2f}-{hi:.2f}: points {s.sum():8d}  error NMAD about the "
                  f"part's median {nmad(er[s]):.1f} m")
        for lo, hi in ((0, .06), (.06, .1), (.1, .2), (.2, np.inf)):
            s = (vr >= lo) & (vr < hi)
            if s.any():
                print(f"  part vertical_rms_px {lo:.2f}-{hi:.2f}: parts {s.sum():5d}  median error NMAD {np.median(nm[s]):.1f} m"
                      f"  median |offset - median| {np.median(np.abs(off[s] - np.median(off))):.1f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
