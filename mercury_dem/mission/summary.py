"""Summary of a mission (``mercury-dem info``): counts, ranges, images per tile, coverage, coverage map,
and per image its footprint statistics (the quantities of ISIS's ``CameraStatistics``).
"""

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
    cols = ["footprint_lat_min", "footprint_lat_max", "footprint_lon_min", "footprint_lon_max"]
    if not all(c in mission.catalog_columns for c in cols):
        return None
    fp = np.column_stack([np.asarray(mission.column(c), dtype=np.float64) for c in cols])
    if fp.size == 0 or not np.all(np.isfinite(fp)):
        return None
    la0, la1 = float(fp[:, 0].min()), float(fp[:, 1].max())
    lo0, lo1 = float(fp[:, 2].min()), float(fp[:, 3].max())
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


def _counts(values: np.ndarray) -> dict[Any, int]:
    """Rows per value, sorted by value, missing values (None, NaN) left out: ``DataFrame.groupby(col).size()``
    without pandas (see :class:`~mercury_dem.mission.store.Mission`).
    """
    keep = [v for v in values.tolist() if v is not None and v == v]
    if not keep:
        return {}
    uniq, n = np.unique(np.asarray(keep), return_counts=True)
    return dict(zip(uniq.tolist(), n.tolist()))


def _range(values: np.ndarray) -> list[float]:
    """[min, max] skipping NaN (NaN when every value is missing), as pandas' ``min``/``max``."""
    v = np.asarray(values, dtype=np.float64)
    v = v[~np.isnan(v)]
    return [float(v.min()), float(v.max())] if v.size else [float("nan"), float("nan")]


def mission_summary(mission: Mission, step_deg: float | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(summary dict, coverage arrays) of a mission. Coverage is over the mission's area: the design's,
    else the images' footprints when they are regional, else the whole body.
    """
    col = mission.column
    area = mission.meta.get("area_deg") or data_area(mission)
    if step_deg is None and area is not None and mission.meta.get("area_deg") is None:
        step = max(1e-3, min(area[1] - area[0], area[3] - area[2]) / 100.0)
    else:
        step = step_deg or coverage_step_deg(len(mission))
    cov = mission_coverage(mission, step, tuple(area) if area else None)
    w = np.cos(np.radians(cov["lat"]))
    count = cov["count"]
    stereo = (count >= 3) & (cov["convergence_deg"] >= 5.0)

    def frac(mask: np.ndarray) -> float:
        return float(np.sum(w * mask) / np.sum(w))

    per_tile = _counts(col("tile_id"))
    n_per_tile = np.array(list(per_tile.values()), dtype=np.int64)
    summary = {
        "mission": str(mission.path),
        "preset": mission.meta.get("preset"),
        "source": mission.meta.get("source", "synthetic"),
        "body": mission.body.to_dict(),
        "images": int(len(mission)),
        "images_by_instrument": {str(k): int(v) for k, v in _counts(col("instrument")).items()},
        "image_size": sorted({f"{s}x{l}" for s, l in zip(col("samples").tolist(), col("lines").tolist())}),
        "pixel_scale_m": _range(col("pixel_scale_m")),
        "incidence_deg": _range(col("incidence_deg")),
        "emission_deg": _range(col("emission_deg")),
        "tiles_with_images": int(n_per_tile.size),
        "images_per_tile": {"min": int(n_per_tile.min()), "median": float(np.median(n_per_tile)),
                            "max": int(n_per_tile.max())},
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
    """PNG of the number of images seeing each grid point (written atomically; Pillow, see
    :mod:`mercury_dem.mission.count_map` for why not matplotlib).
    """
    from mercury_dem.io.atomic import atomic_write_bytes
    from mercury_dem.mission.count_map import png_bytes, render_count_map

    lat, lon, count = cov["lat"], cov["lon"], cov["count"]
    step_lat = lat[1, 0] - lat[0, 0] if lat.shape[0] > 1 else 1.0
    step_lon = lon[0, 1] - lon[0, 0] if lon.shape[1] > 1 else 1.0
    extent = (lon[0, 0] - step_lon / 2, lon[0, -1] + step_lon / 2, lat[0, 0] - step_lat / 2, lat[-1, 0] + step_lat / 2)
    img = render_count_map(count, tuple(float(v) for v in extent), title or "coverage", "east longitude (deg)",
                           "latitude (deg)", "images seeing the point (a-priori pose)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, png_bytes(img))
    return path
