"""Reports of a bundle adjustment: a text report in the spirit of jigsaw's ``bundleout.txt``,
and tables of images, points and residuals.

The functions return strings and DataFrames; writing them to files is
:func:`mercury_dem.io.adjustment_report.write_adjustment_report`'s job.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import xyz_to_lat_lon


def images_table(result: AdjustmentResult) -> pd.DataFrame:
    """One row per image: corrections (rad, m), accepted measures, RMS, sigmas when computed."""
    w = result.pointing_corrections
    d = result.position_corrections
    df = pd.DataFrame({
        "image_id": list(result.image_ids),
        "omega_x_rad": w[:, 0], "omega_y_rad": w[:, 1], "omega_z_rad": w[:, 2],
        "dx_m": d[:, 0], "dy_m": d[:, 1], "dz_m": d[:, 2],
        "measures": np.bincount(result.measure_image, minlength=len(result.image_ids)),
        "accepted": result.accepted_per_image,
        "rms_px": result.rms_per_image,
        "weak": result.weak_images,
    })
    if result.image_sigmas is not None:
        names = ["sigma_omega_x_rad", "sigma_omega_y_rad", "sigma_omega_z_rad", "sigma_x_m", "sigma_y_m", "sigma_z_m"]
        for k in range(result.image_sigmas.shape[1]):
            df[names[k]] = result.image_sigmas[:, k]
    return df


def points_table(result: AdjustmentResult) -> pd.DataFrame:
    """One row per point: adjusted XYZ (m), lat/lon (deg, planetocentric east), radius (m), RMS."""
    p = result.points
    lat, lon = xyz_to_lat_lon(p)
    df = pd.DataFrame({
        "point_id": result.point_ids,
        "x_m": p[:, 0], "y_m": p[:, 1], "z_m": p[:, 2],
        "lat_deg": lat, "lon_deg": lon, "radius_m": np.linalg.norm(p, axis=1),
        "measures": np.bincount(result.measure_point, minlength=len(p)),
        "accepted": result.accepted_per_point,
        "rms_px": result.rms_per_point,
        "underdetermined": result.underdetermined_points,
    })
    if result.point_sigmas is not None:
        df["sigma_x_m"], df["sigma_y_m"], df["sigma_z_m"] = result.point_sigmas.T
    return df


def residuals_table(result: AdjustmentResult) -> pd.DataFrame:
    """One row per measure: point id, image id, residual (computed - measured) sample/line px, rejected."""
    ids = np.asarray(result.image_ids, dtype=object)
    r = result.residuals_px
    return pd.DataFrame({
        "point_id": result.point_ids[result.measure_point],
        "image_id": ids[result.measure_image],
        "residual_sample_px": r[:, 0],
        "residual_line_px": r[:, 1],
        "residual_px": np.hypot(r[:, 0], r[:, 1]),
        "rejected": result.rejected,
    })


def text_report(result: AdjustmentResult, config: AdjustConfig | None = None, title: str = "bundle adjustment", *,
                pointing_sigma_urad: float | None = None) -> str:
    """Human-readable summary: network, constraints, convergence, sigma0 per iteration, residual statistics,
    flagged images and points, worst images. ``pointing_sigma_urad``: the problem's a-priori pointing sigma
    (:attr:`~mercury_dem.adjust.problem.AdjustmentProblem.pointing_sigma_urad`), printed under CONSTRAINTS.
    """
    config = config or AdjustConfig()
    n_img, n_pt, m = len(result.image_ids), len(result.point_ids), result.n_measures
    lines = [
        f"MERCURY-DEM {title.upper()}",
        "=" * 60,
        "",
        "NETWORK",
        f"  images                      {n_img}",
        f"  points                      {n_pt}",
        f"  measures                    {m}",
        f"  rejected measures           {result.n_rejected} ({100.0 * result.n_rejected / max(m, 1):.2f} %)",
        f"  under-determined points     {int(result.underdetermined_points.sum())}",
        f"  weak images (< {config.min_image_measures} measures)   {int(result.weak_images.sum())}",
        f"  islands                     {len(result.diagnosis.islands)}",
        "",
        "CONSTRAINTS (1 sigma)",
        f"  pointing                    {'not stated' if pointing_sigma_urad is None else f'{pointing_sigma_urad:g} urad'}",
        f"  position                    {f'{config.position_sigma_m:g} m' if config.solve_positions else 'held (not solved)'}",
        f"  point lat/lon/radius        {config.point_latitude_sigma_m} / {config.point_longitude_sigma_m} / {config.radius_sigma_m} m",
        f"  robust loss                 {config.robust_loss} (scale {config.robust_scale:g} sigma)",
        f"  rejection                   {f'k = {config.reject_k_mad:g} x MAD' if config.reject_outliers else 'off'}",
        "",
        "SOLUTION",
        f"  converged                   {'yes' if result.converged else 'no'} ({result.reason})",
        f"  iterations                  {result.iterations}",
        f"  linear solver               {result.linear_method}",
        f"  sigma0                      {result.sigma0:.6f}",
        f"  degrees of freedom          {result.dof}",
        f"  RMS residual (px)           {result.rms_px:.4f}  (sample {result.rms_sample_px:.4f}, line {result.rms_line_px:.4f})",
        f"  a-priori RMS residual (px)  {result.initial_rms_px:.4f}",
        f"  seconds                     {result.seconds:.2f} (solve {result.solve_seconds:.2f}, a-posteriori sigmas {result.posterior_seconds:.2f})",
        "",
        "ITERATIONS",
        "  iter      sigma0        cost  rejected   seconds",
    ]
    for e in result.log:
        lines.append(f"  {e['iteration']:4d}  {e['sigma0']:10.6f}  {e['cost']:10.4g}  {e['rejected']:8d}  {e['seconds']:8.2f}")
    finite = np.isfinite(result.rms_per_image)
    if finite.any():
        worst = np.argsort(np.where(finite, result.rms_per_image, -1.0))[::-1][:10]
        lines += ["", "WORST IMAGES (RMS px)"]
        for i in worst:
            if finite[i]:
                lines.append(f"  {result.image_ids[i]:<24s} {result.rms_per_image[i]:8.4f}  ({result.accepted_per_image[i]} measures)")
    weak = np.flatnonzero(result.weak_images)
    if len(weak):
        lines += ["", "WEAK IMAGES", "  " + ", ".join(result.image_ids[i] for i in weak[:50]) + (" ..." if len(weak) > 50 else "")]
    und = np.flatnonzero(result.underdetermined_points)
    if len(und):
        lines += ["", "UNDER-DETERMINED POINTS (not adjusted)",
                  "  " + ", ".join(str(result.point_ids[i]) for i in und[:50]) + (" ..." if len(und) > 50 else "")]
    return "\n".join(lines) + "\n"
