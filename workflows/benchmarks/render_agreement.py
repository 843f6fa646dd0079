"""How well two renderings of the same surface from the TRUE poses agree (issue 31, docs/design/dense.md).

A pair of the dense tests' scene (MDIS-WAC 256^2, a nadir view and a tilted view of lat 5, lon 3; the
truth ``Surface``), both images rendered without noise (no read noise, 1e6 e-/DN: only the 12-bit
quantisation is left) with the renderer variant under test, rectified about the TRUE surface and matched
with the dense chain (``dense_disparity``: SGBM + least-squares refinement). The error is the matcher's
disparity minus the truth's disparity (each rectified left pixel's ray intersected with the truth and
projected into the right image), per chip part: median, 1.4826 MAD, RMS and 95th percentile of |error|
of the refined points; the RMS where the truth's disparity gradient (the local stretch between the
views) is at most its median and in its top 10 %; and the same against the truth's disparity box-averaged over the 9-px refinement
window (what a window matcher can at best return where the disparity is curved).

The truth is the surface at ``--truth-res`` metres (default: the pair's finest pixel scale), the same for
every variant. Scenes (``--scene``): ``wac200`` nadir 200 m/px + 25 deg north (the tests' pair);
``wac200_300`` nadir 200 m/px + 30 deg west at 300 m/px; ``km2000`` / ``km2000_3000`` the same geometry at
2 km/px (and 3 km/px), ``km1500_3000`` 1.5 and 3 km/px (the views' own band limits differ by an
octave) over the tiny preset's surface (seed 42). Variants (``--variants``): names below, each a change of
the sessions <= 19 renderer (``OLD``); ``default`` is the renderer's current default.

No timings: not on the harness. Run (~1-3 min):
``.venv/bin/python workflows/benchmarks/render_agreement.py --scene wac200 km2000_3000``
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "dense"))

import dense_scene as ds  # noqa: E402

from mercury_dem.dense.disparity import MatcherSettings, dense_disparity  # noqa: E402
from mercury_dem.dense.rectify import Chip, rectify_chip  # noqa: E402
from mercury_dem.synth.presets import get_preset  # noqa: E402
from mercury_dem.synth.render import RenderSettings, render_image  # noqa: E402
from mercury_dem.synth.terrain import Surface, SurfaceParams  # noqa: E402

#: the refinement window (MatcherSettings.refine_window)
WINDOW = 9
NOISE_FREE = {"read_noise_dn": 0.0, "gain_e_per_dn": 1e6}
#: the base every variant changes: the renderer of sessions <= 19 (1-px grid, surface band-limited at the grid)
OLD = {"grid_spacing_px": 1.0, "surface_resolution_px": 0.0}
VARIANTS: dict[str, dict[str, Any]] = {
    "old": {},                                                        # grid 1 px, surface at the grid, ss 2
    "default": {"grid_spacing_px": RenderSettings().grid_spacing_px,  # the renderer's current default
                "surface_resolution_px": RenderSettings().surface_resolution_px},
    "grid0.5": {"grid_spacing_px": 0.5, "surface_resolution_px": 1.0},  # same band, finer grid
    "grid0.33": {"grid_spacing_px": 1 / 3, "surface_resolution_px": 1.0},
    "grid0.25": {"grid_spacing_px": 0.25, "surface_resolution_px": 1.0},
    "ss3": {"supersample": 3},
    "ss4": {"supersample": 4},
    "grid0.5_ss4": {"grid_spacing_px": 0.5, "surface_resolution_px": 1.0, "supersample": 4},
    "band2px": {"surface_resolution_px": 2.0},                       # same grid, band halved
    "band2px_grid0.5": {"surface_resolution_px": 2.0, "grid_spacing_px": 0.5},
    "psf0": {"psf_sigma_px": 0.0},
    "psf1": {"psf_sigma_px": 1.0},
    "shared_res": {"surface_resolution_m": -1.0},                    # -1: the pair's finest pixel scale
    "shared_res_grid0.5": {"surface_resolution_m": -1.0, "grid_spacing_px": 0.5},
    "noshadow": {"shadows": False},
}
SCENES = {
    "wac200": (200.0, {}, "default"),
    "wac200_300": (200.0, {"gsd_m": 300.0, "tilt_east_deg": -30.0, "tilt_north_deg": 0.0}, "default"),
    "km2000": (2000.0, {}, "tiny"),
    "km2000_3000": (2000.0, {"gsd_m": 3000.0, "tilt_east_deg": -30.0, "tilt_north_deg": 0.0}, "tiny"),
    "km1500_3000": (1500.0, {"gsd_m": 3000.0, "tilt_east_deg": -30.0, "tilt_north_deg": 0.0}, "tiny"),
}


def surface_of(kind: str) -> Surface:
    """The truth surface of seed 42: the tests' parameters (``default``) or the tiny preset's."""
    return Surface(SurfaceParams(seed=42) if kind == "default" else get_preset("tiny").surface)


def measure(surface: Surface, gsd: float, right_kw: dict[str, Any], settings: RenderSettings,
            truth_res: float, part: int, incidence: float) -> dict[str, float]:
    """Render the scene's pair with ``settings``, match it part by part, and the error figures (px)."""
    sun = ds.sun_at(incidence, 90.0)
    left = ds.view(0.0, sun, gsd_m=gsd)
    right = ds.view(sun=sun, **{"gsd_m": gsd, **right_kw}) if right_kw else ds.view(25.0, sun, gsd_m=gsd)
    rng = np.random.default_rng(3)
    imgs = [render_image(surface, g.camera, g.position, g.rotation, g.sun_position, rng, settings).astype(np.float32)
            for g in (left, right)]
    pair = ds.RenderedPair(surface, imgs[0], imgs[1], left, right, settings)
    pair.truth_height = lambda la, lo: np.asarray(surface.height(la, lo, truth_res))  # type: ignore[method-assign]
    errs, errw, vert, grad = [], [], [], []
    for y0 in range(16, 240, part):
        for x0 in range(16, 240, part):
            rect = rectify_chip(imgs[0], imgs[1], left, right, Chip(x0, y0, part, part, 16),
                                surface_height=pair.truth_height, height_margin_m=3.0 * gsd,
                                psf_sigma_px=0.6)
            dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                                 rect.disparity_max_px, MatcherSettings(min_score=0.8, max_sigma_px=0.3))
            td, tv = ds.true_disparity(pair, rect)
            m = rect.interior_mask() & np.isfinite(dm.disparity)
            errs.append((dm.disparity - td)[m])
            errw.append((dm.disparity - uniform_filter(td, WINDOW, mode="nearest"))[m])
            vert.append(tv[m])
            gy, gx = np.gradient(td)
            grad.append(np.hypot(gx, gy)[m])
    e, ew, g = np.concatenate(errs), np.concatenate(errw), np.concatenate(grad)
    flat, steep = g <= np.median(g), g >= np.percentile(g, 90)
    med = float(np.median(e))
    return {"n": int(e.size), "median_px": med, "nmad_px": float(1.4826 * np.median(np.abs(e - med))),
            "rms_px": float(np.sqrt(np.mean(e**2))), "p95_abs_px": float(np.percentile(np.abs(e), 95)),
            "window_rms_px": float(np.sqrt(np.mean(ew**2))),
            "rms_flat_half_px": float(np.sqrt(np.mean(e[flat] ** 2))),
            "rms_steep_tenth_px": float(np.sqrt(np.mean(e[steep] ** 2))),
            "window_nmad_px": float(1.4826 * np.median(np.abs(ew - np.median(ew)))),
            "truth_vertical_rms_px": float(np.sqrt(np.mean(np.concatenate(vert) ** 2)))}


