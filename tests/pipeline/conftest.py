"""Runs of the whole pipeline on the tiny mission, shared by the pipeline tests."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from mercury_dem.config import Config, load_config

#: The configuration the pipeline tests use, as YAML gives it (tests that run the CLI write it out); the same
#: file the tiny-mission benchmarks read.
TINY_CONFIG_FILE = Path(__file__).resolve().parents[2] / "workflows" / "tiny.yaml"
TINY_OVERRIDES: dict[str, Any] = yaml.safe_load(TINY_CONFIG_FILE.read_text())


def tiny_config(**sections: dict[str, Any]) -> Config:
    """The configuration the pipeline tests use: a small DEM over the tiny mission's area."""
    base: dict[str, Any] = copy.deepcopy(TINY_OVERRIDES)
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    return load_config(overrides=base)


@pytest.fixture(scope="session")
def sync_run(tiny_mission_path: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The tiny mission run in-process (``--scheduler sync``): (run directory, report)."""
    from mercury_dem.pipeline.graph import run_pipeline

    out = tmp_path_factory.mktemp("runs") / "sync"
    report = run_pipeline(tiny_mission_path, out, tiny_config(), scheduler="sync", stream=None)
    return out, report


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
