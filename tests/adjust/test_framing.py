"""The framing-camera model: analytic Jacobians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.adjust.framing import FramingModel, FramingState, enu_frames, inverse_left_jacobian
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac, mdis_wac
from mercury_dem.geometry.pose import look_at_rotation, rotation_from_angles


@pytest.fixture()
def two_camera_problem():
    """A NAC (with MDIS distortion, points near the frame edge) and a WAC image of 8 points."""
    rng = np.random.default_rng(11)
    cams = (mdis_nac(512), mdis_wac(512))
    pos = np.array([latlon_to_xyz(10.0, 20.0, 400e3, datum_radius_m=DATUM_RADIUS_M), latlon_to_xyz(10.05, 20.02, 600e3, datum_radius_m=DATUM_RADIUS_M)])
    target = latlon_to_xyz(10.02, 20.01, 0.0, datum_radius_m=DATUM_RADIUS_M)
    rot = look_at_rotation(pos, np.broadcast_to(target, (2, 3)))
    pts = target + rng.normal(0.0, 3000.0, (8, 3))
    mi = np.repeat([0, 1], 8)
    mp = np.tile(np.arange(8), 2)
    return AdjustmentProblem(cams, np.array([0, 1]), pos, rot, pts, mi, mp, np.zeros((16, 2)), rng.uniform(0.3, 2.0, 16),
                             pointing_sigma_urad=1000.0)


def assert_jacobians_match_differences(model: FramingModel, st: FramingState, jc: np.ndarray, jp: np.ndarray) -> None:
    """The camera (``jc``) and point (``jp``) Jacobians of ``model`` at ``st`` equal central differences."""
    n_img, c = st.omega.shape[0], model.camera_dim
    n_pt = st.points.shape[0]
    zero_p, zero_c = np.zeros((n_pt, 3)), np.zeros((n_img, c))
    for k in range(c):
        h = 1e-7 if k < 3 else 1e-3
        d = np.zeros((n_img, c))
        d[:, k] = h
        num = (model.residuals(model.retract(st, d, zero_p)) - model.residuals(model.retract(st, -d, zero_p))) / (2 * h)
        np.testing.assert_allclose(num, jc[:, :, k], rtol=1e-5, atol=1e-6 * np.abs(jc[:, :, k]).max())
    for k in range(3):
        d = np.zeros((n_pt, 3))
        d[:, k] = 1e-3
        num = (model.residuals(model.retract(st, zero_c, d)) - model.residuals(model.retract(st, zero_c, -d))) / 2e-3
        np.testing.assert_allclose(num, jp[:, :, k], rtol=1e-5, atol=1e-6 * np.abs(jp).max())


@pytest.mark.parametrize("position_sigma", [None, 50.0])
def test_jacobians_match_finite_differences(two_camera_problem, position_sigma):
    prob = two_camera_problem
    rng = np.random.default_rng(12)
    model = FramingModel(prob, position_sigma, (100.0, 200.0, 1e4))
    c = model.camera_dim
    st = FramingState(rng.normal(0, 1e-3, (2, 3)), rng.normal(0, 30, (2, 3)), prob.points + rng.normal(0, 10, (8, 3)))
    r, jc, jp = model.linearize(st)
    assert np.allclose(r, model.residuals(st))
    assert_jacobians_match_differences(model, st, jc, jp)
    # the camera prior's Jacobian (inverse left Jacobian of SO(3) for the pointing part)
    pr, pj = model.camera_prior(st)
    zero_p = np.zeros_like(st.points)
    for k in range(c):
        h = 1e-7 if k < 3 else 1e-3
        d = np.zeros((2, c))
        d[:, k] = h
        num = (model.camera_prior(model.retract(st, d, zero_p))[0] - model.camera_prior(model.retract(st, -d, zero_p))[0]) / (2 * h)
        np.testing.assert_allclose(num, pj[:, :, k], rtol=1e-6, atol=1e-9 * np.abs(pj).max())


def test_distortion_matters_in_the_jacobian(two_camera_problem):
    """The NAC rows differ from those of the same camera without distortion (the chain rule is exercised)."""
    prob = two_camera_problem
    model = FramingModel(prob)
    _, jc, _ = model.linearize(model.initial_state())
    plain = FramingModel(
        AdjustmentProblem((mdis_nac(512, distortion=False), prob.cameras[1]), prob.image_camera, prob.positions,
                          prob.rotations, prob.points, prob.measure_image, prob.measure_point, prob.measures,
                          prob.measure_sigma, pointing_sigma_urad=1000.0))
    _, jc0, _ = plain.linearize(plain.initial_state())
    nac = prob.measure_image == 0
    assert np.abs(jc[nac] - jc0[nac]).max() > 1e-4 * np.abs(jc[nac]).max()
    assert np.allclose(jc[~nac], jc0[~nac])


def test_retract_composes_on_the_left(two_camera_problem):
    model = FramingModel(two_camera_problem)
    st = FramingState(np.array([[1e-3, -2e-3, 5e-4], [0, 0, 0]]), np.zeros((2, 3)), two_camera_problem.points)
    d = np.array([[2e-4, 1e-4, -3e-4], [1e-4, 0, 0]])
    new = model.retract(st, d, np.zeros((8, 3)))
    want = rotation_from_angles(d) @ rotation_from_angles(st.omega)
    np.testing.assert_allclose(rotation_from_angles(new.omega), want, atol=1e-14)


def test_inverse_left_jacobian_small_angle_limit():
    np.testing.assert_allclose(inverse_left_jacobian(np.zeros((1, 3)))[0], np.eye(3))
    w = np.array([[1e-7, 2e-7, -1e-7]])
    np.testing.assert_allclose(inverse_left_jacobian(w)[0], np.eye(3) - 0.5 * np.array(
        [[0, 1e-7, 2e-7], [-1e-7, 0, -1e-7], [-2e-7, 1e-7, 0]]), atol=1e-12)


def test_enu_frames_orthonormal_with_up_radial():
    p = np.array([latlon_to_xyz(30.0, 45.0, 0.0, datum_radius_m=DATUM_RADIUS_M), latlon_to_xyz(-89.9999, 10.0, 0.0, datum_radius_m=DATUM_RADIUS_M), latlon_to_xyz(0, 0, 0, datum_radius_m=DATUM_RADIUS_M)])
    f = enu_frames(p)
    np.testing.assert_allclose(np.einsum("nij,nik->njk", f, f), np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(f[:, :, 2], p / np.linalg.norm(p, axis=1, keepdims=True))
    assert f[0, 2, 1] > 0  # north has +Z component in the northern hemisphere
