"""``mercury-dem tiles``: the tile grid, its 14 regions and 2 hemispheres (and images per tile)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from mercury_dem.config import Config

if TYPE_CHECKING:
    import numpy as np

    from mercury_dem.geometry.tiling import TileGrid

NAME = "tiles"
HELP = "print the tile grid, regions and hemispheres with their tile counts (and images per tile)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mission", help="a mission store: also count its images per tile, region and hemisphere")
    p.add_argument("--tile-size", type=float, help="tile size in degrees (overrides tiling.tile_size_deg)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def tiles_summary(grid: TileGrid, tile_ids: np.ndarray | None = None) -> dict[str, object]:
    """Grid counts, plus image counts when the images' tile ids are given."""
    import numpy as np

    from mercury_dem.geometry.tiling import N_REGIONS, region_name

    out = grid.summary()
    if tile_ids is not None:
        tile_ids = np.asarray(tile_ids, dtype=np.int64)
        reg = grid.region_of_tile(tile_ids) if tile_ids.size else tile_ids
        uniq, counts = np.unique(tile_ids, return_counts=True)
        out["images"] = int(tile_ids.size)
        out["non_empty_tiles"] = int(uniq.size)
        out["images_per_tile"] = {int(t): int(c) for t, c in zip(uniq, counts)}
        out["images_per_region"] = {region_name(r): int(np.sum(reg == r)) for r in range(N_REGIONS)}
        hem = grid.hemisphere_of_region(reg) if tile_ids.size else tile_ids
        out["images_per_hemisphere"] = {"north": int(np.sum(hem == 0)), "south": int(np.sum(hem == 1))}
    return out


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.geometry.tiling import TileGrid

    size = args.tile_size if args.tile_size is not None else config.tiling.tile_size_deg
    grid = TileGrid(size)
    tile_ids = None
    if args.mission:
        from mercury_dem.mission import open_mission

        mission = open_mission(args.mission)
        tile_ids = grid.tile_of(mission.catalog["center_lat"].to_numpy(), mission.catalog["center_lon"].to_numpy())
    s = tiles_summary(grid, tile_ids)
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    print(f"tile grid: {s['tile_size_deg']} deg, {s['rows']} rows x {s['cols']} cols = {s['tiles']} tiles")
    print("(the reference text counts 720 tiles of 10 deg; a 10 deg grid over the sphere has 648)")
    img = s.get("images_per_region", {})
    print(f"{'region':<12}{'tiles':>7}" + (f"{'images':>8}" if img else ""))
    for name, n in s["regions"].items():  # type: ignore[union-attr]
        print(f"{name:<12}{n:>7}" + (f"{img[name]:>8}" if img else ""))
    for h, n in s["hemispheres"].items():  # type: ignore[union-attr]
        extra = f"{s['images_per_hemisphere'][h]:>8}" if img else ""  # type: ignore[index]
        print(f"{'hemisphere ' + h:<12}{n:>7}{extra}")
    if img:
        print(f"images: {s['images']} in {s['non_empty_tiles']} non-empty tiles")
    return 0
