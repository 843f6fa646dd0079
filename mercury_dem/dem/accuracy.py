"""Accuracy of a gridded DEM against a truth surface (pure).

DEM minus truth at the DEM's own pixel centres: RMSE, bias, standard deviation,
mean absolute error and the 5/50/95 percentiles of the error, and the error as a
function of the distance from the pixel to its nearest control point. The result
is a JSON-safe dict the run report stores under ``validation.dem``.

The long-wavelength shape of the error (a block bent by the adjustment: poles high,
mid-latitudes low) is reported twice: by latitude band (``error_vs_latitude``), and, when the
DEM covers most of the sphere, as a least-squares fit of real spherical harmonics up to
``shape_lmax`` (``low_degree``: the RMS over the sphere of each degree's part, the zonal
coefficients, and the error left once they are removed).

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
#: Latitude bands of the error-vs-latitude table, degrees.
LATITUDE_BANDS_DEG: tuple[float, ...] = (-90.0, -60.0, -30.0, -10.0, 10.0, 30.0, 60.0, 90.0)
#: The spherical-harmonic fit of the error needs this share of the sphere covered (below it the
#: low degrees are not separable from each other).
MIN_SPHERE_FRACTION = 0.5


def real_harmonics(lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], lmax: int) -> tuple[
        NDArray[np.float64], list[tuple[int, int, str]]]:
    """4π-normalised real spherical harmonics (each has mean square 1 over the sphere) at points.

    Returns the (n, (lmax+1)²) design matrix and its columns' (degree, order, "cos"/"sin").
    Built on :func:`scipy.special.lpmv` (fine at the low degrees used here; the GTMES evaluation
    in :mod:`mercury_dem.reference.sha` has its own stable recursion for high degrees).
    """
    from scipy.special import lpmv

    x = np.sin(np.radians(lat_deg))
    lam = np.radians(lon_deg)
    cols, names = [], []
    for ell in range(lmax + 1):
        for m in range(ell + 1):
            norm = math.sqrt((1 if m == 0 else 2) * (2 * ell + 1) * math.factorial(ell - m) / math.factorial(ell + m))
            p = norm * lpmv(m, ell, x)
            cols.append(p * np.cos(m * lam))
            names.append((ell, m, "cos"))
            if m > 0:
                cols.append(p * np.sin(m * lam))
                names.append((ell, m, "sin"))
    return np.stack(cols, axis=1), names


def low_degree_shape(err: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64],
                     w: NDArray[np.float64], lmax: int, max_samples: int = 200_000) -> dict[str, Any]:
    """Weighted least-squares fit of degrees 0..lmax to the error (see the module docstring)."""
    step = max(1, int(math.ceil(err.size / max_samples)))
    e, la, lo, ww = err[::step], lat[::step], lon[::step], w[::step]
    design, names = real_harmonics(la, lo, lmax)
    sw = np.sqrt(ww)
    coef, *_ = np.linalg.lstsq(design * sw[:, None], e * sw, rcond=None)
    resid = e - design @ coef
    degree_rms = [float(math.sqrt(sum(c * c for c, (ell, _, _) in zip(coef, names) if ell == d)))
                  for d in range(lmax + 1)]
    return {
        "lmax": lmax,
        "degree_rms_m": degree_rms,
        "zonal_m": [float(c) for c, (ell, m, _) in zip(coef, names) if m == 0],
        "rmse_after_removal_m": float(math.sqrt(float((ww * resid * resid).sum() / ww.sum()))),
        "samples": int(e.size),
    }


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
    latitude_bands_deg: Sequence[float] = LATITUDE_BANDS_DEG,
    shape_lmax: int = 4,
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
    latitude_bands_deg : band edges of the error-vs-latitude table
    shape_lmax : highest degree of the spherical-harmonic fit of the error (0: none)

    Returns
    -------
    dict: ``n_pixels``, ``n_compared``, ``n_no_value``, ``stride``, ``rmse_m``, ``bias_m``,
    ``std_m``, ``mae_m``, ``p5_m``, ``p50_m``, ``p95_m``, ``weighting``, and
    ``error_vs_distance`` (a list of per-bin dicts with ``distance_km_min/max``,
    ``n``, ``rmse_m``, ``bias_m``, ...) when ``distance_m`` is given; ``error_vs_latitude``
    (per band ``lat_min/lat_max``, ``n``, ``rmse_m``, ``bias_m``, ...); ``low_degree`` (see
    :func:`low_degree_shape`) when the compared pixels cover at least
    :data:`MIN_SPHERE_FRACTION` of the sphere, else ``None``.
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
    lat_ok = lat2[ok]
    bands = np.asarray(latitude_bands_deg, dtype=np.float64)
    band = np.digitize(lat_ok, bands[1:-1])
    out["error_vs_latitude"] = [
        {"lat_min": float(bands[b]), "lat_max": float(bands[b + 1]), **_summary(err[band == b], w[band == b])}
        for b in range(len(bands) - 1)
    ]
    # Share of the sphere the compared pixels cover: each pixel's area on the unit sphere over 4π.
    dlat = np.radians(abs(float(la[1] - la[0]))) if la.size > 1 else 0.0
    dlon = np.radians(abs(float(lo[1] - lo[0]))) if lo.size > 1 else 0.0
    fraction = float(w.sum() * dlat * dlon / (4 * math.pi))
    out["sphere_fraction"] = fraction
    out["low_degree"] = (low_degree_shape(err, lat_ok, lon2[ok], w, shape_lmax)
                         if shape_lmax > 0 and fraction >= MIN_SPHERE_FRACTION and err.size > (shape_lmax + 1) ** 2
                         else None)
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
