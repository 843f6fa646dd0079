"""The planetary framing-camera model for the Schur Levenberg-Marquardt core.

Unknowns per image: three pointing corrections ``omega`` (radians; corrected
rotation ``rotation_from_angles(omega) @ R_apriori``, as in
:mod:`mercury_dem.geometry.pose`) and, optionally, three position corrections
``dC`` (metres; ``C = C_apriori + dC``). Unknowns per point: body-fixed XYZ, metres.

Projection of point X in image i (camera K_i):
``v = R_i (X - C_i)``, focal plane ``x = f v_x / v_z``, ``y = f v_y / v_z`` (mm),
distorted ``(x_d, y_d) = D(x, y)`` (the camera's distortion model), pixel
``(s0, l0) + L^-1 (x_d, y_d)`` (``L = p I`` for the MDIS presets: ``(s0 + x_d / p, l0 + y_d / p)``).
Residual = (computed - measured) / sigma.

Jacobians (analytic, chain rule through ``camera.distortion_jacobian``):
``d pix / d v = L^-1 J_D (f / v_z) [[1, 0, -v_x/v_z], [0, 1, -v_y/v_z]]``; the
pointing step is applied on the left, ``R <- exp([d]x) R``, so
``d v / d d = -[v]x``; ``d v / d dC = -R``; ``d v / d X = R``.

Priors (pseudo-observations, whitened):
pointing ``omega / sigma_omega`` (Jacobian ``J_l^-1(omega) / sigma_omega``, the
inverse left Jacobian of SO(3), because steps compose on the left);
position ``dC / sigma_C``; point ``diag(1/sigma_e, 1/sigma_n, 1/sigma_r) E^T (X - X0)``
with ``E`` the local east/north/up frame at the a-priori point (lat/lon sigmas in
metres on the ground, as jigsaw takes them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.problem import AdjustmentProblem, IndexArray, pointing_sigma_radians
from mercury_dem.geometry.pose import angles_from_rotation, rotation_from_angles, skew

#: Measures per vectorized chunk (bounds the temporaries: ~1 KB per measure).
CHUNK = 1_000_000


@dataclass(frozen=True)
class FramingState:
    """Current unknowns: omega (n_img, 3) rad, dC (n_img, 3) m, points (n_pt, 3) m."""

    omega: NDArray[np.float64]
    position_correction: NDArray[np.float64]
    points: NDArray[np.float64]


def inverse_left_jacobian(omega: NDArray[np.float64]) -> NDArray[np.float64]:
    """J_l^-1(omega) (..., 3, 3): ``exp([d]x) exp([w]x) = exp([w + J_l^-1(w) d]x)`` to first order."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    k = skew(omega)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0, 1.0 / (t * t) - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) - 0.5 * k + coef * (k @ k)


