"""Chip rectification about the current surface: epipolar lines horizontal, the search range and memory stated."""

from __future__ import annotations

import numpy as np
import pytest
from dense_scene import GSD_M, chip_of, true_disparity

from mercury_dem.dense.rectify import Chip, rectified_to_images, rectify_chip
from mercury_dem.exceptions import GeometryError


def test_rectified_chip_puts_the_true_parallax_on_rows(lambert_pair) -> None:
    rect = chip_of(lambert_pair)
    assert rect.left.shape == rect.right.shape and 256 <= min(rect.left.shape) <= max(rect.left.shape) <= 260
    assert rect.interior_mask().sum() == pytest.approx(224 * 224, rel=0.01)
    d, vertical = true_disparity(lambert_pair, rect)
    v0, v1, u0, u1 = rect.interior
    d, vertical = d[v0:v1, u0:u1], vertical[v0:v1, u0:u1]
    # the truth's vertical disparity is the rectification error: a tenth of a pixel, as S2P's
    assert np.sqrt(np.mean(vertical**2)) < 0.1 and np.abs(vertical).max() < 0.3
    assert rect.vertical_rms_px < 0.1
    # parallax per metre = parallax/height ratio over the pixel scale (0.466 / 200 m)
    assert rect.parallax_px_per_m == pytest.approx(np.tan(np.radians(25.0)) / GSD_M, rel=0.05)
    # the true disparities lie inside the stated search range (the 1-km surface is within 800 m of the truth)
    assert rect.disparity_min_px <= d.min() and d.max() <= rect.disparity_max_px
    n = rect.disparity_count
    assert n % 16 == 0 and n >= rect.disparity_max_px - rect.disparity_min_px
    assert rect.sgm_memory_bytes == 2 * 2 * rect.left.size * n
    assert rect.left_valid[v0:v1, u0:u1].all() and rect.right_valid[v0:v1, u0:u1].mean() > 0.99


def test_maps_back_to_the_images_are_exact(lambert_pair) -> None:
    """The left map is a rotation about the chip centre; a rectified pixel and its disparity go back to
    the image pixels the chips were sampled from.
    """
    rect = chip_of(lambert_pair)
    hh, ww = rect.left.shape
    u = np.array([16.0, (ww - 1) / 2, 239.0])
    v = np.array([16.0, (hh - 1) / 2, 100.0])
    lp, rp = rectified_to_images(rect, u, v, np.zeros(3))
    np.testing.assert_allclose(lp[1], [16 + 223 / 2, 16 + 223 / 2], atol=1e-9)  # frame centre -> chip centre
    # the rotation keeps distances: rectified and left-image pixel spacing agree
    assert np.linalg.norm(lp[0] - lp[2]) == pytest.approx(np.hypot(223.0, 84.0), rel=1e-12)
    # the chips hold the images' values at the mapped places (both resampled bilinearly)
    import cv2

    ui, vi = np.array([20, 128, 230]), np.array([30, 128, 200])
    lp, rp = rectified_to_images(rect, ui.astype(float), vi.astype(float), np.full(3, 1.0))
    for img, chip, p in ((lambert_pair.left_image, rect.left, lp), (lambert_pair.right_image, rect.right, rp)):
        samp = cv2.remap(img, p[:, :1].astype(np.float32), p[:, 1:].astype(np.float32), cv2.INTER_LINEAR)[:, 0]
        at = chip[vi, ui + (1 if chip is rect.right else 0)]
        np.testing.assert_allclose(samp, at, rtol=2e-3)


def test_a_chip_the_right_image_does_not_see_is_refused(lambert_pair) -> None:
    import dataclasses

    away = dataclasses.replace(lambert_pair.right, position=-lambert_pair.right.position)
    with pytest.raises(GeometryError, match="right camera does not see"):
        rectify_chip(lambert_pair.left_image, lambert_pair.right_image, lambert_pair.left, away, Chip(16, 16, 64, 64, 8))


