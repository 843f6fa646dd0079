"""The ``tiny`` synthetic mission on the Moon, end to end: every product says Moon and measures from 1737.4 km.

``mercury-dem synth --preset tiny --body moon`` keeps the preset's area, cameras and pixel scales on a
body of 1737.4 km (18 images instead of ~40): a pipeline that assumed Mercury anywhere below the mission
would put heights ~702 km off (radius minus Mercury's 2439.4 km datum), or its products on Mercury's CRS.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = pytest.mark.integration

MOON_DATUM_M = 1_737_400.0
#: The Moon's range of heights above that sphere (LOLA: -9.2 km in Antoniadi, +10.8 km near Korolev).
MOON_HEIGHTS_M = (-9_200.0, 10_800.0)


def test_dem_zarr_heights_are_moon_radius_minus_its_datum(moon_tiny_run: tuple[Path, dict[str, Any]]) -> None:
    from mercury_dem.pipeline.dem_stage import open_dem

    run, report = moon_tiny_run
    ds = open_dem(run / "dem.zarr")
    assert json.loads(ds.attrs["body"])["name"] == "MOON" and ds.attrs["datum_radius_m"] == MOON_DATUM_M
    assert "1737.4 km" in ds.attrs["height_reference"]
    e, r = ds.elevation.values, ds.radius.values
    ok = np.isfinite(e)
    assert ok.mean() > 0.4
    np.testing.assert_allclose(r[ok] - MOON_DATUM_M, e[ok], atol=0.25)  # float32 radii step 0.125 m
    assert MOON_HEIGHTS_M[0] < np.nanmin(e) < np.nanmax(e) < MOON_HEIGHTS_M[1]
    assert ds.rio.crs is not None and "1737400" in ds.rio.crs.to_wkt()


def test_dem_against_the_synthetic_truth(moon_tiny_run: tuple[Path, dict[str, Any]]) -> None:
    """Measured (seed 42): adjusted 688 m, merged with the altimetry 621 m RMSE vs the truth over ~24,000
    pixels at 4 pixel/deg; the a-priori DEM ~10 km. The Mercury tiny run's adjusted DEM is tested the same way.
    """
    _, report = moon_tiny_run
    v = report["validation"]["dem"]
    assert v["adjusted"]["n_compared"] > 15_000
    assert v["adjusted"]["rmse_m"] < 1_000.0 and abs(v["adjusted"]["bias_m"]) < 400.0, v["adjusted"]
    for key in ("adjusted", "merged"):
        assert v[key]["rmse_m"] < v["a_priori"]["rmse_m"] / 5


def test_geotiff_pds_and_isis_products(moon_tiny_run: tuple[Path, dict[str, Any]]) -> None:
    import rasterio

    from mercury_dem.pipeline.dem_stage import open_dem

    run, _ = moon_tiny_run
    e = open_dem(run / "dem.zarr").elevation.values
    ok = np.isfinite(e)
    with rasterio.open(run / "products" / "dem.tif") as f:
        a = f.read(1, masked=True).filled(np.nan)
        assert f.units == ("m",) and f.tags()["BODY"] == "MOON"
        assert float(f.tags()["DATUM_RADIUS_M"]) == MOON_DATUM_M and "1737400" in f.crs.to_wkt()
    np.testing.assert_array_equal(a[ok], e[ok])
    with rasterio.open(run / "products" / "pds" / "equirectangular.tif") as f:
        a = f.read(1, masked=True).filled(np.nan)
        assert f.crs.to_string() in ("IAU_2015:30110", "IAU_2015:30115") and f.tags()["BODY"] == "MOON"
    assert np.nanmin(a) == pytest.approx(np.nanmin(e)) and np.nanmax(a) == pytest.approx(np.nanmax(e))
    xml = (run / "products" / "pds" / "equirectangular.xml").read_text()
    assert "<name>Moon</name>" in xml and "Mercury" not in xml
    with rasterio.open(run / "products" / "isis" / "dem_radius.cub") as f:
        a = f.read(1, masked=True).filled(np.nan).astype(np.float64)
        assert "1737400" in f.crs.to_wkt()
    np.testing.assert_allclose(a[ok] - MOON_DATUM_M, e[ok], atol=0.25)
    assert "Moon" in (run / "products" / "isis" / "dem_radius.cub").read_bytes()[:65536].decode("latin-1")


def test_statistics_browse_coverage_and_report(moon_tiny_run: tuple[Path, dict[str, Any]]) -> None:
    run, report = moon_tiny_run
    stats = json.loads((run / "products" / "statistics.json").read_text())["global"]
    assert MOON_HEIGHTS_M[0] < stats["min_m"] < stats["max_m"] < MOON_HEIGHTS_M[1]
    assert stats["n_pixels"] > 0
    for name in ("greyscale.png", "hillshade.png", "colour_hillshade.png", "robinson.png"):
        assert (run / "products" / "browse" / name).stat().st_size > 1000, name
    # the coverage map is an equal-area map of the grid's box on the Moon's sphere (Mercury's: twice the area)
    cov = json.loads((run / "products" / "coverage.json").read_text())
    r_km, (lat0, lat1, lon0, lon1) = MOON_DATUM_M / 1000, (-20.0, 30.0, -25.0, 25.0)  # TINY_OVERRIDES' grid
    box = r_km**2 * np.radians(lon1 - lon0) * (np.sin(np.radians(lat1)) - np.sin(np.radians(lat0)))
    assert cov["map_area_km2"] == pytest.approx(box, rel=0.02)
    assert report["body"]["name"] == "MOON" and report["body"]["datum_radius_m"] == MOON_DATUM_M
    # every run is checked against its body's shape without configuration: a synthetic body's is its truth
    check = report["dem"]["shape_check"]
    assert check["status"] == "ok" and check["body"] == "MOON" and "synthetic truth" in check["shape"]["name"]
    assert abs(check["bias_m"]) < 300.0 and check["n"] > 0
