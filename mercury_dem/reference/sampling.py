"""Bilinear sampling of a (lat, lon) height grid at arbitrary points, across the 0/360 seam.

Pure functions: an :class:`xarray.DataArray` (or its coordinate and value arrays) in, numpy
arrays out. Used to read a reference DEM (LOLA's LDEM) at a DEM's pixels and a DEM at
altimetry shots.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from mercury_dem.geometry.body import wrap_longitude


def _lon_index(lon_coords: NDArray[np.float64], lon: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """Fractional column index of each longitude, and whether the grid wraps around the globe."""
    n = lon_coords.size
    if n == 1:
        return np.where(np.isfinite(lon), 0.0, np.nan), False
    steps = np.diff(lon_coords)
    step = float(np.median(steps))
    if step == 0.0 or not np.allclose(steps, step, rtol=1e-6, atol=1e-9):
        raise ValueError("the grid's longitudes must be evenly spaced (strictly monotonic, one step)")
    periodic = abs(abs(step) * n - 360.0) < 1e-6 * 360.0
    # Distance from the first column along the grid's direction, folded into [0, 360).
    offset = wrap_longitude((lon - lon_coords[0]) * np.sign(step))
    idx = offset / abs(step)
    if periodic:
        return idx, True  # in [0, n): the cell between column n-1 and n wraps to column 0
    # A regional grid: a point a little west of the first column folds to ~360; unfold it.
    span = abs(step) * (n - 1)
    back = offset - 360.0
    idx = np.where(offset > span, back / abs(step), idx)
    return idx, False


def sample_grid(
    values: ArrayLike,
    lat_coords: ArrayLike,
    lon_coords: ArrayLike,
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
) -> NDArray[np.float64]:
    """Bilinear interpolation of a (lat, lon) grid of pixel-centre values.

    Parameters
    ----------
    values : array_like of shape (H, W)
        Grid values (e.g. heights, metres); NaN cells make every sample that touches them NaN.
    lat_coords : array_like of shape (H,)
        Pixel-centre latitudes, degrees, strictly monotonic (ascending or descending).
    lon_coords : array_like of shape (W,)
        Pixel-centre east longitudes, degrees, evenly spaced and monotonic, any range
        (0..360, -180..180, or running past 360). A grid whose W columns span 360° wraps:
        points between the last and the first column interpolate across the seam.
    lat_deg, lon_deg : array_like, broadcastable to a common shape (...)
        Points, planetocentric latitude and east longitude in degrees (any longitude range).

    Returns
    -------
    ndarray of shape (...)
        Interpolated values. NaN outside the grid: beyond the outermost pixel centres in
        longitude for a regional grid; in latitude beyond the outermost pixel *edges* (half a
        pixel past the last centre, where the edge row's value is used), so the polar
        half-pixel bands of a global grid are covered.
    """
    v = np.asarray(values, dtype=np.float64)
    la_c = np.asarray(lat_coords, dtype=np.float64).ravel()
    lo_c = np.asarray(lon_coords, dtype=np.float64).ravel()
    if v.shape != (la_c.size, lo_c.size):
        raise ValueError(f"values of shape {v.shape} do not match {la_c.size} latitudes x {lo_c.size} longitudes")
    lat, lon = np.broadcast_arrays(np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64))
    out_shape = lat.shape
    lat, lon = lat.ravel(), lon.ravel()
    h, w = v.shape
    if h == 0 or w == 0:
        return np.full(out_shape, np.nan)

    # Row index: fractional, from the (monotonic) latitude centres.
    if h > 1:
        dl = np.diff(la_c)
        if not (np.all(dl > 0) or np.all(dl < 0)):
            raise ValueError("the grid's latitudes must be strictly monotonic")
        asc = la_c if dl[0] > 0 else la_c[::-1]
        half_lo, half_hi = (asc[1] - asc[0]) / 2.0, (asc[-1] - asc[-2]) / 2.0
        row = np.interp(lat, asc, np.arange(h, dtype=np.float64))
        inside = (lat >= asc[0] - half_lo) & (lat <= asc[-1] + half_hi) & (np.abs(lat) <= 90.0)
        if dl[0] < 0:
            row = (h - 1) - row
    else:
        row = np.zeros_like(lat)
        inside = np.isfinite(lat)
    col, periodic = _lon_index(lo_c, lon)
    inside &= np.isfinite(col)
    if not periodic:
        inside &= (col >= -1e-9) & (col <= (w - 1) + 1e-9)

    out = np.full(lat.shape, np.nan)
    idx = np.flatnonzero(inside)
    r, c = row[idx], np.clip(col[idx], 0.0, None)
    r0 = np.clip(np.floor(r).astype(np.int64), 0, max(h - 2, 0))
    fr = np.clip(r - r0, 0.0, 1.0) if h > 1 else np.zeros_like(r)
    r1 = np.minimum(r0 + 1, h - 1)
    if periodic:
        c0 = np.floor(c).astype(np.int64) % w
        fc = c - np.floor(c)
        c1 = (c0 + 1) % w
    else:
        c0 = np.clip(np.floor(c).astype(np.int64), 0, max(w - 2, 0))
        fc = np.clip(c - c0, 0.0, 1.0) if w > 1 else np.zeros_like(c)
        c1 = np.minimum(c0 + 1, w - 1)
    out[idx] = (
        v[r0, c0] * (1 - fr) * (1 - fc) + v[r0, c1] * (1 - fr) * fc + v[r1, c0] * fr * (1 - fc) + v[r1, c1] * fr * fc
    )
    return out.reshape(out_shape)


def sample_reference_dem(dem: xr.DataArray, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """Bilinear sample of a (lat, lon) DataArray at points; see :func:`sample_grid`.

    Parameters
    ----------
    dem : xarray.DataArray with dims ("lat", "lon")
        Heights (metres above the radius in ``dem.attrs["datum_radius_m"]``) or any value.
    lat_deg, lon_deg : array_like, broadcastable
        Planetocentric latitude and east longitude, degrees.

    Returns
    -------
    ndarray
        Values at the points, NaN outside the grid or where a touched cell is NaN.
    """
    if set(dem.dims) != {"lat", "lon"}:
        raise ValueError(f"the DEM must have dims ('lat', 'lon'), not {dem.dims}")
    da = dem.transpose("lat", "lon")
    return sample_grid(da.values, da["lat"].values, da["lon"].values, lat_deg, lon_deg)
