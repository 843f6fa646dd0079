"""``viz.BackgroundRun`` and ``viz.follow`` (what notebook 03 drives on a cluster) on a resumed tiny run, in-process.

The run is a copy of the session's tiny run with its global level removed: the background thread adjusts the
globe again (``--scheduler sync``, no DEM) while ``follow`` prints the progress it reads from the store.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.io.run_store import RunStore, read_solution
from tests.viz.runs import TINY_CONFIG


def test_background_run_and_follow(tiny_run: Path, tiny_mission_path: Path, tmp_path: Path) -> None:
    from mercury_dem.config import load_config
    from mercury_dem.viz import BackgroundRun, follow

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run, ignore=shutil.ignore_patterns("dem.zarr", "products", "report.json"))
    RunStore(run).remove_level("global")
    job = BackgroundRun(tiny_mission_path, run, load_config(overrides=TINY_CONFIG), scheduler="sync", dem=False)
    out = io.StringIO()
    progress = follow(run, job.running, interval_s=0.05, stream=out, timeout_s=300)
    report = job.wait(timeout=60)
    assert not job.running() and job.error is None and report["levels"]["global"]["ok"]
    lines = out.getvalue().splitlines()
    assert lines and all(line.startswith("[") and " s] tile " in line for line in lines)
    assert lines[-1].endswith("global 1/1")  # followed to the end: the last line read the finished store
    final = progress.set_index("level")
    assert final.loc["global", "done"] == 1 and final.loc["tile", "done"] + final.loc["tile", "failed"] == final.loc[
        "tile", "total"]
    # the globe adjusted again in the background is the shared run's
    ids0, rot0, _, _ = read_solution(RunStore(tiny_run).solution_path("global", 0))
    ids1, rot1, _, _ = read_solution(RunStore(run).solution_path("global", 0))
    assert (ids0 == ids1).all() and np.allclose(rot0, rot1, atol=1e-12)


def test_background_run_hands_its_error_to_wait(tmp_path: Path) -> None:
    from mercury_dem.config import load_config
    from mercury_dem.viz import BackgroundRun

    job = BackgroundRun(tmp_path / "no-mission", tmp_path / "run", load_config(overrides=TINY_CONFIG),
                        scheduler="sync")
    with pytest.raises(Exception) as err:
        job.wait(timeout=120)
    assert job.error is err.value and not job.running()
