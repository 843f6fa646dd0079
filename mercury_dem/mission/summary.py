"""Summary of a mission (``mercury-dem info``): counts, ranges, images per tile, coverage, coverage map,
and per image its footprint statistics (the quantities of ISIS's ``CameraStatistics``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.mission.coverage import mission_coverage


def coverage_step_deg(n_images: int) -> float:
    """Grid step for the coverage count: finer for small missions, bounded work for large ones."""
    return 0.5 if n_images <= 100 else 1.0 if n_images <= 2000 else 2.0


def data_area(mission: Mission) -> tuple[float, float, float, float] | None:
    """The catalog's footprint extent (degrees, padded by 10 %), or None when unknown or near global."""
    cat = mission.catalog
    cols = ["footprint_lat_min", "footprint_lat_max", "footprint_lon_min", "footprint_lon_max"]
    if not all(c in cat for c in cols) or not np.all(np.isfinite(cat[cols].to_numpy())):
        return None
    la0, la1 = float(cat[cols[0]].min()), float(cat[cols[1]].max())
    lons = cat[cols[2:]].to_numpy()
    lo0, lo1 = float(lons[:, 0].min()), float(lons[:, 1].max())
    if lo1 - lo0 > 180.0 or la1 - la0 > 90.0:
        return None
    pad_la, pad_lo = 0.1 * (la1 - la0) + 1e-3, 0.1 * (lo1 - lo0) + 1e-3
    return (max(-90.0, la0 - pad_la), min(90.0, la1 + pad_la), lo0 - pad_lo, lo1 + pad_lo)


def image_statistics(mission: Mission, radius_m: float | None = None, step: int = 1) -> dict[str, Any]:
    """Per image: :func:`~mercury_dem.mission.catalog.footprint_statistics` on a sphere (default: the datum)."""
    from mercury_dem.mission.catalog import footprint_statistics

    r = mission.body.datum_radius_m if radius_m is None else float(radius_m)
    out = {}
    for image_id in mission.image_ids:
        c, rot = mission.a_priori_pose(image_id)
        sun = mission.sun_position(image_id)
        out[image_id] = footprint_statistics(mission.camera(image_id), c, rot, sun if np.all(np.isfinite(sun)) else None,
                                             r, step)
    return {"radius_m": r, "pixel_step": step, "images": out}


def mission_summary(mission: Mission, step_deg: float | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(summary dict, coverage arrays) of a mission. Coverage is over the mission's area: the design's,
    else the images' footprints when they are regional, else the whole body."""
    cat = mission.catalog
    area = mission.meta.get("area_deg") or data_area(mission)
    if step_deg is None and area is not None and mission.meta.get("area_deg") is None:
        step = max(1e-3, min(area[1] - area[0], area[3] - area[2]) / 100.0)
    else:
        step = step_deg or coverage_step_deg(len(cat))
    cov = mission_coverage(mission, step, tuple(area) if area else None)
    w = np.cos(np.radians(cov["lat"]))
    count = cov["count"]
    stereo = (count >= 3) & (cov["convergence_deg"] >= 5.0)

    def frac(mask: np.ndarray) -> float:
        return float(np.sum(w * mask) / np.sum(w))

    per_tile = cat.groupby("tile_id").size()
    summary = {
        "mission": str(mission.path),
        "preset": mission.meta.get("preset"),
        "source": mission.meta.get("source", "synthetic"),
        "body": mission.body.to_dict(),
        "images": int(len(cat)),
        "images_by_instrument": {str(k): int(v) for k, v in cat.groupby("instrument").size().items()},
        "image_size": sorted({f"{s}x{l}" for s, l in zip(cat["samples"], cat["lines"])}),
        "pixel_scale_m": [float(cat["pixel_scale_m"].min()), float(cat["pixel_scale_m"].max())],
        "incidence_deg": [float(cat["incidence_deg"].min()), float(cat["incidence_deg"].max())],
        "emission_deg": [float(cat["emission_deg"].min()), float(cat["emission_deg"].max())],
        "tiles_with_images": int(per_tile.size),
        "images_per_tile": {"min": int(per_tile.min()), "median": float(per_tile.median()), "max": int(per_tile.max())},
        "images_per_tile_by_id": {int(k): int(v) for k, v in per_tile.items()},
        "coverage": {
            "grid_step_deg": step,
            "area_deg": list(area) if area is not None else None,
            "fraction_seen": frac(count >= 1),
            "fraction_seen_3x": frac(count >= 3),
            "fraction_stereo_3x_5deg": frac(stereo),
            "median_images_per_point": float(np.median(count)),
        },
        "has_truth": bool(mission.has_truth),
        "partial": mission.meta.get("partial"),
        # counts from altimetry.json only (cheap: the shots are not read)
        "altimetry": mission.altimetry.summary() if mission.altimetry is not None else None,
    }
    return summary, cov


def coverage_map(cov: dict[str, Any], path: str | Path, title: str = "") -> Path:
    """PNG of the number of images seeing each grid point (matplotlib's Agg canvas).

    Drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas directly, with fixed margins:
    ``matplotlib.pyplot`` (its backend machinery) and ``tight_layout`` cost ``mercury-dem info``
    about half of its run time and change nothing in this one-axes figure.
    """
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import BoundaryNorm
    from matplotlib.figure import Figure

    lat, lon, count = cov["lat"], cov["lon"], cov["count"]
    step_lat = lat[1, 0] - lat[0, 0] if lat.shape[0] > 1 else 1.0
    step_lon = lon[0, 1] - lon[0, 0] if lon.shape[1] > 1 else 1.0
    extent = (lon[0, 0] - step_lon / 2, lon[0, -1] + step_lon / 2, lat[0, 0] - step_lat / 2, lat[-1, 0] + step_lat / 2)
    top = max(6, int(count.max()))
    bounds = np.arange(-0.5, top + 1.5)
    cmap = colormaps["viridis"].resampled(len(bounds) - 1)
    fig = Figure(figsize=(9, 5))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.11, top=0.92)
    ax = fig.add_subplot()
    im = ax.imshow(count, origin="lower", extent=extent, cmap=cmap, norm=BoundaryNorm(bounds, cmap.N), aspect="auto")
    fig.colorbar(im, ax=ax, label="images seeing the point (a-priori pose)", ticks=np.arange(0, top + 1, max(1, top // 10)))
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.set_title(title or "coverage")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path
