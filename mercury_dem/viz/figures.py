"""Static matplotlib figures of a run and its mission (for notebooks and reports).

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot
(no global figure state to close; Jupyter's inline backend displays it), from the
tables of :mod:`mercury_dem.viz`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle

from mercury_dem.io.run_store import RunStore
from mercury_dem.plan.tree import LEVELS
from mercury_dem.viz.status import STATE_COLOURS, STATES, as_store

LEVEL_COLOURS = {"tile": "#7f7f7f", "region": "#1f77b4", "hemisphere": "#ff7f0e", "global": "#2ca02c"}


def signed_lon(lon: Any) -> Any:
    """East longitude in [-180, 180) (maps of areas around 0 deg stay in one piece)."""
    return (np.asarray(lon, dtype=np.float64) + 180.0) % 360.0 - 180.0


def coverage_figure(mission: Mission, step_deg: float | None = None) -> Figure:
    """Number of images (a-priori pose) seeing each point of the mission's area."""
    from mercury_dem.mission.coverage import mission_coverage
    from mercury_dem.mission.summary import coverage_step_deg

    area = mission.meta.get("area_deg")
    step = step_deg or coverage_step_deg(len(mission.catalog))
    cov = mission_coverage(mission, step, tuple(area) if area else None)
    lat, lon, count = cov["lat"], cov["lon"], cov["count"]
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    m = ax.pcolormesh(lon, lat, count, shading="nearest", cmap="viridis")
    fig.colorbar(m, ax=ax, label="images seeing the point")
    cat = mission.catalog
    ax.plot(cat["center_lon"].to_numpy(), cat["center_lat"].to_numpy(), "w+", ms=5, label="image centres")
    ax.set(xlabel="east longitude (deg)", ylabel="latitude (deg)", title=f"coverage ({len(cat)} images)")
    ax.legend(loc="upper right", fontsize="small")
    return fig


