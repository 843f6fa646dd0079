"""Runs of the whole pipeline on the tiny mission, shared by the pipeline tests."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from mercury_dem.config import Config, load_config
from tests.viz.runs import TINY_CONFIG, shared_sync_run

#: The configuration the pipeline tests use, as YAML would give it (tests that run the CLI write it out): the
#: shared run's (tests/viz/runs.py), so a test comparing a run of its own with ``sync_run`` compares like with like.
TINY_OVERRIDES: dict[str, Any] = TINY_CONFIG


def tiny_config(**sections: dict[str, Any]) -> Config:
    """The configuration the pipeline tests use: a small DEM over the tiny mission's area."""
    base: dict[str, Any] = copy.deepcopy(TINY_OVERRIDES)
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    return load_config(overrides=base)


@pytest.fixture(scope="session")
def sync_run(tiny_mission_path: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The tiny mission run in-process (``--scheduler sync``): (run directory, report).

    The session's one run of the tiny mission, shared with the viz, notebook and dashboard tests (``tiny_run``).
    """
    run, report, _ = shared_sync_run(tmp_path_factory, tiny_mission_path)
    return run, report


@pytest.fixture(scope="session")
def sync_run_progress(sync_run: tuple[Path, dict[str, Any]], tiny_mission_path: Path,
                      tmp_path_factory: pytest.TempPathFactory) -> str:
    """The progress lines ``sync_run`` wrote (to a string: not a terminal, the 'lines' display)."""
    return shared_sync_run(tmp_path_factory, tiny_mission_path)[2]


def read_report(run: Path) -> dict[str, Any]:
    return json.loads((run / "report.json").read_text())


@pytest.fixture(scope="session")
def moon_tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The ``tiny`` preset on the Moon (``synth --body moon``, ~18 images) run in-process: (run, report).

    The second body end to end: it fails when anything below the mission assumes Mercury.
    """
    from mercury_dem.config.synth import SynthConfig
    from mercury_dem.pipeline.graph import run_pipeline
    from mercury_dem.synth.generate import generate_mission

    root = tmp_path_factory.mktemp("moon")
    generate_mission(root / "mission", SynthConfig(preset="tiny", body="moon", seed=42))
    report = run_pipeline(root / "mission", root / "run", tiny_config(), scheduler="sync", stream=None)
    return root / "run", report
