"""The run's unit merge through the streamed merge (issue 33 item 1, ``adjust.streamed_merge_levels``).

A hemisphere's three region children (a 6·10³-measure synthetic network cut with overlaps, some measures and
points rejected by the regions' adjustment) merged by ``pipeline.unit_merge.merge_children`` with the key on
(by parts from the stores) and off (every child read, ``merge_networks``): the same network bit for bit, the
children's rejections cleared in both (re-judged at the hemisphere), and the scratch store gone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.config import load_config
from mercury_dem.exceptions import StoreError
from mercury_dem.io.network_store import read_network, write_network
from mercury_dem.io.synthetic_network_store import BlockedNetwork, split_synthetic_network, write_synthetic_network
from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS
from mercury_dem.network.synthetic import SyntheticSpec
from mercury_dem.pipeline.unit_merge import merge_children, mission_image_table
from tests.pipeline.stored_mission import StoredMission


class _Store:
    """What ``merge_children`` uses of a RunStore: the children's network paths and the unit's directory."""

    def __init__(self, root: Path, kids: dict[int, Path]):
        self.root, self.kids = root, kids

    def check_unit(self, level: str, unit_id: int) -> None:
        pass

    def network_path(self, level: str, unit_id: int) -> Path:
        assert level == "region"
        return self.kids[unit_id]

    def unit_dir(self, level: str, unit_id: int) -> Path:
        return self.root / level / str(unit_id)


_Mission = StoredMission


@pytest.fixture(scope="module")
def hemisphere(tmp_path_factory: pytest.TempPathFactory) -> tuple[_Store, _Mission]:
    """Three region stores of one hemisphere (with rejections) and a mission giving their images' geometry."""
    root = tmp_path_factory.mktemp("unit_streamed")
    write_synthetic_network(SyntheticSpec(n_measures=6_000, seed=5, block_points=200), root / "src")
    split = [root / f"split{k}" for k in range(3)]
    split_synthetic_network(root / "src", split, overlap_blocks=1, seed=3)
    rng = np.random.default_rng(0)
    kids = {}
    for k, path in enumerate(split):  # as an adjusted region wrote it: some rejections
        net = read_network(path)
        net = net.replace(measure_rejected=rng.random(net.n_measures) < 0.05,
                          point_rejected=rng.random(net.n_points) < 0.02)
        kids[10 + k] = write_network(net, root / f"region{k}.zarr")
    return _Store(root, kids), _Mission(BlockedNetwork(root / "src"))


