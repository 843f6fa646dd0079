"""Products for planetary software (issue 18 §1): the ISIS shape-model cube isis/dem_radius.cub and the
PDS4 labels pds/*.xml.

A small regional DEM is gridded for Mercury (datum 2439.4 km != IAU sphere 2440.53 km) and the Moon,
across the 0 deg meridian (lon -15..15: ISIS LongitudeDomain 180, CenterLongitude 0) and away from it
(lon 100..130: LongitudeDomain 360, CenterLongitude 180). The cube is read with rasterio and its label
parsed with pvl; each PDS4 label is read back with rasterio.
"""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
import rasterio
import xarray as xr

from mercury_dem.geometry.body import MERCURY, MOON
from mercury_dem.products.planetary import ISIS_NULL_REAL, load_isis_label
from tests.products.regional import LAT, PPD

CASES = {
    "mercury_across_0": (MERCURY, (-15.0, 15.0)),
    "moon_across_0": (MOON, (-15.0, 15.0)),
    "mercury_100_130": (MERCURY, (100.0, 130.0)),
    "moon_100_130": (MOON, (100.0, 130.0)),
}
PDS = ("equirectangular", "north_polar", "south_polar")


#: The fast loop (-m "not integration") grids one Mercury case across 0 deg and one Moon case away from it
#: (~1.7 s of CPU each, gridded once for both test_product_metadata and test_isis_pds4_products: conftest
#: regional_run); make test runs every case.
_FAST = {"mercury_across_0", "moon_100_130"}


@pytest.fixture(scope="module", params=[c if c in _FAST else pytest.param(c, marks=pytest.mark.integration)
                                             for c in CASES])
def run(request, regional_run):
    """(body, lon bounds, run dir, summary): dem.zarr and the products of a small regional DEM with a gap."""
    body, lons = CASES[request.param]
    d, summary = regional_run(body, lons)
    lon_min, lon_max = lons
    return body, (lon_min, lon_max), d, summary


def _dem(d):
    return xr.open_zarr(str(d / "dem.zarr"), consolidated=False, decode_coords="all")


def test_radius_cube_values_are_datum_plus_elevation_and_null(run):
    body, _, d, summary = run
    elev = _dem(d).elevation.values
    cube = d / "products/isis/dem_radius.cub"
    assert summary["isis"]["path"] == str(cube) and str(cube) in summary["files"]
    with rasterio.open(cube) as src:
        assert src.driver == "ISIS3" and src.count == 1 and src.dtypes == ("float32",)
        assert (src.height, src.width) == elev.shape
        assert src.nodata == ISIS_NULL_REAL
        v = src.read(1)
        mask = src.read_masks(1)
    hole = ~np.isfinite(elev)
    assert 0 < hole.sum() < hole.size // 4  # the gap in the points left NaN pixels
    np.testing.assert_array_equal(v == ISIS_NULL_REAL, hole)  # NaN <-> ISIS Null, nowhere else
    np.testing.assert_array_equal(mask == 0, hole)
    want = (body.datum_radius_m + elev.astype(np.float64)).astype(np.float32)
    np.testing.assert_array_equal(v[~hole], want[~hole])
    for i, j in ((0, 0), (37, 11), (150, 59), (449, 89)):
        if not hole[i, j]:
            assert abs(float(v[i, j]) - (body.datum_radius_m + float(elev[i, j]))) <= 0.25  # float32 step at 2440 km
    # The raw bytes are ISIS's Null (0xFF7FFFFB), not NaN (ISIS would take a NaN for a valid radius).
    label = load_isis_label(str(cube))
    start = int(label["IsisCube"]["Core"]["StartByte"]) - 1
    raw = np.fromfile(cube, dtype="<f4", offset=start, count=elev.size).reshape(elev.shape)
    assert not np.isnan(raw).any()
    assert (raw.view("<u4")[hole] == 0xFF7FFFFB).all()


