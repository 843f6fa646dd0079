"""Session-wide synthetic worlds shared by the test areas.

``tiny_mission_path``: the ``tiny`` preset (seed 42), generated once per session;
it is the world of the synth, pipeline and notebook tests.
"""

from __future__ import annotations

from pathlib import Path

import pytest

# No test may leave a process running: a per-test check and a session-end sweep (see the module).
from tests.process_guard import (  # noqa: F401 - pytest hooks, found by name in this conftest
    pytest_configure,
    pytest_runtest_setup,
    pytest_runtest_teardown,
    pytest_sessionfinish,
)

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


#: Fixtures that run a whole stage or the whole pipeline: a test using one is an end-to-end (integration) test.
#: ``tiny_mission_path``/``tiny_mission`` generate the ``tiny`` mission (the synth stage end to end, ~10 s).
_WHOLE_RUN_FIXTURES = {"sync_run", "tiny_run", "tiny_mission_path", "tiny_mission"}

#: Modules every test of which is end to end: a run, a notebook, a browser, or a Dask cluster of worker
#: processes or scheduler scripts (tests/cluster starts real ones; its static checks of manifests, in
#: test_kubernetes*.py, stay in the fast loop).
_WHOLE_RUN_MODULES = {"test_run.py", "test_execution.py", "test_tiny_mission_on_local_cluster.py",
                      "test_jobqueue.py", "test_browser.py", "test_notebooks.py", "test_papermill.py",
                      "test_local_scripts.py", "test_listen_addresses.py"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The two loops: ``integration`` marks, and ``slow`` tests kept out of every selection not naming them.

    ``pytest -m "not integration"`` is the fast inner loop; plain ``pytest`` (``make test``) runs every
    test that is not ``slow``. Tests that use a whole-run fixture, or live in one of
    :data:`_WHOLE_RUN_MODULES`, are marked ``integration`` here; others mark themselves.

    ``addopts`` excludes ``slow`` with ``-m "not slow"``, but a ``-m`` on the command line replaces it:
    ``-m "not integration"`` used to run the slow tests too (52 s of them on this machine). So a slow test
    is deselected here unless the ``-m`` expression mentions ``slow`` (``make test-slow`` is ``-m slow``).
    """
    for item in items:
        if _WHOLE_RUN_FIXTURES & set(getattr(item, "fixturenames", ())) or item.path.name in _WHOLE_RUN_MODULES:
            item.add_marker(pytest.mark.integration)
    if "slow" not in (config.option.markexpr or ""):
        slow = [item for item in items if item.get_closest_marker("slow") is not None]
        if slow:
            config.hook.pytest_deselected(items=slow)
            items[:] = [item for item in items if item.get_closest_marker("slow") is None]
