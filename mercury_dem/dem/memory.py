"""The memory model of the DEM stage: what gridding a map from a point cloud needs, per process.

Checked before anything is written (:func:`check_memory`), so a grid too large for
``dem.memory_limit_gb`` stops with the estimate and what to change, not with a killed worker.
"""

from __future__ import annotations

from typing import Any

from mercury_dem.dem.grid import GridSpec
from mercury_dem.exceptions import GridError

__all__ = ["check_memory", "estimate_memory_bytes"]


def estimate_memory_bytes(grid: GridSpec, n_points: int, cfg: Any) -> dict[str, int]:
    """Estimated peak memory of the DEM stage (per worker) and of the products stage.

    The stage holds the point index (points, footprints, buckets, radii: ~120 B per
    point, twice while it is pickled to a worker) and one chunk's work arrays
    (about 40 float64 per pixel of a query batch plus the haloed chunk layers).
    The products stage holds a few full-map float32 layers (~5 x 4 B per pixel).
    """
    nr, nc = grid.shape
    npix = nr * nc
    h = cfg.smoothing_passes * (cfg.smoothing_size // 2)
    chunk_px = min(cfg.chunk_size + 2 * h, nr + 2 * h) * min(cfg.chunk_size + 2 * h, nc + 2 * h)
    k = max(cfg.neighbours, cfg.shepard_max_points)
    per_worker = 240 * n_points + chunk_px * 8 * 12 + min(chunk_px, 1 << 17) * k * 8 * 6
    products = npix * 4 * 5
    return {"dem_worker": int(per_worker), "products": int(products), "peak": int(max(per_worker, products))}


def check_memory(grid: GridSpec, n_points: int, cfg: Any) -> dict[str, int]:
    """Raise :class:`GridError` with the estimate when the grid would not fit ``dem.memory_limit_gb``."""
    est = estimate_memory_bytes(grid, n_points, cfg)
    limit = cfg.memory_limit_gb * 1e9
    if est["peak"] > limit:
        nr, nc = grid.shape
        raise GridError(
            f"a {nr} x {nc} grid at {grid.pixels_per_degree} pixel/deg from {n_points} points needs about "
            f"{est['peak'] / 1e9:.1f} GB per process (gridding {est['dem_worker'] / 1e9:.2f} GB, products "
            f"{est['products'] / 1e9:.1f} GB), over dem.memory_limit_gb = {cfg.memory_limit_gb}; lower "
            f"dem.pixels_per_degree or raise dem.memory_limit_gb"
        )
    return est
