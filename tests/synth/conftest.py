"""Shared synthetic worlds of the synth tests (the lead may move ``tiny_mission`` to tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mercury_dem.config.synth import SynthConfig


@pytest.fixture(scope="session")
def tiny_mission_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``tiny`` preset (seed 42, default errors), generated once per test session."""
    from mercury_dem.synth.generate import generate_mission

    out = tmp_path_factory.mktemp("missions") / "tiny"
    generate_mission(out, SynthConfig(preset="tiny", seed=42))
    return out


@pytest.fixture(scope="session")
def tiny_mission(tiny_mission_path: Path):
    """The opened ``tiny`` mission (a :class:`mercury_dem.io.mission.Mission`)."""
    from mercury_dem.io.mission import open_mission

    return open_mission(tiny_mission_path)
