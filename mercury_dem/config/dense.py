"""Configuration of the dense stereo stage (issue 31; docs/design/dense.md).

The pair rule is :class:`mercury_dem.dense.pairs.StereoPairCriteria` (the literature's bands: parallax/height
0.1--1, best 0.4--0.6, pixel-scale ratio <= 2.5, similar illumination); the matcher's and the point filters'
keys are the main fields of :class:`mercury_dem.dense.disparity.MatcherSettings` and
:class:`mercury_dem.dense.triangulate.PointFilter` (this package imports neither: the stage runner builds them).
"""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class DenseConfig(ConfigSection):
    """The ``dense`` section: stereo pairs, chips, matching, points and the dense DEM."""

    enabled: bool = param(
        False, "Run the dense stereo stage after the DEM stage (dense.zarr, dem_dense.zarr); off by default: "
        "it costs minutes per tile on a 2-core machine (docs/design/dense.md)",
    )
    tiles: tuple[int, ...] = param(
        (), "Only these tiles' pairs (tile of the pair's left image); empty: every tile (a stated subset, e.g. "
        "for a demo)",
    )
    # --- stereo pairs (StereoPairCriteria) ----------------------------------------------------
    min_parallax_height: float = param(0.1, "Smallest parallax/height ratio of a pair", lo=0.0, hi=10.0)
    max_parallax_height: float = param(1.0, "Largest parallax/height ratio of a pair", lo=0.0, hi=10.0)
    best_parallax_height: tuple[float, ...] = param(
        (0.4, 0.6), "Preferred band (low, high) of the parallax/height ratio; the ranking prefers pairs in it",
    )
    max_scale_ratio: float = param(2.5, "Largest ground-pixel-scale ratio of a pair (coarser / finer)", lo=1.0)
    max_incidence_difference_deg: float = param(
        20.0, "Largest difference of the two images' solar incidence", unit="deg", lo=0.0, hi=180.0)
    max_sun_azimuth_difference_deg: float = param(
        30.0, "Largest difference of the two images' local sun azimuths", unit="deg", lo=0.0, hi=180.0)
    max_incidence_deg: float = param(80.0, "Largest solar incidence of either image", unit="deg", lo=0.0, hi=90.0)
    min_overlap: float = param(0.2, "Smallest share of the left image seen by the right one", lo=0.0, hi=1.0)
    max_pairs_per_image: int = param(4, "Selected pairs an image takes part in, at most (best-ranked first)",
                                     lo=1, hi=1000)
    max_pairs_per_tile: int = param(
        16, "Selected pairs matched per tile, at most (best-ranked first; the others are named in the report)",
        lo=1, hi=100000)
    # --- chips --------------------------------------------------------------------------------
    chip_size: int = param(512, "Interior side of a chip (the unit of dense matching)", unit="pixel",
                           lo=32, hi=4096)
    chip_collar: int = param(32, "Context pixels around a chip's interior", unit="pixel", lo=0, hi=512)
    max_chips_per_pair: int = param(
        64, "Chips matched per pair, at most (row-major order; the others are counted as capped)", lo=1,
        hi=1_000_000)
    max_vertical_px: float = param(
        0.1, "A chip is split into quadrants (recursively) while its rectification leaves more vertical disparity "
        "than this (RMS on its grid over the search range): one homography is exact for a plane only, and a whole "
        "image of the tiny mission (500 km) left 0.4-1.8 px", unit="pixel", lo=0.0)
    min_chip_px: int = param(32, "A chip is not split below this interior side", unit="pixel", lo=8, hi=4096)
    height_margin_factor: float = param(
        3.0, "Height search margin about the sparse DEM: this many times the robust scatter (1.4826 MAD) of the "
        "tie points' heights about it", lo=0.0, hi=100.0)
    min_height_margin_m: float = param(
        1000.0, "The height search margin, at least (the sparse DEM misses relief between its posts)",
        unit="m", lo=1.0)
    # --- matcher (MatcherSettings) --------------------------------------------------------------
    matcher_mode: str = param("sgbm_3way", "OpenCV StereoSGBM mode",
                              choices=("sgbm", "sgbm_3way", "hh", "hh4"))
    block_size: int = param(5, "SGBM matching block (odd)", unit="pixel", lo=1, hi=31)
    refine_window: int = param(9, "Least-squares refinement window side (odd, >= 3)", unit="pixel", lo=3, hi=63)
    refine_method: str = param(
        "window_fit", "Sub-pixel refinement: 'window_fit' (per-pixel least-squares window fit with a disparity "
        "slope, compiled) or 'dense_lk' (whole-image Lucas-Kanade from box filters, cheaper; "
        "docs/benchmarks/dense.md)", choices=("window_fit", "dense_lk"))
    refine_iterations: int = param(2, "Gauss-Newton iterations of the 'dense_lk' refinement", lo=1, hi=10)
    max_sigma_px: float = param(0.5, "A larger stated disparity precision is a no-texture hole", unit="pixel",
                                lo=0.0)
    min_score: float = param(0.5, "A smaller normalised correlation of the refined window is a hole",
                             lo=-1.0, hi=1.0)
    # --- points (PointFilter) -----------------------------------------------------------------
    sigma_floor_px: float = param(
        0.15, "Disparity error added in quadrature to the matcher's for what its window residuals do not show "
        "(view-dependent shading, the rectification, the cameras), in pixels of the pair's coarser image; "
        "calibrated with dense.sigma_scale and dense.sigma_height_floor_factor on the tiny mission's clouds "
        "(seeds 42 and 7: the points' errors against the truth; docs/design/dense.md)", unit="pixel", lo=0.0)
    sigma_scale: float = param(
        1.2, "Factor on the matcher's least-squares disparity sigma (which assumes the residuals are noise) "
        "before the floor is added; calibrated with dense.sigma_floor_px", lo=0.0, hi=100.0)
    sigma_height_floor_factor: float = param(
        0.5, "Height floor of a point's stated precision, added in quadrature: this times the tile's height margin "
        "(dense.height_margin_factor x the tie points' scatter about the sparse DEM, at least "
        "dense.min_height_margin_m). It stands for the relief within the matching window, which a window matcher "
        "does not resolve (the points' error in metres hardly depends on their pair's metres per pixel of "
        "disparity); fitted on tiny seeds 42 and 7. The stated precision is also capped at the range filter's "
        "uniform spread, dense.max_height_offset_factor x the margin / sqrt(3)", lo=0.0, hi=100.0)
    max_miss_pixels: float = param(1.0, "Largest ray miss distance, in left-image pixels at the point's range",
                                   unit="pixel", lo=0.0)
    min_angle_deg: float = param(5.0, "Smallest triangulation angle of a point", unit="deg", lo=0.0, hi=180.0)
    max_sigma_h_m: float | None = param(None, "Largest stated vertical precision of a point; null: no limit",
                                        unit="m", lo=0.0)
    max_height_offset_factor: float = param(
        2.0, "A point farther from the sparse DEM than this times the tile's height margin is removed (count "
        "'range'): on the tiny mission 15-26 % of the points, among them errors of tens of km", lo=0.0)
    # --- the dense DEM --------------------------------------------------------------------------
    grid_pixel_factor: float = param(
        3.0, "Dense DEM pixel = this times the selected pairs' median ground pixel scale (the coarser image of "
        "each pair), then rounded to a multiple of 0.5 pixel/deg", lo=0.5, hi=100.0)
    max_gap_pixels: float = param(
        1.0, "A dense DEM pixel farther than this many of its pixels from every dense point has no dense value "
        "(the sparse DEM fills it): the dense cloud is patchy, so the DEM stage's spacing rule would carry dense "
        "values far beyond the points", unit="pixel", lo=0.1, hi=1000.0)
    sparse_sigma_m: float | None = param(
        500.0, "Stated precision of the sparse DEM where the dense DEM's pixels are fused with it by inverse variance "
        "(dem_dense.zarr elevation; elevation_dense keeps the dense value alone); null: no fusion. On the tiny "
        "mission the sparse DEM's RMSE is 430-560 m and the dense cloud resolves little of what it misses (the "
        "bounds in docs/design/dense.md): fused, the dense DEM is 0.97-0.99 x the sparse, alone 1.14-1.25 x", unit="m",
        lo=0.0)
    fusion_correlation: float = param(
        0.66, "Correlation of the dense and sparse errors used for the fused pixels' stated precision (both miss the "
        "relief neither resolves; measured 0.66 on tiny seed 42)", lo=-1.0, hi=1.0)
    level_to_altimetry: bool = param(
        True, "Where the mission has altimetry: the dense DEM's dense pixels levelled on the shots' mean per tile "
        "(registration's mean level, altimetry.merge.level_on_shots), after its cloud was moved by the "
        "registration's transform. The robust registration leaves the fused DEM's mean above the truth where the "
        "sparse prior's errors are skewed (tiny seed 42: +38 m, levelled +3 m)")
    level_min_shots: int = param(
        500, "Fewest shots on a tile's dense pixels for its own level (fewer: the nearest tile's)", lo=1)
    level_pairs_on_sparse: bool = param(
        True, "Each stereo pair's points shifted, before the gridding, by the clipped mean of (sparse DEM - point) "
        "over the pair's points (dem.dense_grid.pair_level_offsets), so the dense values keep the level of the "
        "sparse DEM (tied to many images, registered and levelled on the altimetry) and add its relief: a pair's "
        "heights share an offset of their own (the demo's four pairs -8 / +49 / +94 / +261 m against the truth; "
        "the dense values alone were +221 m above it after the registration; docs/design/dense.md)")
    pair_level_clip_nmad: float = param(
        3.0, "Pair level: points farther than this many NMAD from the pair's median difference to the sparse DEM "
        "are left out of its mean", lo=1e-9, hi=1e6)
    pair_level_min_points: int = param(
        500, "Pair level: fewest points (on the sparse DEM, after the clipping) for a pair to be shifted", lo=1)
    grid_smoothing_passes: int | None = param(
        None, "Passes of the DEM stage's NaN-aware box filter on the dense DEM; null: dem.smoothing_passes (1). "
        "Measured on tiny seed 42 (workflows/benchmarks/dense_gridding.py, docs/benchmarks/dense.md): lighter "
        "griddings bring the oracle (true heights at the matched points) from 0.72 to 0.20-0.37 x the sparse RMSE "
        "but the real cloud from 1.12 to 1.43-2.24 x (its matching noise is not averaged): the default keeps the "
        "median of 64 with one pass", lo=0, hi=100)
    grid_neighbours: int = param(
        64, "The dense DEM's median11 takes the median of this many nearest points (the sparse DEM's "
        "dem.neighbours is 11): the pairs' points merged by a robust median over about a pixel", lo=1, hi=1000)

    def __post_init__(self) -> None:
        super().__post_init__()
        from mercury_dem.exceptions import ConfigError

        band = self.best_parallax_height
        if len(band) != 2 or not (self.min_parallax_height <= band[0] <= band[1] <= self.max_parallax_height):
            raise ConfigError(
                "config key 'dense.best_parallax_height' must be [low, high] with min_parallax_height <= low <= "
                f"high <= max_parallax_height; got {list(band)} in [{self.min_parallax_height}, "
                f"{self.max_parallax_height}]")
        if self.block_size % 2 != 1 or self.refine_window % 2 != 1:
            raise ConfigError(f"config keys 'dense.block_size' ({self.block_size}) and 'dense.refine_window' "
                              f"({self.refine_window}) must be odd")
