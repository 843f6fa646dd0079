"""Configuration of DEM gridding, the DEM store and its products.

Gridding follows Becker et al. 2016 (``median11``: 11 nearest points, 1-sigma
filter about the median radius, median of the rest; then averaging filters) and
Becker et al. 2015 (``shepard``: modified Shepard inverse-distance weighting with
a radial search of 1.4142 pixel and a 5-nearest-neighbour fallback). Heights are
metres above the 2439.4 km datum sphere.
"""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class DemConfig(ConfigSection):
    """The ``dem`` section: the map, the gridding and the products."""

    # --- the grid ---------------------------------------------------------------------------
    pixels_per_degree: float = param(64.0, "Output grid resolution", unit="pixel/deg", lo=0.01, hi=4096.0)
    # Bounds left unset (None) are taken from the control points: their bounding box plus
    # canvas_margin_pixels, snapped outward to the pixel grid (mercury_dem.dem.extent.config_with_extent,
    # which imports this module: config never imports dem/); all four
    # unset on a global cloud give the globe. Set them to fix the map's extent.
    lat_min: float | None = param(None, "Southern edge of the grid; unset: from the points", unit="deg",
                                  lo=-90.0, hi=90.0)
    lat_max: float | None = param(None, "Northern edge of the grid; unset: from the points", unit="deg",
                                  lo=-90.0, hi=90.0)
    lon_min: float | None = param(None, "Western edge of the grid (east-positive); unset: from the points",
                                  unit="deg", lo=-360.0, hi=360.0)
    lon_max: float | None = param(None, "Eastern edge of the grid (east-positive); unset: from the points",
                                  unit="deg", lo=-360.0, hi=720.0)
    canvas_margin_pixels: int = param(
        1, "Bounds taken from the points: their bounding box widened by this many pixels on each side, then "
        "snapped outward to whole pixels", unit="pixel", lo=0, hi=100000,
    )
    # --- the interpolator -------------------------------------------------------------------
    method: str = param("median11", "Gridding method", choices=("median11", "shepard"))
    neighbours: int = param(11, "Nearest points used per pixel by median11", lo=1, hi=1000)
    sigma_filter: float = param(
        1.0, "median11 keeps points within this many standard deviations of the median radius", lo=0.0, hi=100.0
    )
    search_radius_factor: float = param(
        1.4142,
        "Radial search radius (shepard; and the radius point_count counts within) in pixel sizes",
        unit="pixel",
        lo=0.01,
        hi=1000.0,
    )
    shepard_fallback_neighbours: int = param(
        5, "shepard: nearest points used where the radial search finds none", lo=1, hi=1000
    )
    shepard_max_points: int = param(
        32, "shepard: at most this many nearest points inside the search radius are weighted", lo=1, hi=10000
    )
    max_distance_m: float = param(
        0.0,
        "A pixel whose nearest point is farther than this has no value (NaN, counted as a gap); "
        "0 = from the points' spacing (no_value_spacing_factor)",
        unit="m",
        lo=0.0,
    )
    no_value_spacing_factor: float = param(
        5.0,
        "With max_distance_m = 0: no value beyond this many times the points' typical gap, the median "
        "distance from a place in their bounding box to its nearest point (and never below one pixel; "
        "mercury_dem.dem.spacing)",
        lo=0.01, hi=1e6,
    )
    # --- smoothing after gridding -----------------------------------------------------------
    smoothing_passes: int = param(1, "Passes of the NaN-aware box (averaging) filter; 0 = none", lo=0, hi=100)
    smoothing_size: int = param(3, "Box size of the averaging filter (odd)", unit="pixel", lo=1, hi=101)
    # --- execution --------------------------------------------------------------------------
    chunk_size: int = param(1024, "Map chunk edge (pixels) = Dask task = Zarr chunk", unit="pixel", lo=8, hi=65536)
    query_threads: int = param(
        -1, "Threads of each kd-tree query (scipy 'workers'): -1 = all cores; 1 under Dask with 1 thread/worker",
        lo=-1, hi=1024,
    )
    memory_limit_gb: float = param(
        8.0, "Refuse a grid whose estimated peak memory (per process) exceeds this", unit="GB", lo=0.001
    )
    # --- products ---------------------------------------------------------------------------
    polar_cut_lat: float = param(
        65.0, "PDS convention: equirectangular within +-this latitude, polar stereographic beyond", unit="deg",
        lo=1.0, hi=89.0,
    )
    south_polar_stats_limit: float = param(
        88.0, "Statistics of the south polar region stop at this latitude (reference: 65-88 S)", unit="deg",
        lo=65.0, hi=90.0,
    )
    stats_pixel_km: float = param(2.0, "Pixel scale of the resample the statistics use", unit="km", lo=0.001)
    coverage_pixel_km: float = param(
        0.0,
        "Pixel scale of the sinusoidal equal-area coverage grid; 0 = the DEM's pixel size but at least 1 km "
        "(the reference's 1 km at 64 pixel/deg)",
        unit="km", lo=0.0,
    )
    browse_width: int = param(2048, "Width of the browse PNGs", unit="pixel", lo=64, hi=16384)
    cog: bool = param(True, "Write the GeoTIFFs cloud-optimised (COG driver)")
    profile_samples: int = param(1000, "Samples along an elevation profile", lo=2, hi=1_000_000)
    register_to_altimetry: bool = param(
        True, "When the mission has laser altimetry, register the DEM to it per 10-degree tile and merge the two "
        "(registered.zarr, merged.zarr, registration/ beside dem.zarr)"
    )

    def coverage_pixel_km_for(self, datum_radius_m: float) -> float:
        """``coverage_pixel_km``, with 0 resolved to max(1 km, the DEM's north-south pixel size on the datum)."""
        if self.coverage_pixel_km > 0:
            return self.coverage_pixel_km
        import math

        return max(1.0, 2.0 * math.pi * datum_radius_m / 1000.0 / 360.0 / self.pixels_per_degree)

    def bounds(self) -> tuple[float, float, float, float]:
        """(lat_min, lat_max, lon_min, lon_max) with unset bounds at the globe's (-90, 90, 0, 360)."""
        return (-90.0 if self.lat_min is None else self.lat_min, 90.0 if self.lat_max is None else self.lat_max,
                0.0 if self.lon_min is None else self.lon_min, 360.0 if self.lon_max is None else self.lon_max)

    @property
    def extent_from_points(self) -> bool:
        """True when some bound is unset and comes from the point cloud
        (:func:`mercury_dem.dem.extent.config_with_extent`).
        """
        return None in (self.lat_min, self.lat_max, self.lon_min, self.lon_max)

    def __post_init__(self) -> None:
        super().__post_init__()
        from mercury_dem.exceptions import ConfigError

        if self.lat_min is not None and self.lat_max is not None and self.lat_min >= self.lat_max:
            raise ConfigError(f"config key 'dem.lat_min' ({self.lat_min}) must be below 'dem.lat_max' ({self.lat_max})")
        if self.lon_min is not None and self.lon_max is not None and (
                self.lon_min >= self.lon_max or self.lon_max - self.lon_min > 360.0):
            raise ConfigError(
                f"config keys 'dem.lon_min'/'dem.lon_max' ({self.lon_min}, {self.lon_max}) must span (0, 360] degrees"
            )
        if self.smoothing_size % 2 != 1:
            raise ConfigError(f"config key 'dem.smoothing_size' = {self.smoothing_size} must be odd")
