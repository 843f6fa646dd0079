"""Summary of a mission (``mercury-dem info``): counts, ranges, images per tile, coverage, coverage map."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.synth.coverage import mission_coverage


def coverage_step_deg(n_images: int) -> float:
    """Grid step for the coverage count: finer for small missions, bounded work for large ones."""
    return 0.5 if n_images <= 100 else 1.0 if n_images <= 2000 else 2.0


def mission_summary(mission: Any, step_deg: float | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(summary dict, coverage arrays) of a mission. Coverage is over the mission's area (whole body if global)."""
    cat = mission.catalog
    step = step_deg or coverage_step_deg(len(cat))
    area = mission.meta.get("area_deg")
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
            "area_deg": area,
            "fraction_seen": frac(count >= 1),
            "fraction_seen_3x": frac(count >= 3),
            "fraction_stereo_3x_5deg": frac(stereo),
            "median_images_per_point": float(np.median(count)),
        },
        "has_truth": bool(mission.has_truth),
        "partial": mission.meta.get("partial"),
    }
    return summary, cov


def coverage_map(cov: dict[str, Any], path: str | Path, title: str = "") -> Path:
    """PNG of the number of images seeing each grid point (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm

    lat, lon, count = cov["lat"], cov["lon"], cov["count"]
    step_lat = lat[1, 0] - lat[0, 0] if lat.shape[0] > 1 else 1.0
    step_lon = lon[0, 1] - lon[0, 0] if lon.shape[1] > 1 else 1.0
    extent = (lon[0, 0] - step_lon / 2, lon[0, -1] + step_lon / 2, lat[0, 0] - step_lat / 2, lat[-1, 0] + step_lat / 2)
    top = max(6, int(count.max()))
    bounds = np.arange(-0.5, top + 1.5)
    cmap = plt.get_cmap("viridis", len(bounds) - 1)
    fig, ax = plt.subplots(figsize=(9, 5))
    im = ax.imshow(count, origin="lower", extent=extent, cmap=cmap, norm=BoundaryNorm(bounds, cmap.N), aspect="auto")
    fig.colorbar(im, ax=ax, label="images seeing the point (a-priori pose)", ticks=np.arange(0, top + 1, max(1, top // 10)))
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.set_title(title or "coverage")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
