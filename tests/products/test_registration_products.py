"""Products of the registered and merged DEMs (issue 16 §2): the same read-back checks as the adjusted DEM's.

A regional Mercury DEM across 0° (lon −15…15, with a gap) is registered to synthetic near-polar shots of its
own surface 200 m higher (:func:`register_dem_store`), then :func:`make_registration_products` writes the
products of ``registered.zarr`` and ``merged.zarr``. Each map's products are read back with rasterio by the
checks of the adjusted DEM (``test_product_metadata``, ``test_isis_pds4_products``), pointed at that map: a
directory whose ``dem.zarr`` is the map and whose ``products`` are its products. CRS, units, extent and
pixel values are therefore compared with the map's own zarr, not with ``dem.zarr``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr

import tests.products.test_isis_pds4_products as isis_checks
import tests.products.test_product_metadata as meta_checks
from mercury_dem.config.dem import DemConfig
from mercury_dem.geometry.body import MERCURY
from mercury_dem.pipeline.register_stage import make_registration_products, register_dem_store
from tests.products.regional import LAT, PPD, height, regional_products

#: The register stage and the products stage end to end on a regional DEM (~7 s of set-up): not the fast loop.
pytestmark = pytest.mark.integration

LONS = (-15.0, 15.0)
UP_M = 200.0


def _shots(rng: np.random.Generator) -> pd.DataFrame:
    """Near-polar profiles over 0–40 N, lon −9…9 (six 10° tiles), of the true surface ``UP_M`` higher."""
    frames = []
    for k, lon0 in enumerate(rng.uniform(-9.0, 9.0, 24)):
        lat = np.arange(0.5, 39.5, 0.02)
        lon = (lon0 + 0.05 * (lat - 20.0)) % 360
        radius = MERCURY.datum_radius_m + height(lat, lon) + UP_M + rng.normal(0, 3.0) + rng.normal(0, 1.0, lat.size)
        frames.append(pd.DataFrame({"lat": lat, "lon": lon, "radius_m": radius, "profile_id": k}))
    return pd.concat(frames, ignore_index=True)


@pytest.fixture(scope="module")
def reg_dir(tmp_path_factory):
    """DIR with dem.zarr (+ products), registered.zarr, merged.zarr and their products; the summaries."""
    d = tmp_path_factory.mktemp("registration_products")
    regional_products(MERCURY, LONS, d, seed=7, max_distance_m=60_000.0, hole=True)
    summary = register_dem_store(d / "dem.zarr", _shots(np.random.default_rng(11)), d)
    cfg = DemConfig(pixels_per_degree=PPD, browse_width=120, stats_pixel_km=60.0)
    products = make_registration_products(d, d / "products", cfg)
    return d, summary, products


@pytest.fixture(scope="module", params=["registered", "merged"])
def view(request, reg_dir):
    """A directory where ``dem.zarr`` is the map and ``products`` its products (symlinks), for the checks."""
    d, _, products = reg_dir
    key = request.param
    v = d / f"view_{key}"
    v.mkdir(exist_ok=True)
    for link, target in (("dem.zarr", d / f"{key}.zarr"), ("products", d / "products" / key)):
        if not (v / link).exists():
            (v / link).symlink_to(target, target_is_directory=True)
    return key, v, products[key]


def test_registration_was_applied(reg_dir):
    """The maps are not the adjusted DEM again: the registered DEM is ~UP_M higher where shots were."""
    d, summary, products = reg_dir
    assert summary["tiles_registered"] >= 4 and summary["merged_dense_pixels"] > 50
    dem = xr.open_zarr(d / "dem.zarr", consolidated=False)
    for key in ("registered", "merged"):
        m = xr.open_zarr(d / f"{key}.zarr", consolidated=False)
        diff = (m.elevation - dem.elevation).sel(lat=slice(35, 5), lon=slice(-5, 5)).values
        assert abs(float(np.nanmedian(diff)) - UP_M) < 20.0, (key, np.nanmedian(diff))
    fig = d / "products/registration/rms_per_tile.png"
    assert fig.read_bytes() == (d / "registration/rms_per_tile.png").read_bytes()
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and str(fig) in products["files"]


def test_geotiffs_units_square_pixels(view):
    _, v, _ = view
    for name in meta_checks.TIFS:
        meta_checks.test_every_geotiff_band_has_units_description_square_pixels((MERCURY, LONS, v), name)


def test_dem_tif_extent_crs_and_values(view):
    meta_checks.test_dem_tif_extent_crs_and_values((MERCURY, LONS, view[1]))


def test_pds_equirectangular_and_caps(view):
    _, v, _ = view
    meta_checks.test_pds_equirectangular_central_meridian_extent_and_values((MERCURY, LONS, v))
    for cap in ("north", "south"):
        meta_checks.test_polar_caps_crs_and_values((MERCURY, LONS, v), cap)


def test_isis_cube_and_pds4_labels(view):
    _, v, summary = view
    run = (MERCURY, LONS, v, {**summary, "files": [f.replace(str(v.parent / "products" / view[0]),
                                                             str(v / "products")) for f in summary["files"]]})
    run[3]["isis"] = {**summary["isis"], "path": str(v / "products/isis/dem_radius.cub")}
    isis_checks.test_radius_cube_values_are_datum_plus_elevation_and_null(run)
    isis_checks.test_radius_cube_label_is_an_isis_shape_model_of_the_body(run)
    for name in isis_checks.PDS:
        pds = summary["pds"][name]
        run[3]["pds"] = {name: {**pds, "pds4": {**pds["pds4"], "path": str(v / f"products/pds/{name}.xml")}}}
        isis_checks.test_pds4_labels_read_back_as_the_geotiffs(run, name)


def test_browse_images(view):
    key, v, _ = view
    from PIL import Image

    for name in ("greyscale", "hillshade", "colour_hillshade", "robinson"):
        with Image.open(v / f"products/browse/{name}.png") as im:
            assert im.format == "PNG" and im.width > 50 and im.height > 10
    assert not (v / "products/browse/coverage_distance.png").exists()  # the DEM's coverage is not repeated


def test_existing_products_are_not_replaced(reg_dir):
    from mercury_dem.exceptions import StoreError

    d, _, _ = reg_dir
    with pytest.raises(StoreError, match="already exists"):
        make_registration_products(d, d / "products", DemConfig(pixels_per_degree=PPD))
