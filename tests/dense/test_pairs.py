"""Stereo-pair selection: the geometry of each candidate and the stated reason of each rejection."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from dense_scene import site_frame, sun_at, view

from mercury_dem.dense.pairs import (
    REJECTED,
    SELECTED,
    PairRejection,
    StereoPairCriteria,
    candidate_table,
    parallax_height_ratio,
    select_stereo_pairs,
)


def test_parallax_height_ratio_is_the_base_height_ratio_of_symmetric_and_vertical_pairs() -> None:
    centre, east, north, up = site_frame()
    h = 1.0e6
    for c in (10.0, 25.0, 50.0):
        t = np.radians(c / 2)
        a = centre + h * (up + np.tan(t) * north)
        b = centre + h * (up - np.tan(t) * north)
        assert parallax_height_ratio(centre, a, b) == pytest.approx(2 * np.tan(t), rel=1e-9)
    # a nadir camera and one displaced by the base B at the same height: B / H
    assert parallax_height_ratio(centre, centre + h * up, centre + h * up + 0.4 * h * east) == pytest.approx(0.4, rel=1e-9)
    # a camera at the horizon (no vertical component) gives NaN
    assert np.isnan(parallax_height_ratio(centre, centre + h * up, centre + h * north))


def test_pairs_are_selected_or_rejected_for_the_stated_reasons() -> None:
    sun = sun_at(45.0, 90.0)
    geometry = {
        "nadir": view(0.0, sun),
        "north25": view(25.0, sun),                     # parallax/height tan 25 = 0.466: in the best band
        "north4": view(4.0, sun),                       # 0.07 with nadir: too little parallax
        "coarse": view(25.0, sun, gsd_m=600.0),          # 3x the pixel scale of nadir
        "evening": view(-25.0, sun_at(45.0, 150.0)),    # the sun 60 deg round in azimuth
        "low_sun": view(-25.0, sun_at(75.0, 90.0)),     # incidence 75 vs 45
    }
    far = dataclasses.replace(geometry["nadir"], position=-geometry["nadir"].position)
    geometry["far_side"] = far
    cand = [("nadir", "north25"), ("nadir", "north4"), ("nadir", "coarse"), ("nadir", "evening"),
            ("nadir", "low_sun"), ("nadir", "far_side"), ("nadir", "missing")]
    rows = {(r.left, r.right): r for r in select_stereo_pairs(geometry, StereoPairCriteria(), cand)}
    good = rows[("nadir", "north25")]
    assert good.status == SELECTED and good.rank == 1 and good.reason == ""
    assert good.parallax_height == pytest.approx(np.tan(np.radians(25.0)), abs=0.01)
    assert good.convergence_deg == pytest.approx(25.0, abs=0.1)
    assert good.scale_ratio == pytest.approx(1.0, abs=0.15) and good.overlap > 0.8
    assert good.pixel_scale_left_m == pytest.approx(200.0, rel=0.01)
    assert rows[("nadir", "north4")].reason.startswith("parallax/height 0.07")
    assert "pixel-scale ratio" in rows[("nadir", "coarse")].reason and "> 2.5" in rows[("nadir", "coarse")].reason
    evening = rows[("nadir", "evening")].reason
    assert "sun-azimuth difference 60.0 deg > 30" in evening and "parallax" not in evening
    assert "incidence difference 30.0 deg > 20" in rows[("nadir", "low_sun")].reason
    assert rows[("nadir", "far_side")].status == REJECTED and rows[("nadir", "far_side")].reason
    assert rows[("nadir", "missing")].reason == "no adjusted geometry for missing"
    assert all(r.rank == 0 for r in rows.values() if r.status == REJECTED)
    # the kinds are set where each test fails (the report counts them; nothing parses the reason text)
    kinds = {k: r.rejections for k, r in rows.items()}
    assert kinds[("nadir", "north25")] == ()
    assert kinds[("nadir", "north4")] == (PairRejection.PARALLAX_HEIGHT,)
    assert PairRejection.SCALE_RATIO in kinds[("nadir", "coarse")]
    assert PairRejection.SUN_AZIMUTH in kinds[("nadir", "evening")]
    assert PairRejection.PARALLAX_HEIGHT not in kinds[("nadir", "evening")]
    assert PairRejection.INCIDENCE in kinds[("nadir", "low_sun")]
    assert kinds[("nadir", "far_side")] == (PairRejection.PAIR_GEOMETRY,)
    assert kinds[("nadir", "missing")] == (PairRejection.NO_GEOMETRY,)
    for r in rows.values():  # one kind per failed test, as many as the reason's parts
        assert len(r.rejections) == (len(r.reason.split("; ")) if r.reason else 0)
    table = candidate_table(list(rows.values()))
    assert table["status"].tolist().count(SELECTED) == 1 and table["parallax_height"].shape == (7,)


def test_ranking_prefers_the_best_band_and_the_cap_names_the_full_image() -> None:
    sun = sun_at(45.0, 90.0)
    geometry = {"a": view(0.0, sun), "b": view(25.0, sun), "c": view(-12.0, sun), "d": view(40.0, sun)}
    rows = select_stereo_pairs(geometry, StereoPairCriteria(max_pairs_per_image=1))
    by = {(r.left, r.right): r for r in rows}
    # a-b (0.47) is in the best band; a-c (0.21) and a-d (0.84) are accepted but ranked lower
    assert by[("a", "b")].rank == 1
    assert by[("a", "c")].reason == "cap: image a is already in 1 better-ranked pairs"
    assert by[("a", "c")].rejections == (PairRejection.CAP,)
    selected = [r for r in rows if r.status == SELECTED]
    used = [x for r in selected for x in (r.left, r.right)]
    assert len(used) == len(set(used))  # the cap: every image in at most one selected pair
    scores = {(r.left, r.right): r.score for r in rows if np.isfinite(r.score)}
    assert scores[("a", "b")] > scores[("a", "c")] and scores[("a", "b")] > scores[("a", "d")]


def test_criteria_refuse_an_inconsistent_band() -> None:
    with pytest.raises(ValueError, match="best low"):
        StereoPairCriteria(best_parallax_height=(0.05, 0.6))
