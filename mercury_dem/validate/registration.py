"""Seed 004's check of a registration: in tiles with many profiles, did the profile offsets lower the residuals.

The registration stage (:mod:`mercury_dem.pipeline.register_stage`) reports per tile the RMS of the shots'
residuals against the DEM as given (``rms_before_m``), after the tile transform (``rms_registered_m``) and
after the profile offsets (``rms_after_m``). A tile crossed by many profiles (seed 004: at least 20) is one
where the offsets are well determined; there the final residuals should be below the initial ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["CHECK_KEYS", "profile_check"]

#: The keys of a tile's record the check keeps.
CHECK_KEYS = ("tile_id", "n_profiles", "rms_before_m", "rms_registered_m", "rms_after_m")


def profile_check(tiles: Sequence[dict[str, Any]], min_profiles: int) -> tuple[list[dict[str, Any]], float | None]:
    """The registered tiles with at least ``min_profiles`` profiles (their :data:`CHECK_KEYS`), and the share of
    them whose residual RMS after the profile offsets is below the one before (None when there is no such tile).

    ``tiles``: the stage's per-tile summaries (``ok``, ``n_profiles`` and the RMS keys).
    """
    dense = [t for t in tiles if t.get("ok") and t.get("n_profiles", 0) >= min_profiles]
    records = [{k: t.get(k) for k in CHECK_KEYS} for t in dense]
    share = sum(t["rms_after_m"] < t["rms_before_m"] for t in dense) / len(dense) if dense else None
    return records, share
