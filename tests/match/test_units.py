"""Unit tests of the matching building blocks on small exact inputs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, shift

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac
from mercury_dem.geometry.pose import image_to_ground, look_at_rotation, project
from mercury_dem.match.features import image_quality, spread_best
from mercury_dem.match.outliers import KnnResult, homography_inliers, ratio_test, symmetric_pairs
from mercury_dem.match.pretransform import ImageGeometry, apply_homography, pair_geometry, warp_to_reference
from mercury_dem.match.refine import refine_matches, refine_matches_adaptive, sample_patches


def texture(n: int, seed: int, sigma: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.normal(size=(n, n)), sigma)
    return (2000 + 600 * t / t.std()).astype(np.float32)


def test_spread_best_takes_each_cells_best_first() -> None:
    pts = np.array([[1, 1], [2, 2], [3, 3], [60, 60], [61, 61]], float)
    score = np.array([5, 9, 1, 3, 2], float)
    keep = spread_best(pts, score, 2, (64, 64), 2)
    assert set(keep.tolist()) == {1, 3}  # best of the top-left cell and best of the bottom-right cell


def test_ratio_and_symmetry() -> None:
    ab = KnnResult(np.array([0, 1, 1]), np.array([1.0, 1.0, 5.0]), np.array([2.0, 1.05, 6.0]))
    ba = KnnResult(np.array([0, 2]), np.array([1.0, 5.0]), np.array([3.0, 10.0]))
    ok_ab, ok_ba = ratio_test(ab, 0.9), ratio_test(ba, 0.9)
    assert ok_ab.tolist() == [True, False, True]
    ia, ib = symmetric_pairs(ab, ba, ok_ab, ok_ba)
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 1]


def test_homography_ransac_rejects_injected_outliers() -> None:
    rng = np.random.default_rng(0)
    h = np.array([[1.1, 0.1, 5.0], [-0.05, 0.95, -3.0], [1e-5, 0.0, 1.0]])
    pa = rng.uniform(0, 500, (200, 2))
    pb = apply_homography(h, pa) + rng.normal(0, 0.3, (200, 2))
    bad = rng.choice(200, 30, replace=False)
    pb[bad] += rng.uniform(20, 60, (30, 2))
    inl, _ = homography_inliers(pa, pb, 3.0)
    assert not inl[bad].any()
    assert inl.sum() >= 165


def test_image_quality_reasons() -> None:
    cfg = MatchConfig()
    assert image_quality(texture(64, 0), cfg).ok
    assert "blank" in image_quality(np.zeros((64, 64), np.uint16), cfg).reason
    assert "saturated" in image_quality(np.full((64, 64), 4095, np.uint16) - np.eye(64, dtype=np.uint16), cfg).reason
    flat = (1000 + np.random.default_rng(1).integers(0, 3, (64, 64))).astype(np.uint16)
    assert "textureless" in image_quality(flat, cfg).reason
    assert "not a 2-D image" in image_quality(np.zeros(5), cfg).reason


def _views() -> tuple[ImageGeometry, ImageGeometry]:
    cam = mdis_nac(256, distortion=False)
    centre = latlon_to_xyz(20.0, 100.0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M)
    up = latlon_to_unit(20.0, 100.0)
    ca = centre + 300e3 * up
    cb = centre + 450e3 * up + np.array([30e3, -20e3, 0.0])
    sun = centre * 1e4
    ra = look_at_rotation(ca, centre, (0, 0, 1))
    rb = look_at_rotation(cb, centre + np.array([1e3, 0, 0]), (0.3, 0, 1))
    return ImageGeometry.of(cam, ca, ra, sun, datum_radius_m=DATUM_RADIUS_M), ImageGeometry.of(cam, cb, rb, sun, datum_radius_m=DATUM_RADIUS_M)


def test_pretransform_homography_maps_datum_points() -> None:
    a, b = _views()
    pg = pair_geometry(a, b)
    assert not isinstance(pg, str)
    px = np.random.default_rng(3).uniform(20, 236, (50, 2))
    g, hit = image_to_ground(a.camera, a.position, a.rotation, px, datum_radius_m=DATUM_RADIUS_M)
    truth, _ = project(b.camera, b.position, b.rotation, g)
    assert np.abs(apply_homography(pg.homography, px) - truth).max() < 0.05
    assert pg.scale_ratio == pytest.approx(1.5, rel=0.05)
    assert pg.overlap > 0.9


def test_pretransform_reports_no_overlap() -> None:
    a, b = _views()
    far = ImageGeometry.of(b.camera, b.position, look_at_rotation(b.position, latlon_to_xyz(25.0, 106.0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M), (0, 0, 1)), b.sun_position, datum_radius_m=DATUM_RADIUS_M)
    assert "no a-priori overlap" in pair_geometry(a, far)


def test_warp_follows_the_homography() -> None:
    img = texture(128, 5)
    h = np.array([[0.9, 0.1, 8.0], [-0.1, 0.9, 4.0], [0.0, 0.0, 1.0]])
    warped, valid = warp_to_reference(img, h, (128, 128), scale=1.0)
    p = np.array([[40.0, 50.0], [70.2, 30.7]])
    q = apply_homography(h, p)
    want = sample_patches(img, q, 0)[:, 0, 0]
    got = sample_patches(warped, p, 0)[:, 0, 0]
    assert valid[50, 40] and np.allclose(got, want, atol=2.0)


def test_refinement_recovers_a_subpixel_shift() -> None:
    ref = texture(160, 7, sigma=2.5)
    true_shift = np.array([0.37, -0.62])  # (sample, line): match(x) = ref(x - shift)
    moved = shift(ref.astype(np.float64), (true_shift[1], true_shift[0]), order=3, mode="nearest").astype(np.float32)
    moved = moved * 1.3 + 50.0  # gain and offset must not matter
    g = np.arange(30, 131, 10, dtype=float)
    pa = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    start = np.rint(pa + true_shift) + np.array([1.0, -1.0])  # a pixel off
    r = refine_matches(ref, moved, np.ones_like(ref, bool), pa, start, window=21, search=3)
    assert r.ok.all()
    err = np.linalg.norm(r.points - (pa + true_shift), axis=1)
    assert np.median(err) < 0.02 and err.max() < 0.06


def test_refinement_drops_measures_off_the_data() -> None:
    ref = texture(96, 8)
    valid = np.ones_like(ref, bool)
    valid[:, 60:] = False
    pa = np.array([[30.0, 48.0], [70.0, 48.0]])
    r = refine_matches(ref, ref, valid, pa, pa.copy())
    assert r.ok.tolist() == [True, False]


def test_adaptive_refinement_keeps_measures_near_the_edge_of_a_small_patch() -> None:
    """A 64-pixel warped patch (a 4x pair): measures 9 px from its edge are refined with smaller windows."""
    ref = texture(160, 9, sigma=2.5)
    true_shift = np.array([0.41, 0.23])
    moved = shift(ref.astype(np.float64), (true_shift[1], true_shift[0]), order=3, mode="nearest").astype(np.float32)
    valid = np.zeros_like(ref, bool)
    valid[48:112, 48:112] = True
    g = np.array([57.0, 60.0, 80.0, 100.0, 103.0])
    pa = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    start = np.rint(pa + true_shift)
    fixed = refine_matches(ref, moved, valid, pa, start, window=21, search=3)
    r = refine_matches_adaptive(ref, moved, valid, pa, start, window=21, search=3, min_window=11)
    # only the 9 measures >= 12 px inside the patch fit a 21-pixel window (its bilinear support on data)
    assert fixed.ok.sum() <= 9 and r.ok.sum() >= 20
    assert set(np.unique(r.window[r.ok]).tolist()) <= {21, 15, 11} and (r.window[r.ok] < 21).any()
    err = np.linalg.norm(r.points[r.ok] - (pa[r.ok] + true_shift), axis=1)
    assert np.median(err) < 0.03 and err.max() < 0.1, err


def test_detectors_selectable_by_name() -> None:
    from mercury_dem.match.features import detect_and_describe, stretch_to_8bit

    img8 = stretch_to_8bit(texture(128, 9), 1000, 3000)
    for det, desc in [("FAST", "SIFT"), ("ORB", "ORB"), ("AKAZE", "AKAZE"), ("BRISK", "BRISK"), ("SIFT", "SIFT")]:
        f = detect_and_describe(img8, MatchConfig(detector=det, descriptor=desc, max_keypoints=200))
        assert 0 < f.size <= 200 and f.descriptors.shape[0] == f.size
        assert f.norm == (cv2.NORM_L2 if desc == "SIFT" else cv2.NORM_HAMMING)


def test_ncc_template_shrinks_to_a_small_warped_patch() -> None:
    import numpy as np

    from mercury_dem.match.fallback import NCC_MIN_TEMPLATE_PX, ncc_template_size

    big = np.ones((256, 256), bool)
    assert ncc_template_size(big, 31, 16.0) == 31  # whole image on data: the configured template
    small = np.zeros((256, 256), bool)
    small[100:164, 100:164] = True  # the finer image of a 4x pair: a 64-px patch
    t = ncc_template_size(small, 31, 10.0)
    assert t % 2 == 1 and NCC_MIN_TEMPLATE_PX <= t <= 17
    # the template leaves the guidance search room on the patch
    assert 64 - t >= 2 * 10
    tiny = np.zeros((256, 256), bool)
    tiny[100:120, 100:120] = True
    assert ncc_template_size(tiny, 31, 10.0) == NCC_MIN_TEMPLATE_PX


def _parallax_pair(seed: int, amp: float = 1.0, wavelength: float = 24.0, n: int = 160) -> tuple[np.ndarray, ...]:
    """A texture and its copy displaced by a field varying inside a 21-px window (relief parallax of
    convergent views): ``warped(x + d(x)) = ref(x)``, with d = (amp sin(2 pi y / L) + 0.3, amp cos(2 pi x / L) - 0.2)."""
    ref = texture(n, seed, 1.5)

    def field(x: np.ndarray) -> np.ndarray:
        return np.stack([amp * np.sin(2 * np.pi * x[..., 1] / wavelength) + 0.3,
                         amp * np.cos(2 * np.pi * x[..., 0] / wavelength) - 0.2], -1)

    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    q = np.stack([xx, yy], -1)
    x = q.copy()
    for _ in range(20):  # x + d(x) = q by fixed-point iterations
        x = q - field(x)
    warped = cv2.remap(ref, x[..., 0].astype(np.float32), x[..., 1].astype(np.float32), cv2.INTER_CUBIC,
                       borderMode=cv2.BORDER_REFLECT)
    g = np.arange(24, n - 24, 8.0)
    pa = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return ref, warped, pa, pa + field(pa)


@pytest.mark.parametrize("seed", [3, 4])
def test_dense_flow_follows_parallax_that_varies_inside_the_window(seed: int) -> None:
    """Measured (seeds 3-5, amplitude 1 px, wavelength 24 px, noise-free): the 21-px correlation reads the
    window's mean displacement, median error 0.84-0.87 px; the DIS flow at the point 0.25-0.26 px (p95 0.45-0.47)."""
    from mercury_dem.match.flow import dense_flow, flow_at
    from mercury_dem.match.refine import local_normalize

    ref, warped, pa, truth = _parallax_pair(seed)
    valid = np.ones_like(ref, bool)
    rn, wn = local_normalize(ref, 2.0), local_normalize(warped, 2.0)
    r = refine_matches(ref, warped, valid, pa, np.rint(truth), 21, 3, 4, 0.5, 2.5, rn, wn)
    e_ncc = np.linalg.norm(r.points - truth, axis=1)[r.ok]
    fl = dense_flow(rn, wn, valid)
    assert fl is not None
    d, usable = flow_at(fl, pa)
    e_flow = np.linalg.norm(pa + d - truth, axis=1)[usable]
    assert usable.mean() > 0.95 and e_ncc.size > 150
    assert np.median(e_flow) <= 0.35 and np.percentile(e_flow, 95) <= 0.6, (np.median(e_flow), np.percentile(e_flow, 95))
    assert np.median(e_flow) <= 0.5 * np.median(e_ncc), (np.median(e_flow), np.median(e_ncc))


