"""The DEM stage: dem.zarr layout, CRS round trip, serial == Dask, bad input, coverage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rioxarray  # noqa: F401  (registers the .rio accessor the tests read the CRS with)
from dem_synthetic import truth_height

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.coverage import point_coverage
from mercury_dem.dem.grid import build_point_index
from mercury_dem.exceptions import GridError, StoreError
from mercury_dem.geometry.body import CRS_GEOGRAPHIC, DATUM_RADIUS_M, MERCURY, latlon_to_xyz
from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

CFG = DemConfig(pixels_per_degree=1, chunk_size=48, max_distance_m=400_000.0, coverage_pixel_km=40.0)


@pytest.fixture(scope="module")
def serial_store(tmp_path_factory, global_cloud):
    path = tmp_path_factory.mktemp("serial") / "dem.zarr"
    summary = grid_dem(global_cloud, CFG, path, body=MERCURY)
    return path, summary


def test_store_layout_crs_and_values(serial_store):
    path, summary = serial_store
    ds = open_dem(path)
    assert set(ds.data_vars) == {"elevation", "radius", "point_count", "distance_to_nearest_point", "spread"}
    assert ds.elevation.dtype == np.float32 and ds.point_count.dtype == np.int32
    assert ds.elevation.attrs["units"] == "m"
    assert ds.attrs["datum_radius_m"] == DATUM_RADIUS_M
    assert "2439.4 km" in ds.attrs["height_reference"]
    # Pixel-centre coordinates, north to south.
    assert ds.lat.values[0] == pytest.approx(89.5) and ds.lon.values[0] == pytest.approx(0.5)
    # The CRS survives the round trip, as a coordinate, with its code and WKT2.
    assert "spatial_ref" in ds.coords
    assert ds.rio.crs is not None
    # Its sphere is the height datum (CF: height_above_reference_ellipsoid of the grid mapping's
    # ellipsoid); crs_code is the IAU CRS of the same latitude/longitude.
    assert ds.elevation.attrs["standard_name"] == "height_above_reference_ellipsoid"
    assert pyproj.CRS.from_wkt(ds.rio.crs.to_wkt()).ellipsoid.semi_major_metre == DATUM_RADIUS_M
    assert ds.spatial_ref.attrs["semi_major_axis"] == DATUM_RADIUS_M
    assert pyproj.CRS.from_wkt(ds.spatial_ref.attrs["crs_wkt2"]).ellipsoid.semi_major_metre == DATUM_RADIUS_M
    assert ds.spatial_ref.attrs["crs_code"] == CRS_GEOGRAPHIC
    # Recovery of the truth (sparse cloud: ~0.6 points per 1-deg pixel, so a generous bound).
    lat, lon = np.meshgrid(ds.lat.values, ds.lon.values, indexing="ij")
    err = ds.elevation.values - truth_height(lat, lon)
    assert np.sqrt(np.nanmean(err**2)) < 60.0
    np.testing.assert_allclose(ds.radius.values, ds.elevation.values + DATUM_RADIUS_M, atol=0.5)
    assert summary["n_chunks"] == 4 * 8
    assert summary["no_value_pixels"] == int(np.isnan(ds.elevation.values).sum())
    cov = json.loads(ds.attrs["coverage"])
    assert 0 < cov["occupied_fraction"] < 1


def test_dask_equals_serial(serial_store, global_cloud, tmp_path):
    distributed = pytest.importorskip("distributed")
    path, _ = serial_store
    # In-process workers keep the test fast on a loaded 2-core machine; that the point index
    # survives the trip to a worker process (pickling) is checked below.
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0",
                                  processes=False) as cluster, distributed.Client(cluster) as client:
        summary = grid_dem(global_cloud, CFG, tmp_path / "dem.zarr", client=client, coverage=False, body=MERCURY)
    a, b = open_dem(path), open_dem(tmp_path / "dem.zarr")
    for name in a.data_vars:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
    assert summary["coverage"] is None


def test_point_index_pickles_for_workers(global_cloud):
    import pickle

    index = build_point_index(global_cloud, datum_radius_m=DATUM_RADIUS_M)
    back = pickle.loads(pickle.dumps(index, protocol=5))
    q = global_cloud[:100] * 1.0001
    np.testing.assert_array_equal(back.tree.query(q, k=3)[1], index.tree.query(q, k=3)[1])
    np.testing.assert_array_equal(back.radius, index.radius)


def test_point_index_keeps_its_body_datum_through_pickling(global_cloud):
    """A worker's copy of a Moon index measures heights from the Moon's datum, not a default's."""
    import pickle

    from mercury_dem.geometry.body import MOON

    moon = global_cloud / DATUM_RADIUS_M * MOON.datum_radius_m
    back = pickle.loads(pickle.dumps(build_point_index(moon, MOON.datum_radius_m), protocol=5))
    assert back.datum_radius_m == MOON.datum_radius_m == back.buckets.sphere_radius


