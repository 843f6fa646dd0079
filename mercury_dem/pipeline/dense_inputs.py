"""The dense stage's inputs read from the run (issue 31; docs/design/dense.md, "The stage"): the pair rule and
the matcher's settings from ``config.dense``, the images' adjusted geometry from the global adjustment, and the
sparse DEM as the surface the chips are rectified about and the dense DEM falls back to.

Shared by the tile task (:mod:`mercury_dem.pipeline.dense_tile`), the driver
(:mod:`mercury_dem.pipeline.dense_stage`) and the dense DEM (:mod:`mercury_dem.pipeline.dense_dem`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config import Config
from mercury_dem.io.run_store import RunStore, read_solution


def criteria_of(config: Config) -> Any:
    """The :class:`~mercury_dem.dense.pairs.StereoPairCriteria` of ``config.dense``."""
    from mercury_dem.dense.pairs import StereoPairCriteria

    d = config.dense
    lo, hi = d.best_parallax_height
    return StereoPairCriteria(
        min_parallax_height=d.min_parallax_height, max_parallax_height=d.max_parallax_height,
        best_parallax_height=(lo, hi), max_scale_ratio=d.max_scale_ratio,
        max_incidence_difference_deg=d.max_incidence_difference_deg,
        max_sun_azimuth_difference_deg=d.max_sun_azimuth_difference_deg, max_incidence_deg=d.max_incidence_deg,
        min_overlap=d.min_overlap, max_pairs_per_image=d.max_pairs_per_image)


def matcher_of(config: Config) -> tuple[Any, Any]:
    """The ``MatcherSettings`` and ``PointFilter`` of ``config.dense`` (the other fields: their defaults)."""
    from mercury_dem.dense.disparity import MatcherSettings
    from mercury_dem.dense.triangulate import PointFilter

    d = config.dense
    return (MatcherSettings(mode=d.matcher_mode, block_size=d.block_size, refine_window=d.refine_window,
                            refine_method=d.refine_method, refine_iterations=d.refine_iterations,
                            max_sigma_px=d.max_sigma_px, min_score=d.min_score),
            PointFilter(max_miss_pixels=d.max_miss_pixels, min_angle_deg=d.min_angle_deg,
                        max_sigma_h_m=d.max_sigma_h_m))


def adjusted_geometry(store: RunStore, mission: Any) -> dict[str, Any]:
    """Image id -> :class:`~mercury_dem.match.pretransform.ImageGeometry` with the global adjustment's pose,
    for the images it controlled (at least one measure).
    """
    from mercury_dem.match.pretransform import ImageGeometry

    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(len(sid))
    out: dict[str, Any] = {}
    for i, r, c, n in zip(sid, rot, pos, nmeas):
        if n > 0 and np.all(np.isfinite(r)) and np.all(np.isfinite(c)):
            out[str(i)] = ImageGeometry.of(mission.camera(str(i)), c, r, mission.sun_position(str(i)),
                                           mission.body.datum_radius_m)
    return out


class SparseSurface:
    """The sparse DEM as the chips' ``surface_height`` (bilinear; NaN filled with the DEM's median height).

    Picklable (arrays only), so a task may build it once and pass it around.
    """

    def __init__(self, values: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64]):
        self.values = np.asarray(values, np.float64)
        self.lat = np.asarray(lat, np.float64)
        self.lon = np.asarray(lon, np.float64)
        finite = self.values[np.isfinite(self.values)]
        self.fill = float(np.median(finite)) if finite.size else 0.0

    def sample(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bilinear values, NaN outside the grid or next to a NaN post."""
        from mercury_dem.reference.sampling import sample_grid

        return np.asarray(sample_grid(self.values, self.lat, self.lon, lat, lon), np.float64)

    def __call__(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        h = self.sample(lat, lon)
        return np.where(np.isfinite(h), h, self.fill)


def open_sparse_surface(dem_path: Path) -> SparseSurface:
    """The sparse DEM store's elevation as a :class:`SparseSurface` (loaded)."""
    from mercury_dem.pipeline.dem_stage import open_dem

    ds = open_dem(dem_path)
    e = ds["elevation"].transpose("lat", "lon")
    return SparseSurface(e.values, e["lat"].values, e["lon"].values)
