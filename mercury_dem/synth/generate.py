"""Generating a synthetic mission on disk: plan, a-priori errors, rendering, truth, store.

:func:`generate_mission` is the stage runner behind ``mercury-dem synth``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.config.synth import SynthConfig
from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.io.mission import dem_axes, init_store, write_tables, write_truth_dem
from mercury_dem.synth.mission import catalog_from_poses, perturb_poses, plan_mission, true_poses
from mercury_dem.synth.parallel import cached_surface, render_all
from mercury_dem.synth.presets import MissionDesign, get_preset
from mercury_dem.synth.terrain import Surface


def truth_dem_grid(surface: Surface, design: MissionDesign, rows_per_chunk: int = 256) -> tuple[np.ndarray, float, float, float]:
    """(height (n_lat, n_lon) float32, lat_max, lon_min, ppd) of the design's area (whole body if global)."""
    la0, la1, lo0, lo1 = design.area_deg if design.area_deg is not None else (-90.0, 90.0, 0.0, 360.0)
    ppd = design.truth_dem_ppd
    lat, lon = dem_axes(la0, la1, lo0, lo1, ppd)
    out = np.empty((lat.size, lon.size), np.float32)
    for i in range(0, lat.size, rows_per_chunk):
        la, lo = np.meshgrid(lat[i:i + rows_per_chunk], lon, indexing="ij")
        out[i:i + rows_per_chunk] = surface.height(la, lo)
    return out, la1, lo0, ppd


def generate_mission(
    out: str | Path,
    config: SynthConfig,
    tile_size_deg: float = 10.0,
    overwrite: bool = False,
    workers: int = 1,
    client: Any = None,
    design: MissionDesign | None = None,
    progress: Callable[[int, int], None] | None = None,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """Generate the synthetic mission of ``config.preset`` (or ``design``) at ``out``.

    Written atomically: built under a temporary name, renamed when complete. An
    existing ``out`` is refused unless ``overwrite``. Returns a summary dict
    (images, seconds, per-image render seconds).
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise StoreError(f"{out} already exists; pass --overwrite to replace it (or choose another OUT)")
    t0 = time.perf_counter()
    design = design or get_preset(config.preset)
    params = replace(design.surface, seed=config.seed)
    radius = DATUM_RADIUS_M
    plan = plan_mission(design, config.seed, radius)
    c_true, r_true = true_poses(plan)
    rng = np.random.default_rng([config.seed, 0xA991])
    c_apr, r_apr, omega = perturb_poses(c_true, r_true, config.pointing_sigma_urad * 1e-6, config.position_sigma_m, rng)
    catalog = catalog_from_poses(plan, c_apr, r_apr, tile_size_deg, radius)
    truth = plan.copy()
    for k, ax in enumerate("xyz"):
        truth[f"pointing_error_{ax}_rad"] = omega[:, k]
        truth[f"position_error_{ax}_m"] = c_apr[:, k] - c_true[:, k]
    meta = {
        "preset": design.name,
        "seed": config.seed,
        "pointing_sigma_urad": config.pointing_sigma_urad,
        "position_sigma_m": config.position_sigma_m,
        "tile_size_deg": tile_size_deg,
        "datum_radius_m": radius,
        "n_images": len(catalog),
        "image_size": design.samples,
        "area_deg": list(design.area_deg) if design.area_deg else None,
    }
    with atomic_directory(out, overwrite=overwrite) as tmp:
        init_store(tmp)
        timings = render_all(tmp, plan, params.to_dict(), radius, design.render, config.seed, workers=workers,
                             client=client, progress=progress, scheduler=scheduler)
        surface = cached_surface(params.to_dict(), radius)
        t_dem = time.perf_counter()
        height, lat_max, lon_min, ppd = truth_dem_grid(surface, design)
        write_truth_dem(tmp, height, lat_max, lon_min, ppd, radius)
        t_dem = time.perf_counter() - t_dem
        write_tables(tmp, meta, catalog, truth, {"params": params.to_dict(), "radius_m": radius})
    secs = np.array([s for _, s in timings])
    return {
        "path": str(out),
        "preset": design.name,
        "images": len(catalog),
        "seconds": time.perf_counter() - t0,
        "render_seconds_median": float(np.median(secs)) if secs.size else 0.0,
        "render_seconds_total": float(secs.sum()),
        "truth_dem_seconds": t_dem,
        "truth_dem_shape": list(height.shape),
    }
