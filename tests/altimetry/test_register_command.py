"""``mercury-dem register`` end to end on a small synthetic DEM, and the stage's bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import rioxarray  # noqa: F401  (registers the .rio accessor the tests read the CRS with)
import xarray as xr

from mercury_dem.cli import main
from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.grid import GridSpec
from mercury_dem.exceptions import ConfigError, ReferenceDataError
from mercury_dem.geometry.body import MERCURY
from mercury_dem.pipeline.dem_stage import atomic_store, create_store
from mercury_dem.pipeline.register_stage import register_dem_store
from tests.altimetry.synthetic import R_DATUM, Rigid, Surface, moved_dem, profiles

PPD = 10


@pytest.fixture(scope="module")
def dem_dir(tmp_path_factory):
    """dem.zarr over 29-41 N, 99-121 E (two 10° tiles + margins): a surface moved by 1.5 km E, 250 m up."""
    d = tmp_path_factory.mktemp("register")
    rng = np.random.default_rng(21)
    surf = Surface(rng)
    cfg = DemConfig(pixels_per_degree=PPD, chunk_size=128, lat_min=29.0, lat_max=41.0, lon_min=99.0, lon_max=121.0)
    grid = GridSpec.from_config(cfg, R_DATUM)
    lat, lon = grid.lat_centres(), grid.lon_centres()
    heights = np.empty((lat.size, lon.size))
    for half, (c0, c1), centre in ((0, (99, 110), (35.0, 105.0)), (1, (110, 121), (35.0, 115.0))):
        cols = (lon >= c0) & (lon < c1)
        D = Rigid(centre, np.array([1500.0, 0.0, 250.0 + 50 * half]))
        heights[:, cols] = moved_dem(surf, D, lat, lon[cols])
    heights[:, lon > 119.5] = np.nan  # a gap: shots there are counted off the DEM
    with atomic_store(d / "dem.zarr") as tmp:
        _, layers = create_store(str(tmp), grid, cfg, {"source": "test"}, MERCURY)
        layers["elevation"][...] = heights.astype(np.float32)
    shots = []
    for k, b in enumerate(((30.0, 40.0, 100.0, 110.0), (30.0, 40.0, 110.0, 120.0))):
        p = profiles(surf, rng, b, n_profiles=80, spacing_deg=0.04, sigma_h_m=20.0, sigma_v_m=2.0)
        shots.append(pd.DataFrame({"lat": p.lat, "lon": p.lon, "radius_m": p.radius, "profile_id": p.profile_id + 1000 * k}))
    table = pd.concat(shots, ignore_index=True)
    table.loc[:4, "lat"] = np.nan
    table.to_parquet(d / "shots.parquet")
    return d


def _stored_transform_moves_points_onto_the_registered_map(dem_dir):
    """``registration/transform.json`` is the transform the maps got: the DEM's nodes moved by it
    (``register_points``, as the dense stage moves its cloud) lie on ``registered.zarr``.
    """
    from mercury_dem.altimetry.merge import register_points
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.io.run_store import read_registration_transform
    from mercury_dem.reference.sampling import sample_grid

    t = read_registration_transform(dem_dir / "registration")
    assert t is not None and t["level_offset_m"] is not None
    dem = xr.open_zarr(dem_dir / "dem.zarr", consolidated=False)
    reg = xr.open_zarr(dem_dir / "registered.zarr", consolidated=False)
    lat, lon = dem["lat"].values, dem["lon"].values
    h = dem["elevation"].transpose("lat", "lon").values.astype(np.float64)
    la, lo = np.meshgrid(lat[5:-5:3], lon[5:-5:3], indexing="ij")
    hp = sample_grid(h, lat, lon, la.ravel(), lo.ravel())
    ok = np.isfinite(hp)
    xyz = latlon_to_xyz(la.ravel()[ok], lo.ravel()[ok], height_m=hp[ok], datum_radius_m=R_DATUM)
    qla, qlo, qh = register_points(xyz, la.ravel()[ok], lo.ravel()[ok], R_DATUM, t["table"],
                                   TileGrid(t["tile_size_deg"]), t["level_offset_m"])
    d = qh - sample_grid(reg["elevation"].transpose("lat", "lon").values.astype(np.float64), lat, lon, qla, qlo)
    assert np.isfinite(d).sum() > 100
    # measured median -0.44 m, 90th percentile of |d| 17.7 m: the map was resampled (bilinear) after a 1.5 km shift of
    # a ~1 km relief on a coarse grid, the points were not
    assert abs(np.nanmedian(d)) < 2.0 and np.nanpercentile(np.abs(d), 90) < 30.0, (np.nanmedian(d), np.nanpercentile(np.abs(d), 90))


@pytest.mark.integration  # the whole register stage on a synthetic DEM
def test_register_command_json(dem_dir, capsys):
    rc = main(["register", str(dem_dir), "--altimetry", str(dem_dir / "shots.parquet"), "--json", "--body", "mercury"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["shots_dropped_invalid"] == 5 and out["shots_off_dem"] > 0
    # two tiles; a shot or two moved across the tiles' southern border by its profile's error
    tiles = {t["tile_id"]: t for t in out["tiles"] if t["ok"]}
    assert len(tiles) == 2 and all("min_shots" in t["reason"] for t in out["tiles"] if not t["ok"])
    for t, up in zip(sorted(tiles), (250.0, 300.0)):
        assert abs(tiles[t]["translation_e_m"] + 1500.0) < 150.0 and abs(tiles[t]["translation_u_m"] + up) < up * 0.1
        assert tiles[t]["rms_after_m"] < tiles[t]["rms_before_m"] / 10
    st = out["statistics"]
    assert st["registered"]["rmse_m"] < st["as_given"]["rmse_m"] / 5 and st["merged"]["rmse_m"] <= st["registered"]["rmse_m"]
    reg = xr.open_zarr(dem_dir / "registered.zarr", consolidated=False, decode_coords="all")
    assert reg.attrs["complete"] and reg.rio.crs is not None and float(reg.attrs["datum_radius_m"]) == R_DATUM
    merged = xr.open_zarr(dem_dir / "merged.zarr", consolidated=False)
    assert {"elevation", "altimetry_weight", "shot_count"} <= set(merged.data_vars)
    for f in ("tiles.parquet", "tiles.json", "profiles.parquet", "rms_per_tile.png", "summary.json", "transform.json"):
        assert (dem_dir / "registration" / f).stat().st_size > 0
    _stored_transform_moves_points_onto_the_registered_map(dem_dir)
    # the products of both maps (read back in tests/products/test_registration_products.py)
    for f in ("registered/dem.tif", "registered/isis/dem_radius.cub", "merged/dem.tif", "merged/browse/hillshade.png",
              "registration/rms_per_tile.png"):
        assert str(dem_dir / "products" / f) in out["products"]["files"] and (dem_dir / "products" / f).is_file()
    # outputs are not replaced without --overwrite: a clear error, exit code 2
    assert main(["register", str(dem_dir), "--altimetry", str(dem_dir / "shots.parquet")]) == 2
    assert "--overwrite" in capsys.readouterr().err


@pytest.mark.integration  # the whole register stage on a synthetic DEM (its option-off path)
def test_register_without_products(dem_dir, tmp_path, capsys):
    import shutil

    shutil.copytree(dem_dir / "dem.zarr", tmp_path / "dem.zarr")
    (tmp_path / "products" / "merged").mkdir(parents=True)  # left by someone: refused before any work
    assert main(["register", str(tmp_path), "--altimetry", str(dem_dir / "shots.parquet")]) == 2
    assert "products/merged already exists" in capsys.readouterr().err and not (tmp_path / "merged.zarr").exists()
    assert main(["register", str(tmp_path), "--altimetry", str(dem_dir / "shots.parquet"), "--no-products"]) == 0
    assert (tmp_path / "merged.zarr").is_dir() and not any((tmp_path / "products" / "merged").iterdir())


def test_register_refuses_bad_input(dem_dir, capsys, tmp_path):
    bad = tmp_path / "bad.parquet"
    pd.DataFrame({"lat": [1.0], "lon": [2.0], "radius": [3.0]}).to_parquet(bad)
    assert main(["register", str(dem_dir), "--altimetry", str(bad), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "radius_m" in err and "profile_id" in err
    assert main(["register", str(dem_dir), "--altimetry", str(bad), "--body", "moon"]) == 2
    assert "MERCURY" in capsys.readouterr().err
    with pytest.raises(ReferenceDataError, match="no usable shot"):
        register_dem_store(dem_dir / "dem.zarr", pd.DataFrame({"lat": [np.nan], "lon": [0.0], "radius_m": [1.0],
                                                               "profile_id": [0]}), tmp_path)


@pytest.mark.integration  # the whole register stage on a synthetic DEM
def test_distributed_equals_sync(dem_dir, tmp_path):
    """The same tiles on a dask.distributed client (threads, in-process) as on the synchronous one."""
    from distributed import Client, LocalCluster

    shots = pd.read_parquet(dem_dir / "shots.parquet")
    sync = register_dem_store(dem_dir / "dem.zarr", shots, tmp_path / "sync")
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        dist = register_dem_store(dem_dir / "dem.zarr", shots, tmp_path / "dist", client=client)
    a = pd.DataFrame(sync["tiles"]).sort_values("tile_id").reset_index(drop=True)
    b = pd.DataFrame(dist["tiles"]).sort_values("tile_id").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    ra = xr.open_zarr(tmp_path / "sync" / "merged.zarr", consolidated=False)["elevation"].values
    rb = xr.open_zarr(tmp_path / "dist" / "merged.zarr", consolidated=False)["elevation"].values
    np.testing.assert_array_equal(ra, rb)


@pytest.mark.integration  # the whole register stage on a synthetic DEM
def test_register_reads_rdr_csv(dem_dir, tmp_path, capsys):
    """The same shots as an MLA-like RDR CSV (radii in km, profiles from time gaps) register the same."""
    import shutil

    d = tmp_path / "csv"
    shutil.copytree(dem_dir / "dem.zarr", d / "dem.zarr")
    t = pd.read_parquet(dem_dir / "shots.parquet").dropna()
    t = t.sort_values(["profile_id", "lat"])
    time_s = t["profile_id"].to_numpy() * 1000.0 + t.groupby("profile_id").cumcount().to_numpy() * 0.1
    csv = pd.DataFrame({"ET": time_s, "Pt_Longitude": t["lon"], "Pt_Latitude": t["lat"],
                        "Pt_Radius": t["radius_m"] / 1000.0})
    csv.to_csv(d / "mla.csv", index=False, float_format="%.9f")
    assert main(["register", str(d), "--altimetry", str(d / "mla.csv"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ok = [t for t in out["tiles"] if t["ok"]]
    assert len(ok) == 2 and all(abs(t["translation_e_m"] + 1500.0) < 150.0 for t in ok)
    assert out["profiles_fitted"] >= 150


def test_grid_and_register_take_the_moon(tmp_path, capsys):
    """``grid --body moon`` writes a lunar dem.zarr (1737.4 km datum); ``register`` refuses it as Mercury's."""
    from mercury_dem.geometry.body import MOON, latlon_to_xyz

    rng = np.random.default_rng(4)
    lat, lon = rng.uniform(10, 12, 4000), rng.uniform(20, 22, 4000)
    np.save(tmp_path / "pts.npy", latlon_to_xyz(lat, lon, 100.0, MOON.datum_radius_m))
    assert main(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path), "--ppd", "8", "--no-coverage",
                 "--body", "moon"]) == 0
    ds = xr.open_zarr(tmp_path / "dem.zarr", consolidated=False)
    assert float(ds.attrs["datum_radius_m"]) == MOON.datum_radius_m and "MOON" in ds.attrs["body"]
    assert abs(float(np.nanmedian(ds["elevation"].values)) - 100.0) < 1.0
    pd.DataFrame({"lat": [11.0], "lon": [21.0], "radius_m": [MOON.datum_radius_m], "profile_id": [0]}).to_parquet(
        tmp_path / "s.parquet")
    capsys.readouterr()
    assert main(["register", str(tmp_path), "--altimetry", str(tmp_path / "s.parquet"), "--body", "mercury"]) == 2
    assert "MOON" in capsys.readouterr().err
    assert main(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path / "x"), "--body", "vesta"]) == 2


