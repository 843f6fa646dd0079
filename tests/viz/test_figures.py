"""The figures draw what the tables hold (colours of states, panels per level, hillshade of the DEM)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
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
    """Each figure of a run draws its table: the bars count the measures, the lines are the sigma0 histories,
    the dots are the images' errors and the points' residuals, the mesh is the coverage count."""
    import json

    from mercury_dem.io.network_store import read_network

    report = json.loads((Path(tiny_run) / "report.json").read_text())
    res = residuals_by_level(tiny_run)
    fig = residual_histograms_figure(res)
    assert [ax.get_title().split("\n")[0] for ax in fig.axes] == ["region", "hemisphere", "global"]
    for ax in fig.axes:  # one bar per bin; together they hold every active measure of the level (the last bin clipped)
        level = ax.get_title().split("\n")[0]
        r = res[(res["level"] == level) & res["active"]]["residual_px"].to_numpy(float)
        assert sum(bar.get_height() for bar in ax.patches) == np.isfinite(r).sum() > 0, level
    _png(fig, tmp_path / "hist.png")

    hist = sigma0_history(tiny_run)
    fig = sigma0_figure(hist)
    lines = fig.axes[0].get_lines()
    units = [g for _, g in hist.groupby(["level", "id"], sort=False)]
    ok_units = [r for r in report["levels"]["region"] + report["levels"]["hemisphere"] + [report["levels"]["global"]]
                if r["ok"]]
    assert len(lines) == len(units) == len(ok_units)  # one line per adjusted unit
    for line, g in zip(lines, units):
        np.testing.assert_array_equal(line.get_ydata(), g["sigma0"].to_numpy())
        assert line.get_label() == g["name"].iloc[0]
    _png(fig, tmp_path / "sigma0.png")

    err = pointing_errors(tiny_run, tiny_mission)
    fig = pointing_figure(err)
    dots = fig.axes[0].collections[0].get_offsets()
    np.testing.assert_array_equal(np.asarray(dots), err[["a_priori_px", "adjusted_px"]].to_numpy(float))
    assert 0 < len(err) <= report["levels"]["global"]["images"]
    rms = float(np.sqrt(np.mean(err["adjusted_px"] ** 2)))  # the same errors as the report's validation
    assert rms == pytest.approx(report["validation"]["image_space_error_px"]["adjusted_rms"], rel=0.05)
    _png(fig, tmp_path / "pointing.png")

    net = read_network(Path(tiny_run) / "global" / "0" / "network.zarr")
    pts, ims = point_residuals(net), image_residuals(net, tiny_mission)
    fig = residual_map_figure(pts, ims)
    dots, squares = fig.axes[0].collections[:2]
    used = pts[pts["n_active"] > 0]
    assert len(used) > 0.5 * net.n_points
    np.testing.assert_allclose(np.asarray(dots.get_offsets()), used[["lon", "lat"]].to_numpy(float))
    np.testing.assert_allclose(dots.get_array(), used["rms_px"].to_numpy(float))
    assert len(squares.get_offsets()) == int((ims["n_active"] > 0).sum())
    _png(fig, tmp_path / "map.png")

    fig = coverage_figure(tiny_mission, step_deg=2.0)
    count = np.asarray(fig.axes[0].collections[0].get_array())
    centres = fig.axes[0].get_lines()[0]
    assert len(centres.get_xdata()) == len(tiny_mission.catalog)
    assert count.max() >= 2 and count.min() >= 0  # overlapping images: some point seen twice or more
    _png(fig, tmp_path / "coverage.png")


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
