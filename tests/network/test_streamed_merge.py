"""The streamed merge (issue 33 item 1): children's stores merged by parts equal ``merge_networks`` in memory,
and its point blocks give the in-memory blocked adjustment's solution.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
    setup_from_config,
)
from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
from mercury_dem.adjust.network import problem_from_network
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import StoreError
from mercury_dem.io.merged_network_store import stream_merge
from mercury_dem.io.network_store import read_network
from mercury_dem.io.synthetic_network_store import (
    BlockedNetwork,
    StoredBlocks,
    split_synthetic_network,
    write_synthetic_network,
)
from mercury_dem.network.merge import merge_networks
from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS
from mercury_dem.network.streamed_merge import join_edges, median_of_counts, merge_partitions
from mercury_dem.network.synthetic import SyntheticSpec

CFG = AdjustConfig(max_iterations=8)
POINTING_SIGMA_URAD = 450.0  # the synthetic networks' injected a-priori pointing error (1 sigma per axis)
BLOCK_POINTS = 700


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A 4·10⁴-measure synthetic network (seed 11, not tuned on) cut into three overlapping children."""
    root = tmp_path_factory.mktemp("streamed")
    write_synthetic_network(SyntheticSpec(n_measures=40_000, seed=11, block_points=800), root / "src")
    kids = [root / k for k in "abc"]
    split_synthetic_network(root / "src", kids, overlap_blocks=1, seed=2)
    src = BlockedNetwork(root / "src")
    summary = stream_merge("hemisphere 0", [(k.name, k) for k in kids], root / "out", lambda ids: src.images,
                           block_points=BLOCK_POINTS, part_measures=5_000)
    ref, stats = merge_networks([read_network(k) for k in kids])
    return {"root": root, "kids": kids, "src": src, "summary": summary, "ref": ref, "stats": stats}


def test_streamed_merge_equals_in_memory_merge(world) -> None:
    """The merged store (in parts, conflicts included) is ``merge_networks``' network row for row, with its counts."""
    got = read_network(world["root"] / "out" / "network")  # the merged network store, as export-isis reads it
    ref, stats, s = world["ref"], world["stats"], world["summary"]
    assert list(got.image_ids) == list(ref.image_ids)
    for name in ("point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):  # row for row, bit for bit
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    # the merge did join (shared border points), with conflicts, and was done in several parts
    assert stats.n_points_joined > 1000 and stats.n_conflicts > 0 and s.merge_parts > 3 and s.image_parts > 3
    for k in ("n_points_in", "n_measures_in", "n_points", "n_measures", "n_points_joined", "n_measures_collapsed",
              "n_conflicts", "n_conflict_measures", "n_points_dropped", "ids_renumbered"):
        assert getattr(s.stats, k) == getattr(stats, k), k
    assert s.stats.n_networks == 3 and s.to_dict()["n_children"] == 3 and "stats" not in s.to_dict()
    assert s.median_sigma_px == float(np.median(problem_from_network(
        ref, *_geometry(world["src"], ref.n_images))[0].measure_sigma))


def _geometry(src, n):
    im = src.images
    return [im.cameras[k] for k in im.image_camera][:n], im.positions[:n], im.rotations[:n]


def test_streamed_blocks_give_the_in_memory_solution(world) -> None:
    """Same points and measures in the blocks, the same adjusted pointing (to 1e-9 rad) as today's path:
    merge in memory, ``problem_from_network``, ``blocked_bundle_adjust``.
    """
    ref = world["ref"]
    cams, pos, rot = _geometry(world["src"], ref.n_images)
    problem, _ = problem_from_network(ref, cams, pos, rot, CFG, pointing_sigma_urad=POINTING_SIGMA_URAD)
    expected = blocked_bundle_adjust(problem, CFG, block_points=BLOCK_POINTS)
    net = BlockedNetwork(world["root"] / "out")
    im = net.images
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, CFG,
                              pointing_sigma_urad=POINTING_SIGMA_URAD, float32=CFG.blocked_float32)
    opt = options_from_config(CFG, world["summary"].median_sigma_px)
    engine = SyncEngine([BlockShard(StoredBlocks(str(net.root), tuple(range(net.n_blocks))), setup, opt)])
    res = blocked_levenberg_marquardt(engine, setup, opt)
    assert res.measures == problem.n_measures and res.points == problem.n_points
    assert res.iterations == expected.iterations and res.rejected == int(expected.rejected.sum())
    err = np.abs(res.rotations - expected.rotations).max()
    assert err < 1e-9, err
    # and the adjustment did move the pointing (a test that can fail: 450 µrad a-priori errors)
    assert np.abs(expected.rotations - problem.rotations).max() > 1e-5


