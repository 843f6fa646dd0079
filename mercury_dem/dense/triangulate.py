"""Intersecting the rays of dense matches with the adjusted cameras: points, miss distances, angles, precision.

Each match (a left and a right image pixel) gives two rays of the adjusted cameras; the point is the
midpoint of their common perpendicular (the least-squares point of two rays, closed form, vectorised;
written here because OpenCV's ``triangulatePoints`` takes 3x4 projection matrices of undistorted pinholes
and returns neither the miss distance nor the angle).

Per point:

* ``miss_m``: the length of the common perpendicular (ASP's "intersection error"); with rectified
  matches it comes from the vertical disparity the matcher did not see plus the cameras' residual error;
* ``angle_deg``: the triangulation angle between the two rays at the point;
* ``sigma_h_m``: the stated vertical precision, ``|dh/dd| * sigma_d``: the height change per pixel of
  disparity along the rectified epipolar direction (finite difference through the same triangulation,
  so the pair's geometry -- parallax/height ratio, pixel scale, obliquity -- is in it exactly), times the
  matcher's stated disparity precision (:mod:`mercury_dem.dense.disparity`, times ``sigma_scale``) combined
  with a floor (``sigma_floor_px``) for what the window's residuals do not show: the rectification, the
  cameras, and view-dependent shading; then, in metres, a height floor (``sigma_height_floor_m``: relief
  within the matching window, which a window matcher cannot resolve, and its pull toward the surface the
  search is centred on) and a cap (``sigma_height_cap_m``: a point kept only within +-R of that surface has
  a spread of at most R/sqrt(3) about it, the uniform distribution's, however weak its pair's geometry).

:func:`filter_points` applies the limits on each and says how many each removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.dense.rectify import RectifiedChip, rectified_to_images
from mercury_dem.geometry.body import xyz_to_latlon
from mercury_dem.geometry.pose import pixel_rays
from mercury_dem.match.pretransform import ImageGeometry, apply_homography


@dataclass(frozen=True)
class DensePoints:
    """Columnar dense points of one chip (N points).

    Attributes
    ----------
    xyz : ndarray (N, 3), body-fixed metres
    lat, lon, height : ndarray (N,), planetocentric degrees (east, 0..360) and metres above the datum
    left_px, right_px : ndarray (N, 2), the match's image pixels (sample, line), 0-based
    miss_m : ndarray (N,), ray intersection miss distance, metres
    angle_deg : ndarray (N,), triangulation angle, degrees
    sigma_h_m : ndarray (N,), stated vertical precision (1 sigma), metres
    score : ndarray (N,), the matcher's score (zero-mean normalised correlation)
    sigma_match_px : ndarray (N,) or None, the matcher's own disparity sigma (rectified pixels, before
        ``sigma_scale`` and the floor): kept so the precision model can be recalibrated on the cloud
    m_per_px : ndarray (N,) or None, ``|dh/dd|``, metres of height per rectified pixel of disparity
    """

    xyz: NDArray[np.float64]
    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    height: NDArray[np.float64]
    left_px: NDArray[np.float64]
    right_px: NDArray[np.float64]
    miss_m: NDArray[np.float64]
    angle_deg: NDArray[np.float64]
    sigma_h_m: NDArray[np.float64]
    score: NDArray[np.float64]
    sigma_match_px: NDArray[np.float64] | None = None
    m_per_px: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.height.shape[0])

    def subset(self, keep: NDArray[np.bool_]) -> DensePoints:
        """The points where ``keep`` (N,) is True."""
        values: dict[str, Any] = {f: (None if getattr(self, f) is None else getattr(self, f)[keep])
                                  for f in self.__dataclass_fields__}
        return DensePoints(**values)


def intersect_rays(
    o1: NDArray[np.float64], d1: NDArray[np.float64], o2: NDArray[np.float64], d2: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Midpoints (N, 3), miss distances (N,) and angles (N,, degrees) of ray pairs (origins, unit directions).

    Parallel rays give NaN points.
    """
    w = o1 - o2
    b = np.sum(d1 * d2, axis=-1)
    d = np.sum(d1 * w, axis=-1)
    e = np.sum(d2 * w, axis=-1)
    den = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(den > 1e-15, (b * e - d) / den, np.nan)
        t2 = np.where(den > 1e-15, (e - b * d) / den, np.nan)
    p1 = o1 + t1[:, None] * d1
    p2 = o2 + t2[:, None] * d2
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(d1, d2), axis=-1), b))
    return 0.5 * (p1 + p2), np.linalg.norm(p1 - p2, axis=-1), angle


