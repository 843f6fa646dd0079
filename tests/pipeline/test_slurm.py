"""The tiny mission through real ``sbatch`` jobs: a one-node SLURM started by the test, ``run --cluster slurm``.

Slow (two to four minutes here): CI runs it after ``make test`` (``.ci/run``); by hand,
``pytest -m slow tests/pipeline/test_slurm.py``. Needs root and Debian's slurm-wlm and munge,
which ``make test`` installs; skipped with the reason otherwise.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from mercury_dem.products.make import open_dem
from tests.cluster import slurm as real_slurm
from tests.cluster.conftest import script_env

from .conftest import TINY_OVERRIDES
from .test_execution import assert_same_run


@pytest.mark.slow
@pytest.mark.integration
def test_tiny_mission_on_real_slurm_jobs_equals_the_in_process_run(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    why = real_slurm.missing()
    if why:
        pytest.skip(why)
    ref, _ = sync_run
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(TINY_OVERRIDES))
    run = tmp_path / "run"
    with real_slurm.one_node_slurm(tmp_path / "slurm") as slurm:
        env = script_env(
            **slurm.env,
            # One job of two single-threaded workers on this 2-core node.
            DASK_JOBQUEUE__SLURM__CORES="2", DASK_JOBQUEUE__SLURM__PROCESSES="2",
            DASK_JOBQUEUE__SLURM__MEMORY="6GiB", DASK_JOBQUEUE__SLURM__WALLTIME="00:30:00",
            DASK_JOBQUEUE__SLURM__LOCAL_DIRECTORY=str(tmp_path / "scratch"),
        )
        t0 = time.monotonic()
        res = subprocess.run(
            [sys.executable, "-m", "mercury_dem.cli", "run", str(tiny_mission_path), "--out", str(run),
             "--config", str(config), "--cluster", "slurm", "--jobs", "1", "--wait-workers", "2",
             "--timeout", "300", "--scheduler-host", "127.0.0.1", "--quiet"],
            capture_output=True, text=True, timeout=1500, env=env,
        )
        seconds = time.monotonic() - t0
        assert res.returncode == 0, f"{res.stdout[-3000:]}\n{res.stderr[-3000:]}\n{slurm.log('slurmctld')}"
        # The workers were real SLURM jobs, and the launcher cancelled them at the end.
        acct = slurm.run("squeue", "-h", "-o", "%i %T")
        assert acct.stdout.strip() == "", acct.stdout
    logs = sorted((tmp_path / "run.dask" / "logs").glob("*.err"))
    assert logs, "no SLURM job log: the workers did not run as batch jobs"
    assert any("Registered to" in p.read_text(errors="replace") for p in logs)
    report = json.loads((run / "report.json").read_text())
    assert report["execution"]["mode"] == "scheduler-file"
    # The same result as the in-process run.
    assert_same_run(ref, run)
    a = open_dem(ref / "dem.zarr")["elevation"].values
    b = open_dem(run / "dem.zarr")["elevation"].values
    assert a.shape == b.shape and np.allclose(a, b, rtol=0, atol=1e-6, equal_nan=True)
    print(f"tiny on one-node SLURM: {seconds:.0f} s")
