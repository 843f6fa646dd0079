"""Configuration of DEM gridding."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class DemConfig(ConfigSection):
    pixels_per_degree: float = param(64.0, "Output grid resolution", unit="pixel/deg", lo=0.01, hi=4096.0)
    method: str = param("median11", "Gridding method", choices=("median11", "shepard"))
    neighbours: int = param(11, "Nearest points used per pixel by median11", lo=1, hi=1000)