def test_existing_store_needs_overwrite(serial_store, global_cloud):
    path, _ = serial_store
    with pytest.raises(StoreError, match="overwrite"):
        grid_dem(global_cloud, CFG, path, body=MERCURY)


def test_empty_cloud_and_memory_limit(tmp_path, global_cloud):
    with pytest.raises(GridError, match="empty"):
        grid_dem(np.zeros((0, 3)), CFG, tmp_path / "a.zarr", body=MERCURY)
    big = DemConfig(pixels_per_degree=512, memory_limit_gb=8.0)
    with pytest.raises(GridError, match=r"needs about \d+\.\d GB.*memory_limit_gb"):
        grid_dem(global_cloud, big, tmp_path / "b.zarr", body=MERCURY)
    assert not (tmp_path / "a.zarr").exists() and not (tmp_path / "b.zarr").exists()


def test_coverage_counts_and_distances():
    R = DATUM_RADIUS_M
    # Three clusters on the equator: 1, 2 and 3 points within one 100 km pixel each.
    lon = np.array([0.2, 20.2, 20.25, 40.2, 40.22, 40.24])
    index = build_point_index(latlon_to_xyz(np.zeros(6) + 0.2, lon, 0.0, datum_radius_m=DATUM_RADIUS_M), datum_radius_m=DATUM_RADIUS_M)
    cov = point_coverage(index, pixel_km=100.0)
    s = cov.summary()
    assert s["occupied_pixels"] == 3
    assert s["share_with_1"] == pytest.approx(1 / 3)
    assert s["share_with_2"] == pytest.approx(1 / 3)
    assert s["share_with_3_or_more"] == pytest.approx(1 / 3)
    # Equal-area grid: the map pixels add up to the sphere's area within the outline's raggedness.
    assert s["map_area_km2"] == pytest.approx(4 * np.pi * (R / 1000) ** 2, rel=0.02)
    # Largest distance to the nearest point: about the antipode of the cluster (pi R - ~20 deg).
    assert s["nearest_point_km"]["min"] < 100.0
    assert s["nearest_point_km"]["max"] < 2 * R / 1000
    assert s["nearest_point_km"]["max"] > 0.8 * 2 * R / 1000


@pytest.mark.slow
def test_dask_worker_processes_equal_serial(serial_store, global_cloud, tmp_path):
    """Same as test_dask_equals_serial with real worker processes (the index is pickled once per worker)."""
    distributed = pytest.importorskip("distributed")
    path, _ = serial_store
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0",
                                  processes=True) as cluster, distributed.Client(cluster) as client:
        grid_dem(global_cloud, CFG, tmp_path / "dem.zarr", client=client, coverage=False, body=MERCURY)
    a, b = open_dem(path), open_dem(tmp_path / "dem.zarr")
    for name in a.data_vars:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)


