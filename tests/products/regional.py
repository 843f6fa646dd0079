"""A small regional DEM and its products, for the product-metadata tests (one builder, two test modules)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.config.dem import DemConfig
from mercury_dem.geometry.body import Body, latlon_to_xyz

#: 1/3 is inexact in floating point, so differences of float coordinates give unequal x/y sizes.
PPD = 3
LAT = (-75.0, 75.0)


def height(lat: Any, lon: Any) -> Any:
    """The smooth test surface, metres above the datum."""
    la, lo = np.radians(lat), np.radians(lon)
    return 1500.0 * np.sin(2 * la) * np.cos(3 * lo) + 800.0 * np.cos(la) * np.sin(2 * lo + 0.3)


def regional_products(body: Body, lon_bounds: tuple[float, float], out: Path, *, seed: int,
                      max_distance_m: float, hole: bool = False) -> dict[str, Any]:
    """Grid 12,000 points of :func:`height` over ``lon_bounds`` x ``LAT`` into ``out/dem.zarr`` (with
    its coverage) and make the products in ``out/products``; ``hole`` leaves a gap of NaN pixels.
    Returns the products summary."""
    from mercury_dem.pipeline.dem_stage import grid_dem
    from mercury_dem.products.make import make_products

    lon_min, lon_max = lon_bounds
    rng = np.random.default_rng(seed)
    n = 12_000
    lat = np.degrees(np.arcsin(rng.uniform(math.sin(math.radians(-76)), math.sin(math.radians(76)), n)))
    lon = rng.uniform(lon_min - 1, lon_max + 1, n)
    if hole:
        keep = ~((lat > 20) & (lat < 40) & (lon > lon_min + 5) & (lon < lon_min + 15))
        lat, lon = lat[keep], lon[keep]
    pts = latlon_to_xyz(lat, lon, height(lat, lon), datum_radius_m=body.datum_radius_m)
    cfg = DemConfig(pixels_per_degree=PPD, chunk_size=64, max_distance_m=max_distance_m, coverage_pixel_km=100.0,
                    stats_pixel_km=60.0, browse_width=120, lat_min=LAT[0], lat_max=LAT[1], lon_min=lon_min,
                    lon_max=lon_max)
    grid_dem(pts, cfg, out / "dem.zarr", body=body)
    return make_products(out / "dem.zarr", out / "products", cfg)