def main() -> None:
    """Every scene x variant: one line each (and ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", nargs="+", default=["wac200"], choices=sorted(SCENES))
    ap.add_argument("--variants", nargs="+", default=["old", "grid0.5", "grid0.33", "ss4", "band2px", "psf0",
                                                       "shared_res"], choices=sorted(VARIANTS))
    ap.add_argument("--lambert", type=float, default=1.0, help="lambert_weight (1: Lambert, as the tests' floor)")
    ap.add_argument("--truth-res", type=float, default=0.0, help="truth resolution, m (0: the finest pixel scale)")
    ap.add_argument("--part", type=int, default=112, help="chip part size, px (the interior is 224^2)")
    ap.add_argument("--incidence", type=float, default=45.0)
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    out = []
    surfaces: dict[str, Surface] = {}
    for scene in a.scene:
        gsd, right_kw, kind = SCENES[scene]
        surface = surfaces.setdefault(kind, surface_of(kind))
        finest = min(gsd, right_kw.get("gsd_m", gsd))
        truth_res = a.truth_res or finest
        for name in a.variants:
            kw = dict(VARIANTS[name])
            if kw.get("surface_resolution_m") == -1.0:
                kw["surface_resolution_m"] = finest
            st = replace(RenderSettings(lambert_weight=a.lambert, **NOISE_FREE, **OLD), **kw)
            r = measure(surface, gsd, right_kw, st, truth_res, a.part, a.incidence)
            r.update(scene=scene, variant=name, truth_res_m=truth_res, lambert_weight=a.lambert)
            out.append(r)
            print(f"{scene:12s} {name:20s} n={r['n']:6d} median {r['median_px']:+.3f}  nmad {r['nmad_px']:.3f}  "
                  f"rms {r['rms_px']:.3f}  p95 {r['p95_abs_px']:.3f} | vs 9-px box of the truth: nmad "
                  f"{r['window_nmad_px']:.3f} rms {r['window_rms_px']:.3f} | rms where |grad d| <= median "
                  f"{r['rms_flat_half_px']:.3f}, in its top 10 % {r['rms_steep_tenth_px']:.3f} (truth vertical {r['truth_vertical_rms_px']:.3f} px)", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