def test_store_is_atomic_with_zarr_completion_mark(serial_store):
    """io.atomic's directory swap with the Zarr attribute as the mark: no marker file, no leftovers."""
    import warnings

    import xarray as xr

    path, _ = serial_store
    assert not (path / ".complete").exists()
    assert not [p for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.tmp-")]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = xr.open_zarr(path, consolidated=False)
    assert ds.attrs["complete"] is True
    assert (path.parent / "coverage.zarr").exists() and not (path.parent / "coverage.zarr" / ".complete").exists()


@pytest.mark.parametrize("chunk_size", [48, 512])
def test_direct_store_layout_equals_xarray_template(tmp_path, chunk_size):
    """create_store (zarr API) writes the same metadata and coordinates as the xarray template."""
    import xarray as xr

    from mercury_dem.dem.grid import GridSpec
    from mercury_dem.pipeline.dem_stage import create_store, dem_template

    cfg = DemConfig(pixels_per_degree=1, lat_min=-60, lat_max=60, chunk_size=chunk_size)
    grid = GridSpec.from_config(cfg, datum_radius_m=DATUM_RADIUS_M)
    a, b = tmp_path / "a.zarr", tmp_path / "b.zarr"
    dem_template(grid, cfg, {"source": "test"}, body=MERCURY).to_zarr(str(a), mode="w", compute=False, consolidated=False,
                                                         zarr_format=3)
    create_store(str(b), grid, cfg, {"source": "test"}, body=MERCURY)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b
    for f in files_a:
        if f.name == "zarr.json":
            assert json.loads((a / f).read_text()) == json.loads((b / f).read_text()), str(f)
    da, db = (xr.open_zarr(str(p), consolidated=False, decode_coords="all") for p in (a, b))
    xr.testing.assert_identical(da, db)


def test_point_index_reports_its_size_to_dask(global_cloud):
    """Dask's memory accounting of the scattered index counts its arrays (not ~50 bytes of object)."""
    import warnings

    from dask.sizeof import sizeof

    index = build_point_index(global_cloud, datum_radius_m=DATUM_RADIUS_M)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        n = sizeof(index)
    b = index.buckets
    assert n >= b.xyz.nbytes + b.radius.nbytes + b.order.nbytes + b.cell_start.nbytes
    assert n < 2 * (b.xyz.nbytes + b.radius.nbytes + b.order.nbytes + b.cell_start.nbytes) + 10_000


def test_spatial_ref_attributes_cached_on_disk(tmp_path, monkeypatch):
    """The CRS attributes come from the user's cache once computed (a cold 'grid' then loads no rioxarray,
    rasterio or pyproj); the cached value is the fresh one, and a damaged cache file is computed again."""
    import os
    import subprocess
    import sys

    from mercury_dem.geometry.body import MERCURY, MOON
    from mercury_dem.dem.store_schema import compute_spatial_ref_attrs
    from mercury_dem.io.crs_cache import spatial_ref_attrs

    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "cache"))
    for body in (MERCURY, MOON):
        spatial_ref_attrs.cache_clear()
        first = spatial_ref_attrs(body)  # computed, then written
        spatial_ref_attrs.cache_clear()
        assert spatial_ref_attrs(body) == first == compute_spatial_ref_attrs(body)
    files = sorted((tmp_path / "cache" / "crs").glob("*.json"))
    assert len(files) == 2
    files[0].write_text('{"key": "not json')  # damaged: ignored, computed and rewritten
    spatial_ref_attrs.cache_clear()
    assert {spatial_ref_attrs(b)["semi_major_axis"] for b in (MERCURY, MOON)} == {
        MERCURY.datum_radius_m, MOON.datum_radius_m}
    assert json.loads(files[0].read_text())["attrs"]
    spatial_ref_attrs.cache_clear()
    # a fresh process writing a store with the cache warm: no GDAL/PROJ stack imported
    code = ("import sys\nfrom mercury_dem.config.dem import DemConfig\nfrom mercury_dem.dem.grid import GridSpec\n"
            "from mercury_dem.geometry.body import MERCURY\n"
            "from mercury_dem.pipeline.dem_stage import create_store\n"
            "cfg = DemConfig(pixels_per_degree=1, lat_min=-10, lat_max=10, lon_min=0, lon_max=20)\n"
            f"create_store({str(tmp_path / 's.zarr')!r}, GridSpec.from_config(cfg, MERCURY.datum_radius_m), cfg, "
            "None, MERCURY)\n"
            "print(sorted(m for m in ('rioxarray', 'rasterio', 'pyproj', 'xarray') if m in sys.modules))")
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
