"""The figures draw what the tables hold (colours of states, panels per level, hillshade of the DEM)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.viz import (
    STATE_COLOURS,
    coverage_figure,
    dem_error,
    dem_validation_figure,
    hillshade_figure,
    image_residuals,
    point_residuals,
    pointing_errors,
    pointing_figure,
    residual_histograms_figure,
    residual_map_figure,
    residuals_by_level,
    sigma0_figure,
    sigma0_history,
    tile_status,
    tile_status_figure,
)


def _png(fig: Figure, path: Path) -> None:
    fig.savefig(path, dpi=50)
    assert path.stat().st_size > 2000


def test_tile_figure_colours_each_tile_by_state(tiny_run: Path, tmp_path: Path) -> None:
    tiles = tile_status(tiny_run)
    fig = tile_status_figure(tiles)
    rects = [p for p in fig.axes[0].patches if isinstance(p, Rectangle)]
    assert len(rects) == len(tiles)
    assert [to_hex(r.get_facecolor()) for r in rects] == [STATE_COLOURS[s] for s in tiles["state"]]
    _png(fig, tmp_path / "tiles.png")


def test_run_figures(tiny_run: Path, tiny_mission, tmp_path: Path) -> None:
    res = residuals_by_level(tiny_run)
    fig = residual_histograms_figure(res)
    assert len(fig.axes) == 3
    _png(fig, tmp_path / "hist.png")
    _png(sigma0_figure(sigma0_history(tiny_run)), tmp_path / "sigma0.png")
    _png(pointing_figure(pointing_errors(tiny_run, tiny_mission)), tmp_path / "pointing.png")
    from mercury_dem.io.network_store import read_network

    net = read_network(Path(tiny_run) / "global" / "0" / "network.zarr")
    _png(residual_map_figure(point_residuals(net), image_residuals(net, tiny_mission)), tmp_path / "map.png")
    _png(coverage_figure(tiny_mission, step_deg=2.0), tmp_path / "coverage.png")


def test_dem_figures(tiny_run: Path, tiny_mission, tmp_path: Path) -> None:
    from mercury_dem.products.browse import auto_exaggeration, hillshade
    from mercury_dem.products.make import open_dem

    fig = hillshade_figure(tiny_run)
    shade = fig.axes[0].images[0].get_array()
    ds = open_dem(Path(tiny_run) / "dem.zarr")
    h, lat, lon = ds["elevation"].values.astype(float), ds["lat"].values, ds["lon"].values
    want = hillshade(h, lat, lon, exaggeration=auto_exaggeration(h, lat, lon, radius_m=DATUM_RADIUS_M), radius_m=DATUM_RADIUS_M)
    np.testing.assert_allclose(np.ma.filled(shade, np.nan), want, equal_nan=True)
    _png(fig, tmp_path / "dem.png")
    err = dem_error(tiny_run, tiny_mission)["error"]
    ok = np.isfinite(err)
    report_rmse = __import__("json").loads((Path(tiny_run) / "report.json").read_text())["validation"]["dem"]["adjusted"]["rmse_m"]
    # unweighted here, cos(lat)-weighted in the report: same order of magnitude over +-30 deg
    assert 0.8 * report_rmse < np.sqrt(np.mean(err[ok] ** 2)) < 1.25 * report_rmse
    _png(dem_validation_figure(tiny_run, tiny_mission), tmp_path / "dem_err.png")
