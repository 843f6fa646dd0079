"""Session-wide synthetic worlds shared by the test areas.

``tiny_mission_path``: the ``tiny`` preset (seed 42), generated once per session;
it is the world of the synth, pipeline and notebook tests.
"""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared"


@pytest.fixture(scope="session")
def tiny_mission_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from mercury_dem.config.synth import SynthConfig
    from mercury_dem.synth.generate import generate_mission

    out = tmp_path_factory.mktemp("missions") / "tiny"
    generate_mission(out, SynthConfig(preset="tiny", seed=42))
    return out


@pytest.fixture(scope="session")
def tiny_mission(tiny_mission_path: Path):
    from mercury_dem.mission import open_mission

    return open_mission(tiny_mission_path)
