from __future__ import annotations

from pathlib import Path

import pytest

from tests.viz.runs import shared_tiny_run

NOTEBOOKS = Path(__file__).resolve().parents[2] / "workflows" / "notebooks"


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory, tiny_mission_path: Path) -> Path:
    return shared_tiny_run(tmp_path_factory, tiny_mission_path)
