"""The merge tree of a run: tiles -> regions -> hemispheres -> globe, defined once.

The levels, which level a unit's children belong to, and the tree of a run's
non-empty tiles are read from here by the run (:mod:`mercury_dem.pipeline.graph`
submits exactly this tree), the stage runners (the children of a unit), the run
store (the level names of its directories), the reports and status tables
(:mod:`mercury_dem.viz.status`) and the cascade benchmark
(``workflows/benchmarks/cascade_replay.py``). The geometry of the cut (which region
holds a tile, which hemisphere a region) is :class:`~mercury_dem.geometry.tiling.TileGrid`'s.

Units are named ``(level, id)``; as task keys and graph nodes ``"<level>-<id>"``
(``tile-17``, ``region-3``, ``hemisphere-1``, ``global-0``).

The constants import nothing heavy (a command module may read them for its ``--help``);
the functions import the tile grid, and with it numpy, when called.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cached_property

#: The levels of the cascade, from the leaves to the root.
LEVELS: tuple[str, ...] = ("tile", "region", "hemisphere", "global")
#: The levels whose units merge their children's networks and bundle adjust them.
ADJUSTED_LEVELS: tuple[str, ...] = LEVELS[1:]
#: The level of a merged unit's children.
CHILD_LEVEL: Mapping[str, str] = {"region": "tile", "hemisphere": "region", "global": "hemisphere"}
#: Hemispheres (0 north, 1 south) and the one global unit.
N_HEMISPHERES = 2
GLOBAL_ID = 0


def unit_key(level: str, unit_id: int) -> str:
    """Task key / graph node of a unit: ``"region-3"``."""
    return f"{level}-{int(unit_id)}"


def level_of_key(key: str) -> str:
    """The level of a key made by :func:`unit_key`."""
    return key.rsplit("-", 1)[0]


def units_of_level(level: str, tile_size_deg: float) -> list[int]:
    """Every unit id a level can have on the full grid (whether or not a run has tiles there)."""
    from mercury_dem.geometry.tiling import N_REGIONS, TileGrid

    if level == "tile":
        return list(range(TileGrid(tile_size_deg).n_tiles))
    return list(range({"region": N_REGIONS, "hemisphere": N_HEMISPHERES, "global": 1}[level]))


def child_ids(level: str, unit_id: int, tile_size_deg: float) -> list[int]:
    """Ids of every unit of the level below that makes up a region, hemisphere or the globe.

    All of them, on the full grid; :func:`merge_tree` keeps only those of a run's tiles.
    """
    from mercury_dem.geometry.tiling import TileGrid

    grid = TileGrid(tile_size_deg)
    if level == "region":
        return grid.tiles_of_region(unit_id).tolist()
    if level == "hemisphere":
        return grid.regions_of_hemisphere(unit_id).tolist()
    if level == "global":
        return list(range(N_HEMISPHERES))
    raise ValueError(f"a {level!r} unit has no children; one of {', '.join(CHILD_LEVEL)}")


@dataclass(frozen=True)
class MergeTree:
    """The units of a run per level and the children of every merged unit.

    Attributes
    ----------
    units : per level (every name of :data:`LEVELS`), the unit ids in submission order: the
        tiles as given to :func:`merge_tree`, then regions, hemispheres and the globe in id order.
    children : per merged unit ``(level, id)``, the ids of its children (of level
        ``CHILD_LEVEL[level]``), in the order of ``units`` of that level. Never empty.
    """

    units: Mapping[str, tuple[int, ...]]
    children: Mapping[tuple[str, int], tuple[int, ...]]

    def totals(self) -> dict[str, int]:
        """Units per level."""
        return {lvl: len(self.units[lvl]) for lvl in LEVELS}

    @cached_property
    def order(self) -> tuple[str, ...]:
        """Every unit's key in submission order (tiles, regions, hemispheres, globe)."""
        return tuple(unit_key(lvl, u) for lvl in LEVELS for u in self.units[lvl])

    @cached_property
    def deps(self) -> dict[str, tuple[str, ...]]:
        """The tree as a DAG of keys: ``deps[key]`` are the keys it waits for (empty for a tile)."""
        out: dict[str, tuple[str, ...]] = {unit_key("tile", t): () for t in self.units["tile"]}
        for lvl in ADJUSTED_LEVELS:
            for u in self.units[lvl]:
                out[unit_key(lvl, u)] = tuple(unit_key(CHILD_LEVEL[lvl], c) for c in self.children[(lvl, u)])
        return out

    def keys(self, level: str) -> list[str]:
        """The keys of one level, in submission order."""
        return [unit_key(level, u) for u in self.units[level]]

    @staticmethod
    def level_of(key: str) -> str:
        return level_of_key(key)


def merge_tree(tile_size_deg: float, tiles: Iterable[int] | None = None) -> MergeTree:
    """The tree of a run over ``tiles`` (default: every tile of the grid).

    Units without children are left out (a region none of whose tiles is in ``tiles``,
    a hemisphere without such a region, the globe without hemispheres), as the run does.

    Parameters
    ----------
    tile_size_deg : the tile size (one of :data:`~mercury_dem.geometry.tiling.ALLOWED_TILE_SIZES`)
    tiles : the run's non-empty tile ids; their order is kept (it is the submission order)
    """
    import numpy as np

    from mercury_dem.geometry.tiling import TileGrid

    grid = TileGrid(tile_size_deg)
    tile_ids = tuple(range(grid.n_tiles)) if tiles is None else tuple(int(t) for t in tiles)
    region_of = grid.region_of_tile(np.asarray(tile_ids, dtype=np.int64)).tolist() if tile_ids else []
    children: dict[tuple[str, int], tuple[int, ...]] = {}
    regions = sorted(set(region_of))
    for r in regions:
        children[("region", r)] = tuple(t for t, rr in zip(tile_ids, region_of) if rr == r)
    hemis = sorted({int(grid.hemisphere_of_region(r)) for r in regions})
    for h in hemis:
        children[("hemisphere", h)] = tuple(r for r in regions if int(grid.hemisphere_of_region(r)) == h)
    glob = (GLOBAL_ID,) if hemis else ()
    if glob:
        children[("global", GLOBAL_ID)] = tuple(hemis)
    units = {"tile": tile_ids, "region": tuple(regions), "hemisphere": tuple(hemis), "global": glob}
    return MergeTree(units=units, children=children)
