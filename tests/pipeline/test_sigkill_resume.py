"""The whole run SIGKILLed at random moments (>= 20, over every stage) and resumed each time: same result.

Issue 19 §2. Each attempt is ``mercury-dem run ... --scheduler sync`` in its own process group,
killed with SIGKILL after a random delay (or left to finish once 20 kills are done); the next
attempt resumes the same run directory. At the end the global solution, network and DEM equal
the uninterrupted run's, and no temporary file or unit without its completion marker is left.
Slow (about four minutes here): ``pytest -m slow tests/pipeline/test_sigkill_resume.py``; the
figures go to docs/benchmarks.md ("Faults").
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from mercury_dem.io.atomic import COMPLETE_MARKER
from mercury_dem.products.make import open_dem

from .conftest import TINY_OVERRIDES
from .test_execution import assert_same_run

KILLS = 20
LEVELS = ("tile", "region", "hemisphere", "global")


def _stage(run: Path) -> str:
    """How far the run had got: the last level with a finished unit, or the DEM/products."""
    if (run / "report.json").exists():
        return "done"
    if (run / "dem.zarr").exists():
        return "products"
    done = [lvl for lvl in LEVELS if any((run / lvl).glob(f"*/{COMPLETE_MARKER}"))]
    return f"after {done[-1]}" if done else ("plan" if (run / "plan").exists() else "start")


@pytest.mark.slow
@pytest.mark.integration
def test_sigkill_at_random_moments_then_resume_gives_the_uninterrupted_result(
        sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path, tmp_path: Path) -> None:
    ref, _ = sync_run
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(TINY_OVERRIDES))
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "mercury_dem.cli", "run", str(tiny_mission_path), "--out", str(run),
           "--config", str(config), "--scheduler", "sync", "--quiet"]
    rng = np.random.default_rng(int(os.environ.get("MERCURY_DEM_FAULT_SEED", "19")))
    kills: list[dict[str, Any]] = []
    attempts = 0
    t_start = time.monotonic()
    while True:
        attempts += 1
        assert attempts <= KILLS + 5, f"the run did not finish after {attempts - 1} attempts: {kills}"
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        if len(kills) < KILLS:
            # Delays from a fresh start-up (~3 s of imports) to well into a stage.
            delay = float(rng.uniform(2.0, 12.0))
            try:
                proc.wait(timeout=delay)
            except subprocess.TimeoutExpired:
                before = _stage(run)
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                kills.append({"after_s": round(delay, 1), "stage": before})
                continue
        else:
            proc.wait(timeout=1200)
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        assert proc.returncode == 0, err[-3000:]
        break
    seconds = time.monotonic() - t_start
    stages = sorted({k["stage"] for k in kills})
    print(f"{len(kills)} SIGKILLs over stages {stages}; finished on attempt {attempts} in {seconds:.0f} s")
    assert len(kills) == KILLS
    assert len(stages) >= 3, stages  # spread over the run, not all at start-up
    # Nothing half-written: no temporary siblings, every unit directory complete.
    leftovers = [str(p.relative_to(run)) for p in run.rglob("*") if ".tmp-" in p.name]
    assert leftovers == [], leftovers[:10]
    for level in LEVELS:
        for unit in (run / level).iterdir() if (run / level).exists() else ():
            assert (unit / COMPLETE_MARKER).exists(), f"{unit} has no completion marker"
    report = json.loads((run / "report.json").read_text())
    assert report["levels"]["global"]["ok"]
    assert_same_run(ref, run)
    a = open_dem(ref / "dem.zarr")["elevation"].values
    b = open_dem(run / "dem.zarr")["elevation"].values
    assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    (tmp_path / "kills.json").write_text(json.dumps({"kills": kills, "attempts": attempts, "seconds": seconds}))
