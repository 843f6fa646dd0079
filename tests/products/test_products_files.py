"""Product files: GeoTIFF/COG with the Mercury CRS, PDS equirectangular and polar caps, PNGs, JSON."""

from __future__ import annotations

import json
import shutil
import subprocess

import matplotlib.image as mpimg
import numpy as np
import pyproj
import pytest
import rasterio
from products_synthetic import CFG, NOISE_M, truth_height

from mercury_dem.exceptions import GridError, StoreError
from mercury_dem.geometry.body import CRS_GEOGRAPHIC, DATUM_RADIUS_M, MERCURY, latlon_to_xyz
from mercury_dem.products.make import make_products, open_dem


def _centres(src):
    """Pixel-centre x (W,), y (H,) of a north-up raster."""
    t = src.transform
    return t.c + (np.arange(src.width) + 0.5) * t.a, t.f + (np.arange(src.height) + 0.5) * t.e


def test_geotiff_is_the_dem_with_mercury_crs(dem_dir, products):
    ds = open_dem(dem_dir / "dem.zarr")
    with rasterio.open(dem_dir / "products/dem.tif") as src:
        # The grid mapping of dem.zarr: the datum sphere (heights are above the CRS's own ellipsoid),
        # with the latitude/longitude of IAU_2015:19900.
        crs = pyproj.CRS.from_user_input(src.crs.to_wkt())
        assert crs.is_geographic and crs.ellipsoid.semi_major_metre == 2439400.0
        lon, lat = pyproj.Transformer.from_crs(crs, CRS_GEOGRAPHIC, always_xy=True).transform([10.0, 250.0], [-30.0, 60.0])
        np.testing.assert_allclose([lon, lat], [[10.0, 250.0], [-30.0, 60.0]], atol=1e-9)
        assert src.units == ("m",) and "datum" in src.descriptions[0]
        assert src.dtypes[0] == "float32" and np.isnan(src.nodata)
        assert src.overviews(1)  # cloud-optimised: overviews inside
        x, y = _centres(src)
        np.testing.assert_allclose(x, ds.lon.values)
        np.testing.assert_allclose(y, ds.lat.values)
        np.testing.assert_array_equal(src.read(1), ds.elevation.values)
        assert src.tags()["DATUM_RADIUS_M"] == "2439400.0"


@pytest.mark.skipif(shutil.which("gdalinfo") is None, reason="gdalinfo (Debian gdal-bin) not installed")
def test_gdalinfo_opens_the_cog_with_mercury_crs(products, dem_dir):
    out = subprocess.run(["gdalinfo", str(dem_dir / "products/dem.tif")], capture_output=True, text=True,
                         check=True).stdout
    assert "Mercury datum sphere (R = 2439400 m) / Ocentric" in out
    assert "LAYOUT=COG" in out
    assert "2439400" in out and "2440530" not in out.split("Metadata:")[0]


def test_pds_equirectangular_is_affine_cut(dem_dir, products):
    ds = open_dem(dem_dir / "dem.zarr")
    with rasterio.open(dem_dir / "products/pds/equirectangular.tif") as src:
        x, y = _centres(src)
        tr = pyproj.Transformer.from_crs(src.crs, CRS_GEOGRAPHIC, always_xy=True)
        lon, _ = tr.transform(x, np.zeros_like(x))
        _, lat = tr.transform(np.zeros_like(y), y)
        rows = np.abs(ds.lat.values) < 65
        np.testing.assert_allclose(lat, ds.lat.values[rows], atol=1e-6)
        np.testing.assert_allclose(np.mod(lon, 360), ds.lon.values, atol=1e-6)
        np.testing.assert_array_equal(src.read(1), ds.elevation.values[rows])


@pytest.mark.parametrize("cap", ["north", "south"])
def test_polar_caps_are_reprojected_truth(dem_dir, products, cap):
    with rasterio.open(dem_dir / f"products/pds/{cap}_polar.tif") as src:
        v = src.read(1)
        x, y = _centres(src)
        xx, yy = np.meshgrid(x, y)
        # Compare CRSs by transforming points (GDAL renames the stereographic variant).
        lon, lat = pyproj.Transformer.from_crs(src.crs, CRS_GEOGRAPHIC, always_xy=True).transform(xx, yy)
    ok = np.isfinite(v)
    assert ok.mean() > 0.6  # the inscribed circle of lat 65 is ~79 % of the square
    assert (np.abs(lat[ok]) >= 65 - 1e-6).all()
    assert (np.sign(lat[ok]) == (1 if cap == "north" else -1)).all()
    err = v[ok] - truth_height(lat[ok], lon[ok])
    # The reprojected cap is as close to the truth as the DEM's own cap pixels are (the truth's
    # three-lobed pattern is sharp at the pole, so the DEM error there exceeds the equatorial one).
    ds = open_dem(dem_dir / "dem.zarr")
    la2, lo2 = np.meshgrid(ds.lat.values, ds.lon.values, indexing="ij")
    in_cap = (la2 >= 65) if cap == "north" else (la2 <= -65)
    e_dem = (ds.elevation.values - truth_height(la2, lo2))[in_cap]
    rmse_dem = np.sqrt(np.nanmean(e_dem**2))
    assert np.sqrt(np.mean(err**2)) < 1.2 * rmse_dem + 2.0
    assert rmse_dem < 2 * NOISE_M
    assert products["pds"][f"{cap}_polar"]["valid_fraction_in_cap"] > 0.99


