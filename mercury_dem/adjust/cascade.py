"""Decisions of the adjustment cascade (region → hemisphere → global) about one unit: pure functions.

A merged unit is adjusted from its children's networks and solutions. What it does with them
changes the result, so it is decided here (arrays and dataclasses in and out) and not in the
stage runner (:mod:`mercury_dem.pipeline.stages`), which only loads the children, calls these and
saves the unit:

- :func:`rejudged_network`: every measure of an adjusted child is judged again at this level
  (its rejections are cleared); a tile's network (never adjusted) is taken as it is.
- :func:`warm_start`: an image adjusted in several children starts from the child in which it had
  the most measures.
- :func:`unit_config`: a unit's network may hold islands (each held by its a-priori constraints)
  and images without measures (held at their a-priori pose and named), neither of which stops it.
- :func:`adjusts_by_blocks`: a large unit of the configured levels is adjusted over point blocks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.plan.tree import ADJUSTED_LEVELS

if TYPE_CHECKING:
    from mercury_dem.network.model import ControlNetwork

__all__ = ["ChildSolution", "adjusts_by_blocks", "rejudged_network", "unit_config", "warm_start"]


def rejudged_network(network: ControlNetwork, child_level: str) -> ControlNetwork:
    """A child's network as the next level merges it: an adjusted child's rejections cleared.

    Every measure is judged again at this level (a measure rejected by a region's adjustment may fit
    the hemisphere's solution). The a-priori coordinates stay those of the tiles (the a-priori DEM of
    the validation is gridded from them). A tile's network (``child_level == "tile"``, never adjusted)
    is returned unchanged.

    Parameters
    ----------
    network : ControlNetwork
        The child's network as its unit wrote it.
    child_level : str
        The child's level (``tile``, ``region``, ``hemisphere``).

    Returns
    -------
    ControlNetwork
        ``network`` itself for a tile; else a copy with ``measure_rejected`` and ``point_rejected`` all False.
    """
    if child_level not in ADJUSTED_LEVELS:
        return network
    return network.replace(
        measure_rejected=np.zeros_like(network.measure_rejected),
        point_rejected=np.zeros_like(network.point_rejected),
    )


@dataclass(frozen=True)
class ChildSolution:
    """One child's adjusted pointing (its ``solution.parquet``).

    Attributes
    ----------
    image_ids : ndarray of str, shape (N,)
    rotations : ndarray, shape (N, 3, 3)
    positions : ndarray, shape (N, 3)
    n_measures : ndarray of int, shape (N,), or None
        Accepted measures per image; None (an older solution without the column) counts 1 each.
    """

    image_ids: NDArray[Any]
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    n_measures: NDArray[np.int64] | None = None


def warm_start(image_ids: Sequence[str], rotations: NDArray[np.float64], positions: NDArray[np.float64],
               solutions: Sequence[ChildSolution]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Starting pointing of each image of a merged unit from its children's solutions.

    An image near a border was adjusted in several children; it starts from the child in which it had
    the most measures (the best-determined solution), ties broken by the earlier child in
    ``solutions`` (the runner passes them in the merge tree's order of child ids). Images no child
    adjusted keep their a-priori pose.

    Parameters
    ----------
    image_ids : sequence of str
        The unit's images, in the order of ``rotations``/``positions``.
    rotations, positions : ndarray, shape (N, 3, 3) and (N, 3)
        The a-priori pose of each image (not modified).
    solutions : sequence of ChildSolution

    Returns
    -------
    (rotations, positions) : new arrays, shapes as given.
    """
    index = {k: n for n, k in enumerate(image_ids)}
    rot, pos = rotations.copy(), positions.copy()
    best = np.full(len(image_ids), -1, dtype=np.int64)
    for sol in solutions:
        sid = sol.image_ids
        nmeas = sol.n_measures if sol.n_measures is not None else np.ones(len(sid), int)
        for k, image_id in enumerate(sid):
            n = index.get(str(image_id))
            if n is not None and nmeas[k] > best[n]:
                best[n] = nmeas[k]
                rot[n], pos[n] = sol.rotations[k], sol.positions[k]
    return rot, pos


def unit_config(config: AdjustConfig, image_ids: Sequence[str], measure_image: NDArray[np.integer]
                ) -> tuple[AdjustConfig, list[str]]:
    """The adjustment configuration of one unit's network, and its images without measures.

    A unit's network is adjusted whatever its image graph looks like: islands (disconnected groups of
    images) are adjusted together, each held by its a-priori constraints, and reported by id
    (``allow_islands`` forced on); an image without a measure (an imported or edited network) carries
    no information: it is held at its a-priori pose and named, instead of making the whole solve an
    AdjustmentError.

    Parameters
    ----------
    config : AdjustConfig
    image_ids : sequence of str, length N
    measure_image : ndarray of int
        Image index of every measure of the network.

    Returns
    -------
    (config, images_without_measures)
    """
    cfg = dataclasses.replace(config, allow_islands=True)
    ids = np.asarray(image_ids).astype(str)
    no_measures = ids[np.bincount(np.asarray(measure_image, np.int64), minlength=ids.size) == 0]
    if no_measures.size:
        cfg = dataclasses.replace(cfg, held_images=tuple(dict.fromkeys([*cfg.held_images, *no_measures.tolist()])))
    return cfg, no_measures.tolist()


def adjusts_by_blocks(config: AdjustConfig, level: str | None, n_measures: int) -> bool:
    """Whether a unit is adjusted over point blocks (:mod:`mercury_dem.adjust.blocked_bundle`).

    A unit of ``config.blocked_levels`` with at least ``config.blocked_min_measures`` measures is (the same
    solution to solver tolerance, less memory); ``blocked_min_measures`` None: never, 0: always on those
    levels; ``level`` None (a network adjusted outside the cascade): never.
    """
    return (level is not None and level in config.blocked_levels and config.blocked_min_measures is not None
            and n_measures >= config.blocked_min_measures)
