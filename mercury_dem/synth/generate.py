"""Generating a synthetic mission on disk: plan, a-priori errors, rendering, truth, store.

:func:`generate_mission` is the stage runner behind ``mercury-dem synth``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.compute.client import ComputeClient
from mercury_dem.config.synth import SynthConfig
from mercury_dem.exceptions import ConfigError, StoreError
from mercury_dem.geometry.body import Body, body_by_name
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.mission.store import MissionWriter
from mercury_dem.mission.truth import dem_axes, write_truth_dem, write_truth_tables
from mercury_dem.synth.mission import catalog_from_poses, mission_cameras, perturb_poses, plan_mission, true_poses
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


def image_selection(spec: str | int | slice | None, n_images: int) -> NDArray[np.int64] | None:
    """Indices of the design's images to generate: None (all), ``N`` (the first N) or ``"A:B"`` (A..B-1).

    Raises ConfigError naming the selection and the design's image count when it
    selects nothing or is malformed.
    """
    if spec is None:
        return None
    if isinstance(spec, slice):
        sel = spec
    elif isinstance(spec, int) or (isinstance(spec, str) and ":" not in spec):
        try:
            sel = slice(0, int(spec))
        except ValueError:
            raise ConfigError(f"image selection {spec!r}: expected N or A:B (integers)") from None
    else:
        try:
            a, b = (int(x) if x.strip() else None for x in spec.split(":"))
        except ValueError:
            raise ConfigError(f"image selection {spec!r}: expected N or A:B (integers)") from None
        sel = slice(a, b)
    idx = np.arange(n_images)[sel]
    if idx.size == 0:
        raise ConfigError(f"image selection {spec!r} selects none of the design's {n_images} images")
    return idx


def generate_mission(
    out: str | Path,
    config: SynthConfig,
    tile_size_deg: float = 10.0,
    overwrite: bool = False,
    workers: int = 1,
    client: ComputeClient | None = None,
    design: MissionDesign | None = None,
    progress: Callable[[int, int], None] | None = None,
    scheduler: str | None = None,
    images: str | int | slice | None = None,
) -> dict[str, Any]:
    """Generate the synthetic mission of ``config.preset`` (or ``design``) at ``out``.

    Written atomically: built under a temporary name, renamed when complete. An
    existing ``out`` is refused unless ``overwrite``. Returns a summary dict
    (images, seconds, per-image render seconds).

    ``images`` (``N``, ``"A:B"`` or a slice) generates only those images of the
    design, through the same code path and with the same ids, poses, errors and
    noise as in the full mission (to test or time the ``large`` preset on a
    small machine). Such a mission is marked partial in ``mission.json``
    (``"partial": {...}``, ``n_images`` the images present, ``n_images_design``
    the full design's count) and its catalog and truth hold only those images.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise StoreError(f"{out} already exists; pass --overwrite to replace it (or choose another OUT)")
    t0 = time.perf_counter()
    design = design or get_preset(config.preset)
    if config.render_grid_px > 0:
        render = replace(design.render, grid_spacing_px=config.render_grid_px, surface_resolution_px=1.0)
        design = replace(design, render=render)
    params = replace(design.surface, seed=config.seed)
    body = body_by_name(config.body)
    if params.shape_harmonics and body.name != "MERCURY":
        raise ConfigError(f"the preset {design.name!r} takes its long wavelengths from Mercury's shape "
                          f"({params.shape_harmonics}); choose the tiny or large preset for the {body.name.title()}")
    radius = body.datum_radius_m
    plan = plan_mission(design, config.seed, radius)
    c_true, r_true = true_poses(plan)
    rng = np.random.default_rng([config.seed, 0xA991])
    c_apr, r_apr, omega = perturb_poses(c_true, r_true, config.pointing_sigma_urad, config.position_sigma_m, rng)
    catalog = catalog_from_poses(plan, c_apr, r_apr, tile_size_deg, body)
    truth = plan.copy()
    for k, ax in enumerate("xyz"):
        truth[f"pointing_error_{ax}_rad"] = omega[:, k]
        truth[f"position_error_{ax}_m"] = c_apr[:, k] - c_true[:, k]
    n_design = len(plan)
    plan = plan.assign(index=np.arange(n_design))
    idx = image_selection(images, n_design)
    if idx is not None:
        plan, catalog, truth = (t.iloc[idx].reset_index(drop=True) for t in (plan, catalog, truth))
    meta = {
        "source": "synthetic",
        "preset": design.name,
        "seed": config.seed,
        "pointing_sigma_urad": config.pointing_sigma_urad,
        "position_sigma_m": config.position_sigma_m,
        "tile_size_deg": tile_size_deg,
        "datum_radius_m": radius,
        "n_images_design": n_design,
        "image_size": design.samples,
        "area_deg": list(design.area_deg) if design.area_deg else None,
        # how the images were drawn (a mission written before session 20 has no key: the preset's 1-px grid)
        "render": asdict(design.render),
    }
    if idx is not None:
        meta["partial"] = {
            "images": [int(idx[0]), int(idx[-1]) + 1] if np.all(np.diff(idx) == 1) else idx.tolist(),
            "n_images": int(idx.size),
            "n_images_design": n_design,
            "note": f"PARTIAL mission: {idx.size} of the {n_design} images of the {design.name!r} design "
                    "(coverage, tiles and statistics are those of the subset, not of the design)",
        }
    with atomic_directory(out, overwrite=overwrite) as tmp:
        writer = MissionWriter(tmp)
        timings = render_all(tmp, plan, params.to_dict(), radius, design.render, config.seed, workers=workers,
                             client=client, progress=progress, scheduler=scheduler)
        surface = cached_surface(params.to_dict(), radius)
        t_dem = time.perf_counter()
        height, lat_max, lon_min, ppd = truth_dem_grid(surface, design)
        write_truth_dem(tmp, height, lat_max, lon_min, ppd, radius)
        t_dem = time.perf_counter() - t_dem
        write_truth_tables(tmp, truth, {"params": params.to_dict(), "radius_m": radius,
                                        "factory": "mercury_dem.synth.terrain:surface_from_dict"})
        alt_summary = None
        if design.altimetry is not None and design.altimetry.n_orbits > 0:
            alt_summary = write_simulated_altimetry(writer, tmp, design, surface, body, config.seed, tile_size_deg)
            meta["altimetry"] = alt_summary
        writer.finish(meta, body, mission_cameras(plan)[0], catalog)
    secs = np.array([s for _, s in timings])
    return {
        "path": str(out),
        "preset": design.name,
        "images": len(catalog),
        "images_design": n_design,
        "partial": idx is not None,
        "seconds": time.perf_counter() - t0,
        "render_seconds_median": float(np.median(secs)) if secs.size else 0.0,
        "render_seconds_total": float(secs.sum()),
        "truth_dem_seconds": t_dem,
        "truth_dem_shape": list(height.shape),
        "altimetry": alt_summary,
    }


def write_simulated_altimetry(writer: MissionWriter, root: Path, design: MissionDesign, surface: Surface, body: Body,
                              seed: int, tile_size_deg: float) -> dict[str, Any]:
    """Simulate the design's MLA profiles of the truth surface; write the shots (screened as an RDR reader
    would: flagged and off-body shots dropped and counted) into the mission's altimetry store and the injected
    per-profile orbit errors into ``truth/altimetry_profiles.parquet``. Returns counts and seconds.
    """
    from mercury_dem.altimetry.simulate import ORBIT_CONSTANTS, screen_shots, simulate_altimetry
    from mercury_dem.altimetry.store import ShotSource, combine_shots

    assert design.altimetry is not None
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 0xA171])  # its own stream: images and truth do not depend on it
    area = tuple(design.area_deg) if design.area_deg is not None else None
    gm, rotation_s = ORBIT_CONSTANTS[body.name]
    sim = simulate_altimetry(design.altimetry, surface.height, rng, datum_radius_m=body.datum_radius_m,
                             area_deg=area, gm=gm, rotation_period_s=rotation_s)  # type: ignore[arg-type]
    kept, dropped = screen_shots(sim.shots, body.datum_radius_m)
    n_profiles = int(kept["profile_id"].nunique()) if len(kept) else 0
    source = ShotSource(f"simulated MLA (seed {seed})", len(sim.shots), len(kept), n_profiles, dropped)
    writer.write_altimetry(combine_shots([kept], [source]), sources=[source], body=body, tile_size_deg=tile_size_deg,
                           extra={"simulation": design.altimetry.to_dict()})
    sim.profiles.to_parquet(Path(root) / "truth" / "altimetry_profiles.parquet", index=False)
    return {"n_shots": int(len(kept)), "n_simulated": int(len(sim.shots)), "n_profiles": n_profiles,
            "dropped": dropped, "seconds": time.perf_counter() - t0}
