"""The a-priori uncertainty of the mission's pointing: declared by the mission, overridable here once.

One concept, one key. The mission declares how wrong its a-priori (SPICE) pointing may be
(``pointing_sigma_urad`` in ``mission.json``: the synthetic generator writes the sigma it injected,
``mercury-dem ingest --pointing-sigma-urad`` records the user's). The run configuration may override
it with ``apriori.pointing_sigma_urad``; matching (the guidance window) and the bundle adjustment (the
pointing constraint) both use the one resolved value (:func:`resolve_pointing_sigma_urad`), handed to
them as an argument, always in microradians and always under this name: ``match_tile(...,
pointing_sigma_urad=)`` and ``AdjustmentProblem.pointing_sigma_urad`` (the library's ``match`` and
``adjust`` sections carry no copy of it, and nothing overwrites a section at run time).

Until session 11 it was three keys with two defaults (``match.pointing_sigma_urad`` 450 µrad,
``adjust.pointing_sigma_deg`` 0.2°, each with a ``pointing_sigma_from_mission`` switch, and the
generator's ``synth.pointing_sigma_urad`` in the run configuration). Those keys are refused with a
message naming this one (:data:`RETIRED_KEYS`): the old two values cannot be mapped onto one silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param
from mercury_dem.exceptions import ConfigError


@dataclass(frozen=True)
class AprioriConfig(ConfigSection):
    """A-priori uncertainties of the mission's geometry (null: what the mission declares)."""

    pointing_sigma_urad: float | None = param(
        None, "A-priori pointing uncertainty per axis and image (1 sigma), used by matching (guidance window) and "
        "the adjustment (pointing constraint). Null: the mission's declared value (mission.json "
        "pointing_sigma_urad: synth's injected sigma, or 'ingest --pointing-sigma-urad'); a number overrides it",
        unit="urad", lo=1e-3, hi=1e5,
    )


_NEW = "apriori.pointing_sigma_urad (microradians; null: the mission's declared value)"

#: Keys of earlier versions refused with what to write instead (key -> message).
RETIRED_KEYS: dict[str, str] = {
    "match.pointing_sigma_urad": f"the a-priori pointing uncertainty is one key now: {_NEW}",
    "match.pointing_sigma_from_mission": f"the mission's declared pointing uncertainty is always used unless {_NEW} "
                                         "overrides it",
    "adjust.pointing_sigma_deg": f"the a-priori pointing uncertainty is one key now, in microradians: {_NEW} "
                                 "(1 deg = 17453.3 urad; the old default 0.2 deg = 3490.7 urad)",
    "adjust.pointing_sigma_from_mission": f"the mission's declared pointing uncertainty is always used unless {_NEW} "
                                          "overrides it",
    "synth": "the generator's settings are not part of the run configuration: give them to 'mercury-dem synth' "
             "(--preset, --seed, --pointing-sigma-urad, --position-sigma-m); the mission records the pointing sigma "
             f"it injected, and {_NEW} overrides it for a run",
}


def refuse_retired_keys(data: dict[str, object], source: str) -> None:
    """Raise :class:`ConfigError` naming the first retired key in a raw configuration mapping.

    Parameters
    ----------
    data : the nested mapping read from YAML (or given as overrides)
    source : where it came from, for the message (a file name, or "overrides")
    """
    for key, why in RETIRED_KEYS.items():
        section, _, name = key.partition(".")
        sec = data.get(section)
        if (not name and section in data) or (name and isinstance(sec, dict) and name in sec):
            raise ConfigError(f"{source}: config key '{key}' is no longer accepted: {why}")


def resolve_pointing_sigma_urad(configured: float | None, declared: float | None, mission: str) -> float:
    """The a-priori pointing sigma (µrad) a run uses: the configured override, else the mission's declared one.

    Parameters
    ----------
    configured : ``apriori.pointing_sigma_urad`` of the run configuration (None: not overridden)
    declared : the mission's ``pointing_sigma_urad`` (None: it declares none)
    mission : the mission's name or path, for the message

    Returns
    -------
    float : the sigma per axis, microradians

    Raises
    ------
    ConfigError : neither says one (a mission ingested without ``--pointing-sigma-urad`` and no override):
        there is no safe guess, since real SPICE pointing ranges over two orders of magnitude.
    """
    if configured is not None:
        return float(configured)
    if declared is not None and declared > 0:
        return float(declared)
    raise ConfigError(
        f"mission {mission} declares no a-priori pointing uncertainty (mission.json pointing_sigma_urad) and the "
        "configuration sets none: set apriori.pointing_sigma_urad (microradians, 1 sigma per axis) in the run "
        "configuration, or re-ingest with --pointing-sigma-urad"
    )


#: The a-priori pointing sigma (µrad) of the commands that adjust a network without a mission (``adjust-isis``,
#: ``adjust-network``) when ``apriori.pointing_sigma_urad`` is not set: 0.2 deg, their default since they exist.
MISSIONLESS_POINTING_SIGMA_URAD = math.radians(0.2) * 1e6


def missionless_pointing_sigma_urad(configured: float | None) -> float:
    """The a-priori pointing sigma (µrad) of an adjustment without a mission: ``apriori.pointing_sigma_urad``,
    else :data:`MISSIONLESS_POINTING_SIGMA_URAD` (a network file states no pointing uncertainty).
    """
    return MISSIONLESS_POINTING_SIGMA_URAD if configured is None else float(configured)
