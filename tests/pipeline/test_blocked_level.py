"""The run's hemisphere/global units over point blocks (issue #17, ``adjust.blocked_min_measures``).

The tiny run's global unit (with its re-centred radius priors and the altimetry's two passes) is adjusted
again from the run store with the threshold forced to 0, and compared with the default (in-memory) path:
with float64 storage to solver tolerance, with the default float32 storage within 10⁻³ px (measured
2026-11-26: 3.1e-9 rad, ~6e-5 px; docs/design/adjust.md, "Memory").
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.io.run_store import RunStore
from mercury_dem.mission import open_mission
from mercury_dem.pipeline.stages import _adjust_unit

from .conftest import tiny_config

pytestmark = pytest.mark.integration


def test_global_unit_blocked_equals_in_memory(sync_run: tuple[Path, dict[str, Any]]) -> None:
    run, _ = sync_run
    store = RunStore(run)
    summary, a = _adjust_unit(store, "global", 0, tiny_config())  # (UnitSummary, UnitFiles)
    ref = summary.adjustment
    assert "blocked" not in ref
    mission = open_mission(store.read_run()["mission"])
    ifov = min(mission.camera(str(i)).pixel_size_mm / mission.camera(str(i)).focal_length_mm
               for i in a.solution.image_ids)
    for float32, bound_rad in ((False, 1e-10), (True, 1e-3 * ifov)):
        blk_summary, b = _adjust_unit(store, "global", 0, tiny_config(adjust={
            "blocked_min_measures": 0, "blocked_block_points": 150, "blocked_float32": float32}))
        blk = blk_summary.adjustment
        assert blk["blocked"]["blocks"] >= 2
        assert blk["iterations"] == ref["iterations"] and blk["rejected"] == ref["rejected"]
        assert np.array_equal(a.solution.image_ids, b.solution.image_ids)
        assert np.abs(a.solution.rotations - b.solution.rotations).max() < bound_rad
        assert np.array_equal(a.network.measure_rejected, b.network.measure_rejected)
        assert blk["sigma0"] == pytest.approx(ref["sigma0"], rel=1e-6)
    # a hemisphere unit below the threshold keeps the in-memory path
    hemi, _ = _adjust_unit(store, "hemisphere", 0, tiny_config(adjust={"blocked_min_measures": 10**9}))
    assert "blocked" not in hemi.adjustment


def _global_unit_on_worker(run: str, config: Any) -> Any:
    """What ``graph._unit_task`` does on a worker, without writing the unit (the fixture's store is shared)."""
    from mercury_dem.pipeline.shard_engine import shard_engine_factory

    factory = shard_engine_factory()
    assert factory is not None  # inside a Dask worker's task
    return _adjust_unit(RunStore(run), "global", 0, config, engine_factory=factory)


def test_global_unit_blocks_on_the_runs_dask_workers(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """The unit's task, on a worker of a 2-worker LocalCluster, spreads its blocks over both workers
    (shard actors, the task seceded meanwhile) and gets the in-process blocked solution."""
    from distributed import Client

    from mercury_dem.compute import local_cluster
    from mercury_dem.pipeline.shard_engine import shard_engine_factory

    assert shard_engine_factory() is None  # not in a worker: in process
    run, _ = sync_run
    cfg = tiny_config(adjust={"blocked_min_measures": 0, "blocked_block_points": 150, "blocked_float32": False})
    ref_summary, a = _adjust_unit(RunStore(run), "global", 0, cfg)
    ref = ref_summary.adjustment
    assert ref["blocked"]["engine"] == "in process"
    with local_cluster(2, 1, processes=False, memory_limit=0) as cluster, Client(cluster) as client:
        got_summary, b = client.submit(_global_unit_on_worker, str(run), cfg, pure=False).result()
        got = got_summary.adjustment
        # the actors were released when the unit finished: nothing is left on the workers (freed asynchronously)
        for _ in range(50):
            left = client.run(lambda dask_worker: len(dask_worker.state.actors) + len(dask_worker.data))
            if not any(left.values()):
                break
            time.sleep(0.1)
        assert not any(left.values()), left
    assert got["blocked"]["engine"] == "dask (2 workers)"
    assert got["blocked"]["blocks"] == ref["blocked"]["blocks"] >= 2
    assert got["iterations"] == ref["iterations"] and got["rejected"] == ref["rejected"]
    assert np.array_equal(a.solution.image_ids, b.solution.image_ids)
    # two shards sum the reduced system in another order than one: equal to rounding, not bit for bit
    assert np.abs(a.solution.rotations - b.solution.rotations).max() < 1e-10
    assert np.array_equal(a.network.measure_rejected, b.network.measure_rejected)
    assert np.allclose(a.network.residuals, b.network.residuals, atol=1e-6, equal_nan=True)
    assert np.allclose(a.network.adjusted_xyz, b.network.adjusted_xyz, atol=1e-3, equal_nan=True)  # metres
    assert got["sigma0"] == pytest.approx(ref["sigma0"], rel=1e-9)