def test_a_rotated_chip_keeps_its_whole_interior_and_its_collar(lambert_pair) -> None:
    """A pair whose parallax runs diagonally in the left image (right view tilted north-east): the rectified
    frame grows to hold the rotated interior and the collar, and the interior mask is the chip's pixels.
    """
    from dense_scene import sun_at, view

    p = lambert_pair
    right = view(18.0, sun_at(45.0, 90.0), tilt_east_deg=18.0)
    chip = Chip(40, 60, 100, 120, 12)
    rect = rectify_chip(p.left_image, p.left_image, p.left, right, chip, surface_height=p.current_surface)
    theta = np.degrees(np.arctan2(rect.to_left[1, 0], rect.to_left[0, 0])) % 90.0
    assert 20.0 < theta < 70.0, theta  # really rotated
    mask = rect.interior_mask()
    assert mask.sum() == pytest.approx(100 * 120, rel=0.02)
    rows, cols = np.nonzero(mask)
    hh, ww = mask.shape
    assert rows.min() >= 11 and cols.min() >= 11 and hh - rows.max() >= 12 and ww - cols.max() >= 12
    v0, v1, u0, u1 = rect.interior
    assert (v0, v1, u0, u1) == (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)


@pytest.fixture(scope="module")
def wide_pair():
    """The test pair's geometry at 2 km/px (the tiny mission's scale): a 256^2 chip spans 500 km of a curved
    body, over which one homography is not epipolar. Blank images: only the geometry is used.
    """
    from dense_scene import RenderedPair, sun_at, truth_surface, view

    sun = sun_at(45.0, 90.0)
    blank = np.zeros((256, 256), np.float32)
    return RenderedPair(truth_surface(), blank, blank, view(0.0, sun, gsd_m=2000.0), view(25.0, sun, gsd_m=2000.0),
                        None)


def test_a_wide_chip_is_split_until_it_is_epipolar(wide_pair) -> None:
    """Whole, the 500-km chip leaves over a pixel of the truth's vertical disparity (measured 0.4-1.8 px on the
    tiny mission); split by its own vertical_rms_px (no truth), every part keeps the truth's vertical disparity
    under 0.1 px and its true disparities inside the stated search range, and the parts tile the chip once.
    """
    from mercury_dem.dense.chip import rectify_split

    p = wide_pair
    chip = Chip(0, 0, 256, 256, 16)
    surface = p.current_surface
    whole = rectify_chip(p.left_image, p.right_image, p.left, p.right, chip, surface, 800.0)
    _, vertical = true_disparity(p, whole)
    assert whole.vertical_rms_px > 0.1 and np.sqrt(np.mean(vertical[whole.interior_mask()] ** 2)) > 0.1
    parts, failed = rectify_split(p.left_image, p.right_image, p.left, p.right, chip, surface, 800.0,
                                  max_vertical_px=0.1, min_chip_px=16)
    assert failed == 0 and len(parts) > 1
    assert sum(c.width * c.height for c, _ in parts) == 256 * 256
    covered = np.zeros((256, 256), int)
    for c, rect in parts:
        covered[c.y0:c.y0 + c.height, c.x0:c.x0 + c.width] += 1
        assert rect.vertical_rms_px <= 0.1 or min(c.width, c.height) < 32
        d, vertical = true_disparity(p, rect)
        inner = rect.interior_mask()
        assert np.sqrt(np.mean(vertical[inner] ** 2)) < 0.1
        assert rect.disparity_min_px <= d[inner].min() and d[inner].max() <= rect.disparity_max_px
    assert (covered == 1).all()


def test_the_search_range_holds_the_surface_homography_residual(wide_pair) -> None:
    """On a curved surface the homography's residual along the epipolar lines is a disparity offset (pixels on a
    500-km chip): the true disparities lie inside the stated range even for the whole chip.
    """
    p = wide_pair
    rect = rectify_chip(p.left_image, p.right_image, p.left, p.right, Chip(0, 0, 256, 256, 16), p.current_surface,
                        800.0)
    d, _ = true_disparity(p, rect)
    inner = rect.interior_mask() & np.isfinite(d)
    margin = 800.0 * abs(rect.parallax_px_per_m) + 2.0
    assert np.abs(d[inner]).max() > margin  # the margin alone would clip
    assert rect.disparity_min_px <= d[inner].min() and d[inner].max() <= rect.disparity_max_px
