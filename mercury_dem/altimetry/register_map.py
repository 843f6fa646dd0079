"""A whole map registered to altimetry and merged with it, one block of rows at a time.

The registration stage (:mod:`mercury_dem.pipeline.register_stage`) loads the DEM and the tiles'
transforms, calls :func:`register_and_merge_blockwise` and saves what it hands back. The map is never
held whole: the function reads rows through ``read_rows(i0, i1)``, keeps the transformed map in a
``scratch`` array the caller provides (a float64 Zarr array on disk, a numpy array in a test) and gives
each finished block to ``write(r0, r1, registered, merged)``. Nothing here opens a file.

Why blocks and not a Dask map: every pixel depends only on neighbours within two margins (the
transforms' largest displacement, :func:`transform_margin_rows`, and the merge's reach,
:func:`~mercury_dem.altimetry.merge.merge_halo_px`), so a block computed with those margins and cropped
equals the whole-map computation (a test compares them), with a block's memory.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mercury_dem.altimetry.merge import (
    MeanLevel,
    MergedDem,
    MergeOptions,
    blended_scalar,
    max_displacement_m,
    mean_level_offsets,
    merge_dem,
    merge_halo_px,
    register_dem,
)
from mercury_dem.altimetry.register import ProfileOffsets, TileTransform, enu_frame
from mercury_dem.geometry.body import latlon_to_unit, xyz_to_latlon
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.reference.sampling import sample_grid

__all__ = ["SAMPLE_NAMES", "BlockwiseMaps", "ShotPositions", "corrected_shots", "level_allowed_tiles",
           "register_and_merge_blockwise", "row_blocks", "row_of", "rows_per_block", "sample_blockwise",
           "transform_margin_rows"]

#: The maps sampled at the corrected shots: the DEM as given, after the tile transforms, after the mean
#: level (the registered map), and the merged map.
SAMPLE_NAMES = ("as_given", "transformed", "registered", "merged")

Rows = Callable[[int, int], NDArray[np.float64]]
BlockWriter = Callable[[int, int, NDArray[np.float64], MergedDem], None]


class Scratch(Protocol):
    """A (H, W) float64 array with slice reads and writes: a Zarr array, or a numpy array."""

    def __getitem__(self, key: Any) -> Any: ...

    def __setitem__(self, key: Any, value: Any) -> None: ...


@dataclass(frozen=True)
class ShotPositions:
    """Shots as the merge uses them: latitude, east longitude (degrees), radius (m), shape (N,) each."""

    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    radius_m: NDArray[np.float64]


@dataclass(frozen=True)
class BlockwiseMaps:
    """What :func:`register_and_merge_blockwise` computes beside the maps it writes.

    ``samples``: :data:`SAMPLE_NAMES` → the map's height at each shot (NaN off the map);
    ``n_dense_pixels``: merged pixels gridded from the altimetry; ``level``: the mean level's per-tile
    offsets (its ``height`` not kept: an empty array), None when the map was not levelled.
    """

    samples: dict[str, NDArray[np.float64]]
    n_dense_pixels: int
    level: MeanLevel | None


def corrected_shots(shots: pd.DataFrame, profiles: ProfileOffsets, datum_radius_m: float) -> ShotPositions:
    """Shots (columns lat, lon, radius_m, profile_id, tile_id) moved by their profile's fitted offset.

    Shots of profiles without a fitted offset are unchanged. The offset is east/north/up at the
    profile's tile centre (:func:`~mercury_dem.altimetry.register.enu_frame`).
    """
    x = latlon_to_unit(shots["lat"].to_numpy(), shots["lon"].to_numpy()) * shots["radius_m"].to_numpy()[:, None]
    pf = profiles.to_frame()
    if len(pf):
        key = pd.DataFrame({"profile_id": shots["profile_id"].to_numpy(), "tile_id": shots["tile_id"].to_numpy()})
        pf = pf[pf["fitted"]]
        m = key.merge(pf, on=["profile_id", "tile_id"], how="left")
        d = m[["offset_e_m", "offset_n_m", "offset_u_m"]].to_numpy(dtype=np.float64)
        has = np.isfinite(d).all(axis=1)
        if has.any():
            E = enu_frame(m["centre_lat"].to_numpy()[has], m["centre_lon"].to_numpy()[has])
            x[has] += np.einsum("nij,nj->ni", E, d[has])
    lat, lon, h = xyz_to_latlon(x, datum_radius_m)
    return ShotPositions(lat, lon, h + datum_radius_m)


def level_allowed_tiles(transforms: Sequence[TileTransform], n_tiles: int) -> NDArray[np.bool_]:
    """The tiles that may level themselves on the shots' mean: those whose transform was fitted.

    A tile without a transform takes its neighbours' offset
    (:func:`~mercury_dem.altimetry.merge.mean_level_offsets`' fill): its own mean difference would
    carry the unregistered DEM's error into the level.
    """
    allowed = np.zeros(n_tiles, bool)
    allowed[[t.tile_id for t in transforms if t.ok]] = True
    return allowed


def row_of(lat_pts: NDArray[np.float64], lat: NDArray[np.float64]) -> NDArray[np.int64]:
    """The nearest grid row of each latitude (clipped to the grid; the grid's latitudes evenly spaced)."""
    if lat.size < 2:
        return np.zeros(lat_pts.shape, dtype=np.int64)
    r = np.rint((lat_pts - lat[0]) / (lat[1] - lat[0]))
    return np.clip(np.nan_to_num(r, nan=0.0), 0, lat.size - 1).astype(np.int64)


def row_blocks(n_rows: int, block_rows: int) -> list[tuple[int, int]]:
    """``[(r0, r1), ...]``: consecutive blocks of ``block_rows`` rows (the last one shorter) covering ``n_rows``."""
    return [(r0, min(r0 + block_rows, n_rows)) for r0 in range(0, n_rows, block_rows)]


def rows_per_block(n_rows: int, n_cols: int, block_pixels: float, min_rows: int) -> int:
    """As many rows as make ``block_pixels`` pixels, at least ``min_rows``, at most the map's rows
    (but never fewer than ``min_rows``: a map shorter than that is one block).
    """
    return max(min_rows, min(n_rows, int(block_pixels // max(n_cols, 1))))


def transform_margin_rows(transforms: Sequence[TileTransform], datum_radius_m: float, lat: NDArray[np.float64],
                          surface_height_m: float) -> int:
    """Rows a block must read on each side for the transforms: their largest displacement of a surface
    up to ``surface_height_m`` above the datum (:func:`~mercury_dem.altimetry.merge.max_displacement_m`),
    in rows, plus two.
    """
    step_deg = abs(float(lat[1] - lat[0])) if lat.size > 1 else 1.0
    shift_deg = math.degrees(max_displacement_m(transforms, datum_radius_m + surface_height_m) / datum_radius_m)
    return int(math.ceil(shift_deg / step_deg)) + 2


def sample_blockwise(read_rows: Rows, lat: NDArray[np.float64], lon: NDArray[np.float64], plat: NDArray[np.float64],
                     plon: NDArray[np.float64], block_rows: int) -> NDArray[np.float64]:
    """``sample_grid`` of the whole map at the points, reading it one block of rows (+1 row each side) at a time."""
    out = np.full(plat.shape, np.nan)
    rows = row_of(plat, lat)
    H = lat.size
    for r0, r1 in row_blocks(H, block_rows):
        sel = np.flatnonzero((rows >= r0) & (rows < r1))
        if not sel.size:
            continue
        i0, i1 = max(r0 - 1, 0), min(r1 + 1, H)
        out[sel] = sample_grid(read_rows(i0, i1), lat[i0:i1], lon, plat[sel], plon[sel])
    return out


class _ShotRows:
    """The shots sorted by their grid row: those of a range of rows in O(log N)."""

    def __init__(self, shot_lat: NDArray[np.float64], lat: NDArray[np.float64]) -> None:
        rows = row_of(shot_lat, lat)
        self.order = np.argsort(rows, kind="stable")
        self.sorted_rows = rows[self.order]

    def between(self, r0: int, r1: int) -> NDArray[np.intp]:
        return self.order[np.searchsorted(self.sorted_rows, r0):np.searchsorted(self.sorted_rows, r1)]


def _sample_rows(grid: Any, rows: slice, lat: NDArray[np.float64], lon: NDArray[np.float64], shots: ShotPositions,
                 own: NDArray[np.intp]) -> NDArray[np.float64]:
    """``sample_grid`` of ``grid`` (the map's ``rows``) at the shots ``own``."""
    return sample_grid(grid, lat[rows], lon, shots.lat[own], shots.lon[own])


def _transform_pass(read_rows: Rows, scratch: Scratch, lat: NDArray[np.float64], lon: NDArray[np.float64],
                    datum: float, transforms: Sequence[TileTransform], tiles: TileGrid, blocks: list[tuple[int, int]],
                    margin_rows: int, shots: ShotPositions, by_row: _ShotRows,
                    samples: dict[str, NDArray[np.float64]]) -> None:
    """Pass 1: each block registered (:func:`register_dem` with ``rows``) into ``scratch``; the DEM as given
    and, once every row is in, the transformed map sampled at the shots.
    """
    H = lat.size
    for r0, r1 in blocks:
        i0, i1 = max(r0 - margin_rows, 0), min(r1 + margin_rows, H)
        win = read_rows(i0, i1)
        scratch[r0:r1, :] = register_dem(win, lat[i0:i1], lon, datum, transforms, tiles, rows=(r0 - i0, r1 - i0))
        own = by_row.between(r0, r1)
        if own.size:
            i0s, i1s = max(r0 - 1, 0), min(r1 + 1, H)
            samples["as_given"][own] = _sample_rows(win[i0s - i0:i1s - i0], slice(i0s, i1s), lat, lon, shots, own)
    for r0, r1 in blocks:
        own = by_row.between(r0, r1)
        if own.size:
            i0s, i1s = max(r0 - 1, 0), min(r1 + 1, H)
            samples["transformed"][own] = _sample_rows(scratch[i0s:i1s, :], slice(i0s, i1s), lat, lon, shots, own)


def _merge_pass(scratch: Scratch, level: MeanLevel | None, lat: NDArray[np.float64], lon: NDArray[np.float64],
                datum: float, tiles: TileGrid, merge_options: MergeOptions, blocks: list[tuple[int, int]],
                shots: ShotPositions, by_row: _ShotRows, samples: dict[str, NDArray[np.float64]],
                write: BlockWriter) -> int:
    """Pass 2: each block's transformed rows and the merge's margin levelled (:func:`blended_scalar`,
    pointwise), merged (:func:`merge_dem`, the shots near the block), and the block's own rows written.
    Returns the merged map's dense pixels.
    """
    H = lat.size
    hm = merge_halo_px(merge_options)
    level_on = level is not None and bool(level.own.any())
    n_dense = 0
    for r0, r1 in blocks:
        e0, e1 = max(r0 - hm, 0), min(r1 + hm, H)  # the block and the merge's margin
        reg = scratch[e0:e1, :]
        if level_on:
            assert level is not None
            LA, LO = np.meshgrid(lat[e0:e1], lon, indexing="ij")
            reg = reg + blended_scalar(level.offset_m, tiles, LA.ravel(), LO.ravel()).reshape(reg.shape)
        near = by_row.between(e0 - 1, e1 + 1)
        merged = merge_dem(reg, lat[e0:e1], lon, datum, shots.lat[near], shots.lon[near], shots.radius_m[near],
                           merge_options)
        core = slice(r0 - e0, r1 - e0)
        n_block = int((merged.shot_count[core] >= merge_options.min_shots_per_pixel).sum())
        write(r0, r1, reg[core], MergedDem(merged.height[core], merged.altimetry_weight[core],
                                           merged.shot_count[core], merged.n_shots_used, n_block))
        n_dense += n_block
        own = by_row.between(r0, r1)
        if own.size:
            samples["registered"][own] = _sample_rows(reg, slice(e0, e1), lat, lon, shots, own)
            samples["merged"][own] = _sample_rows(merged.height, slice(e0, e1), lat, lon, shots, own)
    return n_dense


def register_and_merge_blockwise(
    read_rows: Rows, lat: NDArray[np.float64], lon: NDArray[np.float64], datum_radius_m: float,
    transforms: Sequence[TileTransform], tiles: TileGrid, shots: ShotPositions, *, scratch: Scratch,
    write: BlockWriter, block_rows: int, merge_options: MergeOptions, level_allowed: NDArray[np.bool_] | None,
    surface_height_m: float, level_min_shots: int, level_clip_nmad: float,
) -> BlockwiseMaps:
    """The registered and merged maps of a DEM, computed one block of rows at a time.

    Parameters
    ----------
    read_rows : ``read_rows(i0, i1)`` → the DEM's rows i0..i1-1, float64 metres above ``datum_radius_m``
    lat, lon : (H,), (W,) the grid's pixel centres (degrees; latitudes evenly spaced)
    transforms, tiles : the tiles' fitted transforms and their grid
    shots : the shots corrected by their profile offsets (:func:`corrected_shots`)
    scratch : a (H, W) float64 array the transformed map is kept in between the passes
    write : ``write(r0, r1, registered, merged)`` receives each block's rows, in row order: the
        registered heights (float64) and the :class:`~mercury_dem.altimetry.merge.MergedDem` cropped to
        them (its ``n_shots_used`` the block's merge's, ``n_dense_pixels`` the block's own rows')
    block_rows : rows per block
    merge_options : the merge's settings (:class:`~mercury_dem.altimetry.merge.MergeOptions`)
    level_allowed : (n_tiles,) the tiles that may level themselves (:func:`level_allowed_tiles`), or
        None: no mean level
    surface_height_m : the surface lies below this height above the datum (bounds the transforms'
        displacement, :func:`transform_margin_rows`)
    level_min_shots, level_clip_nmad : the mean level's ``min_shots`` and ``clip_nmad``
        (:func:`~mercury_dem.altimetry.merge.mean_level_offsets`)

    Between the passes the mean level's per-tile offsets
    (:func:`~mercury_dem.altimetry.merge.mean_level_offsets`) are computed from the whole map's samples.
    """
    samples = {name: np.full(shots.lat.shape, np.nan) for name in SAMPLE_NAMES}
    blocks = row_blocks(lat.size, block_rows)
    by_row = _ShotRows(shots.lat, lat)
    margin = transform_margin_rows(transforms, datum_radius_m, lat, surface_height_m)
    _transform_pass(read_rows, scratch, lat, lon, datum_radius_m, transforms, tiles, blocks, margin, shots, by_row,
                    samples)
    level = None
    if level_allowed is not None:
        offset, own_t, shots_t = mean_level_offsets((shots.radius_m - datum_radius_m) - samples["transformed"],
                                                    shots.lat, shots.lon, tiles, allowed=level_allowed,
                                                    min_shots=level_min_shots, clip_nmad=level_clip_nmad)
        level = MeanLevel(np.zeros((0, 0)), offset, own_t, shots_t)
    n_dense = _merge_pass(scratch, level, lat, lon, datum_radius_m, tiles, merge_options, blocks, shots, by_row,
                          samples, write)
    return BlockwiseMaps(samples, n_dense, level)
