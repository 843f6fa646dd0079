"""Configuration of control-network building and merging."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class NetworkConfig(ConfigSection):
    merge_tolerance_px: float = param(
        1.0, "Measures of one image closer than this are the same measure when tracks and networks merge",
        unit="px", lo=0.0, hi=100.0,
    )
    measure_sigma_px: float = param(0.5, "A-priori sigma of a matched measure (sample and line)", unit="px", lo=1e-6, hi=100.0)
    min_image_measures: int = param(
        6, "Images with fewer measures are reported as under-determined", lo=0, hi=100000
    )
