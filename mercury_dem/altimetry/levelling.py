"""Whether a block's heights are levelled by the block itself: the decision, from its points and the shots.

The rule is :func:`mercury_dem.adjust.datum.levelling_decision` (a block wide enough to carry its own surface,
not mostly held by the altimetry); what it needs from the altimetry — which tie points the shots would
constrain — is counted here, which is why the decision lives in ``altimetry/`` (which imports ``adjust/``)
and not in ``adjust/`` or the stage runner (:mod:`mercury_dem.altimetry.unit_terms` passes it to :func:`mercury_dem.adjust.unit.adjust_unit_network`).
Pure: arrays and dataclasses in and out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from mercury_dem.adjust.datum import LevellingDecision, levelling_decision, recentres  # recentres: re-exported
from mercury_dem.altimetry.constraints import AltimetryShotsArrays, radius_priors_within
from mercury_dem.config.adjust import AdjustConfig

__all__ = ["levelling_for", "recentres"]


def levelling_for(points_xyz: ArrayLike, cfg: AdjustConfig,
                  altimetry: AltimetryShotsArrays | None = None) -> LevellingDecision:
    """The :class:`~mercury_dem.adjust.datum.LevellingDecision` of a block about to be adjusted.

    Parameters
    ----------
    points_xyz : (n, 3) the block's tie points, body-fixed, m (its a-priori points: the extent is theirs)
    cfg : the adjustment configuration: ``point_prior_recentre_min_extent_deg``,
        ``point_prior_recentre_max_altimetry_share``, and the altimetry search (``altimetry_search_m``, whose
        largest radius counts, ``altimetry_min_shots``)
    altimetry : the shots, or None (none: no point is constrained)

    Returns
    -------
    The decision. The points the altimetry would constrain are those with enough shots within the largest
    search radius (:func:`~mercury_dem.altimetry.constraints.radius_priors_within`: the count, not the priors
    the adjustment will use, which are fitted around the first pass's points).
    """
    pts = np.asarray(points_xyz, np.float64)
    constrained = None
    if altimetry is not None and len(altimetry.radius_m):
        constrained = radius_priors_within(
            pts, altimetry.lat_deg, altimetry.lon_deg, altimetry.radius_m, shot_sigma_m=altimetry.sigma_m,
            search_radius_m=float(max(cfg.altimetry_search_m)), min_shots=cfg.altimetry_min_shots,
        ).constrained
    return levelling_decision(pts, constrained, min_extent_deg=cfg.point_prior_recentre_min_extent_deg,
                              max_altimetry_share=cfg.point_prior_recentre_max_altimetry_share)
