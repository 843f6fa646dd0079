"""Pointing error before and after the adjustment, against the synthetic truth (validation only)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

from pathlib import Path

import numpy as np
import pandas as pd

from mercury_dem.exceptions import StoreError
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.validate.run import per_image_pointing
from mercury_dem.viz.status import as_store


def pointing_errors(run: str | Path | RunStore, mission: Mission, level: str = "global", unit_id: int = 0) -> pd.DataFrame:
    """Per image of a unit's solution against the truth: image_id, instrument, n_measures,
    a_priori_px, adjusted_px (the error in the image's own pixels: a pixel grid through
    the true pose onto the true surface, re-projected with the pose; the figure the
    report's ``image_space_error_px`` summarises), a_priori_urad, adjusted_urad,
    adjusted_relative_urad (common rotation removed), the boresight/twist split of the
    adjusted angle, and ifov_urad.

    Built by :func:`mercury_dem.validate.run.per_image_pointing`, the function behind the
    report's ``validation`` block, with the solution's positions; images without measures
    are left out. Needs a mission with truth.
    """
    store = as_store(run)
    if mission.truth is None:
        raise StoreError(f"mission {getattr(mission, 'path', '?')} has no truth; pointing errors need a synthetic mission")
    path = store.solution_path(level, unit_id)
    if not (store.unit_complete(level, unit_id) and path.is_file()):
        raise StoreError(f"{level} {unit_id} of {store.root} has no solution yet (run not finished or unit failed)")
    sid, rot, pos, table = read_solution(path)
    nm = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(sid.size, np.int64)
    keep = nm > 0
    ids = [str(i) for i in sid[keep]]
    e = per_image_pointing(ids, rot[keep], mission, pos[keep])
    cols = ["a_priori_px", "adjusted_px", "a_priori_urad", "adjusted_urad", "adjusted_relative_urad",
            "adjusted_boresight_urad", "adjusted_twist_urad", "ifov_urad"]
    return pd.DataFrame({"image_id": ids, "instrument": e["instrument"], "n_measures": nm[keep],
                         **{c: e[c] for c in cols}})
