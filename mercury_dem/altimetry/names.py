"""The stored name of an altimetry profile's id, and the old names still read.

A laser altimeter's ground track is a **profile** everywhere in code and in what is written
(``profile_id``, ``n_profiles``); "track" means a feature track (:mod:`mercury_dem.network.tracks`).
Files written before the rename, and users' shot files, may carry the old names ``track_id`` and
``n_tracks``: every reader passes what it read through :func:`upgrade_columns` /
:func:`upgrade_keys`, which map an old name to the new one (when the new one is absent) and log a
deprecation warning naming both. Nothing is ever written under an old name.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

PROFILE_ID = "profile_id"
N_PROFILES = "n_profiles"
#: Old stored name → the name it is read as.
RENAMED: dict[str, str] = {"track_id": PROFILE_ID, "n_tracks": N_PROFILES}

logger = logging.getLogger("mercury_dem.altimetry")
_noted: set[tuple[str, str]] = set()  # one warning per file and name, not one per tile read


def _note(where: str, old: str, new: str, what: str) -> None:
    if (where, old) in _noted:
        return
    _noted.add((where, old))
    logger.warning("%s: %s '%s' is the old name of '%s' and is read as it (deprecated: write '%s')",
                   where, what, old, new, new)


def stored_columns(columns: Iterable[str], present: Iterable[str]) -> list[str]:
    """The names to ask a file for: each new name the file holds only under its old name becomes the old name."""
    have = set(present)
    old_of = {new: old for old, new in RENAMED.items()}
    return [old_of[c] if c not in have and old_of.get(c) in have else c for c in columns]


def upgrade_columns(table: pd.DataFrame, where: str) -> pd.DataFrame:
    """``table`` with its old-named columns renamed (see the module docstring); the same object when none."""
    rename = {old: new for old, new in RENAMED.items() if old in table.columns and new not in table.columns}
    for old, new in rename.items():
        _note(where, old, new, "column")
    return table.rename(columns=rename) if rename else table


def upgrade_keys(d: dict[str, Any], where: str) -> dict[str, Any]:
    """A copy of ``d`` with its old-named keys renamed (see the module docstring); ``d`` itself when none."""
    rename = {old: new for old, new in RENAMED.items() if old in d and new not in d}
    if not rename:
        return d
    for old, new in rename.items():
        _note(where, old, new, "key")
    return {rename.get(k, k): v for k, v in d.items()}


__all__ = ["N_PROFILES", "PROFILE_ID", "RENAMED", "stored_columns", "upgrade_columns", "upgrade_keys"]
