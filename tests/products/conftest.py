"""A small gridded DEM store (global, 2 pixel/deg, with a gap) shared by the product tests."""

from __future__ import annotations

import numpy as np
import pytest
from products_synthetic import CFG, NOISE_M, truth_height  # noqa: F401

from mercury_dem.geometry.body import DATUM_RADIUS_M, MERCURY, latlon_to_xyz


@pytest.fixture(scope="session")
def dem_dir(tmp_path_factory):
    """DIR with dem.zarr (+ coverage.zarr) gridded from 120k noisy points; no points in lat 10..30, lon 190..220."""
    from mercury_dem.pipeline.dem_stage import grid_dem

    rng = np.random.default_rng(21)
    n = 120_000
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, n)))
    lon = rng.uniform(0, 360, n)
    keep = ~((lat > 10) & (lat < 30) & (lon > 190) & (lon < 220))
    lat, lon = lat[keep], lon[keep]
    pts = latlon_to_xyz(lat, lon, truth_height(lat, lon) + rng.normal(0, NOISE_M, lat.size), datum_radius_m=DATUM_RADIUS_M)
    d = tmp_path_factory.mktemp("run")
    grid_dem(pts, CFG, d / "dem.zarr", body=MERCURY)
    return d


@pytest.fixture(scope="session")
def products(dem_dir):
    """make_products on the shared store, with truth and one profile."""
    from mercury_dem.products.make import make_products

    return make_products(dem_dir / "dem.zarr", dem_dir / "products", CFG, truth_height,
                         profiles=[(-40.0, 10.0, 50.0, 100.0)])