@pytest.mark.integration  # the whole register stage on a synthetic DEM
def test_blockwise_maps_equal_the_whole_map(dem_dir, tmp_path):
    """Registered and merged maps computed 7 rows at a time (less than the merge's 12-row margin) equal the
    whole-map computation (one block of all 120 rows: the whole-map functions on the whole map)."""
    shots = pd.read_parquet(dem_dir / "shots.parquet")
    whole = register_dem_store(dem_dir / "dem.zarr", shots, tmp_path / "whole", block_rows=10_000)
    small = register_dem_store(dem_dir / "dem.zarr", shots, tmp_path / "small", block_rows=7)
    assert whole["block_rows"] == 10_000 and small["block_rows"] == 7
    assert small["merged_dense_pixels"] == whole["merged_dense_pixels"] > 100
    for store, names in (("registered.zarr", ("elevation",)),
                         ("merged.zarr", ("elevation", "altimetry_weight", "shot_count"))):
        a = xr.open_zarr(tmp_path / "whole" / store, consolidated=False)
        b = xr.open_zarr(tmp_path / "small" / store, consolidated=False)
        assert b["elevation"].encoding["chunks"][0] == 7
        for name in names:
            va, vb = a[name].values, b[name].values
            np.testing.assert_array_equal(np.isnan(va) if va.dtype.kind == "f" else va == 0,
                                          np.isnan(vb) if vb.dtype.kind == "f" else vb == 0)
            np.testing.assert_allclose(vb, va, rtol=0, atol=1e-3, equal_nan=True)  # float32 maps; ~1e-9 m apart
    w = xr.open_zarr(tmp_path / "whole" / "merged.zarr", consolidated=False)
    assert 0 < float(w["altimetry_weight"].mean()) < 1  # the merge did blend (the check compares something)
    for k in ("as_given", "registered", "merged"):
        assert small["statistics"][k]["n"] == whole["statistics"][k]["n"]
        assert small["statistics"][k]["rmse_m"] == pytest.approx(whole["statistics"][k]["rmse_m"], abs=1e-6)


