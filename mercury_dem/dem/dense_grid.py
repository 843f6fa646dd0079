"""The dense DEM's grid rules (pure): resolution from the pairs' pixel scale, bounds, precision, control distance.

Used by :mod:`mercury_dem.pipeline.dense_dem` (docs/design/dense.md, "The stage", step 5).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray


def dense_grid_ppd(pixel_scales_m: NDArray[np.float64], factor: float, datum_radius_m: float) -> float:
    """Pixels per degree of the dense DEM: ``factor`` x the median pixel scale, rounded to a multiple of 0.5
    (so 180 and 360 degrees are whole pixels), at least 0.5.
    """
    pixel_m = factor * float(np.median(pixel_scales_m))
    raw = 2.0 * math.pi * datum_radius_m / 360.0 / pixel_m
    return max(0.5, round(raw * 2.0) / 2.0)


def snapped_bounds(bounds: tuple[float, float, float, float], ppd: float) -> tuple[float, float, float, float]:
    """(lat_min, lat_max, lon_min, lon_max) snapped outward to whole pixels of ``ppd`` (latitudes within +-90)."""
    a0, a1, o0, o1 = bounds
    lat0 = max(-90.0, math.floor(a0 * ppd + 1e-9) / ppd)
    lat1 = min(90.0, math.ceil(a1 * ppd - 1e-9) / ppd)
    lon0 = math.floor(o0 * ppd + 1e-9) / ppd
    lon1 = math.ceil(o1 * ppd - 1e-9) / ppd
    if lon1 - lon0 > 360.0:
        lon1 = lon0 + 360.0
    return lat0, lat1, lon0, lon1


def pixel_precision(cloud: dict[str, NDArray[Any]], lat: NDArray[np.float64], lon: NDArray[np.float64],
                    ppd: float, k: int) -> NDArray[np.float64]:
    """Per pixel the stated precision of the points inside it (NaN: none).

    With the cloud's ``pair`` column: ``median(sigma_h) / sqrt(min(m, k))``, ``m`` the number of distinct pairs
    among the pixel's points. A pair's points in one pixel share most of their matching window (a dense DEM pixel is
    about three image pixels, the window nine), so their errors move together: a pair is one sample, not one per
    point. Measured on the tiny mission (seeds 42 and 7, docs/design/dense.md): true / stated RMS 0.70 and 0.75,
    0.46 % and 0.22 % of the pixels beyond 3 stated sigma, where counting every point as independent
    (``1.2533 x median / sqrt(min(n, k))``) gave 1.40 and 1.16 with 12 % beyond. Without a ``pair`` column, that
    older rule.
    """
    H, W = lat.size, lon.size
    lat_max = float(lat[0]) + 0.5 / ppd
    lon_min = float(lon[0]) - 0.5 / ppd
    i = np.floor((lat_max - cloud["lat"]) * ppd).astype(np.int64)
    j = np.floor(np.mod(cloud["lon"] - lon_min, 360.0) * ppd).astype(np.int64)
    ok = (i >= 0) & (i < H) & (j >= 0) & (j < W) & np.isfinite(cloud["sigma_h_m"])
    flat = i[ok] * W + j[ok]
    sig = cloud["sigma_h_m"][ok].astype(np.float64)
    pair = cloud.get("pair")
    by_pair = pair is not None and len(pair) == len(cloud["sigma_h_m"])
    out = np.full(H * W, np.nan)
    if flat.size:
        order = np.lexsort((sig, flat))
        f, s = flat[order], sig[order]
        starts = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
        counts = np.diff(np.r_[starts, f.size])
        med = 0.5 * (s[starts + (counts - 1) // 2] + s[starts + counts // 2])
        if by_pair:
            assert pair is not None
            p = np.asarray(pair)[ok].astype(np.int64)
            distinct = np.unique(np.stack([flat, p], axis=1), axis=0)[:, 0]
            m = np.bincount(distinct, minlength=H * W)[f[starts]]
            out[f[starts]] = med / np.sqrt(np.minimum(m, k))
        else:
            out[f[starts]] = 1.2533 * med / np.sqrt(np.minimum(counts, k))
    return out.reshape(H, W)


def fuse_with_prior(dense: NDArray[np.float64], dense_sigma: NDArray[np.float64], prior: NDArray[np.float64],
                    prior_sigma: float, correlation: float = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The dense elevation fused with a prior (the sparse DEM) by inverse variance, and the fused value's sigma.

    ``w = prior_sigma^2 / (prior_sigma^2 + dense_sigma^2)``, value ``w * dense + (1 - w) * prior``; its sigma
    ``sqrt(w^2 sd^2 + (1 - w)^2 sp^2 + 2 w (1 - w) rho sd sp)`` with ``rho = correlation``: the two errors are
    not independent where both miss the same relief (measured 0.66 on the tiny mission, docs/design/dense.md).
    Where ``dense`` is NaN: the prior and ``prior_sigma``; where only ``dense_sigma`` is NaN (a pixel given a value
    by its neighbours' points): the median of the finite ``dense_sigma``. Where the prior is NaN: the dense value
    and its sigma.
    """
    d = np.asarray(dense, np.float64)
    sd = np.asarray(dense_sigma, np.float64)
    sp = float(prior_sigma)
    pr = np.asarray(prior, np.float64)
    fill = float(np.nanmedian(sd)) if np.isfinite(sd).any() else sp
    sd = np.where(np.isfinite(sd), sd, fill)
    w = sp * sp / (sp * sp + sd * sd)
    value = w * d + (1.0 - w) * pr
    sigma = np.sqrt(w * w * sd * sd + (1.0 - w) ** 2 * sp * sp + 2.0 * w * (1.0 - w) * correlation * sd * sp)
    has_d, has_p = np.isfinite(d), np.isfinite(pr)
    value = np.where(has_d & has_p, value, np.where(has_d, d, pr))
    sigma = np.where(has_d & has_p, sigma, np.where(has_d, sd, np.where(has_p, sp, np.nan)))
    return value, sigma


