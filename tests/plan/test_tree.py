"""The merge tree (``mercury_dem.plan.tree``): its shape on full grids and on a run's subset of tiles."""

from __future__ import annotations

import pytest

from mercury_dem.geometry.tiling import ALLOWED_TILE_SIZES, TileGrid
from mercury_dem.plan.tree import (
    ADJUSTED_LEVELS,
    CHILD_LEVEL,
    LEVELS,
    child_ids,
    level_of_key,
    merge_tree,
    unit_key,
    units_of_level,
)


def test_levels_and_keys() -> None:
    assert LEVELS == ("tile", "region", "hemisphere", "global") and ADJUSTED_LEVELS == LEVELS[1:]
    assert [CHILD_LEVEL[lvl] for lvl in ADJUSTED_LEVELS] == list(LEVELS[:-1])
    assert unit_key("hemisphere", 1) == "hemisphere-1" and level_of_key("global-0") == "global"


def test_full_tree_10_degrees() -> None:
    t = merge_tree(10.0)
    assert t.totals() == {"tile": 648, "region": 14, "hemisphere": 2, "global": 1}
    # every tile feeds exactly one region; regions 0-6 north, 7-13 south
    fed = [c for r in t.units["region"] for c in t.children[("region", r)]]
    assert sorted(fed) == list(range(648))
    assert t.children[("hemisphere", 0)] == tuple(range(7)) and t.children[("hemisphere", 1)] == tuple(range(7, 14))
    assert t.children[("global", 0)] == (0, 1)
    # a 10-degree polar cap is 3 rows x 36 columns; a 0-60 deg sector 6 rows x 6 columns
    assert len(t.children[("region", 0)]) == 108 and len(t.children[("region", 3)]) == 36
    # the DAG view: tiles first, in submission order, then the merged levels
    assert t.order[:648] == tuple(t.keys("tile")) and t.order[-1] == "global-0"
    assert t.deps["global-0"] == ("hemisphere-0", "hemisphere-1") and t.deps["tile-5"] == ()
    assert t.deps["hemisphere-0"] == tuple(f"region-{r}" for r in range(7))


@pytest.mark.parametrize("size", ALLOWED_TILE_SIZES)
def test_children_agree_with_the_tile_grid(size: float) -> None:
    """On every allowed grid the full tree's children are ``child_ids`` (what a runner merges)."""
    t = merge_tree(size)
    grid = TileGrid(size)
    assert t.units["tile"] == tuple(range(grid.n_tiles))
    for lvl in ADJUSTED_LEVELS:
        # a unit of the grid is in the tree exactly when it has a child there (60 deg tiles: the
        # band -30..30 is one row of tiles centred on the equator, all in northern sectors)
        below = set(t.units[CHILD_LEVEL[lvl]])
        present = [u for u in units_of_level(lvl, size) if set(child_ids(lvl, u, size)) & below]
        assert list(t.units[lvl]) == present
        for u in t.units[lvl]:
            assert list(t.children[(lvl, u)]) == [c for c in child_ids(lvl, u, size) if c in below], (size, lvl, u)
    assert merge_tree(10.0).units["region"] == tuple(range(14))
    for r in t.units["region"]:
        assert set(grid.region_of_tile(list(t.children[("region", r)])).tolist()) == {r}


def test_a_subset_leaves_out_empty_units_and_keeps_the_tile_order() -> None:
    # 182: row 5 col 2 (lat -40, lon 20), sector 0-60 south; 0 and 1: south cap
    t = merge_tree(10.0, tiles=[182, 1, 0])
    assert t.units == {"tile": (182, 1, 0), "region": (7, 8), "hemisphere": (1,), "global": (0,)}
    assert t.children[("region", 7)] == (1, 0)  # the order the tiles were given in (submission order)
    assert t.deps["global-0"] == ("hemisphere-1",)
    assert t.keys("region") == ["region-7", "region-8"]


def test_no_tiles_no_tree() -> None:
    t = merge_tree(30.0, tiles=[])
    assert t.totals() == {"tile": 0, "region": 0, "hemisphere": 0, "global": 0} and t.order == ()


def test_bad_input_is_refused() -> None:
    from mercury_dem.exceptions import ConfigError

    with pytest.raises(ConfigError, match="tile size must divide 60"):
        merge_tree(7.0)
    with pytest.raises(ConfigError, match="tile id out of range"):
        merge_tree(30.0, tiles=[72])
    with pytest.raises(ValueError, match="no children"):
        child_ids("tile", 0, 10.0)


@pytest.mark.parametrize("seed", [3, 11])
def test_random_subsets_follow_the_tile_grid(seed: int) -> None:
    """Any set of tiles, in any order: each region gets exactly its tiles, in the given order; every
    hemisphere exactly its present regions; the globe the present hemispheres."""
    import numpy as np

    rng = np.random.default_rng(seed)
    grid = TileGrid(15.0)
    tiles = [int(t) for t in rng.choice(grid.n_tiles, size=40, replace=False)]
    t = merge_tree(15.0, tiles)
    region_of = {x: int(grid.region_of_tile(x)) for x in tiles}
    assert t.units["region"] == tuple(sorted(set(region_of.values())))
    for r in t.units["region"]:
        assert t.children[("region", r)] == tuple(x for x in tiles if region_of[x] == r)
    hemis = sorted({int(grid.hemisphere_of_region(r)) for r in t.units["region"]})
    assert t.units["hemisphere"] == tuple(hemis) and t.children[("global", 0)] == tuple(hemis)
    for h in hemis:
        assert t.children[("hemisphere", h)] == tuple(r for r in t.units["region"] if r // 7 == h)
    assert len(t.order) == len(set(t.order)) == sum(t.totals().values())