def triangulate_pixels(
    left: ImageGeometry, right: ImageGeometry, left_px: NDArray[np.float64], right_px: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`intersect_rays` of matched pixels (N, 2) of two images with their (adjusted) cameras."""
    o1, d1 = pixel_rays(left.camera, left.position, left.rotation, left_px)
    o2, d2 = pixel_rays(right.camera, right.position, right.rotation, right_px)
    return intersect_rays(np.asarray(o1, np.float64), d1, np.asarray(o2, np.float64), d2)


def stated_height_sigma(sigma_m: NDArray[np.float64], floor_m: float = 0.0,
                        cap_m: float | None = None) -> NDArray[np.float64]:
    """``min(hypot(sigma_m, floor_m), cap_m)``: the height floor and the cap of the stated precision (module
    docstring).
    """
    out = np.hypot(sigma_m, floor_m) if floor_m > 0 else np.asarray(sigma_m, np.float64)
    return np.minimum(out, cap_m) if cap_m is not None else out


def triangulate_chip(
    rect: RectifiedChip,
    left: ImageGeometry,
    right: ImageGeometry,
    disparity: NDArray[np.float32],
    sigma_px: NDArray[np.float32],
    score: NDArray[np.float32] | None = None,
    sigma_floor_px: float = 0.05,
    interior_only: bool = True,
    sigma_scale: float = 1.0,
    sigma_height_floor_m: float = 0.0,
    sigma_height_cap_m: float | None = None,
) -> DensePoints:
    """Dense points of a chip's valid disparities.

    Parameters
    ----------
    rect : the rectified chip (its maps back to the images)
    left, right : the adjusted geometry of each image
    disparity, sigma_px : ndarray (H, W) of the rectified chip, NaN in holes
    score : ndarray (H, W) or None
    sigma_floor_px : disparity error added in quadrature to ``sigma_px`` for what the matcher's
        precision does not see: the rectification's vertical residual and the cameras' adjusted
        error (a stated floor; the bundle adjustment's sigma0 in pixels is the natural value), in pixels
        of the coarser image (scaled by ``rect.coarser_px`` into rectified pixels)
    interior_only : keep only the chip's interior (the collar is context for the matcher)
    sigma_scale : factor on the matcher's ``sigma_px`` before the floor is added: its least-squares precision
        assumes the residuals are noise, while a shading difference between the views (the mission
        renderer's Lommel-Seeliger term) shifts the match coherently over the window. The stated disparity
        precision is ``hypot(sigma_scale * sigma_px, sigma_floor_px * coarser_px)``; the stage's values are
        calibrated on dense residuals (``dense.sigma_scale``, ``dense.sigma_floor_px``)
    sigma_height_floor_m : metres added in quadrature to ``|dh/dd| * sigma_d`` (see the module docstring)
    sigma_height_cap_m : the stated precision at most this (None: no cap); the stage passes R/sqrt(3) for its
        range filter's R (``dense.max_height_offset_factor`` x the height margin)

    Returns
    -------
    :class:`DensePoints` in row-major order of the rectified chip
    """
    ok = np.isfinite(disparity) & np.isfinite(sigma_px)
    if interior_only:
        ok &= rect.interior_mask()
    vv, uu = np.nonzero(ok)
    u, v = uu.astype(np.float64), vv.astype(np.float64)
    dd = disparity[ok].astype(np.float64)
    lpx, rpx = rectified_to_images(rect, u, v, dd)
    # the left ray is fixed by the left pixel: computed once, the right one at d and d +- 0.5 px
    o1, d1 = pixel_rays(left.camera, left.position, left.rotation, lpx)
    o1 = np.asarray(o1, np.float64)

    def with_right(right_px: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        o2, d2 = pixel_rays(right.camera, right.position, right.rotation, right_px)
        return intersect_rays(o1, d1, np.asarray(o2, np.float64), d2)

    xyz, miss, angle = with_right(rpx)
    lat, lon, h = xyz_to_latlon(xyz, left.datum_radius_m)
    # dh/dd by a central difference of +-0.5 px through the same maps and rays
    hs = [xyz_to_latlon(with_right(apply_homography(rect.to_right, np.stack([u + dd + step, v], axis=-1)))[0],
                        left.datum_radius_m)[2] for step in (-0.5, 0.5)]
    dh_dd = np.abs(hs[1] - hs[0])
    sig_d = np.hypot(sigma_scale * sigma_px[ok].astype(np.float64), sigma_floor_px * rect.coarser_px)
    sig_h = stated_height_sigma(dh_dd * sig_d, sigma_height_floor_m, sigma_height_cap_m)
    sc = np.full(u.shape, np.nan) if score is None else score[ok].astype(np.float64)
    return DensePoints(xyz, lat, lon, h, lpx, rpx, miss, angle, sig_h, sc,
                       sigma_px[ok].astype(np.float64), dh_dd)


@dataclass(frozen=True)
class PointFilter:
    """Limits on dense points (each NaN-safe: a NaN value fails its limit).

    Attributes
    ----------
    max_miss_m : largest ray miss distance, metres; None: ``max_miss_pixels`` times the left pixel scale
    max_miss_pixels : the miss limit in left-image pixels (at each point's range) when ``max_miss_m`` is None
    min_angle_deg : smallest triangulation angle, degrees
    max_sigma_h_m : largest stated vertical precision, metres (None: no limit)
    """

    max_miss_m: float | None = None
    max_miss_pixels: float = 1.0
    min_angle_deg: float = 5.0
    max_sigma_h_m: float | None = None


def filter_points(points: DensePoints, left: ImageGeometry,
                  limits: PointFilter = PointFilter()) -> tuple[DensePoints, dict[str, int]]:
    """The points within every limit, and how many each limit removed (a point may fail several)."""
    if limits.max_miss_m is not None:
        max_miss = np.full(len(points), limits.max_miss_m)
    else:
        rng = np.linalg.norm(points.xyz - left.position, axis=-1)
        max_miss = limits.max_miss_pixels * rng * left.camera.ifov_rad
    bad_miss = ~(points.miss_m <= max_miss)
    bad_angle = ~(points.angle_deg >= limits.min_angle_deg)
    bad_sigma = (np.zeros(len(points), bool) if limits.max_sigma_h_m is None
                 else ~(points.sigma_h_m <= limits.max_sigma_h_m))
    keep = ~(bad_miss | bad_angle | bad_sigma)
    removed = {"miss": int(bad_miss.sum()), "angle": int(bad_angle.sum()), "sigma_h": int(bad_sigma.sum())}
    return points.subset(keep), removed