def enu_frames(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Local frames (n, 3, 3) whose columns are east, north, up unit vectors at body-fixed points."""
    up = points / np.linalg.norm(points, axis=1, keepdims=True)
    east = np.cross(np.array([0.0, 0.0, 1.0]), up)
    norm = np.linalg.norm(east, axis=1, keepdims=True)
    east = np.where(norm > 1e-12, east / np.where(norm > 1e-12, norm, 1.0), np.array([0.0, 1.0, 0.0]))
    north = np.cross(up, east)
    return np.stack([east, north, up], axis=2)


class FramingModel:
    """:class:`~mercury_dem.adjust.solver.BlockModel` of framing-camera images (camera_dim 3 or 6).

    Parameters
    ----------
    problem : the arrays, with the a-priori pointing sigma (``problem.pointing_sigma_urad``, required)
    position_sigma_m : a-priori position sigma, metres, or None to keep positions fixed
        (camera_dim 3); a number makes positions unknowns (camera_dim 6)
    point_sigma_m : (east, north, radius) a-priori point sigmas in metres, None entries unconstrained
    """

    def __init__(
        self,
        problem: AdjustmentProblem,
        position_sigma_m: float | None = None,
        point_sigma_m: tuple[float | None, float | None, float | None] = (None, None, None),
    ):
        self.problem = problem
        self.camera_dim = 3 if position_sigma_m is None else 6
        self.n_cameras = problem.n_images
        self.n_points = problem.n_points
        # int64, or int32 when the blocked adjuster narrows them (it replaces these and _groups)
        self.camera_index: IndexArray = problem.measure_image
        self.point_index: IndexArray = problem.measure_point
        self.pointing_sigma = pointing_sigma_radians(problem.pointing_sigma_urad)  # radians
        self.position_sigma = None if position_sigma_m is None else float(position_sigma_m)
        self._groups: list[tuple[int, IndexArray]] = [
            (k, np.flatnonzero(problem.image_camera[problem.measure_image] == k)) for k in range(len(problem.cameras))
        ]
        self._inv_sigma = 1.0 / problem.measure_sigma
        sig = list(point_sigma_m)
        per_point = problem.point_radius_sigma
        has_per_point = per_point is not None and bool(np.any(np.isfinite(per_point)))
        rows = [i for i, s in enumerate(sig) if s is not None or (i == 2 and has_per_point)]
        if rows:
            frames = enu_frames(problem.points)  # (n_pt, 3, 3) columns e, n, u
            # (n_pt, rows) inverse sigmas; a per-point radius sigma (altimetry) replaces the configured one
            scale = np.array([[0.0 if sig[i] is None else 1.0 / sig[i] for i in rows]] * self.n_points)  # type: ignore[operator]
            if has_per_point:
                k = rows.index(2)
                given = np.isfinite(per_point)  # type: ignore[arg-type]
                scale[given, k] = 1.0 / per_point[given]  # type: ignore[index]
            self._point_prior_jac = frames.transpose(0, 2, 1)[:, rows, :] * scale[:, :, None]
        else:
            self._point_prior_jac = None

    def initial_state(self) -> FramingState:
        n = self.n_cameras
        omega = np.zeros((n, 3))
        init = self.problem.initial_rotations
        if init is not None:
            # start from given rotations; the pointing constraint stays centred on problem.rotations
            omega = angles_from_rotation(np.matmul(init, np.swapaxes(self.problem.rotations, -1, -2)))
        return FramingState(omega, np.zeros((n, 3)), self.problem.points.copy())

    def rotations(self, state: FramingState) -> NDArray[np.float64]:
        """Corrected rotations (n_img, 3, 3)."""
        out: NDArray[np.float64] = np.matmul(rotation_from_angles(state.omega), self.problem.rotations)
        return out

    def positions(self, state: FramingState) -> NDArray[np.float64]:
        return self.problem.positions + state.position_correction

    def _evaluate(self, state: FramingState, jacobian: bool
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]:
        prob = self.problem
        m = prob.n_measures
        rot = self.rotations(state)
        pos = self.positions(state)
        res = np.empty((m, 2))
        jc = np.empty((m, 2, self.camera_dim)) if jacobian else None
        jp = np.empty((m, 2, 3)) if jacobian else None
        for k, group in self._groups:
            cam = prob.cameras[k]
            for s in range(0, len(group), CHUNK):
                idx = group[s : s + CHUNK]
                img = self.camera_index[idx]
                r_i = rot[img]
                v = np.matmul(r_i, (state.points[self.point_index[idx]] - pos[img])[:, :, None])[:, :, 0]
                pix = cam.camera_to_pixel(v)
                inv_s = self._inv_sigma[idx]
                res[idx] = (pix - prob.measures[idx]) * inv_s[:, None]
                if jc is None or jp is None:  # not jacobian
                    continue
                f, p = cam.focal_length_mm, cam.pixel_size_mm
                iz = 1.0 / v[:, 2]
                x, y = f * v[:, 0] * iz, f * v[:, 1] * iz
                dxy = np.zeros((len(idx), 2, 3))
                dxy[:, 0, 0] = f * iz
                dxy[:, 1, 1] = f * iz
                dxy[:, 0, 2] = -x * iz
                dxy[:, 1, 2] = -y * iz
                jd = cam.distortion_jacobian(x, y)
                if cam.focal_plane_map:  # general pixel <- focal-plane affine: d(pixel)/d(x_d) = L^-1
                    dpix = np.matmul(np.matmul(cam.focal_to_pixel_matrix(), jd), dxy) * inv_s[:, None, None]
                else:  # L = p I (kept in this form: the MDIS presets' numbers do not change)
                    dpix = np.matmul(jd, dxy) * (inv_s / p)[:, None, None]  # (n, 2, 3)
                jc[idx, :, 0:3] = -np.matmul(dpix, skew(v))
                jpp = np.matmul(dpix, r_i)
                jp[idx] = jpp
                if self.camera_dim == 6:
                    jc[idx, :, 3:6] = -jpp
        return res, jc, jp

    def residuals(self, state: FramingState) -> NDArray[np.float64]:
        return self._evaluate(state, False)[0]

    def linearize(self, state: FramingState) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        res, jc, jp = self._evaluate(state, True)
        assert jc is not None and jp is not None  # filled when asked for the Jacobians
        return res, jc, jp

    def camera_prior(self, state: FramingState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n, c = self.n_cameras, self.camera_dim
        r = np.zeros((n, c))
        jac = np.zeros((n, c, c))
        r[:, :3] = state.omega / self.pointing_sigma
        jac[:, :3, :3] = inverse_left_jacobian(state.omega) / self.pointing_sigma
        if c == 6:
            r[:, 3:] = state.position_correction / self.position_sigma  # type: ignore[operator]
            jac[:, 3:, 3:] = np.eye(3) / self.position_sigma  # type: ignore[operator]
        return r, jac

    def point_prior(self, state: FramingState) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        if self._point_prior_jac is None:
            return None
        d = state.points - self.problem.points
        return np.matmul(self._point_prior_jac, d[:, :, None])[:, :, 0], self._point_prior_jac

    def retract(self, state: FramingState, d_camera: NDArray[np.float64], d_point: NDArray[np.float64]) -> FramingState:
        omega = angles_from_rotation(np.matmul(rotation_from_angles(d_camera[:, :3]), rotation_from_angles(state.omega)))
        dpos = state.position_correction + d_camera[:, 3:6] if self.camera_dim == 6 else state.position_correction
        return FramingState(omega, dpos, state.points + d_point)

    def parameter_norm(self, state: FramingState) -> float:
        return float(np.sqrt(np.sum(state.points**2) + np.sum(state.omega**2) + np.sum(self.positions(state) ** 2)))