def test_flow_base_position_inverts_the_field() -> None:
    from mercury_dem.match.flow import base_position, dense_flow, flow_at
    from mercury_dem.match.refine import local_normalize

    ref, warped, pa, truth = _parallax_pair(5, amp=0.5, wavelength=48.0)
    fl = dense_flow(local_normalize(ref, 2.0), local_normalize(warped, 2.0), np.ones_like(ref, bool))
    assert fl is not None
    d, _ = flow_at(fl, pa)
    back, ok = base_position(fl, pa + d, pa + 0.7)
    assert ok.all() and np.abs(back - pa).max() < 0.05, np.abs(back - pa).max()


def test_sample_patches_match_bilinear_interpolation_and_replicate_the_border() -> None:
    """Patches equal scipy's order-1 (bilinear) interpolation, nearest-edge outside the image."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(17)
    img = rng.normal(size=(40, 50)).astype(np.float32)
    centres = np.column_stack([rng.uniform(-6, 56, 300), rng.uniform(-6, 46, 300)])
    half = 3
    got = sample_patches(img, centres, half)
    r = np.arange(-half, half + 1)
    xs = np.broadcast_to(centres[:, 0, None, None] + r[None, None, :], got.shape)
    ys = np.broadcast_to(centres[:, 1, None, None] + r[None, :, None], got.shape)
    want = map_coordinates(img.astype(np.float64), [ys.ravel(), xs.ravel()], order=1, mode="nearest").reshape(got.shape)
    assert got.dtype == np.float32 and got.shape == (300, 7, 7)
    np.testing.assert_allclose(got, want, atol=2e-5)


@pytest.mark.parametrize("window", [0.5, 6.0, 13.3, 45.0])
def test_candidate_mask_is_the_per_axis_window_test(window: float) -> None:
    """The k-d tree route (small windows) and the dense route give the all-pairs float32 test exactly,
    points on the window's edge and non-finite predictions included."""
    from mercury_dem.match.guided import candidate_mask

    rng = np.random.default_rng(23)
    pa = rng.uniform(0, 300, (400, 2))
    pb = np.concatenate([pa[:150] + rng.normal(0, 4, (150, 2)), pa[150:200] + window, rng.uniform(0, 300, (250, 2))])
    pa[7] = np.nan
    pb[3] = np.inf
    a32, b32, w32 = pa.astype(np.float32), pb.astype(np.float32), np.float32(window)
    want = (np.abs(a32[:, None, 0] - b32[None, :, 0]) <= w32) & (np.abs(a32[:, None, 1] - b32[None, :, 1]) <= w32)
    got = candidate_mask(pa, pb, window)
    assert got.dtype == np.uint8 and got.shape == (400, 450)
    np.testing.assert_array_equal(got.astype(bool), want)
    m, m_t = candidate_mask(pa, pb, window, transposed=True)
    np.testing.assert_array_equal(m, got)
    assert m_t.flags.c_contiguous
    np.testing.assert_array_equal(m_t, got.T)
    assert want[150:200].any()  # the edge cases are in the test