def test_browse_pngs_look_like_the_dem(dem_dir, products):
    ds = open_dem(dem_dir / "dem.zarr")
    grey = mpimg.imread(dem_dir / "products/browse/greyscale.png")
    assert grey.shape[:2] == (360, 720)
    elev = ds.elevation.values
    ok = np.isfinite(elev)
    assert (grey[..., 3][~ok] == 0).all()  # no value = transparent
    # Grey level is a monotone stretch of elevation.
    r = np.corrcoef(grey[..., 0][ok], np.clip(elev[ok], *np.percentile(elev[ok], [1, 99])))[0, 1]
    assert r > 0.999
    for name in ("hillshade", "colour_hillshade", "robinson", "coverage_distance", "error_vs_truth"):
        img = mpimg.imread(dem_dir / f"products/browse/{name}.png")
        assert img.shape[0] > 100 and img.shape[1] > 300
        assert img[..., :3].std() > 0.05  # not blank


def test_longitude_ticks_across_the_seam_say_the_longitude():
    # A regional map across 0/360 runs on past 360 to stay continuous; its ticks must not say 365.
    from mercury_dem.products.browse import east_longitude_label

    assert [east_longitude_label(x) for x in (340.0, 355.0, 360.0, 365.0, 372.5, -10.0)] == [
        "340", "355", "0", "5", "12.5", "350"]


