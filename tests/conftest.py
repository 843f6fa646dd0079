"""Session-wide synthetic worlds shared by the test areas.

``tiny_mission_path``: the ``tiny`` preset (seed 42), generated once per session;
it is the world of the synth, pipeline and notebook tests.
"""

from __future__ import annotations

import os
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


#: Single tests that are end to end although their module is not, or replicates of a statistical check on more
#: seeds, each with its reason (marked ``integration``, so they leave the fast loop and stay in ``make test``). Listed here, not on the test, to keep the marks of
#: modules other branches edit in one place.
_WHOLE_RUN_TESTS = {
    # a whole command (import-isis, twice) over a real ISIS network of the shared data
    "tests/network/test_cli.py::test_import_with_serial_map": "whole command on real data",
    # every published network read, written as v2 and v5 and read back: real data over many files;
    # the reader/writer stays in the fast loop through the property test test_our_networks_round_trip
    "tests/network/test_isis.py::test_real_networks_round_trip": "real-data round trips over many files",
    # a real Dask scheduler process started and waited on (seconds of sleeping, not computing)
    "tests/cluster/test_idle_timeout.py::test_the_idle_clock_starts_at_the_first_join_not_at_the_start":
        "a real scheduler",
    "tests/cluster/test_idle_timeout.py::test_a_scheduler_nobody_joins_ends_after_the_bound": "a real scheduler",
    "tests/compute/test_no_worker_watchdog.py::test_a_real_scheduler_without_workers_cancels_the_waiting_futures":
        "a real scheduler",
    # two stages chained: children's stores merged by parts, then the blocked adjustment of the merge against
    # the in-memory one (~2.3 s of CPU); the merge alone stays in the loop (test_streamed_merge_equals_...)
    "tests/network/test_streamed_merge.py::test_streamed_blocks_give_the_in_memory_solution":
        "merge then blocked adjustment",
    # Replicates: the same statistical check on another seed (the first seed stays in the fast loop).
    "tests/altimetry/test_adjust_with_altimetry.py::test_altimetry_constraints_fix_the_heights[29]": "second seed",
    "tests/adjust/test_datum.py::test_recentred_radius_constraint_removes_the_pull_toward_the_datum[11]":
        "second seed",
    "tests/altimetry/test_register.py::test_few_profiles_nuisance_does_not_loosen_the_transform[2]": "second seed",
    "tests/altimetry/test_register.py::test_few_profiles_nuisance_does_not_loosen_the_transform[3]": "third seed",
}

#: Module fixtures that run a whole stage, by module: a test of that module using one is end to end.
#: ``default_run`` matches every standard pair of issue 4 with the whole matcher (~3 s of CPU, built on each
#: xdist worker that gets one of its tests); the matcher's unit tests (test_tile, test_units, test_selection,
#: test_track_propagation, and this module's single-pair tests) stay in the fast loop.
_WHOLE_RUN_MODULE_FIXTURES = {
    "tests/match/test_accuracy.py": {"default_run"},
}

#: Test modules sharing a costly session fixture, by group. Under ``make test-fast`` (``-n 2 --dist loadgroup``)
#: :func:`pytest_xdist_make_scheduler` hands each test module to one xdist worker as a whole, and each group's
#: modules together, so a module- or session-scoped fixture is built by one worker, not by each worker that drew
#: one of its tests (``--dist load`` built 10-20 s of CPU of fixtures twice: the products' regional and global
#: DEMs, the ortho scenes, the rendered pairs, the streamed-merge world, 1.5-4 s each).
SHARED_FIXTURE_GROUPS = {
    # regional_run (tests/products/conftest.py): one regional DEM per case for both modules
    "products_regional_dems": ("tests/products/test_product_metadata.py", "tests/products/test_isis_pds4_products.py"),
    # pair_world (tests/match/conftest.py): the rendered standard pairs, ~2.4 s
    "match_pair_world": ("tests/match/test_tile.py", "tests/match/test_accuracy.py"),
    # the rendered pairs of tests/dense/conftest.py (lambert_pair in five modules, ~2 s each)
    "dense_rendered_pairs": ("tests/dense/test_chip.py", "tests/dense/test_disparity.py", "tests/dense/test_rectify.py",
                             "tests/dense/test_refine_kernel.py", "tests/dense/test_triangulate.py"),
}


