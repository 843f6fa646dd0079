"""Metadata that planetary/GIS tools read (issue 18 §1): datum, grid mapping and CF attributes agree,
band units, a CRS on coverage.zarr, valid longitudes across 0 deg, exactly square pixels.

A small regional DEM is gridded for Mercury (datum 2439.4 km != IAU sphere 2440.53 km) and the Moon
(datum == IAU sphere), across the 0 deg meridian (lon -15..15 and the same area as 345..375) and away
from it (lon 100..130); every GeoTIFF is read back with rasterio.
"""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pyproj
import pytest
import rasterio
import rioxarray  # noqa: F401  (registers the .rio accessor the tests read the CRS with)
import xarray as xr

from mercury_dem.geometry.body import MERCURY, MOON
from mercury_dem.products.sampling import sample_bilinear
from tests.products.regional import LAT, PPD

CASES = {
    "mercury_across_0": (MERCURY, (-15.0, 15.0)),
    "moon_across_0": (MOON, (-15.0, 15.0)),
    "mercury_345_375": (MERCURY, (345.0, 375.0)),
    "moon_100_130": (MOON, (100.0, 130.0)),
}
TIFS = ("dem.tif", "pds/equirectangular.tif", "pds/north_polar.tif", "pds/south_polar.tif")


#: The fast loop (-m "not integration") grids one Mercury case across 0 deg and one Moon case away from it
#: (~1.7 s of CPU each, gridded once for both test_product_metadata and test_isis_pds4_products: conftest
#: regional_run); make test runs every case.
_FAST = {"mercury_across_0", "moon_100_130"}


@pytest.fixture(scope="module", params=[c if c in _FAST else pytest.param(c, marks=pytest.mark.integration)
                                             for c in CASES])
def run(request, regional_run):
    """(body, lon bounds, run dir): dem.zarr + coverage.zarr + products of a small regional DEM (with a gap;
    the same as test_isis_pds4_products').
    """
    body, lons = CASES[request.param]
    d, _ = regional_run(body, lons)
    lon_min, lon_max = lons
    return body, (lon_min, lon_max), d


def _centres(src):
    t = src.transform
    return t.c + (np.arange(src.width) + 0.5) * t.a, t.f + (np.arange(src.height) + 0.5) * t.e


def _radius(crs) -> float:
    return pyproj.CRS.from_user_input(crs.to_wkt() if hasattr(crs, "to_wkt") else crs).ellipsoid.semi_major_metre


def test_dem_zarr_grid_mapping_is_the_datum_sphere(run):
    body, _, d = run
    ds = xr.open_zarr(str(d / "dem.zarr"), consolidated=False, decode_coords="all")
    el = ds.elevation
    assert el.attrs["standard_name"] == "height_above_reference_ellipsoid" and el.attrs["units"] == "m"
    assert el.encoding["grid_mapping"] == "spatial_ref"
    # A CF-aware reader takes the reference ellipsoid from the grid mapping: it must be the datum.
    assert ds.rio.crs is not None and _radius(ds.rio.crs) == body.datum_radius_m
    assert ds.spatial_ref.attrs["semi_major_axis"] == body.datum_radius_m
    assert ds.spatial_ref.attrs["semi_minor_axis"] == body.datum_radius_m
    assert pyproj.CRS.from_wkt(ds.spatial_ref.attrs["crs_wkt2"]).ellipsoid.semi_major_metre == body.datum_radius_m
    assert ds.attrs["datum_radius_m"] == body.datum_radius_m
    # crs_code: the IAU code of the same latitude/longitude (exactly the grid mapping for the Moon).
    assert ds.spatial_ref.attrs["crs_code"] == body.crs("geographic")
    iau = pyproj.CRS.from_user_input(body.crs("geographic"))
    if body is MOON:
        assert pyproj.CRS.from_wkt(ds.spatial_ref.attrs["crs_wkt2"]) == iau
    else:
        assert iau.ellipsoid.semi_major_metre == body.radius_m != body.datum_radius_m
    tr = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(ds.rio.crs.to_wkt()), iau, always_xy=True)
    np.testing.assert_allclose(tr.transform([-10.0, 120.0], [33.0, -60.0]), [[-10.0, 120.0], [33.0, -60.0]], atol=1e-9)


