"""Statistics of a DEM against reference heights (altimetry shots, a shape model, a reference DEM).

One datum, stated and never mixed: a DEM's values are heights above its body's datum sphere
(``datum_radius_m``, 2439.4 km for the MESSENGER DEMs); altimetry radii are absolute
(from the centre of mass); a reference DEM's heights are above *its own* radius. Every
comparison converts the reference to a height above the DEM's datum first,

    reference height = reference radius − datum_radius_m
                     = reference height' + reference datum' − datum_radius_m,

and reports statistics of ``DEM − reference`` in metres together with the datum it used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from mercury_dem.reference.sampling import sample_reference_dem
from mercury_dem.reference.sha import ShapeHarmonics, evaluate_grid
from mercury_dem.stats import NMAD_FACTOR

STAT_KEYS = ("n", "n_excluded", "bias_m", "median_m", "std_m", "rmse_m", "nmad_m", "p5_m", "p95_m",
             "min_m", "max_m", "datum_radius_m")


def difference_statistics(diff_m: ArrayLike) -> dict[str, float | int]:
    """Robust and classical statistics of height differences (NaN entries excluded).

    Parameters
    ----------
    diff_m : array_like of shape (N,)
        DEM − reference, metres.

    Returns
    -------
    dict
        ``n`` (finite differences), ``n_excluded`` (NaN/inf), ``bias_m`` (mean), ``median_m``,
        ``std_m`` (sample standard deviation, ddof = 1), ``rmse_m``, ``nmad_m``
        (1.4826 × median |d − median d|), ``p5_m``, ``p95_m``, ``min_m``, ``max_m``. With no
        finite difference the statistics are NaN and ``n`` is 0.
    """
    d = np.asarray(diff_m, dtype=np.float64).ravel()
    finite = np.isfinite(d)
    d = d[finite]
    n = int(d.size)
    out: dict[str, float | int] = {"n": n, "n_excluded": int(finite.size - n)}
    if n == 0:
        out.update({k: float("nan") for k in STAT_KEYS[2:-1]})
        return out
    med = float(np.median(d))
    out.update(
        bias_m=float(np.mean(d)),
        median_m=med,
        std_m=float(np.std(d, ddof=1)) if n > 1 else float("nan"),
        rmse_m=float(np.sqrt(np.mean(d * d))),
        nmad_m=float(NMAD_FACTOR * np.median(np.abs(d - med))),
        p5_m=float(np.percentile(d, 5)),
        p95_m=float(np.percentile(d, 95)),
        min_m=float(np.min(d)),
        max_m=float(np.max(d)),
    )
    return out


def compare_heights(
    dem_heights_m: ArrayLike,
    *,
    datum_radius_m: float,
    reference_radius_m: ArrayLike | None = None,
    reference_heights_m: ArrayLike | None = None,
    reference_datum_radius_m: float | None = None,
) -> dict[str, float | int]:
    """Statistics of DEM − reference at matched points, on the DEM's datum.

    Parameters
    ----------
    dem_heights_m : array_like of shape (N,)
        DEM heights at the points, metres above ``datum_radius_m`` (NaN where the DEM has none).
    datum_radius_m : float
        The DEM's datum radius, metres (keyword only: it must be stated).
    reference_radius_m : array_like of shape (N,), optional
        Absolute reference radii from the centre of mass, metres (altimetry, a shape model).
    reference_heights_m : array_like of shape (N,), optional
        Reference heights, metres above ``reference_datum_radius_m`` (a reference DEM).
        Exactly one of ``reference_radius_m`` and ``reference_heights_m`` is given.
    reference_datum_radius_m : float, optional
        The radius the reference heights are above; required with ``reference_heights_m``.

    Returns
    -------
    dict
        :func:`difference_statistics` of DEM − reference (metres), plus ``datum_radius_m`` and
        ``mean_reference_height_m`` (the reference expressed above the DEM's datum).
    """
    if (reference_radius_m is None) == (reference_heights_m is None):
        raise ValueError("give exactly one of reference_radius_m (absolute) and reference_heights_m")
    if reference_heights_m is not None:
        if reference_datum_radius_m is None:
            raise ValueError("reference_heights_m needs reference_datum_radius_m (the radius they are above)")
        ref_radius = np.asarray(reference_heights_m, dtype=np.float64) + float(reference_datum_radius_m)
    else:
        ref_radius = np.asarray(reference_radius_m, dtype=np.float64)
    dem = np.asarray(dem_heights_m, dtype=np.float64)
    if dem.shape != ref_radius.shape:
        raise ValueError(f"DEM heights {dem.shape} and reference {ref_radius.shape} differ in shape")
    ref_height = ref_radius - float(datum_radius_m)
    stats = difference_statistics(dem - ref_height)
    both = np.isfinite(dem) & np.isfinite(ref_height)
    stats["datum_radius_m"] = float(datum_radius_m)
    stats["mean_reference_height_m"] = float(np.mean(ref_height[both])) if both.any() else float("nan")
    return stats


def _check_datum(dem: xr.DataArray, datum_radius_m: float) -> None:
    stated = dem.attrs.get("datum_radius_m")
    if stated is not None and not np.isclose(float(stated), float(datum_radius_m), rtol=0, atol=1e-3):
        raise ValueError(
            f"the DEM says its heights are above {float(stated)} m but datum_radius_m = {datum_radius_m} "
            f"was given; heights above one radius are never compared as if above another"
        )


def residuals_at_shots(dem: xr.DataArray, shots: pd.DataFrame, datum_radius_m: float) -> NDArray[np.float64]:
    """DEM − shot height at each shot, metres (NaN where the DEM has no value).

    Parameters
    ----------
    dem : xarray.DataArray, dims ("lat", "lon")
        Heights, metres above ``datum_radius_m``.
    shots : pandas.DataFrame
        Columns ``lat``, ``lon`` (degrees) and ``radius_m`` (absolute, metres), as read by
        :func:`mercury_dem.reference.lola.read_altimetry_csv`.
    datum_radius_m : float
        The DEM's datum radius, metres.

    Returns
    -------
    ndarray of shape (N,)
    """
    _check_datum(dem, datum_radius_m)
    h = sample_reference_dem(dem, shots["lat"].to_numpy(), shots["lon"].to_numpy())
    return h - (shots["radius_m"].to_numpy(dtype=np.float64) - float(datum_radius_m))


def compare_dem_with_shots(
    dem: xr.DataArray, shots: pd.DataFrame, datum_radius_m: float
) -> dict[str, Any]:
    """Statistics of a DEM against altimetry shots (bilinear DEM sample at each shot).

    Returns
    -------
    dict
        :func:`compare_heights` statistics; shots outside the DEM or on its gaps count in
        ``n_excluded``; ``n_profiles`` when the shots have a ``profile_id``.
    """
    _check_datum(dem, datum_radius_m)
    h = sample_reference_dem(dem, shots["lat"].to_numpy(), shots["lon"].to_numpy())
    stats: dict[str, Any] = dict(
        compare_heights(h, datum_radius_m=datum_radius_m, reference_radius_m=shots["radius_m"].to_numpy())
    )
    if "profile_id" in shots:
        stats["n_profiles"] = int(shots.loc[np.isfinite(h), "profile_id"].nunique())
    stats["reference"] = "altimetry shots"
    return stats


def compare_dem_with_harmonics(
    dem: xr.DataArray, shape: ShapeHarmonics, datum_radius_m: float, lmax: int = 148, long_lmax: int = 10
) -> dict[str, Any]:
    """Statistics of a DEM against a spherical-harmonic shape evaluated at its pixel centres.

    The shape model is smooth (degree 148 on Mercury is a ~52 km wavelength), so the
    spread includes all the DEM's shorter-wavelength relief; the bias is the meaningful figure,
    and so are the long wavelengths of the difference: ``long_wavelength`` holds the
    area-weighted (cos latitude) bias, the difference per latitude band and, when the DEM covers
    at least half the sphere, the RMS of each spherical-harmonic degree 0..``long_lmax`` of the
    difference (:func:`mercury_dem.dem.accuracy.dem_accuracy`, the same figures as the run's
    DEM − truth). Memory: a few float64 arrays of the DEM's size.

    Returns
    -------
    dict
        :func:`compare_heights` statistics over the DEM's finite pixels (unweighted), plus ``lmax``
        and ``long_wavelength`` (None when ``long_lmax`` is 0).
    """
    _check_datum(dem, datum_radius_m)
    da = dem.transpose("lat", "lon")
    radius = evaluate_grid(shape, da["lat"].values, da["lon"].values, lmax=lmax)
    stats: dict[str, Any] = dict(
        compare_heights(da.values.ravel(), datum_radius_m=datum_radius_m, reference_radius_m=radius.ravel())
    )
    stats["lmax"] = int(lmax)
    stats["reference"] = f"spherical harmonics {shape.source or ''}".strip()
    stats["long_wavelength"] = None
    if long_lmax > 0 and da.sizes["lat"] > 1 and da.sizes["lon"] > 1:
        from mercury_dem.dem.accuracy import dem_accuracy

        ref_h = np.asarray(radius, np.float64) - datum_radius_m
        acc = dem_accuracy(np.asarray(da.values, np.float64), da["lat"].values, da["lon"].values,
                           lambda la, lo: ref_h, max_pixels=ref_h.size, shape_lmax=long_lmax)
        stats["long_wavelength"] = {k: acc[k] for k in ("weighting", "bias_m", "rmse_m", "sphere_fraction",
                                                         "error_vs_latitude", "low_degree")}
    return stats
