"""A small gridded DEM store (global, 2 pixel/deg, with a gap) shared by the product tests, and the regional
DEMs of the metadata and ISIS/PDS4 tests, each gridded once per session.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

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


@pytest.fixture(scope="session")
def regional_run(tmp_path_factory) -> Callable[[Any, tuple[float, float]], tuple[Path, dict[str, Any]]]:
    """``get(body, lon_bounds) -> (run dir, products summary)``: a small regional DEM with a gap and its products
    (:func:`tests.products.regional.regional_products`), built on the first request of each case and shared by
    test_product_metadata and test_isis_pds4_products (the tests only read them): ~1.7 s of CPU a case, which
    each module used to grid again with its own seed.
    """
    from tests.products.regional import regional_products

    built: dict[tuple[str, tuple[float, float]], tuple[Path, dict[str, Any]]] = {}

    def get(body: Any, lons: tuple[float, float]) -> tuple[Path, dict[str, Any]]:
        key = (body.name, lons)
        if key not in built:
            d = tmp_path_factory.mktemp(f"regional_{body.name}_{lons[0]:g}_{lons[1]:g}")
            built[key] = (d, regional_products(body, lons, d, seed=7, max_distance_m=60_000.0, hole=True))
        return built[key]

    return get
