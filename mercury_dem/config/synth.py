"""Configuration of the synthetic mission generator."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class SynthConfig(ConfigSection):
    """The generator's settings (``mercury-dem synth`` flags; not part of the run configuration)."""

    preset: str = param("tiny", "Synthetic mission preset", choices=("tiny", "demo", "large"))
    body: str = param("mercury", "Target body of the synthetic mission (its datum, CRS, orbit constants)",
                      choices=("mercury", "moon"))
    seed: int = param(42, "Seed of the surface, the mission and the noise", lo=0)
    pointing_sigma_urad: float = param(
        450.0, "A-priori pointing error per axis and image (1 sigma)", unit="urad", lo=0.0, hi=1e5
    )
    position_sigma_m: float = param(
        100.0, "A-priori spacecraft position error per axis (1 sigma)", unit="m", lo=0.0, hi=1e5
    )
    render_grid_px: float = param(
        0.0, "Renderer's surface-grid spacing in ground pixels, the surface band-limited at one pixel as with "
             "the preset's grid (0.5: two views agree ~30 % better on km-scale pairs, 3.5-3.7x the render "
             "cost); 0: the preset's renderer (a 1-pixel grid)", unit="px", lo=0.0, hi=2.0
    )
