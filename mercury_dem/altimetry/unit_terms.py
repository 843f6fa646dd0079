"""The altimetry's part in a unit's adjustment (:class:`~mercury_dem.adjust.unit.HeightTerms`): pure.

:func:`mercury_dem.adjust.unit.adjust_unit_network` holds the per-unit strategy; ``adjust/`` sits below
``altimetry/`` (which imports it), so the two things the shots contribute — the count of tie points they
would constrain, for the levelling decision (:func:`~mercury_dem.altimetry.levelling.levelling_for`), and the
two-pass adjustment with radius constraints from them
(:func:`~mercury_dem.altimetry.constraints.bundle_adjust_with_altimetry`) — are passed in as this object.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.datum import LevellingDecision
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.adjust.unit import Solve
from mercury_dem.altimetry.constraints import AltimetryShotsArrays, bundle_adjust_with_altimetry
from mercury_dem.altimetry.levelling import levelling_for
from mercury_dem.config.adjust import AdjustConfig

__all__ = ["AltimetryTerms"]


@dataclass(frozen=True)
class AltimetryTerms:
    """The shots around a unit's tie points (None or empty: none) as :class:`~mercury_dem.adjust.unit.HeightTerms`."""

    shots: AltimetryShotsArrays | None

    def levelling(self, points_xyz: NDArray[np.float64], cfg: AdjustConfig) -> LevellingDecision:
        """:func:`~mercury_dem.altimetry.levelling.levelling_for` with these shots."""
        return levelling_for(points_xyz, cfg, self.shots)

    def adjust(self, problem: AdjustmentProblem, cfg: AdjustConfig,
               solve: Solve) -> tuple[AdjustmentResult, dict[str, Any]] | None:
        """Two passes with the radius constraints of ``cfg``'s altimetry search, and the summary's ``altimetry``
        (the number of shots and the priors' counts); None without shots.
        """
        if self.shots is None or not len(self.shots.radius_m):
            return None
        result, priors = bundle_adjust_with_altimetry(
            problem, cfg, self.shots, search_radius_m=cfg.altimetry_search_m, min_shots=cfg.altimetry_min_shots,
            horizontal_sigma_m=cfg.altimetry_horizontal_sigma_m, surface=cfg.altimetry_surface, adjust=solve,
        )
        return result, {"shots": int(len(self.shots.radius_m)), **priors.summary()}