def test_coverage_zarr_has_a_sinusoidal_crs_of_the_datum(run):
    body, _, d = run
    cov = xr.open_zarr(str(d / "coverage.zarr"), consolidated=False, decode_coords="all")
    crs = pyproj.CRS.from_wkt(cov.rio.crs.to_wkt())
    assert crs.is_projected and crs.ellipsoid.semi_major_metre == body.datum_radius_m
    assert crs.axis_info[0].unit_name == "kilometre"
    assert cov.nearest_point_distance.encoding["grid_mapping"] == "spatial_ref"
    # A point of the map back to latitude/longitude: y = R lat, x = R lon cos(lat) (km).
    tr = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    lon, lat = tr.transform(float(cov.x[len(cov.x) // 2 + 3]), float(cov.y[len(cov.y) // 3]))
    rk = body.datum_radius_m / 1000
    assert lat == pytest.approx(math.degrees(float(cov.y[len(cov.y) // 3]) / rk), abs=1e-9)
    assert lon == pytest.approx(math.degrees(float(cov.x[len(cov.x) // 2 + 3]) / (rk * math.cos(math.radians(lat)))),
                                abs=1e-9)


@pytest.mark.parametrize("name", TIFS)
def test_every_geotiff_band_has_units_description_square_pixels(run, name):
    body, _, d = run
    with rasterio.open(d / "products" / name) as src:
        assert src.count == 1 and src.units == ("m",)
        assert src.descriptions[0] and "datum" in src.descriptions[0]
        assert src.dtypes[0] == "float32" and np.isnan(src.nodata)
        assert abs(src.res[0]) == abs(src.res[1])  # exactly, not approximately
        assert src.transform.b == 0 and src.transform.d == 0
        assert src.tags()["DATUM_RADIUS_M"] == f"{body.datum_radius_m:.1f}"
        assert src.tags()["BODY"] == body.name


def test_dem_tif_extent_crs_and_values(run):
    body, (lon_min, lon_max), d = run
    ds = xr.open_zarr(str(d / "dem.zarr"), consolidated=False, decode_coords="all")
    crosses = lon_min < 0 or lon_max > 360
    west = ((lon_min + 180) % 360 - 180) if crosses else lon_min % 360
    with rasterio.open(d / "products/dem.tif") as src:
        assert src.res == (1 / PPD, 1 / PPD)
        assert (src.bounds.left, src.bounds.top) == (west, LAT[1])  # origin from the bounds, exactly
        np.testing.assert_allclose([src.bounds.right, src.bounds.bottom], [west + lon_max - lon_min, LAT[0]],
                                   rtol=0, atol=1e-9)
        assert src.bounds.right <= 360 and src.bounds.left >= -180
        assert _radius(src.crs) == body.datum_radius_m  # the same grid mapping as dem.zarr
        if body is MOON:
            assert src.crs.to_string() == body.crs("geographic")  # the datum is the IAU sphere: its code
        x, y = _centres(src)
        lon, lat = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(src.crs.to_wkt()), body.crs("geographic"),
                                               always_xy=True).transform(x, np.zeros_like(x))
        np.testing.assert_allclose(np.mod(lon, 360), np.mod(ds.lon.values, 360), atol=1e-9)
        np.testing.assert_allclose(y, ds.lat.values, atol=1e-12)
        v = src.read(1)
    elev = ds.elevation.values
    assert np.isfinite(elev).mean() > 0.9
    np.testing.assert_array_equal(v, elev)
    for i, j in ((0, 0), (37, 11), (150, 59), (449, 89)):
        np.testing.assert_array_equal(v[i, j], elev[i, j])  # NaN where the map has none (a registered map's edge)


def test_pds_equirectangular_central_meridian_extent_and_values(run):
    body, (lon_min, lon_max), d = run
    ds = xr.open_zarr(str(d / "dem.zarr"), consolidated=False, decode_coords="all")
    crosses = lon_min < 0 or lon_max > 360
    rows = np.abs(ds.lat.values) < 65
    R = body.radius_m
    with rasterio.open(d / "products/pds/equirectangular.tif") as src:
        clon = 0.0 if crosses else 180.0
        assert src.tags()["CENTER_LONGITUDE"] == f"{clon:g}"
        want = pyproj.CRS.from_user_input(body.crs("equirectangular" if crosses else "equirectangular_180"))
        got = pyproj.CRS.from_wkt(src.crs.to_wkt())
        # Same CRS: points transform identically.
        probe = ([-1e5, 3e5], [2e5, -4e5])
        to_geo = pyproj.Transformer.from_crs(got, body.crs("geographic"), always_xy=True)
        np.testing.assert_allclose(to_geo.transform(*probe),
                                   pyproj.Transformer.from_crs(want, body.crs("geographic"), always_xy=True)
                                   .transform(*probe), atol=1e-9)
        # x within the projection's +-pi R: the map's longitudes are within 180 deg of clon.
        assert -math.pi * R <= src.bounds.left < src.bounds.right <= math.pi * R
        assert src.res[0] == src.res[1] == R * math.radians(1 / PPD)
        x, y = _centres(src)
        lon, _ = to_geo.transform(x, np.zeros_like(x))
        _, lat = to_geo.transform(np.zeros_like(y), y)
        np.testing.assert_allclose(np.mod(lon, 360), np.mod(ds.lon.values, 360), atol=1e-6)
        np.testing.assert_allclose(lat, ds.lat.values[rows], atol=1e-6)
        np.testing.assert_array_equal(src.read(1), ds.elevation.values[rows])


@pytest.mark.parametrize("cap", ["north", "south"])
def test_polar_caps_crs_and_values(run, cap):
    body, _, d = run
    ds = xr.open_zarr(str(d / "dem.zarr"), consolidated=False, decode_coords="all")
    with rasterio.open(d / f"products/pds/{cap}_polar.tif") as src:
        v = src.read(1)
        x, y = _centres(src)
        assert src.bounds.left == -src.bounds.right and src.bounds.top == -src.bounds.bottom
        xx, yy = np.meshgrid(x, y)
        lon, lat = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(src.crs.to_wkt()), body.crs("geographic"),
                                               always_xy=True).transform(xx, yy)
        # The IAU polar CRS: the pole at the centre, the IAU sphere's scale.
        ref = pyproj.Transformer.from_crs(body.crs(f"{cap}_polar"), body.crs("geographic"), always_xy=True)
        np.testing.assert_allclose(ref.transform(xx[::17, ::17], yy[::17, ::17]), (lon[::17, ::17], lat[::17, ::17]),
                                   atol=1e-9)
    ok = np.isfinite(v)
    assert ok.sum() > 50
    assert (np.abs(lat[ok]) >= 65 - 1e-6).all()
    # The values are the DEM's, sampled at the pixel centres' latitude/longitude.
    want = sample_bilinear(ds.elevation.values, ds.lat.values, ds.lon.values, lat[ok], lon[ok])
    np.testing.assert_allclose(v[ok], want, rtol=1e-6, atol=1e-3)


@pytest.mark.skipif(shutil.which("gdal_translate") is None, reason="gdal_translate (Debian gdal-bin) not installed")
@pytest.mark.parametrize("name", ["dem.tif", "pds/equirectangular.tif"])
def test_gdal_isis3_writer_accepts_the_geotiffs(run, name, tmp_path):
    # GDAL's ISIS3 writer refuses non-square pixels (even a 13th-digit difference).
    out = tmp_path / "out.cub"
    res = subprocess.run(["gdal_translate", "-q", "-of", "ISIS3", str(run[2] / "products" / name), str(out)],
                         capture_output=True, text=True)
    # (it then reports "ERROR 6: Only north-up geotransform with square pixels supported" on stderr,
    # exits 0 and writes a cube without its Mapping group)
    assert res.returncode == 0 and "ERROR" not in res.stderr, res.stderr
    label = out.read_bytes()[:65536].decode("ascii", "replace")
    assert "Group = Mapping" in label and "PixelResolution" in label
