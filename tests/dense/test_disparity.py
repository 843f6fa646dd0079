"""Dense disparity: sub-pixel refinement that does not pixel-lock, a stated precision that means what it
says on noise, and holes flagged (never filled) in shadow, without texture and outside the images.
"""

from __future__ import annotations

import numpy as np
from dense_scene import chip_of

from mercury_dem.dense.disparity import (
    HOLE_NO_TEXTURE,
    HOLE_OUTSIDE,
    HOLE_REFINEMENT,
    HOLE_SHADOW,
    MatcherSettings,
    dense_disparity,
)


def texture(shape: tuple[int, int], shift: float, rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """A band-limited texture (wavelengths 4-40 px) sampled at u + shift: an exact sub-pixel shift."""
    lam = np.exp(rng.uniform(np.log(4.0), np.log(40.0), n))
    th = rng.uniform(0, 2 * np.pi, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    amp = (lam / 40.0) ** 0.5
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    u = u + shift
    out = np.zeros(shape)
    for k in range(n):
        out += amp[k] * np.sin(2 * np.pi / lam[k] * (np.cos(th[k]) * u + np.sin(th[k]) * v) + ph[k])
    return 1500.0 + 120.0 * out


def shifted_pair(d: float, noise_dn: float, seed: int = 1, shape: tuple[int, int] = (96, 160)):
    """Left L(u) and right R with R(u + d) = L(u) (so the disparity u_right - u_left is d), plus noise."""
    rng = np.random.default_rng(seed)
    left = texture(shape, 0.0, np.random.default_rng(99))
    right = texture(shape, -d, np.random.default_rng(99))
    left = left + rng.normal(0, noise_dn, shape)
    right = right + rng.normal(0, noise_dn, shape)
    return left.astype(np.float32), right.astype(np.float32)


def interior(a: np.ndarray) -> np.ndarray:
    return a[16:-16, 24:-24]


def test_refined_disparity_does_not_pixel_lock() -> None:
    """Over fractional shifts 0..7/8 the refinement's median error stays ~0, with no sawtooth in the fraction.

    (A parabola on SGM costs pulls toward integers; so did bicubic resampling of the right chip, by up to
    0.045 px on this texture: the refinement resamples with Lanczos-4.)
    """
    ok = np.ones((96, 160), bool)
    ours = []
    for f in np.arange(8) / 8.0:
        d = 2.0 + f
        left, right = shifted_pair(d, noise_dn=2.0)
        dm = dense_disparity(left, right, ok, ok, -1.0, 6.0)
        e = interior(dm.disparity) - d
        assert np.isfinite(e).mean() > 0.95
        ours.append(np.nanmedian(e))
    ours_a = np.array(ours)
    assert np.abs(ours_a).max() < 0.03, ours_a
    # no dependence of the error on the fraction (pixel locking would make it a sawtooth in f)
    assert np.ptp(ours_a) < 0.04, ours_a


def test_stated_precision_matches_the_noise() -> None:
    """On an exactly shifted texture the only error is the noise; the stated sigma is its RMS within 0.7-1.5."""
    ok = np.ones((96, 160), bool)
    errs, sigs = [], []
    for seed in range(4):
        left, right = shifted_pair(2.37, noise_dn=12.0, seed=seed)
        dm = dense_disparity(left, right, ok, ok, -1.0, 6.0)
        keep = np.isfinite(interior(dm.disparity))
        errs.append(interior(dm.disparity)[keep] - 2.37)
        sigs.append(interior(dm.sigma_px)[keep])
    e, s = np.concatenate(errs), np.concatenate(sigs)
    ratio = np.sqrt(np.mean(e**2)) / np.sqrt(np.mean(s**2))
    assert 0.7 <= ratio <= 1.5, ratio
    assert np.mean(np.abs(e) > 3 * s) <= 0.01


def test_shadow_flat_and_outside_are_flagged_holes() -> None:
    left, right = shifted_pair(2.5, noise_dn=2.0)
    left_valid = np.ones(left.shape, bool)
    left_valid[:, 120:] = False                          # beyond the left image
    rng = np.random.default_rng(5)
    for img in (left, right):
        img[20:50, 30:70] = 10.0 + rng.normal(0, 1.2, (30, 40))      # shadow: the dark level and read noise
        img[60:90, 60:110] = 1500.0 + rng.normal(0, 2.0, (30, 50))   # lit but without texture
    dm = dense_disparity(left, right, left_valid, np.ones(left.shape, bool), -1.0, 6.0)
    shadow = dm.holes[26:44, 36:64]
    assert (shadow & HOLE_SHADOW).all() and np.isnan(dm.disparity[26:44, 36:64]).all()
    flat = dm.holes[66:84, 66:104]
    assert (flat & (HOLE_NO_TEXTURE | HOLE_REFINEMENT) != 0).mean() > 0.95
    assert np.isnan(dm.disparity[66:84, 66:104]).mean() > 0.95
    assert (dm.holes[:, 120:] & HOLE_OUTSIDE).all() and np.isnan(dm.disparity[:, 120:]).all()
    # every NaN is a flagged hole and every hole is NaN: nothing invented, nothing lost silently
    assert np.array_equal(np.isnan(dm.disparity), dm.holes != 0)
    counts = dm.hole_counts()
    assert counts["shadow"] >= 22 * 32 and counts["outside"] >= 96 * 40


def test_holes_where_the_rendered_image_is_in_shadow(low_sun_pair) -> None:
    """Sun at 78 deg incidence: the renderer's cast shadows (lit with shadows off, dark with them on)
    are holes flagged 'shadow' in the rectified chip; none of them gets a disparity.
    """
    import cv2

    from mercury_dem.synth.render import render_reflectance

    p = low_sun_pair
    rect = chip_of(p, height_margin_m=1500.0)
    g = p.left
    args = (p.surface, g.camera, g.position, g.rotation, g.sun_position)
    lit_on = render_reflectance(*args, p.settings)
    import dataclasses

    lit_off = render_reflectance(*args, dataclasses.replace(p.settings, shadows=False))
    shadow = ((lit_on < 0.2 * lit_off) & (lit_off > 0)).astype(np.float32)
    # the shadow mask in the rectified frame (cores only: 2 px in from the shadow's edge)
    shadow = cv2.erode(shadow, np.ones((5, 5), np.uint8))
    m = cv2.warpPerspective(shadow, rect.to_left, rect.left.shape[::-1],
                            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0.5
    v0, v1, u0, u1 = rect.interior
    m[:v0], m[v1:], m[:, :u0], m[:, u1:] = False, False, False, False
    assert m.sum() > 300, m.sum()  # the scene has shadows to test
    dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                         rect.disparity_max_px, MatcherSettings())
    assert np.isnan(dm.disparity[m]).all()
    assert (dm.holes[m] & HOLE_SHADOW != 0).mean() > 0.95
    # and the lit ground away from shadows is mostly matched
    lit = ~m & (dm.holes & HOLE_SHADOW == 0)
    lit[:v0], lit[v1:], lit[:, :u0], lit[:, u1:] = False, False, False, False
    assert np.isfinite(dm.disparity[lit]).mean() > 0.6


def test_block_refinement_equals_the_whole_chip(lambert_pair) -> None:
    """Refining block by block (the default, linear cost) gives every pixel the result of the whole chip."""
    import dataclasses

    from mercury_dem.dense.disparity import refine_disparity, refine_disparity_blocks, sgbm_disparity, to_8bit

    rect = chip_of(lambert_pair)
    s = MatcherSettings()
    l8, r8 = to_8bit(rect.left, rect.right, rect.left_valid & rect.right_valid)
    seed = np.round(sgbm_disparity(l8, r8, rect.disparity_min_px, rect.disparity_max_px, s))
    whole = refine_disparity(rect.left, rect.right, seed, s)
    blocks = refine_disparity_blocks(rect.left, rect.right, seed, dataclasses.replace(s, refine_block_px=48))
    for a, b in zip(whole, blocks):
        both = np.isfinite(a) & np.isfinite(b)
        assert both.sum() > 0.99 * np.isfinite(a).sum()
        np.testing.assert_allclose(a[both], b[both], atol=2e-3)


def test_the_disparity_does_not_depend_on_opencvs_thread_count(lambert_pair) -> None:
    """Serial == distributed needs it: SGBM_3WAY splits rows among threads; the result is bit-identical."""
    import cv2

    rect = chip_of(lambert_pair)
    before = cv2.getNumThreads()
    try:
        out = []
        for n in (1, 3):
            cv2.setNumThreads(n)
            out.append(dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid,
                                       rect.disparity_min_px, rect.disparity_max_px))
    finally:
        cv2.setNumThreads(before)
    assert np.array_equal(out[0].holes, out[1].holes)
    assert np.array_equal(out[0].disparity, out[1].disparity, equal_nan=True)
    assert np.array_equal(out[0].sigma_px, out[1].sigma_px, equal_nan=True)
