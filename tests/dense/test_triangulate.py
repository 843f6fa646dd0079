"""Triangulation of dense matches: heights against the synthetic truth, and a stated precision that means
what it says (issue 31, 'Done when' 2: share beyond 3 sigma <= 1 %, true RMS / stated RMS in 0.7-1.5).

The stated precision uses ``sigma_floor_px = 0.2``: the floor of *noise-free* Lambert renderings of this
pair, measured as the refinement's disparity error (0.18-0.19 px RMS; 0.05 px where the disparity is flat,
0.48 px on the steepest tenth of the relief, where the tilted view foreshortens the window; a finer render
grid does not move it: ``workflows/benchmarks/render_agreement.py``, docs/design/dense.md). It is a property
of the synthetic pair, stated here, not fitted to the figures asserted below.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from dense_scene import GSD_M, chip_of

from mercury_dem.dense.disparity import MatcherSettings, dense_disparity
from mercury_dem.dense.triangulate import (
    PointFilter,
    filter_points,
    intersect_rays,
    stated_height_sigma,
    triangulate_chip,
)

RENDER_FLOOR_PX = 0.2
PARALLAX_HEIGHT = float(np.tan(np.radians(25.0)))
#: metres of height per pixel of disparity in this pair
M_PER_PX = GSD_M / PARALLAX_HEIGHT
SETTINGS = MatcherSettings(min_score=0.8, max_sigma_px=0.3)


def test_intersect_rays_midpoint_miss_and_angle() -> None:
    p = np.array([[1.0, 2.0, 3.0], [-5.0, 0.0, 10.0]])
    d1 = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    a = np.radians(30.0)
    d2 = np.array([[np.sin(a), 0.0, np.cos(a)], [np.cos(a), np.sin(a), 0.0]])
    gap = np.array([[0.0, 0.4, 0.0], [0.0, 0.0, 0.4]])   # perpendicular to both rays
    o1 = p - 100.0 * d1 + gap / 2
    o2 = p - 70.0 * d2 - gap / 2
    x, miss, angle = intersect_rays(o1, d1, o2, d2)
    np.testing.assert_allclose(x, p, atol=1e-9)
    np.testing.assert_allclose(miss, 0.4, atol=1e-9)
    np.testing.assert_allclose(angle, 30.0, atol=1e-9)
    assert np.isnan(intersect_rays(o1[:1], d1[:1], o1[:1] + 1.0, d1[:1])[0]).all()  # parallel rays


def dense_points(pair: Any, floor_px: float = RENDER_FLOOR_PX, right: Any = None) -> tuple[Any, np.ndarray]:
    rect = chip_of(pair)
    dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                         rect.disparity_max_px, SETTINGS)
    pts = triangulate_chip(rect, pair.left, right or pair.right, dm.disparity, dm.sigma_px, dm.score,
                           sigma_floor_px=floor_px)
    return pts, pts.height - pair.truth_height(pts.lat, pts.lon)


def calibration(pts: Any, err: np.ndarray) -> tuple[float, float, float]:
    """(true RMS, true RMS / stated RMS, share of |error| > 3 stated sigma)."""
    rms = float(np.sqrt(np.mean(err**2)))
    return rms, rms / float(np.sqrt(np.mean(pts.sigma_h_m**2))), float(np.mean(np.abs(err) > 3 * pts.sigma_h_m))


@pytest.fixture(scope="module")
def lambert_points(lambert_pair):
    return dense_points(lambert_pair)


@pytest.fixture(scope="module")
def default_points(default_pair):
    return dense_points(default_pair)


def test_dense_heights_against_the_truth_lambert(lambert_points) -> None:
    """Shading the same in both views: heights within a third of a pixel of disparity (~140 m at
    200 m/px and parallax/height 0.47), nearly every interior pixel a point, the rays meeting within a
    tenth of a pixel, every angle the pair's convergence.
    """
    pts, err = lambert_points
    rms, ratio, beyond = calibration(pts, err)
    assert len(pts) > 0.85 * 224 * 224
    assert rms < 0.33 * M_PER_PX, rms                     # measured 110 m (0.26 px)
    assert abs(err.mean()) < 0.07 * M_PER_PX, err.mean()  # measured +22 m
    assert np.median(pts.miss_m) < 0.1 * GSD_M
    np.testing.assert_allclose(np.median(pts.angle_deg), 25.0, atol=0.5)
    assert 0.7 <= ratio <= 1.5, ratio                     # measured 1.02


@pytest.mark.xfail(strict=True, reason="issue 31 target not met: 2.2 % of the points are beyond 3 sigma "
                   "(crater rims, where the window model cannot follow the relief's kink)")
def test_share_beyond_three_sigma_lambert(lambert_points) -> None:
    pts, err = lambert_points
    assert calibration(pts, err)[2] <= 0.01


def test_dense_heights_against_the_truth_default_photometry(default_points) -> None:
    """The renderer's Lommel-Seeliger mix shades each slope differently in the two views: the error
    doubles and half the chip is rejected by the score/precision limits.
    """
    pts, err = default_points
    rms, ratio, beyond = calibration(pts, err)
    assert len(pts) > 0.4 * 224 * 224
    assert rms < 0.66 * M_PER_PX, rms                     # measured 224 m (0.52 px)
    assert abs(err.mean()) < 0.07 * M_PER_PX


@pytest.mark.xfail(strict=True, reason="issue 31 target not met with view-dependent photometry: true/stated "
                   "RMS 1.9, 4.9 % beyond 3 sigma; the stated precision does not model the shading difference")
def test_precision_calibration_default_photometry(default_points) -> None:
    pts, err = default_points
    _, ratio, beyond = calibration(pts, err)
    assert 0.7 <= ratio <= 1.5 and beyond <= 0.01


def test_filters_remove_points_for_their_stated_reasons(lambert_pair, lambert_points) -> None:
    pts, _ = lambert_points
    kept, removed = filter_points(pts, lambert_pair.left)
    assert removed == {"miss": 0, "angle": 0, "sigma_h": 0} and len(kept) == len(pts)
    _, removed = filter_points(pts, lambert_pair.left, PointFilter(min_angle_deg=30.0))
    assert removed["angle"] == len(pts)
    kept, removed = filter_points(pts, lambert_pair.left, PointFilter(max_sigma_h_m=100.0))
    assert 0 < removed["sigma_h"] < len(pts) and (kept.sigma_h_m <= 100.0).all()
    # a right camera displaced 1.5 km across the epipolar plane: the rays miss by ~1.5 km, the filter
    # (1 left pixel = 200 m) removes them
    r, le = lambert_pair.right, lambert_pair.left
    across = np.cross(r.position - le.position, -le.position)
    moved = dataclasses.replace(r, position=r.position + 1500.0 * across / np.linalg.norm(across))
    rect = chip_of(lambert_pair)
    dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                         rect.disparity_max_px, SETTINGS)
    bad = triangulate_chip(rect, lambert_pair.left, moved, dm.disparity, dm.sigma_px, dm.score)
    assert np.median(bad.miss_m) > 1000.0
    kept, removed = filter_points(bad, lambert_pair.left)
    assert removed["miss"] > 0.99 * len(bad)


def test_a_coarser_right_image_across_the_other_axis(coarse_east_pair) -> None:
    """Parallax along the samples and a right image 1.6x coarser: the rectification still leaves < 0.1 px
    of vertical disparity; the left chip is blurred to the right's resolution and the floor counted in the
    coarser image's pixels, so the precision still means what it says (measured: 134 m RMSE, true/stated
    1.12, 1.0 % beyond 3 sigma; without the blur 170 m and 15 %).
    """
    from dense_scene import true_disparity

    p = coarse_east_pair
    rect = chip_of(p)
    assert rect.coarser_px == pytest.approx(1.6, abs=0.1)
    _, vertical = true_disparity(p, rect)
    v0, v1, u0, u1 = rect.interior
    assert np.sqrt(np.mean(vertical[v0:v1, u0:u1] ** 2)) < 0.1
    pts, err = dense_points(p)
    rms, ratio, beyond = calibration(pts, err)
    m_per_px = 1.6 * GSD_M / 0.577  # rectified pixels of the coarser image over the parallax/height ratio
    assert len(pts) > 0.7 * 224 * 224
    assert rms < 0.33 * m_per_px, rms
    assert 0.7 <= ratio <= 1.5, ratio
    assert beyond <= 0.02, beyond


def test_the_stated_precision_is_rebuilt_from_its_stored_parts(lambert_pair, lambert_points) -> None:
    """``sigma_h_m = m_per_px * hypot(sigma_scale * sigma_match_px, floor * coarser_px)``: the cloud keeps the
    matcher's own sigma and |dh/dd| so the precision model can be recalibrated on it (docs/design/dense.md);
    ``sigma_scale`` multiplies the matcher's term only.
    """
    pts, _ = lambert_points
    rect = chip_of(lambert_pair)
    assert pts.sigma_match_px is not None and pts.m_per_px is not None
    np.testing.assert_allclose(pts.sigma_h_m, pts.m_per_px * np.hypot(pts.sigma_match_px,
                                                                      RENDER_FLOOR_PX * rect.coarser_px), rtol=1e-9)
    # |dh/dd| is the pair's metres of height per pixel of disparity (pixel scale over parallax/height)
    assert np.median(pts.m_per_px) == pytest.approx(M_PER_PX, rel=0.05)
    dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                         rect.disparity_max_px, SETTINGS)
    twice = triangulate_chip(rect, lambert_pair.left, lambert_pair.right, dm.disparity, dm.sigma_px, dm.score,
                             sigma_floor_px=0.0, sigma_scale=2.0)
    once = triangulate_chip(rect, lambert_pair.left, lambert_pair.right, dm.disparity, dm.sigma_px, dm.score,
                            sigma_floor_px=0.0)
    np.testing.assert_allclose(twice.sigma_h_m, 2.0 * once.sigma_h_m, rtol=1e-12)
    # the height floor and the cap act on the metres, after |dh/dd| * sigma_d
    capped = triangulate_chip(rect, lambert_pair.left, lambert_pair.right, dm.disparity, dm.sigma_px, dm.score,
                              sigma_floor_px=0.0, sigma_height_floor_m=40.0, sigma_height_cap_m=60.0)
    np.testing.assert_allclose(capped.sigma_h_m, np.minimum(np.hypot(once.sigma_h_m, 40.0), 60.0), rtol=1e-12)
    assert (capped.sigma_h_m == 60.0).any() and (capped.sigma_h_m < 60.0).any()
    kept, _ = filter_points(twice, lambert_pair.left)
    assert kept.sigma_match_px is not None and len(kept.sigma_match_px) == len(kept)


def test_height_floor_and_cap_make_a_mixed_cloud_honest() -> None:
    """A cloud as the tiny mission's (docs/design/dense.md): each point's height error is its matching error
    (``m_per_px`` x 0.2 px) plus relief within the window that no window matcher resolves (300 m), and the stage's
    range filter keeps only points within R = 2 km of the surface the search was centred on. Weak pairs
    (10 km per pixel of disparity) are then uniform within +-R. ``stated_height_sigma`` with the relief as the
    height floor and R/sqrt(3) as the cap states both kinds right; the disparity term alone does not.
    """
    rng = np.random.default_rng(3)
    n, sigma_px, relief, r = 200_000, 0.2, 300.0, 2000.0
    mpp = np.where(np.arange(n) < n // 2, 1000.0, 10_000.0)
    err = mpp * sigma_px * rng.standard_normal(n) + relief * rng.standard_normal(n)
    keep = np.abs(err) <= r
    err, mpp = err[keep], mpp[keep]
    stated = stated_height_sigma(mpp * sigma_px, relief, r / np.sqrt(3.0))
    bare = mpp * sigma_px
    for part in (mpp == 1000.0, mpp == 10_000.0):
        ratio = np.sqrt(np.mean(err[part] ** 2) / np.mean(stated[part] ** 2))
        assert 0.9 <= ratio <= 1.1, ratio
        assert np.mean(np.abs(err[part]) > 3 * stated[part]) <= 0.01
    # without the floor the good pair is overconfident, without the cap the weak pair is far too modest
    good, weak = mpp == 1000.0, mpp == 10_000.0
    assert np.sqrt(np.mean(err[good] ** 2) / np.mean(bare[good] ** 2)) > 1.5
    assert np.sqrt(np.mean(err[weak] ** 2) / np.mean(bare[weak] ** 2)) < 0.7
