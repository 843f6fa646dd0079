"""The chip as the dense stage's unit of work: chips tile an image once; one call from images to points."""

from __future__ import annotations

import numpy as np
import pytest
from dense_scene import GSD_M

from mercury_dem.dense.chip import chip_grid, dense_chip
from mercury_dem.dense.disparity import MatcherSettings
from mercury_dem.dense.rectify import Chip
from mercury_dem.exceptions import GeometryError


def test_chip_interiors_tile_the_window_once() -> None:
    """Every pixel of the window is in exactly one chip's interior; edge chips are smaller."""
    chips = chip_grid(1000, 700, size=256, collar=16, window=(100, 50, 1000, 700))
    cover = np.zeros((700, 1000), int)
    for c in chips:
        cover[c.y0 : c.y0 + c.height, c.x0 : c.x0 + c.width] += 1
        assert c.collar == 16 and 0 < c.width <= 256 and 0 < c.height <= 256
    assert (cover[50:, 100:] == 1).all() and cover[:50].sum() == 0 and cover[:, :100].sum() == 0
    assert len(chips) == 4 * 3


def test_dense_chip_from_images_to_points_with_its_figures(lambert_pair) -> None:
    p = lambert_pair
    res = dense_chip(p.left_image, p.right_image, p.left, p.right, Chip(64, 64, 128, 128, 16),
                     surface_height=p.current_surface, height_margin_m=800.0,
                     settings=MatcherSettings(min_score=0.8, max_sigma_px=0.3), sigma_floor_px=0.2)
    s = res.summary()
    assert s["interior_pixels"] == pytest.approx(128 * 128, rel=0.01)
    assert s["points"] == len(res.points) <= s["matched"] <= s["interior_pixels"]
    assert s["points"] > 0.8 * 128 * 128 and set(s["holes"]) >= {"shadow", "no_match", "outside"}
    err = res.points.height - p.truth_height(res.points.lat, res.points.lon)
    assert np.sqrt(np.mean(err**2)) < 0.33 * GSD_M / np.tan(np.radians(25.0))
    # every point lies in the chip's interior (the collar is context only)
    lp = res.points.left_px
    assert (lp[:, 0] > 64 - 1.5).all() and (lp[:, 0] < 64 + 128 + 0.5).all()


def test_dense_chip_refuses_a_chip_off_the_body(lambert_pair) -> None:
    import dataclasses

    p = lambert_pair
    away = dataclasses.replace(p.left, position=-p.left.position)
    with pytest.raises(GeometryError):
        dense_chip(p.left_image, p.right_image, away, p.right, Chip(0, 0, 64, 64, 8))
