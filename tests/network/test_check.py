"""validate (cnetcheck): each defect found and counted exactly."""

from __future__ import annotations

import numpy as np

from mercury_dem.network import ControlNetwork, validate


def _sound():
    # images A,B,C linked by points 0,1; D,E linked by point 2 (a second island); F has no measure
    return ControlNetwork.from_arrays(
        ["A", "B", "C", "D", "E", "F"], [0, 1, 2],
        [0, 0, 1, 1, 2, 2], [0, 1, 1, 2, 3, 4],
        [10.0, 20, 30, 40, 50, 60], [10.0, 20, 30, 40, 50, 60],
        apriori_xyz=np.ones((3, 3)),
    )


def test_sound_network_statistics():
    rep = validate(_sound(), min_image_measures=2)
    assert rep.n_islands == 2 and rep.islands == [["A", "B", "C"], ["D", "E"]]
    assert rep.images_without_measures == ["F"]
    assert rep.images_few_measures == ["A", "C", "D", "E"]
    assert rep.n_duplicate_measures == 0 and rep.n_points_lt2 == 0 and rep.n_dangling_point_refs == 0
    assert not rep.ok and any("2 islands" in p for p in rep.problems())
    d = rep.to_dict()
    assert d["island_sizes"] == [3, 2] and d["islands_besides_largest"] == [["D", "E"]]
    one = validate(_sound().subset_images(["A", "B", "C"]))
    assert one.ok and one.n_islands == 1, one.summary()


def test_defects_are_counted():
    net = _sound()
    bad = ControlNetwork.from_arrays(
        net.image_ids, [0, 1, 2, 2],
        # measure 6 duplicates (point 0, image A); 7 points to point 9 (dangling); 8 to image 7 (dangling)
        # measure 9 is NaN; point 3 has a single measure (index 10) that lies outside its image (600 > 511.5)
        [0, 0, 1, 1, 2, 2, 0, 9, 1, 1, 3], [0, 1, 1, 2, 3, 4, 0, 0, 7, 0, 5],
        [10.0, 20, 30, 40, 50, 60, 11, 1, 1, np.nan, 600], [10.0, 20, 30, 40, 50, 60, 11, 1, 1, 5, 5],
    )
    rep = validate(bad, image_sizes={iid: (512, 512) for iid in net.image_ids.tolist()})
    assert rep.n_dangling_point_refs == 1 and rep.n_dangling_image_refs == 1
    assert rep.n_duplicate_measures == 1 and rep.duplicate_examples == [("0", "A")]
    assert rep.n_nonfinite_measures == 1
    assert rep.n_outside_image == 1 and rep.outside_by_image == {"F": 1}
    assert rep.n_duplicate_point_ids == 1
    assert rep.n_points_lt2 == 1 and rep.points_lt2_examples == ["2"]  # the second point with id 2
    assert rep.n_points_no_apriori == 4
    assert not rep.ok and len(rep.problems()) >= 5


def test_ignored_and_rejected_do_not_count():
    net = _sound().replace(measure_rejected=[False, True, False, False, False, False])
    rep = validate(net)
    # point 0 keeps one active measure (in A): A is cut off from B, an island of its own
    assert rep.n_points_lt2 == 1 and rep.n_active_measures == 5
    assert rep.islands == [["B", "C"], ["D", "E"], ["A"]]
    assert rep.images_without_measures == ["F"]


def test_large_network_is_fast():
    rng = np.random.default_rng(0)
    n, k, per = 200_000, 2000, 5
    mp = np.repeat(np.arange(n), per)
    mi = (rng.integers(0, k, n)[:, None] + np.arange(per)) % k
    net = ControlNetwork.from_arrays(np.array([f"I{i}" for i in range(k)]), np.arange(n), mp, mi.ravel(),
                                     rng.uniform(0, 1000, n * per), rng.uniform(0, 1000, n * per),
                                     apriori_xyz=np.ones((n, 3)))
    rep = validate(net, image_sizes=np.full((k, 2), 1024))
    assert rep.ok and rep.n_islands == 1 and rep.n_measures == 10**6
    assert rep.seconds < 10.0


def test_singular_parts_names_dropped_images_and_single_measure_points():
    from mercury_dem.network.check import singular_parts

    # A,B,C share point 10; point 11 is seen by C only; D has no measure
    net = ControlNetwork.from_arrays(
        ["A", "B", "C", "D"], [10, 11], [0, 0, 0, 1], [0, 1, 2, 2],
        [1.0, 2, 3, 4], [1.0, 2, 3, 4], apriori_xyz=np.ones((2, 3)),
    )
    used = net.drop_unused_images()
    out = singular_parts(net, used)
    assert out["images_without_measures"] == ["D"]
    assert out["single_measure_points"] == {"count": 1, "ids": [11]}
    assert isinstance(out["single_measure_points"]["ids"][0], int)  # JSON-able, not numpy
    capped = singular_parts(net, used, limit=0)
    assert capped["single_measure_points"] == {"count": 1, "ids": []}
    none = singular_parts(used, used)
    assert none["images_without_measures"] == []
