"""Fill the on-disk caches a cold ``mercury-dem grid`` (and a first dense chip) reads: ``python -m mercury_dem.pipeline.warm``.

``make setup`` runs it once after installing. It grids a small synthetic cloud with each method
for each catalogued body into a temporary directory, so that

- numba compiles the gridding kernels and writes them to its cache (``cache=True``: the package's
  ``__pycache__``); a first ``grid`` after installation otherwise spends seconds compiling,
- numba compiles the dense refinement's window fit (:mod:`mercury_dem.dense.refine_kernel`) the same way
  (~4 s instead of 0.8 s on the first chip of every fresh worker process, measured 2026-12-02), and
- the CRS attributes of every body's ``spatial_ref`` are in the user's cache
  (``$MERCURY_DEM_CACHE/crs/``, :func:`mercury_dem.io.crs_cache.spatial_ref_attrs`).

Nothing is kept but the caches; running it again is cheap. It lives with the DEM stage it runs (until
session 13 it was ``mercury_dem.dem.warm``, the one import of ``pipeline`` by ``dem/``).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path


def warm_caches() -> float:
    """Grid 20,000 points with each method for each body in a temporary directory and compile the dense
    refinement's kernel; return the seconds taken.
    """
    import numpy as np

    from mercury_dem.config.dem import DemConfig
    from mercury_dem.dense.refine_kernel import warm as warm_dense_kernel
    from mercury_dem.geometry.body import BODIES, latlon_to_xyz
    from mercury_dem.io.run_store import DEM_FILE
    from mercury_dem.pipeline.dem_stage import grid_dem

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    lat, lon = rng.uniform(-5, 5, 20_000), rng.uniform(0, 10, 20_000)
    with tempfile.TemporaryDirectory(prefix="mercury-dem-warm-") as tmp:
        for body in BODIES.values():
            pts = latlon_to_xyz(lat, lon, rng.normal(0, 100, lat.size), datum_radius_m=body.datum_radius_m)
            for method in ("median11", "shepard"):
                cfg = DemConfig(pixels_per_degree=8, lat_min=-5, lat_max=5, lon_min=0, lon_max=10, method=method)
                grid_dem(pts, cfg, Path(tmp) / f"{body.name}-{method}" / DEM_FILE, body=body, coverage=False)
    warm_dense_kernel()
    return time.perf_counter() - t0


if __name__ == "__main__":  # pragma: no cover
    print(f"mercury-dem: gridding and dense kernels compiled and CRS attributes cached ({warm_caches():.1f} s)")
