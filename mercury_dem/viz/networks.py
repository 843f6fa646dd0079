"""Statistics and residuals of the control networks a run wrote (regions, hemispheres, globe)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission
    from mercury_dem.network.model import ControlNetwork

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.io.run_store import RunStore
from mercury_dem.plan.tree import ADJUSTED_LEVELS, LEVELS
from mercury_dem.viz.status import as_store


def _networks(store: RunStore, levels: tuple[str, ...]) -> list[tuple[str, int, Any]]:
    from mercury_dem.io.network_store import read_network

    out = []
    for level in levels:
        for uid in store.completed_units(level):
            path = store.network_path(level, uid)
            if path.exists():
                out.append((level, uid, read_network(path)))
    return out


def network_statistics(run: str | Path | RunStore, levels: tuple[str, ...] = LEVELS) -> pd.DataFrame:
    """One row per written network: level, id, images, points, measures, active_measures,
    rejected_fraction, measures_per_point_median, rms_px.

    ``rms_px`` is the RMS of the active measures' residual *components* (sample and
    line pooled, as the adjustment reports it; the residual length's RMS is sqrt(2)
    times larger); NaN for tiles, which are not adjusted.
    """
    rows = []
    for level, uid, net in _networks(as_store(run), levels):
        active = net.active_measures()
        r = np.asarray(net.residuals[active]).ravel()
        r = r[np.isfinite(r)]
        mpp = net.measures_per_point(active_only=True)
        rows.append({
            "level": level, "id": uid, "images": net.n_images, "points": net.n_points, "measures": net.n_measures,
            "active_measures": int(active.sum()),
            "rejected_fraction": float(1.0 - active.mean()) if net.n_measures else np.nan,
            "measures_per_point_median": float(np.median(mpp[mpp > 0])) if np.any(mpp > 0) else np.nan,
            "rms_px": float(np.sqrt(np.mean(r * r))) if r.size else np.nan,
        })
    return pd.DataFrame(rows, columns=["level", "id", "images", "points", "measures", "active_measures",
                                       "rejected_fraction", "measures_per_point_median", "rms_px"])


def residuals_by_level(run: str | Path | RunStore, levels: tuple[str, ...] = ADJUSTED_LEVELS) -> pd.DataFrame:
    """Every measure's residual of every adjusted unit: level, id, residual_sample, residual_line,
    residual_px (length, px), active (used by the final adjustment).
    """
    parts = []
    for level, uid, net in _networks(as_store(run), levels):
        res = np.asarray(net.residuals)
        parts.append(pd.DataFrame({
            "level": level, "id": uid, "residual_sample": res[:, 0], "residual_line": res[:, 1],
            "residual_px": np.hypot(res[:, 0], res[:, 1]), "active": net.active_measures(),
        }))
    cols = ["level", "id", "residual_sample", "residual_line", "residual_px", "active"]
    return pd.concat(parts, ignore_index=True)[cols] if parts else pd.DataFrame(columns=cols)


def _rms_by(index: np.ndarray, r2: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-component RMS (sample and line pooled) of the measures grouped by ``index``, and their count."""
    count = np.bincount(index, minlength=n)
    s = np.bincount(index, weights=r2, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(s / (2.0 * count)), count


def point_residuals(network: ControlNetwork) -> pd.DataFrame:
    """Per point of an adjusted network: point_id, lat, lon (deg, east -180..180), rms_px, n_active."""
    active = network.active_measures() & np.all(np.isfinite(network.residuals), axis=1)
    r2 = np.sum(network.residuals[active] ** 2, axis=1)
    rms, count = _rms_by(network.measure_point[active], r2, network.n_points)
    use_adj = np.all(np.isfinite(network.adjusted_xyz), axis=1)
    lat_a, lon_a, _ = network.point_latlon(adjusted=True)
    lat_p, lon_p, _ = network.point_latlon(adjusted=False)
    lat, lon = np.where(use_adj, lat_a, lat_p), np.where(use_adj, lon_a, lon_p)
    return pd.DataFrame({"point_id": network.point_ids, "lat": lat, "lon": (lon + 180.0) % 360.0 - 180.0,
                         "rms_px": rms, "n_active": count})


def image_residuals(network: ControlNetwork, mission: Mission | None = None) -> pd.DataFrame:
    """Per image of an adjusted network: image_id, rms_px, n_active, and (with the mission) the
    image centre lat, lon (deg, east -180..180) from the catalog.
    """
    active = network.active_measures() & np.all(np.isfinite(network.residuals), axis=1)
    r2 = np.sum(network.residuals[active] ** 2, axis=1)
    rms, count = _rms_by(network.measure_image[active], r2, network.n_images)
    df = pd.DataFrame({"image_id": np.asarray(network.image_ids, dtype=str), "rms_px": rms, "n_active": count})
    if mission is not None:
        cat = mission.catalog.set_index("image_id")
        df["lat"] = cat.loc[df["image_id"], "center_lat"].to_numpy(dtype=float)
        df["lon"] = (cat.loc[df["image_id"], "center_lon"].to_numpy(dtype=float) + 180.0) % 360.0 - 180.0
    return df
