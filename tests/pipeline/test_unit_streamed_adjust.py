"""A unit adjusted straight from its merged store (issue 33 item 1): ``io.adjusted_network_store.adjust_stored_unit``.

Three region stores of a hemisphere (a synthetic network cut with overlaps, some children's measures rejected,
one image left without measures) merged by parts (``stream_merge``), then adjusted by the stored blocks with the
adjusted network written back by blocks, against the in-memory path (``read_network`` of the same store,
``drop_unused_images``, ``adjust_unit_network`` over point blocks): the same poses (to 1e-9 rad; the same
arithmetic, in fact equal), the same adjusted network column for column, the same summary but for timings
and the network-wide RMS (summed in another order: to rounding). And the fallback reasons.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.adjust.unit import adjust_unit_network
from mercury_dem.adjust.unit_streamed import streamed_fallback_reason
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.io.adjusted_network_store import adjust_stored_unit, stored_image_ids
from mercury_dem.io.merged_network_store import stored_singular_parts, stream_merge
from mercury_dem.io.network_store import read_network, write_network
from mercury_dem.io.synthetic_network_store import BlockedNetwork, split_synthetic_network, write_synthetic_network
from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS
from mercury_dem.network.synthetic import SyntheticSpec
from mercury_dem.pipeline.unit_merge import mission_image_table
from tests.pipeline.stored_mission import StoredMission

CFG = AdjustConfig(blocked_min_measures=0, blocked_block_points=150, point_prior_center="datum",
                   point_prior_recentre_levels=(), altimetry_levels=())


_Mission = StoredMission


@pytest.fixture(scope="module")
def merged(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, _Mission, float]:
    """A hemisphere's merged store from three region stores (rejections, an image without measures)."""
    root = tmp_path_factory.mktemp("unit_streamed_adjust")
    write_synthetic_network(SyntheticSpec(n_measures=6_000, seed=5, block_points=200), root / "src")
    split = [root / f"split{k}" for k in range(3)]
    split_synthetic_network(root / "src", split, overlap_blocks=1, seed=3)
    rng = np.random.default_rng(0)
    kids = []
    for k, path in enumerate(split):
        net = read_network(path)
        net = net.replace(measure_rejected=rng.random(net.n_measures) < 0.03)
        keep = net.measure_image != 3  # image 3 loses its measures in every child: not one of the unit's images
        net = net.replace(**{k: getattr(net, k)[keep] for k in MEASURE_COLUMNS})
        kids.append((f"region {k}", write_network(net, root / f"region{k}.zarr")))
    src = BlockedNetwork(root / "src")
    mission = _Mission(src)
    stream_merge("hemisphere north", kids, root / "merged", lambda ids: mission_image_table(mission, ids),  # type: ignore[arg-type]
                 part_measures=1_500, block_points=CFG.blocked_block_points)
    radius = float(np.median(np.linalg.norm(src.store.column_rows("apriori_xyz", 0, 500), axis=1)))
    return root / "merged", mission, radius


def _geometry(mission: _Mission, ids: list[str]) -> tuple[list[Any], np.ndarray, np.ndarray, np.ndarray]:
    cams = [mission.camera(i) for i in ids]
    pos = np.array([mission.a_priori_pose(i)[0] for i in ids])
    rot = np.array([mission.a_priori_pose(i)[1] for i in ids])
    start = rotation_from_angles(np.random.default_rng(1).normal(0.0, 2e-5, (len(ids), 3))) @ rot
    return cams, pos, rot, start


