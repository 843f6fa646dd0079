"""Configuration of control-network building and merging."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class NetworkConfig(ConfigSection):
    """The ``network`` section: tracks and the merging of control networks."""

    merge_tolerance_px: float = param(
        1.0, "Measures of one image closer than this are the same measure when tracks and networks merge",
        unit="px", lo=0.0, hi=100.0,
    )
    measure_sigma_px: float = param(0.5, "A-priori sigma of a matched measure (sample and line)", unit="px", lo=1e-6, hi=100.0)
    convergent_sigma_from_deg: float = param(
        45.0, "Measures of pairs whose views converge by more than this get a larger sigma: measure_sigma_px x "
        "tan(convergence) / tan(this), at most convergent_sigma_max_factor (the per-pair offset of convergent "
        "matches grows about so, docs/benchmarks/match.md, issue 21); such pairs still hold an image that has "
        "nothing else, but no longer pull it against its other pairs. 180 = off", unit="deg", lo=0.0, hi=180.0,
    )
    convergent_sigma_max_factor: float = param(
        10.0, "Largest sigma factor of a convergent pair's measures (views converging by 90 deg or more get it)",
        lo=1.0, hi=1000.0,
    )
    min_image_measures: int = param(
        6, "Images with fewer measures are reported as under-determined", lo=0, hi=100000
    )
