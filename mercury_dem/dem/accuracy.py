"""Accuracy of a gridded DEM against a truth surface (pure).

DEM minus truth at the DEM's own pixel centres: RMSE, bias, standard deviation,
mean absolute error and the 5/50/95 percentiles of the error, and the error as a
function of the distance from the pixel to its nearest control point. The result
is a JSON-safe dict the run report stores under ``validation.dem``.

Statistics are area-weighted (weight ``cos(lat)`` per equirectangular pixel), so
the crowded polar rows of the grid count for the area they cover; the count of
pixels compared is reported unweighted.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Default distance-to-nearest-point bins for the error-vs-distance table, km.
DISTANCE_BINS_KM: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, math.inf)


def weighted_percentiles(values: NDArray[np.float64], weights: NDArray[np.float64],
                         q: Sequence[float]) -> list[float]:
    """Percentiles (q in 0..100) of weighted samples (inverse of the weighted CDF, midpoint rule)."""
    if values.size == 0:
        return [math.nan] * len(q)
    order = np.argsort(values, kind="stable")
    v, w = values[order], weights[order]
    cw = np.cumsum(w)
    cdf = (cw - 0.5 * w) / cw[-1]
    return [float(np.interp(p / 100.0, cdf, v)) for p in q]


def _summary(err: NDArray[np.float64], w: NDArray[np.float64]) -> dict[str, Any]:
    if err.size == 0:
        # None, not NaN: the dict goes into JSON reports.
        return {"n": 0, "rmse_m": None, "bias_m": None, "std_m": None, "mae_m": None,
                "p5_m": None, "p50_m": None, "p95_m": None}
    sw = w.sum()
    bias = float((w * err).sum() / sw)
    rmse = float(math.sqrt((w * err * err).sum() / sw))
    p5, p50, p95 = weighted_percentiles(err, w, (5, 50, 95))
    return {
        "n": int(err.size),
        "rmse_m": rmse,
        "bias_m": bias,
        "std_m": float(math.sqrt(max(rmse * rmse - bias * bias, 0.0))),
        "mae_m": float((w * np.abs(err)).sum() / sw),
        "p5_m": p5,
        "p50_m": p50,
        "p95_m": p95,
    }


def dem_accuracy(
    elevation: NDArray[np.floating],
    lat_deg: NDArray[np.floating],
    lon_deg: NDArray[np.floating],
    truth_height: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
    distance_m: NDArray[np.floating] | None = None,
    *,
    distance_bins_km: Sequence[float] = DISTANCE_BINS_KM,
    max_pixels: int = 4_000_000,
) -> dict[str, Any]:
    """DEM minus truth statistics.

    Parameters
    ----------
    elevation : ndarray of shape (H, W), m above the 2439.4 km datum (NaN = no value)
    lat_deg : (H,) pixel-centre latitudes, degrees
    lon_deg : (W,) pixel-centre east longitudes, degrees
    truth_height : callable (lat, lon) -> m above the same datum, vectorized over arrays
    distance_m : optional (H, W) distance from each pixel to its nearest control point, m
    distance_bins_km : bin edges of the error-vs-distance table
    max_pixels : compare at most about this many pixels; a larger grid is compared on
        a regular subsample (every s-th row and column), recorded as ``stride``

    Returns
    -------
    dict: ``n_pixels``, ``n_compared``, ``n_no_value``, ``stride``, ``rmse_m``, ``bias_m``,
    ``std_m``, ``mae_m``, ``p5_m``, ``p50_m``, ``p95_m``, ``weighting``, and
    ``error_vs_distance`` (a list of per-bin dicts with ``distance_km_min/max``,
    ``n``, ``rmse_m``, ``bias_m``, ...) when ``distance_m`` is given.
    """
    elev = np.asarray(elevation)
    H, W = elev.shape
    if np.shape(lat_deg) != (H,) or np.shape(lon_deg) != (W,):
        raise ValueError(f"lat/lon must have shapes ({H},) and ({W},), got {np.shape(lat_deg)}, {np.shape(lon_deg)}")
    stride = max(1, int(math.ceil(math.sqrt(H * W / max_pixels))))
    e = elev[::stride, ::stride].astype(np.float64)
    la = np.asarray(lat_deg, dtype=np.float64)[::stride]
    lo = np.asarray(lon_deg, dtype=np.float64)[::stride]
    lat2, lon2 = np.meshgrid(la, lo, indexing="ij")
    truth = np.asarray(truth_height(lat2, lon2), dtype=np.float64)
    err_all = e - truth
    ok = np.isfinite(err_all)
    w_all = np.broadcast_to(np.cos(np.radians(la))[:, None], e.shape)
    err, w = err_all[ok], w_all[ok]
    out: dict[str, Any] = {
        "n_pixels": int(H * W),
        "stride": stride,
        "n_no_value": int((~np.isfinite(e)).sum()),
        "weighting": "cos(latitude) (area)",
    }
    s = _summary(err, w)
    out["n_compared"] = s.pop("n")
    out.update(s)
    if distance_m is not None:
        d = np.asarray(distance_m, dtype=np.float64)[::stride, ::stride][ok] / 1000.0
        edges = np.asarray(distance_bins_km, dtype=np.float64)
        which = np.digitize(d, edges) - 1
        table = []
        for b in range(len(edges) - 1):
            m = which == b
            hi = float(edges[b + 1])
            row: dict[str, Any] = {"distance_km_min": float(edges[b]),
                                   "distance_km_max": hi if math.isfinite(hi) else None}  # None = open bin
            row.update(_summary(err[m], w[m]))
            table.append(row)
        out["error_vs_distance"] = table
    return out
