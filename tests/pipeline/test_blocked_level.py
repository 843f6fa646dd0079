"""The run's hemisphere/global units over point blocks (issue #17, ``adjust.blocked_min_measures``).

The tiny run's global unit (with its re-centred radius priors and the altimetry's two passes) is adjusted
again from the run store with the threshold forced to 0, and compared with the default (in-memory) path:
with float64 storage to solver tolerance, with the default float32 storage within 10⁻³ px (measured
2026-11-26: 3.1e-9 rad, ~6e-5 px; docs/design/adjust.md, "Memory").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.io.run_store import RunStore
from mercury_dem.mission import open_mission
from mercury_dem.pipeline.stages import _adjust_unit

from .conftest import tiny_config

pytestmark = pytest.mark.integration


def test_global_unit_blocked_equals_in_memory(sync_run: tuple[Path, dict[str, Any]]) -> None:
    run, _ = sync_run
    store = RunStore(run)
    ref = _adjust_unit(store, "global", 0, tiny_config())
    assert "blocked" not in ref
    a = ref["_files"]
    mission = open_mission(store.read_run()["mission"])
    ifov = min(mission.camera(str(i)).pixel_size_mm / mission.camera(str(i)).focal_length_mm
               for i in a["solution"]["image_ids"])
    for float32, bound_rad in ((False, 1e-10), (True, 1e-3 * ifov)):
        blk = _adjust_unit(store, "global", 0, tiny_config(adjust={
            "blocked_min_measures": 0, "blocked_block_points": 150, "blocked_float32": float32}))
        assert blk["blocked"]["blocks"] >= 2
        assert blk["iterations"] == ref["iterations"] and blk["rejected"] == ref["rejected"]
        b = blk["_files"]
        assert np.array_equal(a["solution"]["image_ids"], b["solution"]["image_ids"])
        assert np.abs(a["solution"]["rotations"] - b["solution"]["rotations"]).max() < bound_rad
        assert np.array_equal(a["network"].measure_rejected, b["network"].measure_rejected)
        assert blk["sigma0"] == pytest.approx(ref["sigma0"], rel=1e-6)
    # a hemisphere unit below the threshold keeps the in-memory path
    hemi = _adjust_unit(store, "hemisphere", 0, tiny_config(adjust={"blocked_min_measures": 10**9}))
    assert "blocked" not in hemi
