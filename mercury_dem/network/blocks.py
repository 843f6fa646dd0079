"""A stored network's image geometry and its point blocks, as the blocked adjustment takes them (data only).

:class:`BlockData` is one point block (what :class:`~mercury_dem.adjust.blocked.BlockShard` turns into its
state), :class:`ImageTable` the a-priori geometry of the images; both are read from a store by
:class:`mercury_dem.io.synthetic_network_store.BlockedNetwork` or made in memory
(:func:`mercury_dem.adjust.blocked.blocks_from_problem`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.camera import FramingCamera


@dataclass(frozen=True)
class ImageTable:
    """The a-priori geometry of a stored network's images."""

    cameras: tuple[FramingCamera, ...]
    image_camera: NDArray[np.int64]
    positions: NDArray[np.float64]
    rotations: NDArray[np.float64]

    @property
    def n_images(self) -> int:
        return len(self.positions)


@dataclass(frozen=True)
class BlockData:
    """One point block as read from the store (point indices local to the block)."""

    block: int
    point_start: int
    apriori_points: NDArray[np.float64]
    measure_image: NDArray[np.int64]
    measure_point: NDArray[np.int64]
    measures: NDArray[np.float64]
    sigma: NDArray[np.float64]  # (M,) px
    held_points: NDArray[np.bool_]
    outlier: NDArray[np.bool_] | None  # truth, when present
    true_points: NDArray[np.float64] | None
    #: (n,) per-point radius constraint, m (NaN: the configured one; None: none given), as
    #: ``AdjustmentProblem.point_radius_sigma`` (altimetry-constrained points of a pipeline unit)
    point_radius_sigma: NDArray[np.float64] | None = None
