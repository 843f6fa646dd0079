"""Configuration of the tile grid and overlap search."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class TilingConfig(ConfigSection):
    """The ``tiling`` section: the tile grid and the overlap search."""

    tile_size_deg: float = param(
        10.0, "Size of the square lat/lon tiles; must divide 60 so regions are whole tiles", unit="deg",
        choices=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 10.0, 12.0, 15.0, 20.0, 30.0, 60.0),
    )
    footprint_edge_points: int = param(
        8, "Points per image side used to trace a footprint on the body", lo=2, hi=256
    )
    min_overlap_fraction: float = param(
        0.02, "Smallest overlap (fraction of the smaller footprint) for a pair to be matched", lo=0.0, hi=1.0
    )
