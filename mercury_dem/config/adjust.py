"""Configuration of the bundle adjustment."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class AdjustConfig(ConfigSection):
    pointing_sigma_deg: float = param(0.2, "A-priori pointing constraint (1 sigma)", unit="deg", lo=1e-9, hi=180.0)
    radius_sigma_m: float = param(10000.0, "A-priori point radius constraint (1 sigma)", unit="m", lo=1e-6)
    max_iterations: int = param(30, "Levenberg-Marquardt iteration limit", lo=1, hi=10000)
    robust_loss: str = param("huber", "Robust loss", choices=("none", "huber", "cauchy"))
    reject_k_mad: float = param(3.0, "Reject measures beyond k x MAD of the residuals", lo=0.5, hi=100.0)