def test_missing_or_incomplete_child_names_unit_and_child(world, tmp_path: Path) -> None:
    """A child's store missing, incomplete or damaged: the project's error naming the unit and the child."""
    kids = world["kids"]
    src = world["src"]
    with pytest.raises(StoreError, match=r"hemisphere 1: the network of child zz .*does not exist"):
        stream_merge("hemisphere 1", [("a", kids[0]), ("zz", tmp_path / "nope")], tmp_path / "o1",
                     lambda ids: src.images)
    broken = tmp_path / "b"
    shutil.copytree(kids[1], broken)
    (broken / ".complete").unlink()
    with pytest.raises(StoreError, match=r"globe 0: the network of child b .*incomplete"):
        stream_merge("globe 0", [("a", kids[0]), ("b", broken)], tmp_path / "o2", lambda ids: src.images)
    # a damaged column: found while streaming, nothing left behind (no output, no spill files)
    shutil.rmtree(broken / "sample")
    (broken / ".complete").write_text("complete\n")
    with pytest.raises(StoreError, match=r"globe 0: the network of child b .*sample"):
        stream_merge("globe 0", [("a", kids[0]), ("b", broken)], tmp_path / "o3", lambda ids: src.images)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_join_and_partitions() -> None:
    """The pure steps on a hand-made case: the join's pairs, the parts of whole components, the median."""
    # points 0,1 share a measure in image 0 (0.3 px apart); 2 is alone; 3,4 share one in image 1
    e = join_edges(np.array([0, 1, 2, 3, 4, 4]), np.array([0, 0, 0, 1, 1, 1]), np.array([10.0, 10.3, 50, 5, 5.1, 90]),
                   np.array([10.0, 10.0, 50, 5, 5.0, 9]), 1.0)
    np.testing.assert_array_equal(e, [[0, 1], [3, 4]])
    part, n = merge_partitions(np.array([3, 2, 4, 1, 1]), e, max_measures=5)
    # components {0,1} (5 measures), {2} (4), {3,4} (2) in order of their first point; parts of <= 5 measures
    np.testing.assert_array_equal(part, [0, 0, 1, 2, 2])
    assert n == 3
    part, n = merge_partitions(np.array([3, 2, 4, 1, 1]), e, max_measures=2)  # a component never splits
    np.testing.assert_array_equal(part, [0, 0, 1, 2, 2])
    assert median_of_counts(np.array([0.5, 1.0, 2.0]), np.array([1, 2, 1])) == np.median([0.5, 1, 1, 2])
    assert median_of_counts(np.array([0.5, 2.0]), np.array([2, 1])) == 0.5


