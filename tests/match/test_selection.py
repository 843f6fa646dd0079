"""Wide-convergence pairs matched only when no narrower route joins their images (match.selection)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from mercury_dem.config.match import MatchConfig
from mercury_dem.match import match_tile
from mercury_dem.match.selection import pair_convergences, redundant_reason, route_cover, wide_pairs


@pytest.fixture(scope="module")
def three_views() -> dict[str, Any]:
    """A nadir view and two views tilted 25 deg north and south of it (WAC 256^2, 1.8 km/px): the
    outer pair converges by ~50 deg, each with the nadir one by ~25 deg."""
    pytest.importorskip("mercury_dem.synth.render")
    from mercury_dem.synth.terrain import Surface, SurfaceParams
    from mercury_dem.validate.matching import convergent_views

    surface = Surface(SurfaceParams(seed=42))
    images, geom, truth = convergent_views(surface, (0.0, 25.0, -25.0), np.random.default_rng(3))
    return {"images": images, "geom": geom, "truth": truth}


PAIRS = [("v0", "v1"), ("v0", "v2"), ("v1", "v2")]


def test_convergence_and_cover_of_the_three_views(three_views: dict[str, Any]) -> None:
    """The convergences are the tilts' (to the a-priori pointing, 450 urad) and the nadir view, which
    looks at the same centre, sees nearly all of the outer pair's overlap; a view elsewhere sees none."""
    g = three_views["geom"]
    conv = pair_convergences(PAIRS, g, MatchConfig(), pointing_sigma_urad=450.0)
    np.testing.assert_allclose(conv, [25.0, 25.0, 50.0], atol=0.5)
    assert list(wide_pairs(conv, MatchConfig())) == [False, False, True]
    assert route_cover(g["v1"], g["v2"], g["v0"]) >= 0.9
    far = dataclasses.replace(g["v0"], position=-g["v0"].position)  # on the far side of the body
    assert route_cover(g["v1"], g["v2"], far) == 0.0


def test_a_route_counts_only_with_enough_matches_on_both_legs(three_views: dict[str, Any]) -> None:
    g, cfg = three_views["geom"], MatchConfig()
    conv = pair_convergences(PAIRS, g, cfg, pointing_sigma_urad=450.0)
    why = redundant_reason(2, PAIRS, conv, [400, 400, 0], g, cfg)
    assert why is not None and "v0" in why and "converge by 50 deg" in why and "redundant_convergence_deg 45" in why
    assert redundant_reason(2, PAIRS, conv, [400, cfg.redundant_route_min_matches - 1, 0], g, cfg) is None
    assert redundant_reason(2, PAIRS, conv, [400, 400, 0], g, dataclasses.replace(cfg, redundant_convergence_deg=20.0)) is None
    far = dict(g, v0=dataclasses.replace(g["v0"], position=-g["v0"].position))  # v0 sees none of the overlap
    assert redundant_reason(2, PAIRS, conv, [400, 400, 0], far, cfg) is None


def test_the_tile_skips_the_wide_pair_only_when_the_route_matched(three_views: dict[str, Any]) -> None:
    """Defaults: the two 25-deg pairs match, the 50-deg pair is skipped with the reason and its geometry
    recorded, and its images share points through v0's keypoints (tracks). With the rule off (180) it is
    matched; when v0 is unreadable (no route) it is matched too."""
    w = three_views
    cfg = MatchConfig(threads=1)
    m, reps = match_tile(w["images"], w["geom"], PAIRS, cfg, pointing_sigma_urad=450.0)
    assert [r.status for r in reps] == ["matched", "matched", "skipped"], [r.reason for r in reps]
    assert reps[2].reason.startswith("redundant") and reps[2].convergence_deg == pytest.approx(50.0, abs=0.5)
    assert np.isfinite(reps[2].incidence_difference_deg) and reps[2].overlap_apriori > 0.5
    # the v0 keypoints matched into both partners: the network's tracks join v1 and v2 through them
    a0 = m.feature_a[m.pair == 0]
    a1 = m.feature_a[m.pair == 1]
    shared = np.intersect1d(a0[a0 >= 0], a1[a1 >= 0])
    assert shared.size >= 100, shared.size

    _, reps_all = match_tile(w["images"], w["geom"], PAIRS, dataclasses.replace(cfg, redundant_convergence_deg=180.0), pointing_sigma_urad=450.0)
    assert [r.status for r in reps_all] == ["matched"] * 3

    no_v0 = dict(w["images"], v0=None)
    _, reps_no = match_tile(no_v0, w["geom"], PAIRS, cfg, pointing_sigma_urad=450.0)
    assert reps_no[2].status == "matched" and reps_no[0].status == "failed"