@pytest.mark.integration  # the whole register stage on a synthetic DEM
def test_the_stage_takes_its_settings_and_tile_grid(dem_dir, tmp_path):
    """The registration section and the tile grid reach the stage: 5° tiles (not a fixed 10°), 50-column chunks."""
    from mercury_dem.config import load_config
    from mercury_dem.geometry.tiling import TileGrid

    cfg = load_config(overrides={"registration": {"chunk_columns": 50}, "tiling": {"tile_size_deg": 5.0}})
    shots = pd.read_parquet(dem_dir / "shots.parquet")
    s = register_dem_store(dem_dir / "dem.zarr", shots, tmp_path, settings=cfg.registration,
                           tiles=TileGrid(cfg.tiling.tile_size_deg))
    grid5 = TileGrid(5.0)
    assert {t["tile_id"] for t in s["tiles"]} <= set(np.unique(grid5.tile_of(shots["lat"].dropna().to_numpy(),
                                                                               shots["lon"][shots["lat"].notna()])))
    assert s["tiles_with_shots"] > 2  # two 10° tiles hold shots; on 5° tiles, more
    reg = xr.open_zarr(tmp_path / "registered.zarr", consolidated=False)
    assert reg["elevation"].encoding["chunks"][1] == 50
    assert json.loads(reg.attrs["registration"])["tile_size_deg"] == 5.0
    with pytest.raises(ConfigError, match="registration.no_such_key"):
        load_config(overrides={"registration": {"no_such_key": 1}})
