"""Configuration of the registration of the DEM to laser altimetry and of their merge.

The stage (:mod:`mercury_dem.pipeline.register_stage`) registers ``dem.zarr`` per tile of the run's
tile grid (``tiling.tile_size_deg``), levels it on the shots' mean and merges the shots into it, one
block of rows at a time (:mod:`mercury_dem.altimetry.register_map`). Whether it runs at all is
``dem.register_to_altimetry``.
"""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class RegistrationConfig(ConfigSection):
    """The ``registration`` section: the DEM registered to altimetry and merged with it."""

    window_margin_deg: float = param(
        1.0, "Each tile's DEM window reaches this far beyond the tile (the transform's fit sees the shots "
        "near its edge on the DEM)", unit="deg", lo=0.0, hi=30.0,
    )
    max_surface_height_m: float = param(
        50_000.0, "The surface lies below this height above the datum: it bounds the tile transforms' "
        "largest displacement, hence how many rows a block reads beyond its own", unit="m", lo=0.0, hi=1e7,
    )
    block_pixels: float = param(
        4e6, "The registered and merged maps are computed this many pixels (whole rows) at a time; memory "
        "follows the block, not the map (docs/benchmarks/altimetry.md)", unit="pixel", lo=1.0, hi=1e10,
    )
    min_block_rows: int = param(16, "A block has at least this many rows", unit="row", lo=1, hi=1_000_000)
    chunk_columns: int = param(
        1024, "Zarr chunk width of registered.zarr and merged.zarr (a chunk is a block's rows high)",
        unit="pixel", lo=1, hi=1_000_000,
    )
    min_shots_per_pixel: int = param(
        2, "Merge: a pixel is gridded from the altimetry (dense) with at least this many shots", lo=1, hi=1_000_000
    )
    gap_px: float = param(
        2.0, "Merge: gaps between dense pixels up to about this size are inside the altimetry's area "
        "(also the smoothing of the correction)", unit="pixel", lo=0.0, hi=1000.0,
    )
    feather_px: float = param(
        5.0, "Merge: width of the blend from the registered DEM to the altimetry", unit="pixel", lo=1e-6, hi=1000.0,
    )
    check_min_profiles: int = param(
        20, "The report's before/after check (dem.registration.improved_share) counts the registered tiles "
        "with at least this many profiles", lo=1, hi=1_000_000,
    )