def tile_status_figure(tiles: pd.DataFrame, title: str = "tiles") -> Figure:
    """The tiles of :func:`~mercury_dem.viz.status.tile_status` on a lat/lon map, coloured by state."""
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    lo0 = signed_lon(tiles["lon_min"].to_numpy())
    for t, a, b, la0, la1, s in zip(tiles["tile"], lo0, tiles["lon_max"] - tiles["lon_min"], tiles["lat_min"],
                                    tiles["lat_max"], tiles["state"]):
        ax.add_patch(Rectangle((a, la0), b, la1 - la0, facecolor=STATE_COLOURS[s], edgecolor="k", lw=0.5))
        ax.text(a + b / 2, (la0 + la1) / 2, str(t), ha="center", va="center", fontsize=7)
    if len(tiles):
        ax.set_xlim(lo0.min() - 5, (lo0 + tiles["lon_max"] - tiles["lon_min"]).max() + 5)
        ax.set_ylim(tiles["lat_min"].min() - 5, tiles["lat_max"].max() + 5)
    ax.set_aspect("equal")
    counts = tiles["state"].value_counts()
    ax.legend(handles=[Patch(facecolor=STATE_COLOURS[s], label=f"{s} ({counts.get(s, 0)})") for s in STATES],
              loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    ax.set(xlabel="east longitude (deg)", ylabel="latitude (deg)", title=title)
    return fig


def residual_histograms_figure(residuals: pd.DataFrame, bins: int = 40) -> Figure:
    """Histogram of the residual length (px) of the active measures, one panel per adjusted level."""
    levels = [lv for lv in LEVELS if lv in set(residuals["level"])]
    fig = Figure(figsize=(3.2 * max(len(levels), 1), 3.2), layout="constrained")
    axes = fig.subplots(1, max(len(levels), 1), squeeze=False)[0]
    finite = residuals.loc[residuals["active"].astype(bool), "residual_px"].to_numpy(dtype=float)
    top = float(np.nanpercentile(finite, 99.5)) if np.isfinite(finite).any() else 1.0
    edges = np.linspace(0.0, max(top, 1e-3), bins + 1)
    for ax, level in zip(axes, levels):
        r = residuals[(residuals["level"] == level) & residuals["active"]]["residual_px"].to_numpy(dtype=float)
        r = r[np.isfinite(r)]
        ax.hist(np.clip(r, 0, edges[-1]), bins=edges, color=LEVEL_COLOURS[level])
        rms = float(np.sqrt(np.mean(r * r))) if r.size else float("nan")
        ax.set_title(f"{level}\n{r.size} active measures, RMS {rms:.2f} px", fontsize="medium")
        ax.set_xlabel("residual length (px; last bin: beyond p99.5)")
        ax.set_yscale("log")
    axes[0].set_ylabel("measures")
    if not levels:
        axes[0].text(0.5, 0.5, "no adjusted network yet", ha="center", va="center", transform=axes[0].transAxes)
    return fig


def sigma0_figure(history: pd.DataFrame) -> Figure:
    """σ0 per iteration of every adjustment unit (from :func:`~mercury_dem.viz.status.sigma0_history`)."""
    fig = Figure(figsize=(6, 3.5), layout="constrained")
    ax = fig.add_subplot()
    for (level, _uid), g in history.groupby(["level", "id"], sort=False):
        ax.plot(g["iteration"], g["sigma0"], "o-", ms=3, color=LEVEL_COLOURS.get(str(level), "k"), alpha=0.8,
                label=str(g["name"].iloc[0]))
    ax.set(xlabel="iteration", ylabel="σ0", title="adjustment convergence")
    if len(history):
        ax.set_yscale("log")
        ax.legend(fontsize="x-small", ncol=2)
    return fig


def pointing_figure(errors: pd.DataFrame, goal_px: float = 0.5) -> Figure:
    """Pointing error per image vs truth, in each image's own pixels (its IFOV): a-priori against
    adjusted (log-log, coloured by the image's measures) with the goal line, and their histograms.

    Pixels, not angles: the twist about the boresight is part of the angle but moves the
    pixels of a narrow image very little, so the angle overstates what matters for mapping
    (``errors`` from :func:`mercury_dem.viz.pointing_errors`, which also has the angles).
    """
    fig = Figure(figsize=(10, 4), layout="constrained")
    a, b = fig.subplots(1, 2)
    x, y = errors["a_priori_px"].to_numpy(float), errors["adjusted_px"].to_numpy(float)
    sc = a.scatter(x, y, c=np.log10(np.maximum(errors["n_measures"].to_numpy(float), 1)), s=14, cmap="viridis")
    fig.colorbar(sc, ax=a, label="log10 measures")
    both = np.concatenate([x, y])
    both = both[np.isfinite(both) & (both > 0)]
    lim = [max(float(both.min()) * 0.5, 1e-3), float(both.max()) * 2] if both.size else [1e-2, 1e2]
    a.plot(lim, lim, "k--", lw=0.8, label="no change")
    a.axhline(goal_px, color="r", lw=0.8, label=f"goal {goal_px:g} px")
    a.set(xscale="log", yscale="log", xlim=lim, ylim=lim, xlabel="a-priori error (px of the image)",
          ylabel="adjusted error (px of the image)", title="pointing error per image")
    a.legend(fontsize="small")
    edges = np.geomspace(lim[0], lim[1], 30)
    for v, name, c in ((x, "a-priori", "#999999"), (y, "adjusted", "#1f77b4")):
        v = v[np.isfinite(v)]
        rms = float(np.sqrt(np.mean(v * v))) if v.size else float("nan")
        b.hist(v, bins=edges, alpha=0.7, color=c, label=f"{name} (RMS {rms:.2f} px)")
    b.set(xscale="log", xlabel="pointing error (px of the image)", ylabel="images", title="before / after")
    b.legend(fontsize="small")
    return fig


def residual_map_figure(points: pd.DataFrame, images: pd.DataFrame | None = None, vmax: float | None = None) -> Figure:
    """RMS residual per point (dots) and per image (squares at the image centre), on a lat/lon map."""
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    p = points[points["n_active"] > 0]
    vals = p["rms_px"].to_numpy(float)
    vmax = vmax or (float(np.nanpercentile(vals, 98)) if vals.size else 1.0)
    m = ax.scatter(p["lon"], p["lat"], c=vals, s=2, cmap="magma_r", vmin=0, vmax=vmax)
    if images is not None and "lat" in images:
        im = images[images["n_active"] > 0]
        ax.scatter(im["lon"], im["lat"], c=im["rms_px"], s=60, marker="s", cmap="magma_r", vmin=0, vmax=vmax,
                   edgecolors="k", linewidths=0.6)
    fig.colorbar(m, ax=ax, label="RMS residual (px)")
    ax.set(xlabel="east longitude (deg)", ylabel="latitude (deg)",
           title=f"residuals: {len(p)} points" + (", squares: images" if images is not None else ""))
    return fig


def _dem(run: str | Path | RunStore) -> Any:
    from mercury_dem.products.make import open_dem

    return open_dem(as_store(run).dem_path)


def hillshade_figure(run: str | Path | RunStore, exaggeration: float | None = None) -> Figure:
    """The run's DEM as colour relief over a hillshade (gaps blank)."""
    from mercury_dem.products.browse import auto_exaggeration, hillshade
    from mercury_dem.products.make import dem_body

    ds = _dem(run)
    h = ds["elevation"].values.astype(np.float64)
    lat, lon = ds["lat"].values, ds["lon"].values
    radius = dem_body(ds).datum_radius_m
    ex = exaggeration or auto_exaggeration(h, lat, lon, radius_m=radius)
    shade = hillshade(h, lat, lon, exaggeration=ex, radius_m=radius)
    extent = (lon.min(), lon.max(), lat.min(), lat.max())
    origin = "upper" if lat[0] > lat[-1] else "lower"
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    ax.imshow(shade, cmap="gray", extent=extent, origin=origin, vmin=0, vmax=1)
    lo, hi = (np.nanpercentile(h, [2, 98]) / 1000.0) if np.isfinite(h).any() else (0.0, 1.0)
    m = ax.imshow(h / 1000.0, cmap="terrain", alpha=0.45, extent=extent, origin=origin, vmin=lo, vmax=hi)
    fig.colorbar(m, ax=ax, label="elevation (km above 2439.4 km; 2-98 % range)", extend="both")
    ax.set(xlabel="east longitude (deg)", ylabel="latitude (deg)",
           title=f"DEM hillshade (vertical exaggeration {ex:.0f}x)")
    return fig


def dem_error(run: str | Path | RunStore, mission: Mission) -> dict[str, Any]:
    """DEM minus the synthetic truth: lat, lon, error (m, NaN in gaps), distance_to_nearest_point (m)."""
    ds = _dem(run)
    lat, lon = ds["lat"].values, ds["lon"].values
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    truth = mission.need_truth().surface().height(la, np.mod(lo, 360.0))
    err = ds["elevation"].values.astype(np.float64) - truth
    dist = ds["distance_to_nearest_point"].values if "distance_to_nearest_point" in ds else np.full(err.shape, np.nan)
    return {"lat": lat, "lon": lon, "error": err, "distance_to_nearest_point": dist}


def dem_validation_figure(run: str | Path | RunStore, mission: Mission) -> Figure:
    """DEM minus truth: map, histogram, and error against the distance to the nearest control point."""
    d = dem_error(run, mission)
    err, lat, lon = d["error"], d["lat"], d["lon"]
    ok = np.isfinite(err)
    fig = Figure(figsize=(12, 3.8), layout="constrained")
    a, b, c = fig.subplots(1, 3)
    lim = float(np.nanpercentile(np.abs(err), 98)) if ok.any() else 1.0
    origin = "upper" if lat[0] > lat[-1] else "lower"
    m = a.imshow(err, cmap="RdBu_r", vmin=-lim, vmax=lim, origin=origin,
                 extent=(lon.min(), lon.max(), lat.min(), lat.max()))
    fig.colorbar(m, ax=a, label="DEM - truth (m)")
    a.set(title="height error", xlabel="east longitude (deg)", ylabel="latitude (deg)")
    e = err[ok]
    rmse = float(np.sqrt(np.mean(e * e))) if e.size else float("nan")
    b.hist(np.clip(e, -lim, lim), bins=50, color="#1f77b4")
    b.set(title=f"RMSE {rmse:.0f} m, bias {float(np.mean(e)) if e.size else float('nan'):.0f} m",
          xlabel="DEM - truth (m)", ylabel="pixels")
    dist = d["distance_to_nearest_point"][ok] / 1000.0
    c.scatter(dist, np.abs(e), s=2, alpha=0.3)
    c.set(xlabel="distance to nearest control point (km)", ylabel="|error| (m)", title="error vs data gap")
    return fig
