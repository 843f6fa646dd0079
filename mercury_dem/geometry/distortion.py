"""Lens distortion models of the framing camera, in our focal-plane millimetres.

Two real models are represented (the third, ``none``, is the identity):

``transverse``
    MDIS (ISIS ``TaylorCameraDistortionMap``, CSM "transverse"): ten-term cubic
    polynomials map *undistorted* focal-plane mm to *distorted* ones, so the
    ground -> image direction is closed form and image -> ground is a Newton
    iteration. Implemented in :mod:`mercury_dem.geometry.camera` (unchanged).
``apollo_metric``
    Apollo Metric camera (ISIS ``ApolloMetricDistortionMap``): from a *distorted*
    point ``(x_d, y_d)`` relative to the principal point ``PP = (x_p, y_p)``,
    ``x = x_d - x_p``, ``y = y_d - y_p``, ``r2 = x^2 + y^2``,

    ``dr = 1 + k1 r2 + k2 r2^2 + k3 r2^3``, ``dt = j1 r2 + j2 r2^2``,

    ``x_u = dr x - dt sin(t0)``, ``y_u = dr y + dt cos(t0)``

    (radial distortion plus a one-directional decentering term at angle ``t0``,
    radians). Here image -> ground is closed form and ground -> image is the
    iteration; the undistorted focal plane is centred on the principal point, so
    the optical axis falls at the distorted point ``PP``.

The coefficients are those of *our* focal plane (``+x`` along increasing sample,
``+y`` along increasing line, see ``docs/conventions.md``). A camera whose NAIF
frame looks along ``-Z`` has one focal-plane axis reversed with respect to ISIS's;
:func:`mercury_dem.geometry.naif_camera.camera_from_naif` converts its PP and
``t0`` at the boundary.

Written here rather than calling ISIS or usgscsm (C++ libraries with SPICE
dependencies) because the camera needs the model's analytic Jacobian inside the
vectorised bundle adjustment, which neither exposes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError

Pair = tuple[NDArray[np.float64], NDArray[np.float64]]


def newton_inverse(
    forward: Callable[[NDArray[np.float64], NDArray[np.float64]], Pair],
    jacobian: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
    tx: NDArray[np.float64],
    ty: NDArray[np.float64],
    x0: NDArray[np.float64],
    y0: NDArray[np.float64],
    tol_mm: float = 1e-12,
    max_iter: int = 20,
) -> Pair:
    """Solve ``forward(x, y) = (tx, ty)`` by Newton's method from ``(x0, y0)``.

    Parameters
    ----------
    forward : map of focal-plane mm (arrays of one shape) to focal-plane mm
    jacobian : its derivative, shape (..., 2, 2), ``[[dfx/dx, dfx/dy], [dfy/dx, dfy/dy]]``
    tx, ty : targets, mm
    x0, y0 : starting point, mm (copied, not modified)
    tol_mm : stop when every step is below this, mm
    max_iter : at most this many steps

    Returns
    -------
    x, y : the solution, mm, shape of ``tx``
    """
    x, y = x0.copy(), y0.copy()
    for _ in range(max_iter):
        fx, fy = forward(x, y)
        rx, ry = fx - tx, fy - ty
        j = jacobian(x, y)
        det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
        dx = (j[..., 1, 1] * rx - j[..., 0, 1] * ry) / det
        dy = (-j[..., 1, 0] * rx + j[..., 0, 0] * ry) / det
        x, y = x - dx, y - dy
        if np.all(np.abs(dx) < tol_mm) and np.all(np.abs(dy) < tol_mm):
            break
    return x, y


def _inverse_2x2(j: NDArray[np.float64]) -> NDArray[np.float64]:
    det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
    inv = np.empty_like(j)
    inv[..., 0, 0] = j[..., 1, 1] / det
    inv[..., 0, 1] = -j[..., 0, 1] / det
    inv[..., 1, 0] = -j[..., 1, 0] / det
    inv[..., 1, 1] = j[..., 0, 0] / det
    return inv


@dataclass(frozen=True)
class ApolloMetricDistortion:
    """The Apollo Metric camera's radial + decentering distortion (ISIS ``ApolloMetricDistortionMap``).

    Parameters
    ----------
    principal_point_mm : (x_p, y_p), the distorted focal-plane point of the optical axis, mm
        (NAIF ``INS<code>_PP``, in our focal-plane axes)
    radial : (k1, k2, k3), mm^-2, mm^-4, mm^-6 (NAIF ``OD_K``)
    decentering : (j1, j2, t0): j1 mm^-2, j2 mm^-4, t0 radians (NAIF ``DECENTER``, t0 in our axes)
    """

    principal_point_mm: tuple[float, float]
    radial: tuple[float, float, float]
    decentering: tuple[float, float, float]

    def __post_init__(self) -> None:
        for name, n in (("principal_point_mm", 2), ("radial", 3), ("decentering", 3)):
            v = getattr(self, name)
            if len(v) != n or not all(math.isfinite(float(c)) for c in v):
                raise GeometryError(f"apollo_metric distortion: {name} needs {n} finite numbers, got {v!r}")

    def _about_pp(self, xd: ArrayLike, yd: ArrayLike) -> tuple[NDArray[np.float64], ...]:
        """(x, y) about the principal point, r^2 and the radial factor 1 + k1 r^2 + k2 r^4 + k3 r^6."""
        k1, k2, k3 = self.radial
        x = np.asarray(xd, dtype=np.float64) - self.principal_point_mm[0]
        y = np.asarray(yd, dtype=np.float64) - self.principal_point_mm[1]
        rr = x * x + y * y
        return x, y, rr, 1.0 + k1 * rr + k2 * rr * rr + k3 * rr * rr * rr

    def undistort(self, xd: ArrayLike, yd: ArrayLike) -> Pair:
        """Distorted -> undistorted focal-plane mm (closed form; ISIS ``SetFocalPlane``)."""
        j1, j2, t0 = self.decentering
        x, y, rr, dr = self._about_pp(xd, yd)
        dt = j1 * rr + j2 * rr * rr
        return dr * x - dt * math.sin(t0), dr * y + dt * math.cos(t0)

    def undistort_jacobian(self, xd: ArrayLike, yd: ArrayLike) -> NDArray[np.float64]:
        """d(x_u, y_u)/d(x_d, y_d), shape (..., 2, 2)."""
        k1, k2, k3 = self.radial
        j1, j2, t0 = self.decentering
        x, y, rr, dr = self._about_pp(xd, yd)
        a = 2.0 * (k1 + 2.0 * k2 * rr + 3.0 * k3 * rr * rr)  # d(dr)/dx = a x, d(dr)/dy = a y
        b = 2.0 * (j1 + 2.0 * j2 * rr)  # d(dt)/dx = b x, d(dt)/dy = b y
        s, c = math.sin(t0), math.cos(t0)
        jac = np.empty(x.shape + (2, 2))
        jac[..., 0, 0] = dr + a * x * x - s * b * x
        jac[..., 0, 1] = a * x * y - s * b * y
        jac[..., 1, 0] = a * x * y + c * b * x
        jac[..., 1, 1] = dr + a * y * y + c * b * y
        return jac

    def distort(self, x: ArrayLike, y: ArrayLike, tol_mm: float = 1e-12, max_iter: int = 20) -> Pair:
        """Undistorted -> distorted focal-plane mm by Newton iteration on :meth:`undistort`.

        ISIS's ``SetUndistortedFocalPlane`` iterates a fixed point to 1e-6 mm; this
        converges to ``tol_mm`` (the exact inverse to rounding).
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        x0 = x + self.principal_point_mm[0]
        y0 = y + self.principal_point_mm[1]
        return newton_inverse(self.undistort, self.undistort_jacobian, x, y, x0, y0, tol_mm, max_iter)

    def distort_jacobian(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """d(x_d, y_d)/d(x, y) at undistorted points, shape (..., 2, 2).

        The inverse of :meth:`undistort_jacobian` at the distorted point (inverse
        function theorem): analytic, no finite differences.
        """
        xd, yd = self.distort(x, y)
        return _inverse_2x2(self.undistort_jacobian(xd, yd))
