"""Pointing error before and after the adjustment, against the synthetic truth (validation only)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.exceptions import StoreError
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.validate.run import common_rotation_removed_urad, pointing_error_urad
from mercury_dem.viz.status import as_store


def pointing_errors(run: str | Path | RunStore, mission: Any, level: str = "global", unit_id: int = 0) -> pd.DataFrame:
    """Per image of a unit's solution: image_id, n_measures, a_priori_urad, adjusted_urad,
    adjusted_relative_urad (common rotation removed), ifov_urad.

    Uses the same measures as the report's ``validation`` block
    (:mod:`mercury_dem.validate.run`); images without measures are left out. Needs a
    mission with truth.
    """
    store = as_store(run)
    if not getattr(mission, "has_truth", False):
        raise StoreError(f"mission {getattr(mission, 'path', '?')} has no truth; pointing errors need a synthetic mission")
    path = store.solution_path(level, unit_id)
    if not (store.unit_complete(level, unit_id) and path.is_file()):
        raise StoreError(f"{level} {unit_id} of {store.root} has no solution yet (run not finished or unit failed)")
    sid, rot, _, table = read_solution(path)
    nm = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(sid.size, np.int64)
    keep = nm > 0
    ids = [str(i) for i in sid[keep]]
    rot = rot[keep]
    true_r = np.array([mission.true_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    apri_r = np.array([mission.a_priori_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    return pd.DataFrame({
        "image_id": ids, "n_measures": nm[keep],
        "a_priori_urad": pointing_error_urad(apri_r, true_r),
        "adjusted_urad": pointing_error_urad(rot, true_r),
        "adjusted_relative_urad": common_rotation_removed_urad(rot, true_r) if ids else np.zeros(0),
        "ifov_urad": [mission.camera(i).ifov_rad * 1e6 for i in ids],
    })