def work_unit(nodeid: str) -> str:
    """The xdist work unit of a test under ``--dist loadgroup``: its group in :data:`SHARED_FIXTURE_GROUPS`, else
    its module (``--dist loadfile``).
    """
    module = nodeid.split("::", 1)[0]
    for group, modules in SHARED_FIXTURE_GROUPS.items():
        if module in modules:
            return group
    return module


@pytest.hookimpl(optionalhook=True)  # an xdist hook: unknown when xdist is not loaded (-p no:xdist)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """``--dist loadgroup``: whole modules, and the groups of :data:`SHARED_FIXTURE_GROUPS`, as work units
    (largest first, xdist's default reordering).

    Our own scheduler because xdist's ``xdist_group`` marks do not group on pytest 9 (xdist 3.8 renames the
    node through ``item._nodeid``, which pytest 9 no longer reads: every test stays its own unit); the
    scheduling itself is xdist's (:class:`xdist.scheduler.LoadScopeScheduling`), only the unit is ours.
    """
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class _ModuleGroups(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    return _ModuleGroups(config, log)  # type: ignore[arg-type]


#: Examples each hypothesis test draws at most in the fast loop (``-m`` naming ``not integration``); ``make test``
#: (plain ``pytest``) and the fuzz benchmark keep every test's own count, and ``MERCURY_DEM_FUZZ_EXAMPLES``, when
#: set, turns the cap off. Every reader is still fuzzed in the loop, on fewer inputs.
FAST_LOOP_FUZZ_EXAMPLES = 10


def _cap_fuzz_examples(items: list[pytest.Item], cap: int) -> None:
    """Lower the ``max_examples`` of each hypothesis test among ``items`` to ``cap``.

    hypothesis has no public switch that overrides a count given in ``@settings`` (a profile only sets the
    default), so the settings object that ``@given`` reads when the test runs is replaced by a child of it.
    """
    from hypothesis import settings

    for item in items:
        test = getattr(item, "obj", None)
        current = getattr(test, "_hypothesis_internal_use_settings", None)
        if current is not None and current.max_examples > cap:
            test._hypothesis_internal_use_settings = settings(current, max_examples=cap)  # type: ignore[union-attr]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The two loops: ``integration`` marks, and ``slow`` tests kept out of every selection not naming them.

    ``pytest -m "not integration"`` is the fast inner loop; plain ``pytest`` (``make test``) runs every
    test that is not ``slow``. Tests that use a whole-run fixture, or live in one of
    :data:`_WHOLE_RUN_MODULES`, or are listed in :data:`_WHOLE_RUN_TESTS` (by name, or one case by its id),
    or use a module fixture of :data:`_WHOLE_RUN_MODULE_FIXTURES`, are marked ``integration`` here;
    others mark themselves. In the fast loop the hypothesis tests draw at most :data:`FAST_LOOP_FUZZ_EXAMPLES`.

    ``addopts`` excludes ``slow`` with ``-m "not slow"``, but a ``-m`` on the command line replaces it:
    ``-m "not integration"`` used to run the slow tests too (52 s of them on this machine). So a slow test
    is deselected here unless the ``-m`` expression mentions ``slow`` (``make test-slow`` is ``-m slow``).
    """
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        module = item.nodeid.split("::")[0]
        whole_run = (_WHOLE_RUN_FIXTURES & fixtures or item.path.name in _WHOLE_RUN_MODULES
                     or item.nodeid.split("[")[0] in _WHOLE_RUN_TESTS or item.nodeid in _WHOLE_RUN_TESTS
                     or _WHOLE_RUN_MODULE_FIXTURES.get(module, set()) & fixtures)
        if whole_run:
            item.add_marker(pytest.mark.integration)
    markexpr = config.option.markexpr or ""
    if "not integration" in markexpr and not os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES"):
        _cap_fuzz_examples(items, FAST_LOOP_FUZZ_EXAMPLES)
    if "slow" not in markexpr:
        slow = [item for item in items if item.get_closest_marker("slow") is not None]
        if slow:
            config.hook.pytest_deselected(items=slow)
            items[:] = [item for item in items if item.get_closest_marker("slow") is None]
