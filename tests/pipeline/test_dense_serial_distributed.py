"""The dense stage gives the same dense.zarr and dem_dense.zarr in-process and on a LocalCluster of 2 processes.

Two tiles of the tiny run (``dense.tiles``: one chip each, ~1 s), each on a fresh copy of the tiny sync run.
Nothing in the stage draws random numbers, a tile's chips run in a fixed order and the chip's disparities do
not depend on OpenCV's thread count (tests/dense), so the arrays must be equal bit for bit.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from tests.pipeline.conftest import tiny_config

#: Two cheap tiles of the tiny mission (seed 42): one chip each.
TILES = (322, 325)


def _dense(run: Path, dst: Path, client: Any) -> dict[str, Any]:
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dense_stage import run_dense_stage

    shutil.copytree(run, dst)
    store = RunStore(dst)
    mission = open_mission(store.read_run()["mission"])
    return run_dense_stage(store, mission, tiny_config(dense={"enabled": True, "tiles": list(TILES)}), client,
                           stream=None)


def _arrays(path: Path) -> dict[str, np.ndarray]:
    import zarr

    out: dict[str, np.ndarray] = {}

    def walk(g: Any, prefix: str) -> None:
        for name, a in g.arrays():
            out[prefix + name] = np.asarray(a[...])
        for name, sub in g.groups():
            walk(sub, prefix + name + "/")

    walk(zarr.open_group(str(path), mode="r"), "")
    return out


def test_serial_and_distributed_dense_stores_are_identical(sync_run: tuple[Path, dict[str, Any]],
                                                           tmp_path: Path) -> None:
    from distributed import Client

    from mercury_dem.compute import SyncClient, local_cluster

    run, _ = sync_run
    serial = _dense(run, tmp_path / "serial", SyncClient())
    with local_cluster(2, 1, memory_limit=0) as cluster, Client(cluster) as client:
        dist = _dense(run, tmp_path / "dist", client)
    assert serial["points"] == dist["points"] > 0
    assert sorted(s for s in serial["tile_seconds"]) == [str(t) for t in TILES]
    for name in ("dense.zarr", "dem_dense.zarr"):
        a, b = _arrays(tmp_path / "serial" / name), _arrays(tmp_path / "dist" / name)
        assert a.keys() == b.keys() and a
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name}/{k}")
