"""Configuration of the registration of the DEM to laser altimetry and of their merge.

The stage (:mod:`mercury_dem.pipeline.register_stage`) registers ``dem.zarr`` per tile of the run's
tile grid (``tiling.tile_size_deg``), levels it on the shots' mean and merges the shots into it, one
block of rows at a time (:mod:`mercury_dem.altimetry.register_map`). Whether it runs at all is
``dem.register_to_altimetry``.
"""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param
from mercury_dem.exceptions import ConfigError

#: The tile transform models, most general first (their parameter counts:
#: :data:`mercury_dem.altimetry.register.MODELS`).
MODEL_NAMES: tuple[str, ...] = ("affine", "similarity", "translation", "vertical")


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
    # the tiles' fit (mercury_dem.altimetry.register.RegisterOptions, which takes its defaults from here)
    models: tuple[str, ...] = param(
        MODEL_NAMES, "Tile transform models tried in order; the first one the shots determine is used "
        f"(a non-empty subset of {', '.join(MODEL_NAMES)})",
    )
    max_param_sigma_m: float = param(
        10.0, "A model is used only when every parameter's standard deviation is below this (metres of "
        "displacement at the tile edge)", unit="m", lo=1e-9, hi=1e9,
    )
    huber_k: float = param(2.0, "Huber threshold of the tile fit, in NMAD of the residuals", lo=1e-9, hi=1e6)
    reject_k: float = param(
        5.0, "Shots farther than this many NMAD from the median residual are rejected", lo=1e-9, hi=1e6,
    )
    max_iterations: int = param(20, "Gauss-Newton iterations per model", lo=1, hi=100_000)
    tolerance_m: float = param(
        0.05, "The tile fit has converged when no parameter changes by more than this", unit="m", lo=1e-9, hi=1e9,
    )
    min_shots: int = param(50, "Fewest usable shots for a tile to be registered", lo=1, hi=1_000_000_000)
    min_profile_shots: int = param(
        10, "Fewest usable shots of a profile for its offset to be fitted", lo=3, hi=1_000_000_000,
    )
    profile_sigma_horizontal_m: float = param(
        2000.0, "Prior standard deviation of a profile offset, east and north", unit="m", lo=1e-9, hi=1e9,
    )
    profile_sigma_vertical_m: float = param(
        500.0, "Prior standard deviation of a profile offset, up", unit="m", lo=1e-9, hi=1e9,
    )
    max_abs_height_m: float = param(
        50_000.0, "Shots farther than this from the datum sphere are invalid (counted)", unit="m", lo=1e-9, hi=1e9,
    )
    profile_nuisance: bool = param(
        True, "Fit the tile transform jointly with one offset per profile as a nuisance, so constant profile "
        "errors do not bias it",
    )
    nuisance_sigma_horizontal_m: float = param(
        100.0, "Expected size of the profiles' errors in the joint fit, east and north", unit="m", lo=1e-9, hi=1e9,
    )
    nuisance_sigma_vertical_m: float = param(
        10.0, "Expected size of the profiles' errors in the joint fit, up", unit="m", lo=1e-9, hi=1e9,
    )
    nuisance_min_within_share: float = param(
        0.05, "Transform directions keeping less than this share of their information once the profile offsets "
        "are free are kept out of the nuisance (docs/design/altimetry.md)", lo=0.0, hi=1.0,
    )
    level_min_shots: int = param(
        500, "Mean level: a tile levels itself on its shots' mean with at least this many shots (others take "
        "the nearest such tile's offset)", lo=1, hi=1_000_000_000,
    )
    level_clip_nmad: float = param(
        10.0, "Mean level: shots farther than this many NMAD from the tile's median difference are left out "
        "of its mean", lo=1e-9, hi=1e6,
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        unknown = [m for m in self.models if m not in MODEL_NAMES]
        if unknown or not self.models:
            raise ConfigError(f"config key 'models' = {list(self.models)!r}: a non-empty list of "
                              f"{', '.join(MODEL_NAMES)}")
