"""The dense stage's rules on its inputs (pure): the per-tile cap of the stereo pairs and the height search margin.

Used by :mod:`mercury_dem.pipeline.dense_stage` (docs/design/dense.md, "The stage").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.dense.pairs import REJECTED, SELECTED, PairRejection
from mercury_dem.stats import NMAD_FACTOR


def cap_per_tile(rows: list[Any], tile_of: dict[str, int], max_per_tile: int,
                 tiles: tuple[int, ...] = ()) -> tuple[list[Any], dict[int, list[int]]]:
    """Apply the per-tile cap and the tile subset to selected pairs (best rank first).

    Returns the rows (capped ones rejected with the reason) and tile id -> indices of its selected rows,
    in rank order.
    """
    out = list(rows)
    per_tile: dict[int, list[int]] = {}
    for i in sorted((i for i, r in enumerate(out) if r.status == SELECTED), key=lambda i: out[i].rank):
        t = int(tile_of.get(out[i].left, -1))
        if tiles and t not in tiles:
            out[i] = replace(out[i], status=REJECTED, rank=0, reason=f"tile {t} not in dense.tiles",
                             rejections=(PairRejection.TILE_SUBSET.value,))
            continue
        got = per_tile.setdefault(t, [])
        if len(got) >= max_per_tile:
            out[i] = replace(out[i], status=REJECTED, rank=0,
                             reason=f"cap: tile {t} already has {max_per_tile} better-ranked pairs",
                             rejections=(PairRejection.CAP.value,))
            continue
        got.append(i)
    return out, {t: v for t, v in per_tile.items() if v}


def height_margins(points_xyz: NDArray[np.float64], surface: Callable[..., NDArray[np.float64]],
                   datum_radius_m: float, tile_size_deg: float, factor: float, floor_m: float,
                   min_points: int = 20) -> tuple[dict[int, float], float]:
    """Per tile the height search margin: ``factor`` x the robust scatter of its tie points' heights about the
    surface, at least ``floor_m``; the run's value (all points) for tiles with fewer than ``min_points``.

    Returns (tile id -> margin in m, the run's margin).
    """
    from mercury_dem.geometry.body import xyz_to_latlon
    from mercury_dem.geometry.tiling import TileGrid

    if points_xyz.shape[0] == 0:
        return {}, floor_m
    lat, lon, h = xyz_to_latlon(points_xyz, datum_radius_m)
    res = h - surface(lat, lon)
    ok = np.isfinite(res)
    tiles = TileGrid(tile_size_deg).tile_of(lat, lon)

    def margin(r: NDArray[np.float64]) -> float:
        s = NMAD_FACTOR * float(np.median(np.abs(r - np.median(r)))) if r.size else 0.0
        return max(floor_m, factor * s)

    run = margin(res[ok])
    out: dict[int, float] = {}
    for t in np.unique(tiles[ok]):
        r = res[ok & (tiles == t)]
        out[int(t)] = margin(r) if r.size >= min_points else run
    return out, run
