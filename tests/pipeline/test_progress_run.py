"""A whole run with progress shown: plain lines with counts and ETAs, no control characters, same results."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.pipeline.graph import run_pipeline

from .conftest import tiny_config

CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f]")


def test_progress_lines(sync_run_progress: str) -> None:
    """The session's tiny run wrote its progress to a string (not a terminal: the 'lines' display)."""
    text = sync_run_progress
    assert not CONTROL.search(text), "progress lines must be plain text in logs"
    lines = text.splitlines()
    cascade = [ln for ln in lines if ln.startswith("adjustment cascade: ")]
    assert cascade[0].startswith("adjustment cascade: tile 0/") and "elapsed" in cascade[0]
    assert re.match(r"adjustment cascade: tile (\d+)/\1.* \| global 1/1 in \d+:\d\d$", cascade[-1])
    grid = [ln for ln in lines if ln.startswith("dem grid: ")]  # the DEM stage reports its chunks
    assert re.match(r"dem grid: 0/(\d+) chunks \(0 %\) elapsed 0:00 ETA \?$", grid[0])
    n = grid[0].split("/")[1].split()[0]
    assert re.match(rf"dem grid: {n}/{n} chunks \(100 %\) in \d+:\d\d$", grid[-1])
    assert any(ln.startswith("products: ") and "files in" in ln for ln in lines)


@pytest.mark.slow  # a second whole run (~40 s here) to show that progress is presentation only; in CI's slow list
def test_progress_does_not_change_the_results(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
                                             tmp_path: Path) -> None:
    shown_run, _ = sync_run  # run with its progress written to a string
    run_pipeline(tiny_mission_path, tmp_path / "run", tiny_config(), scheduler="sync", stream=None)
    # presentation only: the adjusted pointing and the DEM of a quiet run are the shown run's, bit for bit
    for run in (shown_run, tmp_path / "run"):
        assert (run / "dem.zarr").exists()
    ids_a, rot_a, _, _ = read_solution(RunStore(shown_run).solution_path("global", 0))
    ids_b, rot_b, _, _ = read_solution(RunStore(tmp_path / "run").solution_path("global", 0))
    np.testing.assert_array_equal(ids_a, ids_b)
    np.testing.assert_array_equal(rot_a, rot_b)
    a = xr.open_zarr(shown_run / "dem.zarr", consolidated=False)["elevation"].values
    b = xr.open_zarr(tmp_path / "run" / "dem.zarr", consolidated=False)["elevation"].values
    np.testing.assert_array_equal(a, b)