def test_error_map_shows_high_red_low_blue_and_gaps_grey(tmp_path):
    from mercury_dem.products.browse import write_error_png

    lat = np.linspace(9.5, -9.5, 20)
    lon = np.linspace(0.5, 39.5, 40)
    err = np.where(lon < 20, 300.0, -300.0)[None, :].repeat(20, axis=0)
    err[:, 18:22] = np.nan
    img = mpimg.imread(write_error_png(err, lat, lon, tmp_path / "e.png", "t"))[..., :3]
    # The map axes sit in the middle of the figure: sample its left, centre and right thirds on the equator row.
    row = img[img.shape[0] // 2]
    coloured = np.flatnonzero(np.ptp(row, axis=1) > 0.2)  # red or blue pixels (grey has r = g = b)
    left, right = row[coloured[0] + 5], row[coloured[coloured < img.shape[1] * 0.8][-1] - 5]
    assert left[0] > left[2] + 0.2 and right[2] > right[0] + 0.2  # DEM high = red, low = blue
    mid = row[(coloured[0] + coloured[coloured < img.shape[1] * 0.8][-1]) // 2]
    assert np.ptp(mid) < 0.02 and 0.8 < mid[0] < 0.9  # no value = light grey


def test_robinson_map_is_centred_on_regional_data():
    # Global data keep the reference's 0-360 E map; a regional DEM is centred on its longitudes,
    # across the seam too (it would be split between the map's two edges otherwise).
    from mercury_dem.products.browse import robinson_central_meridian

    lon = np.arange(0.5, 360.0, 1.0)
    h = np.full((3, lon.size), np.nan)
    assert robinson_central_meridian(np.zeros_like(h), lon) == 180.0
    h[:, (lon > 100) & (lon < 140)] = 1.0
    assert robinson_central_meridian(h, lon) == 120.0
    h[:] = np.nan
    h[:, (lon > 340) | (lon < 18)] = 1.0
    assert robinson_central_meridian(h, lon) == 359.0
    assert robinson_central_meridian(h, lon - 360.0) == 359.0  # the same map on -180..180


def test_statistics_and_accuracy_json(dem_dir, products):
    stats = json.loads((dem_dir / "products/statistics.json").read_text())
    assert stats["resample"]["factor"] == 2
    for region in ("global", "north_polar", "south_polar", "equatorial"):
        assert stats[region]["n_pixels"] > 0
        assert stats[region]["min_m"] <= stats[region]["median_m"] <= stats[region]["max_m"]
    assert (dem_dir / "products/statistics.txt").read_text().startswith("DEM statistics")
    acc = json.loads((dem_dir / "products/accuracy.json").read_text())
    # Sparse cloud (one point per ~25 km): noise (~0.4 sigma after the median) plus the
    # smoothing of a curved surface over the 11-point neighbourhood; below the point noise.
    assert acc["rmse_m"] < NOISE_M and abs(acc["bias_m"]) < 2.0
    assert acc["n_no_value"] > 0  # the gap
    assert sum(b["n"] for b in acc["error_vs_distance"]) == acc["n_compared"]
    cov = json.loads((dem_dir / "products/coverage.json").read_text())
    assert 0 < cov["occupied_fraction"] <= 1


def test_profile_follows_truth(dem_dir, products):
    data = np.genfromtxt(dem_dir / "products/profile_1.csv", delimiter=",", names=True)
    ok = np.isfinite(data["elevation_m"])
    assert ok.mean() > 0.95
    assert np.sqrt(np.mean((data["elevation_m"][ok] - data["truth_m"][ok]) ** 2)) < NOISE_M
    assert data["distance_km"][-1] == pytest.approx(products["profiles"][0]["length_km"])
    assert (dem_dir / "products/profile_1.png").stat().st_size > 10_000


def test_existing_products_need_overwrite(dem_dir, products):
    with pytest.raises(StoreError, match="already exists.*overwrite"):
        make_products(dem_dir / "dem.zarr", dem_dir / "products", CFG)


def test_missing_store_and_memory_limit(tmp_path, dem_dir):
    with pytest.raises(StoreError, match="no DEM store"):
        make_products(tmp_path / "dem.zarr", tmp_path / "p", CFG)
    import dataclasses

    tiny = dataclasses.replace(CFG, memory_limit_gb=0.001)
    with pytest.raises(GridError, match=r"needs about .* GB"):
        make_products(dem_dir / "dem.zarr", tmp_path / "p", tiny)


def test_regional_map_names_the_caps_it_does_not_reach(tmp_path, dem_dir, products):
    # An equatorial map has no polar caps: their products are named with the reason, not silently absent,
    # and a cap left by an earlier products call (another map) is removed on overwrite.
    import dataclasses

    from mercury_dem.pipeline.dem_stage import grid_dem

    rng = np.random.default_rng(5)
    lat, lon = rng.uniform(-20, 20, 20_000), rng.uniform(100, 140, 20_000)
    cfg = dataclasses.replace(CFG, lat_min=-20.0, lat_max=20.0, lon_min=100.0, lon_max=140.0)
    grid_dem(latlon_to_xyz(lat, lon, truth_height(lat, lon), datum_radius_m=DATUM_RADIUS_M), cfg, tmp_path / "dem.zarr", coverage=False, body=MERCURY)
    out = tmp_path / "products"
    (out / "pds").mkdir(parents=True)
    shutil.copy(dem_dir / "products/pds/north_polar.tif", out / "pds/north_polar.tif")
    summary = make_products(tmp_path / "dem.zarr", out, cfg, overwrite=True)
    assert summary["pds"]["north_polar"] is None and summary["pds"]["south_polar"] is None
    assert set(summary["skipped"]) == {"pds/north_polar.tif", "pds/south_polar.tif"}
    assert "none north of 65 deg" in summary["skipped"]["pds/north_polar.tif"]
    assert "-19.75 to 19.75" in summary["skipped"]["pds/south_polar.tif"]
    # the colour hillshade is titled with the map's name (it once read "south_polar", the caps loop's variable)
    assert summary["browse_title"].startswith("Mercury DEM (")
    named = make_products(tmp_path / "dem.zarr", tmp_path / "named", cfg, name="dense DEM")
    assert named["browse_title"].startswith("Mercury dense DEM (") and "polar" not in named["browse_title"]
    assert not (out / "pds/north_polar.tif").exists()
    assert (out / "pds/equirectangular.tif").exists()
    assert products["skipped"] == {}  # the global map writes every product


def test_hillshade_pair_crops_to_the_right_maps_data_and_shades_both_alike(tmp_path):
    """The dense-vs-sparse browse: both maps shaded with one exaggeration, cropped to where the right one has values."""
    from mercury_dem.products import browse

    lat = np.arange(19.75, -20.0, -0.5)
    lon = np.arange(100.25, 140.0, 0.5)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    crater = -800.0 * np.exp(-((la - 2.0) ** 2 + (lo - 121.0) ** 2) / 2.0)
    right = np.where((np.abs(la) < 5.0) & (np.abs(lo - 120.0) < 6.0), crater, np.nan)
    left = np.zeros_like(crater)
    res = browse.write_hillshade_pair_png(left, right, lat, lon, tmp_path / "pair.png", ("a", "b"), "test",
                                          radius_m=DATUM_RADIUS_M)
    assert (tmp_path / "pair.png").stat().st_size > 0
    assert res["exaggeration"] == pytest.approx(browse.auto_exaggeration(right, lat, lon, radius_m=DATUM_RADIUS_M))
    w, e, s, n = res["extent_deg"]
    # the right map's data (|lat| < 5, 114..126 E) plus crop_to_data's 4-pixel margin (2 deg)
    assert 111.5 <= w <= 114.0 and 126.0 <= e <= 128.5 and -7.5 <= s <= -5.0 and 5.0 <= n <= 7.5
