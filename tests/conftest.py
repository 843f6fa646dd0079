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


#: Fixtures that run the whole pipeline: a test using one is an end-to-end (integration) test.
_WHOLE_RUN_FIXTURES = {"sync_run", "tiny_run"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark end-to-end tests ``integration`` so ``pytest -m "not integration"`` is the fast inner loop.

    Tests that use a whole-run fixture, or live in a module that runs the pipeline itself
    (tests/pipeline/test_run.py, test_execution.py, tests/cluster), are marked here; others mark themselves.
    """
    whole_run_modules = {"test_run.py", "test_execution.py", "test_tiny_mission_on_local_cluster.py",
                         "test_jobqueue.py", "test_browser.py", "test_notebooks.py"}
    for item in items:
        if _WHOLE_RUN_FIXTURES & set(getattr(item, "fixturenames", ())) or item.path.name in whole_run_modules:
            item.add_marker(pytest.mark.integration)
