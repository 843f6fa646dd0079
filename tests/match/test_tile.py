"""match_tile: bad input as per-pair reasons (issue 4, section 6), threads, feature ids, the PairMatches columns."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.match import match_pair, match_tile
from mercury_dem.match.result import PairFailure


def _ids(world: Any, name: str) -> tuple[str, str]:
    return world.pairs[world.names.index(name)]


def test_bad_images_fail_their_pairs_and_the_tile_goes_on(pair_world: Any) -> None:
    a, b = _ids(pair_world, "stereo")
    img = dict(pair_world.images)
    geom = dict(pair_world.geometry)
    shape = img[a].shape
    bad = {
        "blank": np.zeros(shape, np.uint16),
        "saturated": np.full(shape, 4095, np.uint16),
        "textureless": (1000 + np.random.default_rng(0).integers(0, 3, shape)).astype(np.uint16),
        "unreadable": None,
        "truncated": img[b][: shape[0] // 2],
    }
    pairs = [(a, b)]
    for k, v in bad.items():
        img[k] = v
        geom[k] = geom[b]
        pairs.append((a, k))
    pairs.append((a, "not-in-tile"))
    matches, reports = match_tile(img, geom, pairs, MatchConfig(threads=2), pointing_sigma_urad=450.0)
    assert reports[0].status == "matched" and reports[0].n_matches >= 20
    for rep, key in zip(reports[1:6], bad):
        assert rep.status == "failed"
        assert rep.match_id == key and key in rep.reason, rep.reason
    assert "blank" in reports[1].reason and "saturated" in reports[2].reason
    assert "textureless" in reports[3].reason and "unreadable" in reports[4].reason
    assert "truncated" in reports[5].reason
    assert "not-in-tile" in reports[6].reason
    assert set(np.unique(matches.pair).tolist()) == {0}


def test_wrong_a_priori_overlap_is_a_reason(pair_world: Any) -> None:
    a, b = _ids(pair_world, "stereo")
    g = pair_world.geometry[b]
    # A-priori pointing 30 deg off (the WAC field is ~10.5 deg): no overlap at all.
    away = dataclasses.replace(g, rotation=rotation_from_angles(np.array([0.0, np.radians(30.0), 0.0])) @ g.rotation)
    r = match_pair(pair_world.images[a], pair_world.images[b], pair_world.geometry[a], away, MatchConfig(), pointing_sigma_urad=450.0)
    assert r.report.status == "failed" and "no a-priori overlap" in r.report.reason
    assert r.report.failure == PairFailure.NO_PRETRANSFORM
    # A-priori overlap that is wrong by ~40 px (far beyond the guidance window): no false matches.
    off = dataclasses.replace(g, rotation=rotation_from_angles(np.array([0.03, 0.0, 0.0])) @ g.rotation)
    r = match_pair(pair_world.images[a], pair_world.images[b], pair_world.geometry[a], off, MatchConfig(), pointing_sigma_urad=450.0)
    assert r.report.status == "failed" and "too few matches" in r.report.reason
    assert r.report.failure == PairFailure.TOO_FEW_MATCHES
    assert r.points_ref.shape == (0, 2)


def test_illumination_limits_skip_with_reason(pair_world: Any) -> None:
    a, b = _ids(pair_world, "inc30_70")
    cfg = MatchConfig(max_incidence_difference_deg=20.0)
    r = match_pair(pair_world.images[a], pair_world.images[b], pair_world.geometry[a], pair_world.geometry[b], cfg, pointing_sigma_urad=450.0)
    assert r.report.status == "skipped" and "max_incidence_difference_deg" in r.report.reason
    assert r.report.failure == PairFailure.INCIDENCE
    assert r.report.incidence_difference_deg == pytest.approx(40.0, abs=3.0)


def test_threads_do_not_change_results_and_feature_ids_are_stable(pair_world: Any) -> None:
    names = ["stereo", "scale2_finer_rot45", "azimuth45", "scale2_rot30"]
    pairs = [pair_world.pairs[pair_world.names.index(n)] for n in names]
    m1, r1 = match_tile(pair_world.images, pair_world.geometry, pairs, MatchConfig(threads=1), pointing_sigma_urad=450.0)
    m2, r2 = match_tile(pair_world.images, pair_world.geometry, pairs, MatchConfig(threads=2), pointing_sigma_urad=450.0)
    for k, v in m1.columns().items():
        np.testing.assert_array_equal(v, m2.columns()[k], err_msg=k)
    assert [r.n_matches for r in r1] == [r.n_matches for r in r2]
    # One keypoint id = one position of that image, across all pairs of the tile.
    img = np.concatenate([m1.image_a, m1.image_b])
    fid = np.concatenate([m1.feature_a, m1.feature_b])
    pos = np.concatenate([np.stack([m1.sample_a, m1.line_a], -1), np.stack([m1.sample_b, m1.line_b], -1)])
    known = fid >= 0
    key = img[known] * 10**6 + fid[known]
    _, first = np.unique(key, return_index=True)
    inv = np.unique(key, return_inverse=True)[1]
    assert np.abs(pos[known] - pos[known][first][inv]).max() == 0.0
    # Exactly one side of every match carries the id (the side kept in its own geometry).
    assert np.all((m1.feature_a >= 0) != (m1.feature_b >= 0))
    assert len(np.unique(key)) < known.sum()  # the shared reference makes ids repeat across pairs


def test_tile_matches_feed_build_network(pair_world: Any) -> None:
    build = pytest.importorskip("mercury_dem.network.build")
    pairs = [pair_world.pairs[pair_world.names.index(n)] for n in ("stereo", "scale2_rot30")]
    m, _ = match_tile(pair_world.images, pair_world.geometry, pairs, MatchConfig(threads=2), pointing_sigma_urad=450.0)
    ids = list(m.image_ids)
    g = pair_world.geometry
    out = build.build_network(
        ids, m, [g[i].camera for i in ids], np.array([g[i].position for i in ids]),
        np.array([g[i].rotation for i in ids]),
     datum_radius_m=DATUM_RADIUS_M)
    assert out.network.n_points > 50