def test_stored_unit_equals_in_memory(merged: tuple[Path, _Mission, float], tmp_path: Path) -> None:
    """Same poses, same adjusted network column for column, same summary (timings and network RMS aside)."""
    path, mission, radius = merged
    ref_net = read_network(path / "network").drop_unused_images()
    ids = [str(i) for i in ref_net.image_ids]
    assert len(ids) == len(stored_image_ids(path)) - 1  # image 3 has no measure left: not the unit's
    singular = stored_singular_parts(path / "network")
    assert [i for i in stored_image_ids(path) if i not in set(singular["images_without_measures"])] == ids
    cams, pos, rot, start = _geometry(mission, ids)
    ref = adjust_unit_network(ref_net, cams, pos, rot, CFG, pointing_sigma_urad=50.0, datum_radius_m=radius,
                              initial_rotations=start, level="hemisphere")
    got = adjust_stored_unit(path, tmp_path / "adjusted.zarr", ids, cams, pos, rot, CFG, pointing_sigma_urad=50.0,
                             datum_radius_m=radius, initial_rotations=start)
    assert ref.summary["blocked"]["blocks"] > 3 and ref.summary["iterations"] > 1
    assert np.abs(got.rotations - ref.rotations).max() < 1e-9
    np.testing.assert_array_equal(got.image_measures, ref.image_measures)
    np.testing.assert_array_equal(got.image_rms_px, ref.image_rms_px)  # per image: summed in the same order
    net = read_network(got.network_path)
    assert list(net.image_ids) == ids
    assert net.metadata == ref.network.metadata
    for name in ("point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
        np.testing.assert_array_equal(getattr(net, name), getattr(ref.network, name), err_msg=name)
    assert net.measure_rejected.sum() > 0 and np.isfinite(net.residuals).any()
    same = {k for k in ref.summary if "seconds" not in k and k not in ("rms_px", "initial_rms_px")}
    assert {k: got.summary[k] for k in same} == {k: ref.summary[k] for k in same}
    for k in ("rms_px", "initial_rms_px"):
        assert got.summary[k] == pytest.approx(ref.summary[k], rel=1e-12)
    assert "UNDER-DETERMINED" in got.text_report or "islands" in got.text_report


def test_fallback_reasons() -> None:
    """Each part the stored path lacks names itself; a unit it covers has none."""
    assert streamed_fallback_reason(CFG, "hemisphere", 10, altimetry=False) is None
    assert "not adjusted by blocks" in str(streamed_fallback_reason(AdjustConfig(), "hemisphere", 10, altimetry=False))
    assert "altimetry" in str(streamed_fallback_reason(CFG, "global", 10, altimetry=True))
    recentre = AdjustConfig(blocked_min_measures=0, point_prior_recentre_levels=("global",))
    assert "re-centring" in str(streamed_fallback_reason(recentre, "global", 10, altimetry=False))
    post = AdjustConfig(blocked_min_measures=0, posterior_sigmas=True, point_prior_recentre_levels=())
    assert "posterior" in str(streamed_fallback_reason(post, "hemisphere", 10, altimetry=False))


def _adjust_on_worker(path: str, out: str, ids: list[str], geometry: tuple[Any, ...], radius: float) -> Any:
    from mercury_dem.pipeline.shard_engine import shard_engine_factory

    cams, pos, rot, start = geometry
    return adjust_stored_unit(path, out, ids, cams, pos, rot, CFG, pointing_sigma_urad=50.0, datum_radius_m=radius,
                              initial_rotations=start, engine_factory=shard_engine_factory())


def test_stored_unit_blocks_on_the_dask_workers(merged: tuple[Path, _Mission, float], tmp_path: Path) -> None:
    """The unit's task on a worker of a 2-worker LocalCluster: each worker's shard actor reads its own run of the
    stored blocks (``DaskShardEngine.from_blocks`` given ``StoredBlocks``); the in-process solution to rounding
    (two shards sum in another order), the same rejections, nothing left on the workers.
    """
    from distributed import Client

    from mercury_dem.compute import local_cluster

    path, mission, radius = merged
    unused = set(stored_singular_parts(path / "network")["images_without_measures"])
    ids = [i for i in stored_image_ids(path).tolist() if i not in unused]
    geometry = _geometry(mission, ids)
    ref = adjust_stored_unit(path, tmp_path / "sync.zarr", ids, *geometry[:3], CFG, pointing_sigma_urad=50.0,
                             datum_radius_m=radius, initial_rotations=geometry[3])
    with local_cluster(2, 1, processes=False, memory_limit=0) as cluster, Client(cluster) as client:
        got = client.submit(_adjust_on_worker, str(path), str(tmp_path / "dask.zarr"), ids, geometry, radius,
                            pure=False).result()
        for _ in range(50):
            left = client.run(lambda dask_worker: len(dask_worker.state.actors))
            if not any(left.values()):
                break
            time.sleep(0.1)
        assert not any(left.values()), left
    assert got.summary["blocked"]["engine"] == "dask (2 workers)"
    assert got.summary["iterations"] == ref.summary["iterations"]
    assert np.abs(got.rotations - ref.rotations).max() < 1e-10
    a, b = read_network(ref.network_path), read_network(got.network_path)
    np.testing.assert_array_equal(a.measure_rejected, b.measure_rejected)
    assert np.allclose(a.residuals, b.residuals, atol=1e-6, equal_nan=True)
    assert np.allclose(a.adjusted_xyz, b.adjusted_xyz, atol=1e-3, equal_nan=True)