def test_radius_cube_label_is_an_isis_shape_model_of_the_body(run):
    body, (lon_min, lon_max), d, _ = run
    ds = _dem(d)
    mp = load_isis_label(str(d / "products/isis/dem_radius.cub"))["IsisCube"]["Mapping"]
    crosses = lon_min < 0
    assert mp["TargetName"] == body.name.title()  # "Mercury"/"Moon", not the CRS's name
    assert mp["ProjectionName"] == "Equirectangular" and float(mp["CenterLatitude"]) == 0.0
    assert mp["LatitudeType"] == "Planetocentric" and mp["LongitudeDirection"] == "PositiveEast"
    assert mp["LongitudeDomain"] == (180 if crosses else 360)
    assert float(mp["CenterLongitude"]) == (0.0 if crosses else 180.0)
    R = body.radius_m  # the sphere of the map coordinates (the IAU sphere)
    assert mp["EquatorialRadius"].value == mp["PolarRadius"].value == R
    assert mp["EquatorialRadius"].units == "meters"
    # Extent and resolution match dem.zarr.
    assert mp["Scale"].value == pytest.approx(PPD, rel=1e-12)
    assert mp["PixelResolution"].value == pytest.approx(R * math.radians(1 / PPD), rel=1e-12)
    west = lon_min if crosses else lon_min % 360
    assert (float(mp["MinimumLatitude"]), float(mp["MaximumLatitude"])) == LAT
    assert (float(mp["MinimumLongitude"]), float(mp["MaximumLongitude"])) == (west, west + lon_max - lon_min)
    clon = float(mp["CenterLongitude"])
    assert float(mp["UpperLeftCornerX"]) == pytest.approx(R * math.radians(west - clon), abs=1e-6)
    assert float(mp["UpperLeftCornerY"]) == pytest.approx(R * math.radians(LAT[1]), abs=1e-6)
    # Pixel centres back to latitude/longitude with the cube's own CRS: dem.zarr's coordinates.
    with rasterio.open(d / "products/isis/dem_radius.cub") as src:
        t = src.transform
        x = t.c + (np.arange(src.width) + 0.5) * t.a
        y = t.f + (np.arange(src.height) + 0.5) * t.e
        tr = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(src.crs.to_wkt()), body.crs("geographic"),
                                         always_xy=True)
        lon, _ = tr.transform(x, np.zeros_like(x))
        _, lat = tr.transform(np.full_like(y, clon * 0), y)
    np.testing.assert_allclose(np.mod(lon, 360), np.mod(ds.lon.values, 360), atol=1e-9)
    np.testing.assert_allclose(lat, ds.lat.values, atol=1e-9)


@pytest.mark.parametrize("name", PDS)
def test_pds4_labels_read_back_as_the_geotiffs(run, name):
    body, _, d, summary = run
    tif, xml = d / f"products/pds/{name}.tif", d / f"products/pds/{name}.xml"
    assert str(xml) in summary["files"] and summary["pds"][name]["pds4"]["path"] == str(xml)
    with rasterio.open(tif) as a, rasterio.open(xml) as b:
        assert b.driver == "PDS4"
        assert (b.width, b.height, b.count, b.dtypes) == (a.width, a.height, 1, ("float32",))
        assert b.transform.almost_equals(a.transform, precision=1e-6)
        assert pyproj.CRS.from_wkt(b.crs.to_wkt()).ellipsoid.semi_major_metre == body.radius_m
        assert b.units == ("m",)
        va, vb = a.read(1), b.read(1)
        np.testing.assert_array_equal(va, vb)  # the label describes the GeoTIFF's own pixels
        assert np.isfinite(vb).any()
        t = b.transform
        probe = (t.c + t.a * (b.width // 2 + 0.5), t.f + t.e * (b.height // 3 + 0.5))
        want = pyproj.Transformer.from_crs(summary["pds"][name]["crs"], body.crs("geographic"),
                                           always_xy=True).transform(*probe)
        got = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(b.crs.to_wkt()), body.crs("geographic"),
                                          always_xy=True).transform(*probe)
        np.testing.assert_allclose(np.mod(got[0] - want[0] + 180, 360) - 180, 0, atol=1e-9)
        assert got[1] == pytest.approx(want[1], abs=1e-9)
    text = xml.read_text()
    assert f"<file_name>{tif.name}</file_name>" in text
    assert f"<name>{body.name.title()}</name>" in text and "(2015) - Sphere</name>" not in text.split(
        "</Target_Identification>")[0]


def test_no_temporary_files_left(run):
    _, _, d, _ = run
    left = [p.name for p in (d / "products").rglob(".*")]
    assert left == []


def test_pds4_label_of_a_geotiff_with_empty_strips(tmp_path):
    """GDAL defers all-NaN / all-zero strips of an uncompressed GeoTIFF to the file's end unless told not
    to; the raw layout keeps them in order, so the PDS4 label can describe the pixels as one array."""
    from mercury_dem.products.geotiff import pixel_transform, write_raster
    from mercury_dem.products.planetary import write_pds4_label

    a = np.full((130, 90), np.nan, dtype=np.float32)
    a[60:70] = 5.0
    a[100:] = 0.0
    p = write_raster(a, pixel_transform(-1e5, 1e5, 1000.0), MOON.crs("north_polar"), tmp_path / "cap.tif", raw=True)
    info = write_pds4_label(p, MOON, (0.0, 65.0, 360.0, 90.0))
    with rasterio.open(info["path"]) as b:
        np.testing.assert_array_equal(b.read(1), a)
    assert f"<name>{MOON.name.title()}</name>" in (tmp_path / "cap.xml").read_text()
