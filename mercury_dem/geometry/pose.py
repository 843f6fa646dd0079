"""Exterior orientation: projection, back-projection, ray intersection and angles.

A pose is a body-fixed spacecraft (camera) position ``C`` in metres and a rotation
``R`` (3 x 3, body-fixed -> camera frame) such that a body-fixed point ``X`` has
camera-frame coordinates ``R @ (X - C)``. Batched functions take ``positions``
of shape (N, 3) and ``rotations`` of shape (N, 3, 3).

Pointing corrections of the bundle adjustment are three small angles
``omega`` (radians, about the camera X, Y, Z axes): the corrected rotation is
``rotation_from_angles(omega) @ R``. For small angles omega_x and omega_y move the
image along line and sample, omega_z twists it about the boresight.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.body import xyz_to_latlon
from mercury_dem.geometry.camera import FramingCamera

#: A height model: (lat_deg, lon_deg) arrays -> height above the datum, metres.
HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """Cross-product matrices [v]x of shape (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_from_angles(omega: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices exp([omega]x) (Rodrigues) for rotation vectors (..., 3), radians."""
    w = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = skew(w)
    k2 = k @ k
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    eye = np.broadcast_to(np.eye(3), k.shape)
    out: NDArray[np.float64] = eye + a * k + b * k2
    return out


def angles_from_rotation(rotation: ArrayLike) -> NDArray[np.float64]:
    """Rotation vectors (..., 3) of rotation matrices (log map; angles below pi)."""
    r = np.asarray(rotation, dtype=np.float64)
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    v = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    s = np.sin(theta)
    scale = np.where(theta < 1e-8, 0.5, theta / (2.0 * np.where(s == 0, 1.0, s)))
    return v * scale[..., None]


def look_at_rotation(position: ArrayLike, target: ArrayLike, north: ArrayLike = (0.0, 0.0, 1.0)) -> NDArray[np.float64]:
    """Rotation (body -> camera) that puts ``target`` on the boresight.

    The camera's -Y axis (up in the image, decreasing line) points as close to
    ``north`` as possible. Batched over leading dimensions.
    """
    c = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - c
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    n = np.broadcast_to(np.asarray(north, dtype=np.float64), z.shape)
    # Degenerate when looking along `north`: fall back to +X body.
    alt = np.broadcast_to(np.array([1.0, 0.0, 0.0]), z.shape)
    cross_n = np.linalg.norm(np.cross(z, n), axis=-1, keepdims=True)
    n = np.where(cross_n < 1e-9, alt, n)
    x = np.cross(z, n)  # camera +X (sample) points "east" when looking down
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-2)


def validate_pose(image_id: str, position: ArrayLike, rotation: ArrayLike, tol: float = 1e-6) -> None:
    """Raise :class:`GeometryError` naming the image and field when a pose is unusable."""
    c = np.asarray(position, dtype=np.float64)
    r = np.asarray(rotation, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise GeometryError(f"image {image_id}: field 'position' must be 3 finite numbers (m), got {c.tolist()}")
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise GeometryError(f"image {image_id}: field 'rotation' must be a finite 3x3 matrix")
    err = np.abs(r @ r.T - np.eye(3)).max()
    if err > tol or np.linalg.det(r) < 0:
        raise GeometryError(
            f"image {image_id}: field 'rotation' is not a proper orthonormal matrix "
            f"(max |R R^T - I| = {err:.2e}, det = {np.linalg.det(r):.6f}); re-derive it from the pointing"
        )


def body_to_camera(position: ArrayLike, rotation: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Camera-frame coordinates (N, 3) of body-fixed points (N, 3) for one pose."""
    p = np.asarray(points, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    return p @ np.asarray(rotation, dtype=np.float64).T


def project(
    camera: FramingCamera, position: ArrayLike, rotation: ArrayLike, points: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ground -> image for one pose.

    Returns
    -------
    pixels : (N, 2) sample, line (NaN behind the camera)
    depth : (N,) camera-frame Z, metres
    """
    v = body_to_camera(position, rotation, points)
    return camera.camera_to_pixel(v), v[..., 2]


def pixel_rays(
    camera: FramingCamera, position: ArrayLike, rotation: ArrayLike, pixels: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Body-fixed ray origins (N, 3) and unit directions (N, 3) of pixels for one pose."""
    v = camera.pixel_to_camera(pixels)
    d = v @ np.asarray(rotation, dtype=np.float64)  # R^T v
    o = np.broadcast_to(np.asarray(position, dtype=np.float64), d.shape)
    return o, d


def intersect_sphere(
    origins: ArrayLike, directions: ArrayLike, radius: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Nearest intersection of rays with spheres about the origin.

    Returns points (N, 3) (NaN where missed) and a hit mask. ``radius`` may be an
    array (one radius per ray).
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    r = np.asarray(radius, dtype=np.float64)
    b = np.sum(o * d, axis=-1)
    c = np.sum(o * o, axis=-1) - r * r
    disc = b * b - c
    hit = (disc >= 0) & (-b - np.sqrt(np.maximum(disc, 0.0)) > 0)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    pts = o + t[..., None] * d
    pts[~hit] = np.nan
    return pts, hit


def image_to_ground(
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    pixels: ArrayLike,
    height: HeightFunction | None = None,
    *,
    datum_radius_m: float,
    tol_m: float = 1e-4,
    max_iter: int = 50,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Image -> ground: intersect pixel rays with the datum, then iterate against ``height``.

    Without a height function the datum sphere is the surface. With one, the ray
    is intersected with the sphere of radius datum + h(lat, lon) at the previous
    estimate until the point moves less than ``tol_m`` (a fixed-point iteration,
    which converges for slopes well below the emission complement).

    Returns points (N, 3) body-fixed metres (NaN where the ray misses) and a hit mask.
    """
    o, d = pixel_rays(camera, position, rotation, pixels)
    pts, hit = intersect_sphere(o, d, datum_radius_m)
    if height is None:
        return pts, hit
    for _ in range(max_iter):
        lat, lon, _ = xyz_to_latlon(pts[hit], datum_radius_m)
        r = np.full(hit.shape, datum_radius_m)
        r[hit] = datum_radius_m + height(lat, lon)
        new, newhit = intersect_sphere(o, d, r)
        hit = hit & newhit
        moved = np.linalg.norm(np.where(hit[..., None], new - pts, 0.0), axis=-1)
        pts = np.where(hit[..., None], new, np.nan)
        if np.all(moved[hit] < tol_m):
            break
    return pts, hit


def illumination_angles(
    ground: ArrayLike,
    spacecraft: ArrayLike,
    sun: ArrayLike,
    normal: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Incidence, emission and phase angles (degrees) at ground points.

    ``normal`` defaults to the sphere normal (the label's convention: angles on the
    reference sphere, not the local slope).
    """
    g = np.asarray(ground, dtype=np.float64)
    n = g if normal is None else np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    to_sc = np.asarray(spacecraft, dtype=np.float64) - g
    to_sun = np.asarray(sun, dtype=np.float64) - g
    to_sc = to_sc / np.linalg.norm(to_sc, axis=-1, keepdims=True)
    to_sun = to_sun / np.linalg.norm(to_sun, axis=-1, keepdims=True)

    def ang(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        out: NDArray[np.float64] = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
        return out

    return ang(n, to_sun), ang(n, to_sc), ang(to_sun, to_sc)


def pixel_scale_m(camera: FramingCamera, slant_distance_m: ArrayLike) -> NDArray[np.float64]:
    """Pixel scale at a slant distance: distance x IFOV (the PDS label convention)."""
    return np.asarray(slant_distance_m, dtype=np.float64) * camera.ifov_rad