def test_streamed_unit_merge_equals_in_memory(hemisphere: tuple[_Store, _Mission]) -> None:
    """Key on (several parts) and off: the same merged network bit for bit, rejections cleared, scratch gone."""
    store, mission = hemisphere
    kids = sorted(store.kids)
    ref = merge_children(store, "hemisphere", 0, kids, load_config(), mission)  # type: ignore[arg-type]
    cfg = load_config(overrides={"adjust": {"streamed_merge_levels": ["hemisphere", "global"],
                                            "streamed_merge_part_measures": 1_500}})
    got = merge_children(store, "hemisphere", 0, kids, cfg, mission)  # type: ignore[arg-type]
    assert list(got.image_ids) == list(ref.image_ids)
    for name in ("point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    assert not got.measure_rejected.any() and not got.point_rejected.any()  # re-judged at this level
    assert got.n_points < sum(read_network(p).n_points for p in store.kids.values())  # the overlaps joined
    assert not any((store.root / "hemisphere").glob(".*"))  # the scratch store removed


def test_streamed_unit_merge_names_a_damaged_child(hemisphere: tuple[_Store, _Mission], tmp_path: Path) -> None:
    """A child whose store is missing: the project's error naming the unit and the child's store."""
    store, mission = hemisphere
    bad = _Store(tmp_path, {**store.kids, 11: tmp_path / "missing.zarr"})
    cfg = load_config(overrides={"adjust": {"streamed_merge_levels": ["hemisphere"]}})
    with pytest.raises(StoreError, match="hemisphere north: the network of child region .*missing.zarr"):
        merge_children(bad, "hemisphere", 0, sorted(bad.kids), cfg, mission)  # type: ignore[arg-type]
    assert not any((tmp_path / "hemisphere").glob(".*"))


def test_mission_image_table_one_camera_per_model(hemisphere: tuple[_Store, _Mission]) -> None:
    """The geometry the merged store records: each image's camera, pose, in the merged order."""
    _, mission = hemisphere
    ids = np.array(list(mission.index)[::-1])
    table = mission_image_table(mission, ids)  # type: ignore[arg-type]
    assert table.n_images == len(ids) and len(table.cameras) == len({id(c) for c in mission.cams})
    k = mission.index[str(ids[3])]
    assert table.cameras[table.image_camera[3]] is mission.camera(str(ids[3]))
    np.testing.assert_array_equal(table.rotations[3], mission.rot[k])


@pytest.mark.integration
def test_run_units_streamed_equal_in_memory(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """The tiny run's hemisphere and global units adjusted again from its store with the key on, by blocks:
    merged by parts, adjusted from the merged store's blocks and written back by blocks, against the in-memory
    blocked path: the same adjusted network, pointing (to 1e-9 rad: the same arithmetic, so in fact equal) and
    summary; the summary says the streamed path was used, and why not where it does not apply.
    """
    import shutil

    from mercury_dem.io.run_store import RunStore
    from mercury_dem.pipeline.stages import _adjust_unit

    from .conftest import tiny_config

    run, _ = sync_run
    store = RunStore(run)
    blocked = {"blocked_min_measures": 0, "point_prior_recentre_levels": [], "altimetry_levels": []}
    on = tiny_config(adjust={**blocked, "streamed_merge_levels": ["hemisphere", "global"],
                             "streamed_merge_part_measures": 500})
    for level in ("hemisphere", "global"):
        ref_summary, ref = _adjust_unit(store, level, 0, tiny_config(adjust=blocked))
        got_summary, got = _adjust_unit(store, level, 0, on)
        assert got_summary.adjustment["streamed"]["used"] is True and got.network is None
        got_net = read_network(got.network_dir)
        shutil.rmtree(got.network_dir)
        assert got_summary.adjustment["iterations"] == ref_summary.adjustment["iterations"]
        assert got_summary.single_measure_points == ref_summary.single_measure_points
        assert got_summary.adjustment["images_without_measures"] == ref_summary.adjustment["images_without_measures"]
        assert got_summary.adjustment["islands"] == ref_summary.adjustment["islands"]
        assert np.array_equal(got.solution.image_ids, ref.solution.image_ids)
        assert np.abs(got.solution.rotations - ref.solution.rotations).max() < 1e-9
        assert list(got_net.image_ids) == list(ref.network.image_ids)
        for name in ("point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
            np.testing.assert_array_equal(getattr(got_net, name), getattr(ref.network, name), err_msg=name)
    fallback, _ = _adjust_unit(store, "global", 0, tiny_config(adjust={"streamed_merge_levels": ["global"]}))
    assert fallback.adjustment["streamed"] == {
        "used": False, "reason": "not adjusted by blocks (adjust.blocked_levels / blocked_min_measures): the global "
        "is solved in memory, so its merged network is read back"}


def test_stored_singular_parts_equal_the_networks(hemisphere: tuple[_Store, _Mission], tmp_path: Path) -> None:
    """What the unit summary names (images without measures, single-measure points) read from a merged store by
    row chunks equals ``singular_parts`` of the network in memory (an image left without measures, single points).
    """
    from mercury_dem.io.merged_network_store import stored_singular_parts
    from mercury_dem.network.check import singular_parts

    store, mission = hemisphere
    net = merge_children(store, "hemisphere", 0, sorted(store.kids), load_config(), mission)  # type: ignore[arg-type]
    gone = net.measure_image != 3  # image 3 loses its measures; some points are left with one
    net = net.replace(measure_image=net.measure_image[gone], measure_point=net.measure_point[gone],
                      **{k: getattr(net, k)[gone] for k in MEASURE_COLUMNS if k not in ("measure_image", "measure_point")})
    path = write_network(net, tmp_path / "merged.zarr")
    ref = singular_parts(net, net.drop_unused_images())
    got = stored_singular_parts(path, rows=700)
    assert got == ref
    assert got["images_without_measures"] == [str(net.image_ids[3])] and got["single_measure_points"]["count"] > 0
