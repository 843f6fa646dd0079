"""The plan of a run's images: the tile and region of every usable image and the a-priori overlap pairs. Pure.

The stage runner (:func:`mercury_dem.pipeline.stages.plan_run`) reads each image's camera and a-priori pose
from the mission (an image whose geometry is unusable arrives with its reason in ``excluded``), calls
:func:`plan_images` and writes the tables to ``RUN/plan``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["ImagePlan", "plan_images"]


@dataclass(frozen=True)
class ImagePlan:
    """Where each image goes and which pairs overlap a priori.

    Attributes
    ----------
    tile, region : (N,) int64, the image's tile and region (-1: excluded)
    excluded : (N,) object array of str, why the image takes no part ("" when it does)
    i, j : (P,) int64, image indices of each overlapping pair (i < j)
    fraction : (P,) float64, the pair's a-priori overlap fraction
    tile_size_deg, tiles_total : the grid's
    """

    tile: NDArray[np.int64]
    region: NDArray[np.int64]
    excluded: NDArray[Any]
    i: NDArray[np.int64]
    j: NDArray[np.int64]
    fraction: NDArray[np.float64]
    tile_size_deg: float
    tiles_total: int

    @property
    def ok(self) -> NDArray[np.bool_]:
        """(N,) bool, the images that take part."""
        return np.asarray(self.excluded == "", bool)

    def non_empty_tiles(self) -> list[int]:
        """The tiles holding at least one usable image, ascending."""
        return sorted(set(self.tile[self.ok].tolist()))


def plan_images(
    image_ids: NDArray[np.str_],
    center_lat: NDArray[np.float64],
    center_lon: NDArray[np.float64],
    cameras: Sequence[Any],
    camera_index: NDArray[np.int64],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    excluded: NDArray[Any],
    *,
    tile_size_deg: float,
    min_overlap_fraction: float,
    datum_radius_m: float,
) -> ImagePlan:
    """Tile every usable image by its centre and find the overlapping pairs among them.

    Parameters
    ----------
    image_ids : (N,) str
    center_lat, center_lon : (N,) planetocentric degrees of each image's centre (NaN: missing, then excluded)
    cameras : the distinct cameras; ``camera_index`` (N,) says each image's
    positions : (N, 3) body-fixed metres; rotations : (N, 3, 3) camera-to-body, a priori
    excluded : (N,) str, "" for an image whose geometry is usable, else why not (not modified)
    tile_size_deg : the tile grid's (:class:`~mercury_dem.geometry.tiling.TileGrid`)
    min_overlap_fraction, datum_radius_m : of the overlap test (:func:`~mercury_dem.geometry.footprints.overlap_graph`)
    """
    from mercury_dem.geometry.footprints import overlap_graph
    from mercury_dem.geometry.tiling import TileGrid

    grid = TileGrid(tile_size_deg)
    excluded = np.array(excluded, dtype=object, copy=True)
    ok = excluded == ""
    bad_centre = ok & ~(np.isfinite(center_lat) & np.isfinite(center_lon))
    excluded[bad_centre] = [f"image {i}: centre latitude/longitude missing; fix the catalog"
                            for i in image_ids[bad_centre]]
    ok &= ~bad_centre
    tile = np.full(image_ids.size, -1, dtype=np.int64)
    tile[ok] = grid.tile_of(center_lat[ok], center_lon[ok])
    region = np.full(image_ids.size, -1, dtype=np.int64)
    region[ok] = grid.region_of_tile(tile[ok])
    good = np.flatnonzero(ok)
    graph = overlap_graph(
        list(cameras), camera_index[good], positions[good], rotations[good],
        min_fraction=min_overlap_fraction, radius_m=datum_radius_m,
    ) if len(cameras) else None
    i = good[graph.i] if graph is not None else np.zeros(0, np.int64)
    j = good[graph.j] if graph is not None else np.zeros(0, np.int64)
    fraction = graph.fraction if graph is not None else np.zeros(0)
    return ImagePlan(tile, region, excluded, i, j, fraction, grid.tile_size_deg, grid.n_tiles)