def control_distance(control_xyz: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64],
                     datum_radius_m: float) -> NDArray[np.float64]:
    """(H, W) horizontal distance (m, chord on the datum sphere) from each pixel centre to its nearest control point."""
    from scipy.spatial import cKDTree

    from mercury_dem.geometry.body import latlon_to_unit

    foot = control_xyz / np.linalg.norm(control_xyz, axis=1, keepdims=True) * datum_radius_m
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    q = latlon_to_unit(la.ravel(), lo.ravel()) * datum_radius_m
    d, _ = cKDTree(foot).query(q)
    return np.asarray(d, np.float64).reshape(la.shape)


def pair_level_offsets(difference: NDArray[np.float64], pair: NDArray[Any], *, clip_nmad: float,
                       min_points: int) -> tuple[NDArray[np.float64], dict[int, float]]:
    """Per point the offset that puts its stereo pair's points on the prior's level, and the offsets per pair.

    ``difference`` is ``prior(point) - point`` (N,), NaN where the prior has no value; ``pair`` the points' pair
    index (N,). A pair's offset is the mean of its finite differences within ``clip_nmad`` NMAD of their median
    (gross points out, the skew kept: the mean, as the altimetry's mean level), where at least ``min_points``
    remain; other pairs get 0 (returned per point, NaN-free). Why: a pair's heights share an offset of their own
    (its relative orientation left by the adjustment, the shading difference between its two views): on the demo
    -8 / +49 / +94 / +261 m against the truth for its four pairs, where the sparse DEM, tied to many images and
    levelled on the altimetry, is within the registration's level. A dense DEM pixel merges several pairs, so
    this is done per pair on the points, before the gridding. Numpy's own grouping (``np.unique``): no library
    has a clipped group mean.
    """
    d = np.asarray(difference, np.float64).ravel()
    p = np.asarray(pair).ravel()
    out = np.zeros(d.shape)
    offsets: dict[int, float] = {}
    for k in np.unique(p):
        m = p == k
        x = d[m]
        x = x[np.isfinite(x)]
        if x.size < min_points:
            continue
        med = float(np.median(x))
        nmad = 1.4826 * float(np.median(np.abs(x - med)))
        keep = x[np.abs(x - med) <= clip_nmad * max(nmad, 1e-9)]
        if keep.size < min_points:
            continue
        offsets[int(k)] = float(keep.mean())
        out[m] = offsets[int(k)]
    return out, offsets
