"""Elevation profiles along a great circle between two points (Preusker et al.: height profiles)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit, xyz_to_latlon  # noqa: E402
from mercury_dem.products.sampling import sample_bilinear  # noqa: E402


def parse_profile(text: str) -> tuple[float, float, float, float]:
    """``"lat1,lon1,lat2,lon2"`` (degrees) -> a tuple; ValueError naming the problem otherwise."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 4:
        raise ValueError(f"a profile is 'lat1,lon1,lat2,lon2' in degrees, got {text!r}")
    try:
        lat1, lon1, lat2, lon2 = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"a profile is four numbers 'lat1,lon1,lat2,lon2' in degrees, got {text!r}") from None
    for la in (lat1, lat2):
        if not -90.0 <= la <= 90.0:
            raise ValueError(f"profile latitude {la} is outside [-90, 90] degrees")
    return lat1, lon1, lat2, lon2


def elevation_profile(
    elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating],
    ends: tuple[float, float, float, float], n: int = 1000, *, radius_m: float,
) -> dict[str, NDArray[np.float64]]:
    """Sample the DEM along the great circle between two points.

    Returns arrays ``distance_km`` (along the arc, on the datum sphere), ``lat``,
    ``lon`` (degrees) and ``elevation`` (m, NaN where the DEM has no value), each (n,).
    """
    lat1, lon1, lat2, lon2 = ends
    a = latlon_to_unit(lat1, lon1)
    b = latlon_to_unit(lat2, lon2)
    omega = math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b)))
    t = np.linspace(0.0, 1.0, n)
    if omega < 1e-12:
        pts = np.repeat(a[None, :], n, axis=0)
    else:
        pts = (np.sin((1 - t) * omega)[:, None] * a + np.sin(t * omega)[:, None] * b) / math.sin(omega)
    plat, plon, _ = xyz_to_latlon(pts * radius_m, radius_m)
    elev = sample_bilinear(elevation, lat, lon, plat, plon).astype(np.float64)
    return {"distance_km": t * omega * radius_m / 1000.0, "radius_m": np.full(1, radius_m), "lat": plat, "lon": plon, "elevation": elev}


def write_profile(profile: dict[str, NDArray[np.float64]], png: str | Path, csv: str | Path,
                  truth_height: Callable[[Any, Any], Any] | None = None) -> dict[str, Any]:
    """Plot a profile (and the truth, when given) and write its samples as CSV."""
    d, e = profile["distance_km"], profile["elevation"]
    cols = [d, profile["lat"], profile["lon"], e]
    header = "distance_km,lat_deg,lon_deg,elevation_m"
    fig, ax = plt.subplots(figsize=(10, 4))
    fig.subplots_adjust(left=0.09, right=0.98, top=0.9, bottom=0.13)
    ax.plot(d, e, color="C0", lw=1.5, label="DEM")
    if truth_height is not None:
        tr = np.asarray(truth_height(profile["lat"], profile["lon"]), dtype=np.float64)
        ax.plot(d, tr, color="k", lw=1.0, ls="--", label="truth")
        cols.append(tr)
        header += ",truth_m"
        ax.legend()
    lo = np.nanmin(e) if np.isfinite(e).any() else 0.0
    ax.fill_between(d, np.where(np.isfinite(e), e, np.nan), lo - 0.05 * (abs(lo) + 1), color="C0", alpha=0.15)
    ends = (profile["lat"][0], profile["lon"][0], profile["lat"][-1], profile["lon"][-1])
    ax.set_title("Elevation profile from ({:.2f}°, {:.2f}°E) to ({:.2f}°, {:.2f}°E)".format(*ends))
    ax.set_xlabel("distance along the great circle (km)")
    ax.set_ylabel(f"elevation above {float(profile.get('radius_m', [DATUM_RADIUS_M])[0]) / 1000:g} km datum (m)")
    ax.grid(alpha=0.3)
    fig.savefig(png, dpi=100)
    plt.close(fig)
    np.savetxt(csv, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.6f")
    return {"png": str(png), "csv": str(csv), "length_km": float(d[-1]),
            "valid_fraction": float(np.isfinite(e).mean())}
