"""merge_networks: joining tile networks by shared measures, across the seam and the pole."""

from __future__ import annotations

import numpy as np
import pytest
from network_world import all_pairs, make_matches, measure_sets, truth_of_measures

from mercury_dem.exceptions import NetworkError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.network import ControlNetwork, PointType, build_network, merge_networks, validate


def _tile_networks(w, tiles, id_starts=None):
    nets = []
    for t, refs in enumerate(tiles):
        pairs = [(a, b) for a, b in all_pairs(len(w.image_ids)) if a in refs or b in refs]
        m, _ = make_matches(w, pairs)
        start = (id_starts or [t * 100000 for t in range(len(tiles))])[t]
        nets.append(build_network(w.image_ids, m, w.camera, w.positions, w.rotations, point_id_start=start, datum_radius_m=DATUM_RADIUS_M).network)
    return nets


@pytest.mark.parametrize("world_name", ["seam_world", "pole_world"])
def test_tiles_merge_into_the_whole(world_name, request):
    """Tiles west/east of the seam (or around the pole) share the cross pairs; merged they equal the
    network built from all pairs at once."""
    w = request.getfixturevalue(world_name)
    nets = _tile_networks(w, [{0, 1, 2}, {3, 4, 5}])
    whole = build_network(w.image_ids, make_matches(w, all_pairs(6))[0], w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M).network
    merged, st = merge_networks(nets)
    assert measure_sets(merged) == measure_sets(whole)
    assert merged.n_points == whole.n_points and st.n_conflicts == 0 and not st.ids_renumbered
    assert st.n_measures_collapsed == sum(n.n_measures for n in nets) - merged.n_measures
    # joined points: a-priori is the measure-weighted mean of the tiles' (the same geometry here)
    t = truth_of_measures(w, merged)
    first = np.flatnonzero(np.r_[True, np.diff(merged.measure_point) > 0])
    err = np.linalg.norm(merged.apriori_xyz - w.truth[t[first]], axis=1)
    assert np.median(err) < 3 * w.sigma_px * w.gsd_m
    assert validate(merged).ok
    # the lon range straddles the seam (or the latitudes reach the pole): pixel-space joins do not care
    lat, lon, _ = merged.point_latlon()
    if world_name == "seam_world":
        assert lon.min() < 0.05 and lon.max() > 359.95
    else:
        assert lat.max() > 89.99


def test_merge_is_deterministic_and_order_independent(seam_world):
    nets = _tile_networks(seam_world, [{0, 1}, {2, 3}, {4, 5}])
    a, _ = merge_networks(nets)
    b, _ = merge_networks(nets)
    c, _ = merge_networks(nets[::-1])
    assert a.equals(b, check_metadata=True)
    assert measure_sets(a) == measure_sets(c)


def test_tolerance_decides_joins(seam_world):
    w = seam_world
    n1, n2 = _tile_networks(w, [{0, 1, 2}, {3, 4, 5}])
    rng = np.random.default_rng(3)
    # tile 2's measures moved by 0.3 px: still the same measures; their merged position is the mean
    d = rng.normal(0, 1, (n2.n_measures, 2))
    d *= 0.3 / np.linalg.norm(d, axis=1, keepdims=True)
    near = n2.replace(sample=n2.sample + d[:, 0], line=n2.line + d[:, 1])
    merged, st = merge_networks([n1, near], tolerance_px=1.0)
    whole_sets = measure_sets(merge_networks([n1, n2])[0])
    assert merged.n_points == len(whole_sets) and st.n_conflicts == 0
    # 1.5 px away: nothing joins (every point stays separate)
    far = n2.replace(sample=n2.sample + 1.5)
    merged2, st2 = merge_networks([n1, far], tolerance_px=1.0)
    assert merged2.n_points == n1.n_points + n2.n_points and st2.n_points_joined == 0


def _tiny(ids, pid, pts, imgs, s, l, images=("A", "B", "C")):
    return ControlNetwork.from_arrays(np.array(images), np.array(pid), np.array(pts), np.array(imgs),
                                      np.array(s, float), np.array(l, float))


def test_conflicting_join_drops_the_disagreeing_image():
    # P (net 1) = {A:(10,10), B:(50,50), C:(5,5)}; Q (net 2) = {A:(10.4,10), B:(80,80)}: the same feature in A,
    # two different ones in B -> B's measures of the merged point are a conflict, dropped and counted
    n1 = _tiny(None, [1], [0, 0, 0], [0, 1, 2], [10, 50, 5], [10, 50, 5])
    n2 = _tiny(None, [2], [0, 0], [0, 1], [10.4, 80], [10, 80])
    merged, st = merge_networks([n1, n2])
    assert st.n_conflicts == 1 and st.n_conflict_measures == 2
    assert merged.n_points == 1 and merged.point_ids.tolist() == [1]
    assert merged.image_ids[merged.measure_image].tolist() == ["A", "C"]
    np.testing.assert_allclose(merged.sample, [10.2, 5.0])


def test_point_ids_and_attributes():
    n1 = _tiny(None, [0, 1], [0, 0, 1, 1], [0, 1, 1, 2], [1, 2, 30, 40], [1, 2, 30, 40])
    n2 = _tiny(None, [0], [0, 0], [0, 1], [1, 99], [1, 99], images=("A", "C"))
    n1 = n1.replace(apriori_xyz=np.array([[1.0, 2, 3], [4, 5, 6]]), point_type=[2, 2])
    n2 = n2.replace(apriori_xyz=np.array([[4.0, 5, 6]]), point_type=[4], point_ignored=[True])
    merged, st = merge_networks([n1, n2])
    # n2's point joins n1's point 0 (shared measure A:(1,1)); weighted mean of a-priori 2:2 measures
    assert st.n_points_joined == 2 and merged.n_points == 2 and not st.ids_renumbered
    assert merged.point_ids.tolist() == [0, 1]
    np.testing.assert_allclose(merged.apriori_xyz[0], [2.5, 3.5, 4.5])
    assert merged.point_type[0] == PointType.FIXED and not merged.point_ignored[0]
    assert merged.image_ids.tolist() == ["A", "B", "C"]
    # distinct points with the same id: 'keep' refuses, 'auto' renumbers
    n3 = _tiny(None, [1], [0, 0], [0, 1], [200, 200], [200, 200])
    with pytest.raises(NetworkError, match="collide"):
        merge_networks([n1, n3], point_ids="keep")
    m2, st2 = merge_networks([n1, n3])
    assert st2.ids_renumbered and m2.point_ids.tolist() == [0, 1, 2]


def test_string_and_int_ids_mix_as_strings():
    n1 = _tiny(None, ["AS15_1"], [0, 0], [0, 1], [1, 2], [1, 2])
    n2 = _tiny(None, [7], [0, 0], [0, 1], [50, 60], [50, 60])
    merged, _ = merge_networks([n1, n2])
    assert merged.point_ids.tolist() == ["AS15_1", "7"]


def test_dangling_indices_are_refused():
    bad = _tiny(None, [0], [0, 0], [0, 3], [1, 2], [1, 2])
    with pytest.raises(NetworkError, match="network 1 .*dangling"):
        merge_networks([_tiny(None, [5], [0, 0], [0, 1], [1, 2], [1, 2]), bad])
