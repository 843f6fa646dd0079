"""Lens distortion models of the framing camera, in our focal-plane millimetres.

Two real models are written out here first (``none`` is the identity; usgscsm's other frame
models are :class:`CsmDistortion`, at the end of this module):

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


# -- the distortion models of usgscsm's frame sensor ------------------------------

#: The usgscsm/ALE distortion models :class:`CsmDistortion` implements, with their number of coefficients
#: (the ``optical_distortion`` key of an ISD; ``transverse`` is the camera's own polynomial, not here).
CSM_DISTORTION_SIZES = {"radial": 3, "cahvor": 5, "dawnfc": 1, "radtan": 5, "lrolrocnac": 1, "kaguyalism": 10}
#: Models whose closed form is distorted -> undistorted (the others are undistorted -> distorted).
_CLOSED_UNDISTORT = ("radial", "cahvor", "lrolrocnac", "kaguyalism")
#: Newton's inverse of a closed form stops when every step is below this, mm; a point whose residual
#: is then above :data:`CSM_RESIDUAL_MM` did not converge and becomes NaN.
CSM_STEP_MM = 1e-12
CSM_RESIDUAL_MM = 1e-9
CSM_MAX_ITER = 30


@dataclass(frozen=True)
class CsmDistortion:
    """A lens distortion model of usgscsm's frame sensor, in the ISD's focal-plane millimetres.

    The models and their coefficients, as usgscsm's ``Distortion.cpp`` orders them
    (``d`` distorted, ``u`` undistorted focal-plane mm, ``r`` the radius of the point the
    closed form starts from):

    ``radial`` (k0, k1, k2)
        ``u = d (1 - (k0 + k1 r^2 + k2 r^4))``, r = |d| (ISIS/Cassini ISS, LRO WAC, MDIS-WAC).
    ``cahvor`` (k0, k1, k2, x0, y0)
        ``radial`` about the point (x0, y0): ``u = c + (d - c)(1 - dr(|d - c|))``.
    ``dawnfc`` (k,)
        ``d = u (1 + k r^2)``, r = |u| (Dawn FC).
    ``radtan`` (k1, k2, p1, p2, k3)
        OpenCV's radial-tangential model on ``u / f``: with ``x = u_x / f``, ``y = u_y / f``,
        ``r^2 = x^2 + y^2``, ``d / f = (x g + 2 p1 x y + p2 (r^2 + 2 x^2), y g + p1 (r^2 + 2 y^2) + 2 p2 x y)``,
        ``g = 1 + k1 r^2 + k2 r^4 + k3 r^6``.
    ``lrolrocnac`` (k,)
        ``u = (d_x, d_y / (1 + k d_y^2))`` (LROC NAC).
    ``kaguyalism`` (bx, a0, a1, a2, a3, by, b0, b1, b2, b3)
        ``u = d + (bx + a(r), by + b(r))``, r = |d|, ``a(r) = a0 + a1 r + a2 r^2 + a3 r^3`` (Kaguya TC/MI).

    The closed form is evaluated as written; its inverse is Newton's method with the
    closed form's analytic Jacobian, started at the given point, until every step is
    below :data:`CSM_STEP_MM` (at most :data:`CSM_MAX_ITER` steps). A point whose final
    residual exceeds :data:`CSM_RESIDUAL_MM` (a fold of the model, far outside the
    image) is NaN. usgscsm's own iterations stop at 1e-6 mm (and LROC NAC's at 1e-10 mm),
    so the two agree to about that.

    Parameters
    ----------
    model : one of :data:`CSM_DISTORTION_SIZES`
    coefficients : the model's coefficients, in usgscsm's order
    focal_length_mm : the focal length ``radtan`` normalises by (the ISD's, as a positive number)
    axes : (sx, sy), each +1 or -1: our focal plane's axes in the ISD's (``x_isd = sx x``); not
        (1, 1) only for an ISD of a camera that looks along its frame's -Z (negative focal length)
    """

    model: str
    coefficients: tuple[float, ...]
    focal_length_mm: float = 1.0
    axes: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self) -> None:
        n = CSM_DISTORTION_SIZES.get(self.model)
        if n is None:
            raise GeometryError(f"distortion model {self.model!r} is not one of {sorted(CSM_DISTORTION_SIZES)}")
        if len(self.coefficients) != n or not all(math.isfinite(float(c)) for c in self.coefficients):
            raise GeometryError(f"{self.model} distortion: needs {n} finite coefficients, got {self.coefficients!r}")
        if not (math.isfinite(self.focal_length_mm) and self.focal_length_mm > 0):
            raise GeometryError(f"{self.model} distortion: focal_length_mm must be > 0, got {self.focal_length_mm}")
        if len(self.axes) != 2 or any(a not in (1.0, -1.0) for a in self.axes):
            raise GeometryError(f"{self.model} distortion: axes must be two signs (+1/-1), got {self.axes!r}")

    # -- the closed form and its Jacobian, in the ISD's axes ----------------------
    def _closed(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> Pair:
        c = self.coefficients
        if self.model in ("radial", "cahvor"):
            x0, y0 = (c[3], c[4]) if self.model == "cahvor" else (0.0, 0.0)
            sx, sy = x - x0, y - y0
            rr = sx * sx + sy * sy
            keep = 1.0 - (c[0] + rr * (c[1] + rr * c[2]))
            return x0 + sx * keep, y0 + sy * keep
        if self.model == "dawnfc":
            g = 1.0 + c[0] * (x * x + y * y)
            return x * g, y * g
        if self.model == "radtan":
            f = self.focal_length_mm
            xn, yn = x / f, y / f
            k1, k2, p1, p2, k3 = c
            rr = xn * xn + yn * yn
            g = 1.0 + rr * (k1 + rr * (k2 + rr * k3))
            return (f * (xn * g + 2.0 * p1 * xn * yn + p2 * (rr + 2.0 * xn * xn)),
                    f * (yn * g + p1 * (rr + 2.0 * yn * yn) + 2.0 * p2 * xn * yn))
        if self.model == "lrolrocnac":
            return x + 0.0, y / (1.0 + c[0] * y * y)
        # kaguyalism
        r = np.hypot(x, y)
        return (x + c[0] + c[1] + r * (c[2] + r * (c[3] + r * c[4])),
                y + c[5] + c[6] + r * (c[7] + r * (c[8] + r * c[9])))

    def _closed_jacobian(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        c = self.coefficients
        jac = np.zeros(np.shape(x) + (2, 2))
        if self.model in ("radial", "cahvor"):
            x0, y0 = (c[3], c[4]) if self.model == "cahvor" else (0.0, 0.0)
            sx, sy = x - x0, y - y0
            rr = sx * sx + sy * sy
            keep = 1.0 - (c[0] + rr * (c[1] + rr * c[2]))
            h = 2.0 * (c[1] + 2.0 * c[2] * rr)  # d(keep)/d(sx) = -h sx
            jac[..., 0, 0] = keep - h * sx * sx
            jac[..., 0, 1] = -h * sx * sy
            jac[..., 1, 0] = -h * sx * sy
            jac[..., 1, 1] = keep - h * sy * sy
        elif self.model == "dawnfc":
            g = 1.0 + c[0] * (x * x + y * y)
            jac[..., 0, 0] = g + 2.0 * c[0] * x * x
            jac[..., 0, 1] = 2.0 * c[0] * x * y
            jac[..., 1, 0] = 2.0 * c[0] * x * y
            jac[..., 1, 1] = g + 2.0 * c[0] * y * y
        elif self.model == "radtan":
            f = self.focal_length_mm
            xn, yn = x / f, y / f
            k1, k2, p1, p2, k3 = c
            rr = xn * xn + yn * yn
            g = 1.0 + rr * (k1 + rr * (k2 + rr * k3))
            dg = 2.0 * (k1 + rr * (2.0 * k2 + 3.0 * k3 * rr))  # dg/dxn = dg xn
            jac[..., 0, 0] = g + dg * xn * xn + 2.0 * p1 * yn + 6.0 * p2 * xn
            jac[..., 0, 1] = dg * xn * yn + 2.0 * p1 * xn + 2.0 * p2 * yn
            jac[..., 1, 0] = dg * xn * yn + 2.0 * p1 * xn + 2.0 * p2 * yn
            jac[..., 1, 1] = g + dg * yn * yn + 6.0 * p1 * yn + 2.0 * p2 * xn
        elif self.model == "lrolrocnac":
            q = 1.0 + c[0] * y * y
            jac[..., 0, 0] = 1.0
            jac[..., 1, 1] = (1.0 - c[0] * y * y) / (q * q)
        else:  # kaguyalism: d a(r)/dx = a'(r) x / r (0 at r = 0, where r is not differentiable)
            r = np.hypot(x, y)
            with np.errstate(divide="ignore", invalid="ignore"):
                ux, uy = np.where(r > 0, x / r, 0.0), np.where(r > 0, y / r, 0.0)
            da = c[2] + r * (2.0 * c[3] + 3.0 * c[4] * r)
            db = c[7] + r * (2.0 * c[8] + 3.0 * c[9] * r)
            jac[..., 0, 0] = 1.0 + da * ux
            jac[..., 0, 1] = da * uy
            jac[..., 1, 0] = db * ux
            jac[..., 1, 1] = 1.0 + db * uy
        return jac

    def _invert(self, tx: NDArray[np.float64], ty: NDArray[np.float64]) -> Pair:
        """Solve ``_closed(x, y) = (tx, ty)`` (ISD axes); NaN where it does not converge."""
        with np.errstate(all="ignore"):
            x, y = newton_inverse(self._closed, self._closed_jacobian, tx, ty, tx, ty, CSM_STEP_MM, CSM_MAX_ITER)
            fx, fy = self._closed(x, y)
            bad = ~(np.abs(fx - tx) <= CSM_RESIDUAL_MM) | ~(np.abs(fy - ty) <= CSM_RESIDUAL_MM)
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)

    def _isd_axes(self, x: ArrayLike, y: ArrayLike) -> Pair:
        return (self.axes[0] * np.asarray(x, dtype=np.float64), self.axes[1] * np.asarray(y, dtype=np.float64))

    # -- public: our focal-plane axes ----------------------------------------------
    def distort(self, x: ArrayLike, y: ArrayLike) -> Pair:
        """Undistorted -> distorted focal-plane mm (usgscsm ``applyDistortion``)."""
        xi, yi = self._isd_axes(x, y)
        xd, yd = self._invert(xi, yi) if self.model in _CLOSED_UNDISTORT else self._closed(xi, yi)
        return self.axes[0] * xd, self.axes[1] * yd

    def undistort(self, xd: ArrayLike, yd: ArrayLike) -> Pair:
        """Distorted -> undistorted focal-plane mm (usgscsm ``removeDistortion``)."""
        xi, yi = self._isd_axes(xd, yd)
        x, y = self._closed(xi, yi) if self.model in _CLOSED_UNDISTORT else self._invert(xi, yi)
        return self.axes[0] * x, self.axes[1] * y

    def distort_jacobian(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """d(x_d, y_d)/d(x, y) at undistorted points, shape (..., 2, 2).

        Analytic: the inverse of the closed form's Jacobian (inverse function theorem) for the
        models whose closed form is the undistortion.
        """
        xi, yi = self._isd_axes(x, y)
        if self.model in _CLOSED_UNDISTORT:
            xd, yd = self._invert(xi, yi)
            jac = _inverse_2x2(self._closed_jacobian(xd, yd))
        else:
            jac = self._closed_jacobian(xi, yi)
        s = np.array(self.axes)
        out: NDArray[np.float64] = jac * s[:, None] * s[None, :]  # S J S, S = diag(axes)
        return out
