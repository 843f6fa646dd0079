"""The run compares the registered and merged maps with the configured shape model too
(report.json dem.reference_by_map), over the adjusted DEM's compared pixels; a map on another grid is
an error entry, not a crash. Synthetic maps of known offsets from GTMES (exact figures)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from mercury_dem.config.reference import ReferenceConfig
from mercury_dem.geometry.body import MERCURY
from mercury_dem.io.run_store import RunStore
from mercury_dem.pipeline.dem_run import _shape_reference_of_maps
from mercury_dem.pipeline.reference_check import reference_by_map_table
from mercury_dem.reference.sha import GTMES_PACKAGED, evaluate_grid, read_shadr


def _write(path: Path, lat: np.ndarray, lon: np.ndarray, h: np.ndarray, **extra: np.ndarray) -> str:
    ds = xr.Dataset({"elevation": (("lat", "lon"), h.astype(np.float32)),
                     **{k: (("lat", "lon"), v) for k, v in extra.items()}},
                    coords={"lat": lat, "lon": lon}, attrs={"complete": True})
    ds.to_zarr(str(path), consolidated=False)
    return str(path)


def test_registered_and_merged_maps_against_the_shape(tmp_path: Path) -> None:
    lat = np.arange(89.0, -90.0, -2.0)
    lon = np.arange(1.0, 360.0, 2.0)
    gtmes = evaluate_grid(read_shadr(GTMES_PACKAGED), lat, lon, lmax=12) - MERCURY.datum_radius_m
    near = np.where(lat[:, None] > 0, 0.0, 1e9) + np.zeros(lon.size)  # only the north was "measured"
    _write(tmp_path / "dem.zarr", lat, lon, gtmes + 100.0, distance_to_nearest_point=near)
    reg = {"registered": _write(tmp_path / "registered.zarr", lat, lon, gtmes + 150.0),
           "merged": _write(tmp_path / "merged.zarr", lat, lon, gtmes - 30.0)}
    cfg = ReferenceConfig(shape_harmonics=GTMES_PACKAGED, shape_lmax=12, max_point_distance_m=50_000.0)
    out = _shape_reference_of_maps(RunStore(tmp_path), reg, MERCURY, cfg)
    n_near = int((near <= 50_000.0).sum())
    for key, offset in (("registered", 150.0), ("merged", -30.0)):
        (s,) = out[key].values()
        assert s["n"] == n_near and abs(s["bias_m"] - offset) < 0.05 and s["rmse_m"] < abs(offset) + 0.05, s
        bands = [b for b in s["long_wavelength"]["error_vs_latitude"] if b.get("n")]
        assert bands and all(b["lat_max"] > 0.0 for b in bands)  # the south was not compared
    text = reference_by_map_table(out)
    assert "Merged DEM minus reference" in text and "Registered DEM minus reference" in text
    # a map on another grid: recorded, the others still compared
    reg["merged"] = _write(tmp_path / "merged_other.zarr", lat[::2], lon, (gtmes - 30.0)[::2])
    out = _shape_reference_of_maps(RunStore(tmp_path), reg, MERCURY, cfg)
    assert "not the DEM's" in out["merged"]["error"] and "error" not in out["registered"]
    assert "Merged DEM: not compared" in reference_by_map_table(out)
