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


def _complete_units(run: Path, level: str) -> int:
    return sum(1 for _ in (run / level).glob(f"*/{COMPLETE_MARKER}")) if (run / level).exists() else 0


#: Where the kills go, in run order: (label, level whose next finished unit triggers the kill, how many
#: of them in this attempt; or None: a delay after start-up). A killed DEM stage starts again from
#: scratch on resume, so the late targets stay reachable however many kills went before.
TARGETS = (
    [("start-up", None, 0)] * 2
    + [("tiles", "tile", n) for n in (1, 2, 1, 3, 2, 1, 2, 1, 2, 1)]
    + [("regions", "region", 1)] * 3
    + [("hemispheres", "hemisphere", 1)] * 2
    + [("DEM", "global-done", 0)] * 3
    + [("products", "dem-done", 0)] * 2
)


def _due(run: Path, target: tuple[str, str | None, int], counts0: dict[str, int], waited: float,
         delay: float) -> bool:
    _, level, n = target
    if level is None:
        return waited >= delay
    if level == "global-done":  # the DEM is being gridded: the global unit is done, no dem.zarr yet
        return (run / "global" / "0" / COMPLETE_MARKER).exists() and waited >= delay
    if level == "dem-done":  # products: dem.zarr is committed, report.json not yet
        return (run / "dem.zarr").exists() and waited >= delay
    # The target's own units, or any later stage reached first (the level ran out of units): kill then.
    later = any(_complete_units(run, lvl) > counts0[lvl] for lvl in LEVELS[LEVELS.index(level) + 1:])
    return _complete_units(run, level) - counts0[level] >= n or later or (run / "dem.zarr").exists()


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
    targets = list(TARGETS)
    while True:
        attempts += 1
        assert attempts <= 2 * KILLS, f"the run did not finish after {attempts - 1} attempts: {kills}"
        counts0 = {lvl: _complete_units(run, lvl) for lvl in LEVELS}
        log = tmp_path / f"attempt{attempts}.err"
        with open(log, "wb") as err_fh:  # the child keeps its own descriptor
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err_fh, start_new_session=True)
        try:
            t0 = time.monotonic()
            target = targets[0] if targets else None
            # start-up kills within the first seconds; DEM/products kills a little into the stage
            delay = float(rng.uniform(0.5, 3.0) if target and target[1] is None else rng.uniform(0.0, 1.0))
            killed = False
            while target is not None and proc.poll() is None:
                if _due(run, target, counts0, time.monotonic() - t0, delay if target[1] is None else 3.0 + delay):
                    before = _stage(run)
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                    kills.append({"target": target[0], "after_s": round(time.monotonic() - t0, 1), "stage": before})
                    targets.pop(0)
                    killed = True
                    break
                time.sleep(0.05)
            if killed:
                continue
            proc.wait(timeout=1200)
        finally:  # an assertion, a timeout or an interruption must not leave the run (and its children) behind
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        assert proc.returncode == 0, log.read_text(errors="replace")[-3000:]
        if not targets:
            break
        # The run finished before this target could be hit (e.g. all regions were done): skip it.
        kills.append({"target": targets.pop(0)[0], "after_s": None, "stage": "missed"})
        if all(k["stage"] == "missed" for k in kills[-3:]) and len(kills) >= 3:
            break
    seconds = time.monotonic() - t_start
    hit = [k for k in kills if k["stage"] != "missed"]
    print(f"{len(hit)} SIGKILLs ({sorted({k['target'] for k in hit})}); finished on attempt {attempts} in {seconds:.0f} s")
    assert len(hit) >= KILLS, kills
    assert {k["target"] for k in hit} >= {"start-up", "tiles", "regions", "DEM", "products"}, kills
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
