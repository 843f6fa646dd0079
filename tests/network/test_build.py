"""build_network: tracks from matches, conflicts, a-priori coordinates by ray intersection."""

from __future__ import annotations

import numpy as np
import pytest
from network_world import all_pairs, make_matches, make_world, truth_of_measures

from mercury_dem.exceptions import NetworkError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.pose import pixel_rays
from mercury_dem.network import PairMatches, build_network, triangulate_points, validate


def _point_truth(world, net):
    t = truth_of_measures(world, net)
    assert np.all(t >= 0)
    # every point's measures come from one truth point (purity)
    lo = np.full(net.n_points, np.iinfo(np.int64).max)
    hi = np.full(net.n_points, -1)
    np.minimum.at(lo, net.measure_point, t)
    np.maximum.at(hi, net.measure_point, t)
    assert np.array_equal(lo, hi), "a network point mixes several ground features"
    return lo


@pytest.mark.parametrize("world_name", ["seam_world", "pole_world"])
@pytest.mark.parametrize("known", [True, False])
def test_tracks_and_apriori_recover_truth(world_name, known, request):
    w = request.getfixturevalue(world_name)
    m, _ = make_matches(w, all_pairs(6), known_features=known)
    net, st = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    assert st.n_conflicts == 0 and st.n_matches_invalid == 0
    truth = _point_truth(w, net)
    seen = np.flatnonzero(w.visible.sum(0) >= 2)
    assert np.array_equal(np.sort(truth), seen), "one point per ground feature seen twice"
    assert np.array_equal(net.measures_per_point(), w.visible[:, truth].sum(0))
    assert validate(net).ok
    # a-priori from exact poses: error set by the pixel noise. Rays converge by ~33 deg
    # between the widest cameras; sigma_px * gsd is ~1 m, so a few metres at most.
    err = np.linalg.norm(net.apriori_xyz - w.truth[truth], axis=1)
    scale = w.sigma_px * w.gsd_m
    assert np.median(err) < 3 * scale
    assert err.max() < 15 * scale
    assert st.n_triangulated == net.n_points


def test_point_ids_and_order(seam_world):
    w = seam_world
    m, _ = make_matches(w, all_pairs(6))
    net, _ = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, point_id_start=1000, datum_radius_m=DATUM_RADIUS_M)
    assert net.point_ids[0] == 1000 and np.all(np.diff(net.point_ids) == 1)
    key = net.measure_point * net.n_images + net.measure_image
    assert np.all(np.diff(key) > 0), "measures sorted by (point, image), no duplicates"
    # deterministic
    net2, _ = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, point_id_start=1000, datum_radius_m=DATUM_RADIUS_M)
    assert net.equals(net2)


