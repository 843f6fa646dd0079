"""The cascade's decisions about one unit (adjust.cascade): rejections re-judged, warm start, unit configuration."""

from __future__ import annotations

import numpy as np

from mercury_dem.adjust.cascade import ChildSolution, adjusts_by_blocks, rejudged_network, unit_config, warm_start
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.network import ControlNetwork


def _net():
    net = ControlNetwork.from_arrays(
        ["A", "B", "C"], [1, 2], [0, 0, 1, 1], [0, 1, 1, 2],
        [1.0, 2, 3, 4], [1.0, 2, 3, 4], apriori_xyz=np.ones((2, 3)),
    )
    return net.replace(measure_rejected=np.array([True, False, False, True]), point_rejected=np.array([False, True]))


def test_rejections_are_cleared_for_adjusted_children_only():
    net = _net()
    assert rejudged_network(net, "tile") is net  # a tile was never adjusted: taken as it is
    for level in ("region", "hemisphere"):
        again = rejudged_network(net, level)
        assert not again.measure_rejected.any() and not again.point_rejected.any()
        np.testing.assert_array_equal(again.apriori_xyz, net.apriori_xyz)  # the tiles' a-priori points kept
        assert net.measure_rejected.sum() == 2  # the input is not modified


def _rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_warm_start_takes_the_child_with_most_measures_first_on_ties():
    ids = ["A", "B", "C", "D"]
    rot0 = np.stack([np.eye(3)] * 4)
    pos0 = np.arange(12, dtype=float).reshape(4, 3)
    one = ChildSolution(np.array(["A", "B", "X"]), np.stack([_rot(0.1), _rot(0.2), _rot(0.3)]),
                        np.full((3, 3), 1.0), np.array([5, 3, 9]))
    two = ChildSolution(np.array(["B", "A", "C"]), np.stack([_rot(-0.2), _rot(-0.1), _rot(-0.3)]),
                        np.full((3, 3), 2.0), np.array([7, 5, 1]))
    rot, pos = warm_start(ids, rot0, pos0, [one, two])
    np.testing.assert_allclose(rot[0], _rot(0.1))  # A: 5 vs 5, the first child wins the tie
    np.testing.assert_allclose(rot[1], _rot(-0.2))  # B: 3 vs 7
    np.testing.assert_allclose(rot[2], _rot(-0.3))  # C: only in the second
    np.testing.assert_allclose(rot[3], np.eye(3))  # D: in no child, a-priori kept
    np.testing.assert_allclose(pos[:, 0], [1.0, 2.0, 2.0, 9.0])
    assert np.array_equal(rot0, np.stack([np.eye(3)] * 4))  # inputs not modified
    # without a measure count (an older solution) each image counts once: the first child wins
    rot, _ = warm_start(ids, rot0, pos0, [ChildSolution(one.image_ids, one.rotations, one.positions),
                                         ChildSolution(two.image_ids, two.rotations, two.positions)])
    np.testing.assert_allclose(rot[1], _rot(0.2))


def test_unit_config_allows_islands_and_holds_images_without_measures():
    cfg = AdjustConfig(held_images=("B",))
    assert not cfg.allow_islands
    out, missing = unit_config(cfg, ["A", "B", "C", "D"], np.array([0, 1, 1, 0]))
    assert out.allow_islands
    assert missing == ["C", "D"]
    assert out.held_images == ("B", "C", "D")  # kept, then the new ones, no repeat
    out, missing = unit_config(AdjustConfig(), ["A", "B"], np.array([0, 1]))
    assert missing == [] and out.held_images == () and out.allow_islands


def test_units_adjusted_over_blocks_are_large_units_of_the_blocked_levels():
    cfg = AdjustConfig(blocked_min_measures=1000, blocked_levels=("hemisphere", "global"))
    assert adjusts_by_blocks(cfg, "global", 1000) and adjusts_by_blocks(cfg, "hemisphere", 5000)
    assert not adjusts_by_blocks(cfg, "global", 999)  # too small
    assert not adjusts_by_blocks(cfg, "region", 10**6)  # not a blocked level
    assert not adjusts_by_blocks(cfg, None, 10**6)  # outside the cascade
    assert not adjusts_by_blocks(AdjustConfig(blocked_min_measures=None), "global", 10**9)  # off by default
    assert adjusts_by_blocks(AdjustConfig(blocked_min_measures=0), "global", 0)  # 0: always on those levels