def test_rejections_kept_or_cleared_as_the_cascade_rejudges(world, tmp_path: Path) -> None:
    """A child with rejected measures and points: kept as stored, or cleared (``clear_rejections``, as
    ``rejudged_network`` for an adjusted child); either way ``merge_networks``' network row for row.
    """
    import zarr

    from mercury_dem.adjust.cascade import rejudged_network

    kids = world["kids"]
    b = tmp_path / "b"
    shutil.copytree(kids[1], b)
    g = zarr.open_group(str(b), mode="r+", zarr_format=3)
    g["measure_rejected"][-400:-100] = True  # past the border shared with a (a merged measure takes the first)
    g["point_rejected"][-90:-50] = True
    src = world["src"]
    for clear in (False, True):
        out = tmp_path / f"o{int(clear)}"
        stream_merge("region 3", [("a", kids[0]), ("b", b)], out, lambda ids: src.images, part_measures=4_000,
                     clear_rejections=clear)
        nets = [read_network(kids[0]), read_network(b)]
        if clear:
            nets = [rejudged_network(n, "region") for n in nets]
        ref = merge_networks(nets).network
        got = read_network(out / "network")
        assert got.measure_rejected.any() != clear
        for name in ("point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)


def test_string_ids_colliding_ids_and_a_split_component(tmp_path: Path) -> None:
    """Small hand-made children: string and integer ids mix as strings; colliding ids are renumbered over the
    whole (as ``point_ids="auto"``); a conflict that splits a joined group keeps ``merge_networks``' order even
    when the group's parts land in different merge parts.
    """
    from mercury_dem.io.network_store import write_network
    from mercury_dem.network.blocks import ImageTable
    from mercury_dem.network.model import ControlNetwork

    def net(pid, pts, imgs, s, images=("A", "B", "C")):
        return ControlNetwork.from_arrays(np.array(images), np.array(pid), np.array(pts), np.array(imgs),
                                          np.array(s, float), np.array(s, float))

    def geometry(ids):
        from mercury_dem.geometry.camera import mdis_nac

        cam = mdis_nac(128)
        n = len(ids)
        return ImageTable((cam,), np.zeros(n, np.int64), np.zeros((n, 3)), np.tile(np.eye(3), (n, 1, 1)))

    cases = {
        # X {A 10, B 5} and W {B 40, C 40} in one child, Y {A 10.4, C 70} and Z {A 10.9, D 90} in the other:
        # X, Y, Z joined in A (chained within 1 px) but A spreads 1.27 px: a conflict drops A and splits them;
        # with one component a part, Y and Z (input points 2, 3) must wait for W (1)
        "split": [net([1, 2], [0, 0, 1, 1], [0, 1, 1, 2], [10, 5, 40, 40], images=("A", "B", "C", "D")),
                  net([3, 4], [0, 0, 1, 1], [0, 2, 0, 3], [10.4, 70, 10.9, 90], images=("A", "B", "C", "D"))],
        "strings": [net(["AS15_1", "AS15_2"], [0, 0, 1, 1], [0, 1, 1, 2], [1, 2, 40, 41]),
                    net([7, 8], [0, 0, 1, 1], [0, 1, 0, 2], [50, 60, 1.3, 3])],
        "collide": [net([1, 2], [0, 0, 1, 1], [0, 1, 1, 2], [1, 2, 40, 41]),
                    net([2, 1], [0, 0, 1, 1], [0, 1, 0, 2], [50, 60, 70, 80])],
    }
    for name, nets in cases.items():
        kids = [write_network(n, tmp_path / f"{name}{i}") for i, n in enumerate(nets)]
        ref, stats = merge_networks(nets)
        for part_measures in (1, 3, 100):
            out = tmp_path / f"{name}_out{part_measures}"
            s = stream_merge(name, [(k.name, k) for k in kids], out, geometry, part_measures=part_measures)
            got = read_network(out / "network")
            assert s.stats.ids_renumbered == stats.ids_renumbered and s.stats.n_conflicts == stats.n_conflicts, name
            assert got.point_ids.tolist() == ref.point_ids.tolist(), (name, part_measures)
            for col in ("apriori_xyz", *MEASURE_COLUMNS):
                np.testing.assert_array_equal(getattr(got, col), getattr(ref, col), err_msg=f"{name} {col}")
    assert merge_networks(cases["collide"]).stats.ids_renumbered
    split = merge_networks(cases["split"])
    assert split.stats.n_conflicts == 1 and split.network.point_ids.tolist() == [1, 2, 3, 4]
