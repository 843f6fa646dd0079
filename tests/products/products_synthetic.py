"""The known surface and configuration of the product tests (helpers for tests/products)."""

from __future__ import annotations

import numpy as np

from mercury_dem.config.dem import DemConfig

NOISE_M = 20.0


def truth_height(lat, lon):
    """The known surface, metres above the 2439.4 km datum (same as tests/dem)."""
    la, lo = np.radians(lat), np.radians(lon)
    return 1500.0 * np.sin(2 * la) * np.cos(3 * lo) + 800.0 * np.cos(la) * np.sin(2 * lo + 0.3)


CFG = DemConfig(pixels_per_degree=2, chunk_size=128, max_distance_m=60_000.0, coverage_pixel_km=50.0,
                stats_pixel_km=40.0, browse_width=720, profile_samples=400)