def test_conflicting_match_is_split_not_merged(seam_world):
    w = seam_world
    m, pt = make_matches(w, all_pairs(6))
    # a wrong match: image 0's feature of point a matched to image 1's feature of point b
    a, b = 10, 20
    bad = PairMatches([0], [1], [w.observed[0, a, 0]], [w.observed[0, a, 1]], [w.observed[1, b, 0]],
                      [w.observed[1, b, 1]], [a], [b])
    net, st = build_network(w.image_ids, PairMatches.concatenate([m, bad]), w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    # the wrong match has no triangle support inside the conflicting track: removed, both points intact
    assert st.n_links_pruned == 1 and st.n_conflicts == 0
    truth = _point_truth(w, net)  # purity: no point mixes a and b
    counts = dict(zip(truth.tolist(), net.measures_per_point().tolist()))
    assert counts[a] == w.visible[:, a].sum() and counts[b] == w.visible[:, b].sum()
    assert validate(net).ok


def _rows(o, rows):
    """PairMatches from (image_a, point_a, image_b, point_b) rows of observed pixels, keypoint id = point."""
    r = np.array(rows)
    return PairMatches(r[:, 0], r[:, 2], o[r[:, 0], r[:, 1], 0], o[r[:, 0], r[:, 1], 1], o[r[:, 2], r[:, 3], 0],
                       o[r[:, 2], r[:, 3], 1], r[:, 1], r[:, 3])


def test_unsupported_ambiguity_is_cut(seam_world):
    """Image 0's feature matched to two features of image 1 and nothing else: neither match has
    support, both are removed and the lone observations dropped (counted)."""
    w = seam_world
    a, b = 10, 20
    m = _rows(w.observed, [(0, a, 1, a), (0, a, 1, b), (2, a, 3, a)])
    net, st = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    assert st.n_links_pruned == 2 and st.n_conflicts == 0 and st.n_short_tracks == 3
    assert net.n_points == 1 and set(net.image_ids[net.measure_image].tolist()) == {"IMG002", "IMG003"}


def test_supported_conflict_drops_the_ambiguous_image(seam_world):
    """Two features of image 1 both supported by triangles: the conflict cannot be cut by
    support, so image 1's observations of that track are dropped and counted."""
    w = seam_world
    a, b = 10, 20
    m = _rows(w.observed, [(0, a, 1, a), (0, a, 1, b), (2, a, 1, a), (2, a, 1, b), (0, a, 2, a)])
    net, st = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    assert st.n_links_pruned == 0 and st.n_conflicts == 1 and st.n_conflict_observations == 4
    assert net.n_points == 1 and set(net.image_ids[net.measure_image].tolist()) == {"IMG000", "IMG002"}
    assert np.all(truth_of_measures(w, net) == a)


def test_unknown_features_join_within_tolerance_only(seam_world):
    w = seam_world
    m, _ = make_matches(w, [(0, 1), (1, 2)], known_features=False)
    net, st = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    # tracks run through image 1: 3 measures per point seen in 0, 1 and 2
    assert np.all(net.measures_per_point() <= 3) and np.any(net.measures_per_point() == 3)
    # shift image 1's pixels of pair (1, 2) by 1.5 px: beyond the tolerance, the tracks stop joining
    shifted = PairMatches(m.image_a, m.image_b, np.where(m.image_a == 1, m.sample_a + 1.5, m.sample_a), m.line_a,
                          m.sample_b, m.line_b)
    net2, _ = build_network(w.image_ids, shifted, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    assert np.all(net2.measures_per_point() == 2)


def test_invalid_matches_are_counted_or_rejected(seam_world):
    w = seam_world
    m = PairMatches([0, 0, 1], [1, 0, 2], [1.0, 2.0, np.nan], [1.0, 2.0, 3.0], [5.0, 6.0, 7.0], [5.0, 6.0, 7.0])
    _, st = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, datum_radius_m=DATUM_RADIUS_M)
    assert st.n_matches_invalid == 2  # a self-match and a NaN pixel
    with pytest.raises(NetworkError, match="image_b=9"):
        build_network(w.image_ids, PairMatches([0], [9], [1.0], [1.0], [1.0], [1.0]), w.camera, w.positions,
                      w.rotations, datum_radius_m=DATUM_RADIUS_M)


def test_single_ray_and_weak_geometry_land_on_datum(seam_world):
    w = seam_world
    px = w.observed[0, :5]
    mp = np.arange(5)
    xyz, method = triangulate_points(mp, np.zeros(5, np.int64), px, w.camera, w.positions, w.rotations, 5, datum_radius_m=DATUM_RADIUS_M)
    assert np.all(method == 1)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), DATUM_RADIUS_M, rtol=1e-12)
    o, d = pixel_rays(w.camera, w.positions[0], w.rotations[0], px)
    off = (xyz - o) - np.sum((xyz - o) * d, axis=1, keepdims=True) * d
    assert np.abs(off).max() < 1e-3, "the datum point lies on the ray"
    # two cameras 1 m apart: convergence far below 1 deg -> datum, not a wild intersection
    pos = np.stack([w.positions[0], w.positions[0] + [1.0, 0, 0]])
    rot = np.stack([w.rotations[0], w.rotations[0]])
    xyz2, method2 = triangulate_points(np.array([0, 0]), np.array([0, 1]), np.stack([px[0], px[0]]), w.camera, pos,
                                       rot, 1, datum_radius_m=DATUM_RADIUS_M)
    assert method2[0] == 1 and abs(np.linalg.norm(xyz2[0]) - DATUM_RADIUS_M) < 1e-6


def test_more_noise_more_error():
    """The a-priori error scales with the injected pixel noise."""
    errs = []
    for sigma in (0.1, 1.0):
        w = make_world(10.0, 200.0, n_points=200, sigma_px=sigma, seed=5)
        m, _ = make_matches(w, all_pairs(6))
        net, _ = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, tolerance_px=10 * sigma, datum_radius_m=DATUM_RADIUS_M)
        t = truth_of_measures(w, net)
        first = np.flatnonzero(np.r_[True, np.diff(net.measure_point) > 0])
        errs.append(np.median(np.linalg.norm(net.apriori_xyz - w.truth[t[first]], axis=1)))
    assert 5 < errs[1] / errs[0] < 20
