"""Summary statistics of a DEM as in Becker et al. 2016, Table 1.

The reference resampled its DEM to 2 km/pixel "to increase signal-to-noise
ratio" and reported mean, median, standard deviation, minimum and maximum
elevation and the mean and standard deviation of slope "calculated over a 3x3
pixel box or 6-km baseline", globally and for the north polar (65-90 N), south
polar (65-88 S) and equatorial regions.

Here:

* resample: NaN-aware block mean of the equirectangular DEM by the integer factor
  closest to ``pixel_km`` / (native north-south pixel size);
* slope: Horn's 3x3 gradient on the resample, with the true east-west spacing
  ``R cos(lat) dlon`` of each row (longitude wraps on a global grid), degrees;
* every statistic but min/max is area-weighted (``cos(lat)`` per pixel) so the
  converging meridians do not over-count the poles; the median is the weighted
  median;
* equatorial = ``|lat| < polar_cut`` (65 deg), the complement of both caps.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.dem.accuracy import weighted_percentiles


def block_mean(a: NDArray[np.floating], f: int, rows_per_strip: int = 4096) -> NDArray[np.float32]:
    """NaN-aware f x f block mean (trailing partial blocks averaged over what they hold).

    Works in row strips so a full-size DEM is never copied whole in float64.
    """
    if f <= 1:
        return np.asarray(a, dtype=np.float32).copy()
    H, W = a.shape
    Ho, Wo = -(-H // f), -(-W // f)
    out = np.empty((Ho, Wo), dtype=np.float32)
    step = max(f, (rows_per_strip // f) * f)
    for r0 in range(0, H, step):
        r1 = min(r0 + step, H)
        s = np.asarray(a[r0:r1], dtype=np.float64)
        ph, pw = (-s.shape[0]) % f, (-W) % f
        s = np.pad(s, ((0, ph), (0, pw)), constant_values=np.nan)
        valid = np.isfinite(s)
        v = np.where(valid, s, 0.0).reshape(s.shape[0] // f, f, Wo, f)
        c = valid.reshape(s.shape[0] // f, f, Wo, f).sum(axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            out[r0 // f : r0 // f + c.shape[0]] = v.sum(axis=(1, 3)) / c
    return out


def block_centres(centres: NDArray[np.floating], f: int) -> NDArray[np.float64]:
    """Centres of f-blocks of a regularly spaced coordinate (partial last block included)."""
    c = np.asarray(centres, dtype=np.float64)
    n = c.size
    idx = np.arange(0, n, f)
    return np.array([c[i : min(i + f, n)].mean() for i in idx])


def slope_deg(
    height: NDArray[np.floating], lat_deg: NDArray[np.floating], dlat_deg: float, dlon_deg: float,
    wrap_lon: bool, radius_m: float
) -> NDArray[np.float64]:
    """Slope (degrees) by Horn's 3x3 method on an equirectangular grid (rows north to south).

    NaN where any of the 3x3 neighbours has no value, and on the first/last row
    (and first/last column unless ``wrap_lon``).
    """
    z = np.asarray(height, dtype=np.float64)
    if wrap_lon:
        zp = np.concatenate([z[:, -1:], z, z[:, :1]], axis=1)
    else:
        zp = np.pad(z, ((0, 0), (1, 1)), constant_values=np.nan)
    zp = np.pad(zp, ((1, 1), (0, 0)), constant_values=np.nan)
    H, W = z.shape

    def s(di: int, dj: int) -> NDArray[np.float64]:
        return zp[1 + di : 1 + di + H, 1 + dj : 1 + dj + W]

    dzdx = ((s(-1, 1) + 2 * s(0, 1) + s(1, 1)) - (s(-1, -1) + 2 * s(0, -1) + s(1, -1)))
    dzdy = ((s(-1, -1) + 2 * s(-1, 0) + s(-1, 1)) - (s(1, -1) + 2 * s(1, 0) + s(1, 1)))  # north minus south
    dx = radius_m * np.cos(np.radians(np.asarray(lat_deg)))[:, None] * math.radians(dlon_deg)
    dy = radius_m * math.radians(dlat_deg)
    with np.errstate(divide="ignore", invalid="ignore"):
        gx = dzdx / (8.0 * dx)
        gy = dzdy / (8.0 * dy)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def _region_stats(h: NDArray[np.float64], slope: NDArray[np.float64], w: NDArray[np.float64]) -> dict[str, Any]:
    ok = np.isfinite(h)
    hv, wv = h[ok], w[ok]
    so = np.isfinite(slope)
    sv, sw = slope[so], w[so]
    if hv.size == 0:
        return {"n_pixels": 0, "mean_m": None, "median_m": None, "std_m": None, "min_m": None, "max_m": None,
                "slope_mean_deg": None, "slope_std_deg": None}
    mean = float((wv * hv).sum() / wv.sum())
    out = {
        "n_pixels": int(hv.size),
        "mean_m": mean,
        "median_m": weighted_percentiles(hv, wv, [50])[0],
        "std_m": float(math.sqrt((wv * (hv - mean) ** 2).sum() / wv.sum())),
        "min_m": float(hv.min()),
        "max_m": float(hv.max()),
        "slope_mean_deg": None,
        "slope_std_deg": None,
    }
    if sv.size:
        sm = float((sw * sv).sum() / sw.sum())
        out["slope_mean_deg"] = sm
        out["slope_std_deg"] = float(math.sqrt((sw * (sv - sm) ** 2).sum() / sw.sum()))
    return out


def dem_statistics(
    elevation: NDArray[np.floating],
    lat_deg: NDArray[np.floating],
    lon_deg: NDArray[np.floating],
    *,
    pixel_km: float = 2.0,
    polar_cut: float = 65.0,
    south_limit: float = 88.0,
    radius_m: float,
) -> dict[str, Any]:
    """Table 1 of the reference for a DEM on an equirectangular grid.

    Parameters
    ----------
    elevation : (H, W) m above the datum, rows north to south, NaN = no value
    lat_deg, lon_deg : (H,), (W,) pixel centres, degrees (regularly spaced)
    pixel_km : pixel scale of the resample the statistics use (reference: 2 km)
    polar_cut : latitude bounding the polar regions (reference: 65)
    south_limit : the south polar region stops at this latitude (reference: 88)

    Returns
    -------
    dict with ``resample`` (factor, pixel_km actually used, shape) and regions
    ``global``, ``north_polar``, ``south_polar``, ``equatorial`` each holding
    n_pixels, mean_m, median_m, std_m, min_m, max_m, slope_mean_deg, slope_std_deg.
    """
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    dlat = abs(lat[1] - lat[0]) if lat.size > 1 else 1.0
    dlon = abs(lon[1] - lon[0]) if lon.size > 1 else dlat
    native_km = radius_m * math.radians(dlat) / 1000.0
    f = max(1, int(round(pixel_km / native_km)))
    h = block_mean(elevation, f).astype(np.float64)
    la = block_centres(lat, f)
    wrap = abs(dlon * lon.size - 360.0) < 1e-6 and lon.size % f == 0
    slope = slope_deg(h, la, dlat * f, dlon * f, wrap, radius_m)
    w = np.broadcast_to(np.cos(np.radians(la))[:, None], h.shape)
    regions = {
        "global": np.ones(la.shape, dtype=bool),
        "north_polar": la >= polar_cut,
        "south_polar": (la <= -polar_cut) & (la >= -south_limit),
        "equatorial": np.abs(la) < polar_cut,
    }
    out: dict[str, Any] = {
        "resample": {"factor": f, "pixel_km": native_km * f, "shape": list(h.shape),
                     "method": "NaN-aware block mean"},
        "weighting": "cos(latitude) (area); min/max unweighted",
        "slope": "Horn 3x3 on the resample, true east-west spacing, degrees",
        "regions_deg": {"north_polar": [polar_cut, 90.0], "south_polar": [-south_limit, -polar_cut],
                        "equatorial": [-polar_cut, polar_cut]},
    }
    for name, rows in regions.items():
        out[name] = _region_stats(h[rows], slope[rows], w[rows])
    return out


def format_statistics_table(stats: dict[str, Any]) -> str:
    """A printable table (one column per region) of :func:`dem_statistics`."""
    names = ["global", "north_polar", "south_polar", "equatorial"]
    rows = [("mean (m)", "mean_m", "{:.0f}"), ("median (m)", "median_m", "{:.0f}"), ("std (m)", "std_m", "{:.0f}"),
            ("min (m)", "min_m", "{:.0f}"), ("max (m)", "max_m", "{:.0f}"),
            ("slope mean (deg)", "slope_mean_deg", "{:.2f}"), ("slope std (deg)", "slope_std_deg", "{:.2f}"),
            ("pixels", "n_pixels", "{:d}")]
    head = f"{'':18s}" + "".join(f"{n:>14s}" for n in names)
    lines = [f"DEM statistics at {stats['resample']['pixel_km']:.2f} km/pixel (area-weighted)", head]
    for label, key, fmt in rows:
        cells = []
        for n in names:
            v = stats[n].get(key)
            cells.append(f"{'-' if v is None else fmt.format(v):>14s}")
        lines.append(f"{label:18s}" + "".join(cells))
    return "\n".join(lines)
