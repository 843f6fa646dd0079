"""Bilinear sampling of (lat, lon) grids: exactness on planes, the 0/360 seam, edges, NaN."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from mercury_dem.reference.sampling import sample_grid, sample_reference_dem


def _plane(lat, lon):
    return 3.0 * lat - 0.5 * lon + 7.0


def test_bilinear_is_exact_on_a_plane():
    lat = np.arange(-10.0, 10.1, 2.0)
    lon = np.arange(100.0, 120.1, 2.5)
    v = _plane(lat[:, None], lon[None, :])
    rng = np.random.default_rng(1)
    pl, pn = rng.uniform(-10, 10, 200), rng.uniform(100, 120, 200)
    np.testing.assert_allclose(sample_grid(v, lat, lon, pl, pn), _plane(pl, pn), atol=1e-9)
    # Descending latitudes (the project's DEM order) give the same values.
    np.testing.assert_allclose(sample_grid(v[::-1], lat[::-1], lon, pl, pn), _plane(pl, pn), atol=1e-9)


def test_global_grid_wraps_across_the_seam():
    lat = np.array([-0.5, 0.5])
    lon = np.arange(0.5, 360.0, 1.0)  # 360 columns, centres 0.5 .. 359.5
    v = np.zeros((2, 360))
    v[:, -1], v[:, 0] = 10.0, 20.0  # 359.5 -> 10, 0.5 -> 20
    pts = np.array([359.75, 0.0, 360.0, -0.25, 0.25, 720.25, 359.5])
    got = sample_grid(v, lat, lon, np.zeros_like(pts), pts)
    np.testing.assert_allclose(got, [12.5, 15.0, 15.0, 12.5, 17.5, 17.5, 10.0])


@pytest.mark.parametrize("lon0", [-10.0, 350.0])
def test_regional_grid_across_the_seam(lon0):
    """A grid spanning 350..10 E, written as -10..9 or as 350..369: same samples."""
    lon = lon0 + np.arange(20.0)
    lat = np.array([0.0, 1.0])
    east = np.arange(20.0)  # value = degrees east of 350 E
    v = np.vstack([east, east])
    pts = np.array([355.5, 359.9, 0.0, 5.25, -5.0, 365.25, 9.0])
    got = sample_grid(v, lat, lon, np.full(pts.shape, 0.5), pts)
    np.testing.assert_allclose(got, [5.5, 9.9, 10.0, 15.25, 5.0, 15.25, 19.0], atol=1e-9)
    outside = sample_grid(v, lat, lon, np.full(3, 0.5), np.array([9.5, 349.5, 180.0]))
    assert np.all(np.isnan(outside))


def test_edges_nan_and_outside():
    lat = np.array([89.5, 88.5, 87.5])  # descending, a polar band of 1-degree pixels
    lon = np.arange(0.5, 360.0, 1.0)
    v = np.tile(np.array([[1.0], [2.0], [3.0]]), (1, 360))
    v[1, 100] = np.nan
    got = sample_grid(v, lat, lon, [89.9, 90.0, 87.1, 86.9, 88.0, 88.5, 10.0], [0.0, 0.0, 0.0, 0.0, 0.0, 100.5, 0.0])
    # Within half a pixel of the outer centres: edge row; beyond: NaN; touching a NaN cell: NaN.
    np.testing.assert_allclose(got[:3], [1.0, 1.0, 3.0])
    assert np.isnan(got[3]) and got[4] == pytest.approx(2.5) and np.isnan(got[5]) and np.isnan(got[6])


def test_dataarray_wrapper_and_shapes():
    lat = np.array([0.0, 1.0])
    lon = np.array([0.0, 1.0, 2.0])
    da = xr.DataArray(np.arange(6.0).reshape(2, 3), dims=("lat", "lon"), coords={"lat": lat, "lon": lon})
    got = sample_reference_dem(da.transpose("lon", "lat"), np.array([[0.5, 0.5]]), np.array([[0.5, 1.5]]))
    assert got.shape == (1, 2)
    np.testing.assert_allclose(got, [[2.0, 3.0]])
    with pytest.raises(ValueError, match="dims"):
        sample_reference_dem(da.rename(lat="y"), 0.0, 0.0)
    with pytest.raises(ValueError, match="evenly spaced"):
        sample_grid(np.zeros((2, 3)), lat, np.array([0.0, 1.0, 3.0]), 0.0, 0.0)
