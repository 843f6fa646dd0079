"""Geometric pre-transform of a pair from its a-priori geometry (like ISIS ``FASTGEOM``).

A grid of reference pixels is intersected with the datum sphere and projected
into the match image; a homography ``H`` (reference pixel -> match pixel) is
fitted to those points by least squares (``cv2.findHomography``, method 0).
Warping the match image with ``H`` (``cv2.warpPerspective`` with
``WARP_INVERSE_MAP``) puts it in the reference's geometry: scale, rotation and
perspective differences are gone and a true match lies at the same pixel up to
the pointing error and relief parallax. Warped-frame positions map back to the
original match image exactly by ``H`` (it is the warp's own sampling function).

The same grid gives the pair's a-priori overlap, scale ratio and illumination
(incidence of each image and sun-azimuth difference at the overlap centre).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import illumination_angles, image_to_ground, project


@dataclass(frozen=True)
class ImageGeometry:
    """A-priori geometry of one image: camera, pose and sun.

    Attributes
    ----------
    camera : the framing camera (its samples x lines is the image size)
    position : ndarray (3,), spacecraft position, body-fixed metres
    rotation : ndarray (3, 3), body-fixed -> camera (``v_cam = R @ (X - C)``)
    sun_position : ndarray (3,), Sun position, body-fixed metres
    datum_radius_m : the body's datum sphere, the surface of the pre-transform
    """

    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]
    sun_position: NDArray[np.float64]
    datum_radius_m: float

    @staticmethod
    def of(camera: FramingCamera, position: ArrayLike, rotation: ArrayLike, sun_position: ArrayLike,
           datum_radius_m: float) -> ImageGeometry:
        return ImageGeometry(
            camera,
            np.asarray(position, dtype=np.float64).reshape(3),
            np.asarray(rotation, dtype=np.float64).reshape(3, 3),
            np.asarray(sun_position, dtype=np.float64).reshape(3),
            float(datum_radius_m),
        )


@dataclass(frozen=True)
class PairGeometry:
    """What the a-priori geometry says about a pair.

    Attributes
    ----------
    homography : ndarray (3, 3), reference pixel -> match pixel (homogeneous), a-priori on the datum
    fit_rms_px : RMS of the homography fit, match pixels (datum curvature, distortion)
    overlap : share of the reference image whose datum point falls inside the match image (0..1)
    scale_ratio : ground pixel size ratio, >= 1 (the coarser over the finer) at the overlap centre
    match_px_per_ref_px : linear scale of ``homography`` at the overlap centre
    incidence_ref_deg, incidence_match_deg : incidence at the overlap centre (sphere normal)
    sun_azimuth_difference_deg : difference of the local sun azimuths, 0..180
    guidance_px : guidance window half-width, reference pixels: ``guidance_sigmas`` times the
        combined pointing and position error of both images, plus ``guidance_margin_px``
    convergence_deg : angle between the two cameras' rays at the overlap centre (0 = the same view
        direction; the relief's parallax left by the datum pre-transform grows with it)
    overlap_centre_m : ndarray (3,), the overlap centre on the datum, body-fixed metres (where the angles
        above are computed; the stereo-pair selection measures the parallax/height ratio there), or None
    """

    homography: NDArray[np.float64]
    fit_rms_px: float
    overlap: float
    scale_ratio: float
    match_px_per_ref_px: float
    incidence_ref_deg: float
    incidence_match_deg: float
    sun_azimuth_difference_deg: float
    guidance_px: float
    convergence_deg: float = float("nan")
    overlap_centre_m: NDArray[np.float64] | None = None


def sun_azimuth_deg(ground: NDArray[np.float64], sun: NDArray[np.float64]) -> float:
    """Azimuth of the Sun (degrees clockwise from north) at a ground point (3,), body-fixed."""
    up = ground / np.linalg.norm(ground)
    east = np.cross([0.0, 0.0, 1.0], up)
    if np.linalg.norm(east) < 1e-9:  # at a pole: any horizontal direction is "north"
        east = np.cross([0.0, 1.0, 0.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    s = sun - ground
    return float(np.degrees(np.arctan2(s @ east, s @ north)) % 360.0)


def angle_difference_deg(a: float, b: float) -> float:
    """Absolute difference of two angles in degrees, folded into 0..180."""
    d = abs(a - b) % 360.0
    return float(min(d, 360.0 - d))


def apply_homography(h: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Map points (N, 2) by a homography (3, 3)."""
    p = np.asarray(points, dtype=np.float64)
    q = p @ h[:, :2].T + h[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return q[:, :2] / q[:, 2:3]


def pair_geometry(
    ref: ImageGeometry,
    match: ImageGeometry,
    grid: int = 9,
    pointing_sigma_urad: float = 0.0,
    guidance_sigmas: float = 3.0,
    guidance_margin_px: float = 0.0,
    position_sigma_m: float = 0.0,
) -> PairGeometry | str:
    """The pre-transform homography, overlap, scale and illumination of a pair, or a failure reason.

    Returns a string (the reason) when the reference does not see the body or the
    pair has no a-priori overlap. ``pointing_sigma_urad`` (µrad per axis) and ``position_sigma_m``: how wrong
    each image's a-priori pointing and position may be (1 sigma), for the guidance window.
    """
    cam_r, cam_m = ref.camera, match.camera
    t = (np.arange(grid) + 0.5) / grid
    ss, ll = np.meshgrid(t * cam_r.samples - 0.5, t * cam_r.lines - 0.5)
    px_r = np.stack([ss.ravel(), ll.ravel()], axis=-1)
    ground, hit = image_to_ground(cam_r, ref.position, ref.rotation, px_r, datum_radius_m=ref.datum_radius_m)
    if hit.sum() < 4:
        return "reference image does not see the body at enough grid points for the pre-transform"
    px_m, depth = project(cam_m, match.position, match.rotation, ground[hit])
    front = (depth > 0) & np.all(np.isfinite(px_m), axis=-1)
    inside = front & cam_m.in_image(np.nan_to_num(px_m, nan=-1e9))
    overlap = float(inside.sum()) / float(px_r.shape[0])
    if not inside.any():
        return "no a-priori overlap (no reference grid point projects into the match image)"
    # Fit over the overlap (plus its neighbours) when it is well covered, else over all visible points.
    use = front & cam_m.in_image(np.nan_to_num(px_m, nan=-1e9), margin=-0.25 * max(cam_m.samples, cam_m.lines))
    if use.sum() < 8:
        use = front
    if use.sum() < 4:
        return "too few reference grid points are in front of the match camera"
    src = px_r[hit][use].astype(np.float64)
    dst = px_m[use].astype(np.float64)
    h, _ = cv2.findHomography(src, dst, 0)
    if h is None or not np.all(np.isfinite(h)):
        return "pre-transform homography could not be fitted (degenerate a-priori geometry)"
    fit_rms = float(np.sqrt(np.mean(np.sum((apply_homography(h, src) - dst) ** 2, axis=-1))))
    # Overlap centre, local scale and illumination there.
    centre_r = px_r[hit][inside].mean(axis=0)
    scale = _local_scale(h, centre_r)
    g = ground[hit][inside].mean(axis=0)
    g = g / np.linalg.norm(g) * np.linalg.norm(ground[hit][0])
    inc_r = float(illumination_angles(g, ref.position, ref.sun_position)[0])
    inc_m = float(illumination_angles(g, match.position, match.sun_position)[0])
    daz = angle_difference_deg(sun_azimuth_deg(g, ref.sun_position), sun_azimuth_deg(g, match.sun_position))
    # Guidance: pointing and position error of each image (as angles seen from the camera, in
    # IFOV pixels), the match image's converted to reference pixels, combined.
    range_r = float(np.linalg.norm(g - ref.position))
    range_m = float(np.linalg.norm(g - match.position))
    ang_r = float(np.hypot(pointing_sigma_urad * 1e-6, position_sigma_m / range_r))
    ang_m = float(np.hypot(pointing_sigma_urad * 1e-6, position_sigma_m / range_m))
    sig_r = ang_r / cam_r.ifov_rad
    sig_m = ang_m / cam_m.ifov_rad / max(scale, 1e-9)
    guidance = guidance_sigmas * float(np.hypot(sig_r, sig_m)) + guidance_margin_px
    ray_r, ray_m = (ref.position - g) / range_r, (match.position - g) / range_m
    convergence = float(np.degrees(np.arccos(np.clip(ray_r @ ray_m, -1.0, 1.0))))
    return PairGeometry(
        homography=h,
        fit_rms_px=fit_rms,
        overlap=overlap,
        scale_ratio=float(max(scale, 1.0 / max(scale, 1e-12))),
        match_px_per_ref_px=float(scale),
        incidence_ref_deg=inc_r,
        incidence_match_deg=inc_m,
        sun_azimuth_difference_deg=daz,
        guidance_px=guidance,
        convergence_deg=convergence,
        overlap_centre_m=g,
    )


def _local_scale(h: NDArray[np.float64], p: NDArray[np.float64], d: float = 1.0) -> float:
    """sqrt |det J| of a homography at a point: match pixels per reference pixel (linear)."""
    pts = np.array([p, p + [d, 0.0], p + [0.0, d]])
    q = apply_homography(h, pts)
    j = np.stack([(q[1] - q[0]) / d, (q[2] - q[0]) / d], axis=-1)
    return float(np.sqrt(abs(np.linalg.det(j))))


def warp_to_reference(
    match_image: NDArray[np.float32],
    homography: NDArray[np.float64],
    ref_shape: tuple[int, int],
    scale: float,
    psf_sigma_px: float = 0.7,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The match image resampled in the reference geometry, and where it is valid.

    Parameters
    ----------
    match_image : ndarray (lines, samples) float32, DN
    homography : reference pixel -> match pixel
    ref_shape : (lines, samples) of the reference image
    scale : match pixels per reference pixel. Above 1 (the match image is finer)
        it is low-pass filtered first with a Gaussian of sigma
        ``psf_sigma_px * sqrt(scale**2 - 1)`` match pixels, so that after the warp
        its blur equals that of an image taken at the reference's pixel scale
        (both images having a point spread of ``psf_sigma_px`` of their own pixels,
        pixel footprint included); this also prevents aliasing
    psf_sigma_px : point-spread sigma of the images in their own pixels

    Returns
    -------
    warped : ndarray ref_shape float32 (border pixels replicated outside the match image)
    valid : ndarray ref_shape bool, True where the bilinear sample is fully inside the match image
    """
    src = match_image
    if scale > 1.05:
        src = cv2.GaussianBlur(src, (0, 0), sigmaX=psf_sigma_px * float(np.sqrt(scale * scale - 1.0)))
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    size = (int(ref_shape[1]), int(ref_shape[0]))
    # Replicated borders keep the detectors from seeing an artificial edge where the data ends.
    warped = cv2.warpPerspective(src, homography, size, flags=flags, borderMode=cv2.BORDER_REPLICATE)
    return warped, valid_region(homography, match_image.shape, ref_shape)


def valid_region(
    homography: NDArray[np.float64], match_shape: tuple[int, ...], ref_shape: tuple[int, int]
) -> NDArray[np.bool_]:
    """Reference-frame pixels whose bilinear sample lies fully inside the match image.

    A homography maps the match image's border (its pixel-centre rectangle) to a
    quadrilateral, which is filled and shrunk by one pixel for safety. When a
    corner maps through infinity (the match image sees the horizon of the
    reference plane) the region is found by warping an image of ones instead.
    """
    hm, wm = int(match_shape[0]), int(match_shape[1])
    corners = np.array([[0.0, 0.0], [wm - 1.0, 0.0], [wm - 1.0, hm - 1.0], [0.0, hm - 1.0]])
    inv = np.linalg.inv(homography)
    q = corners @ inv[:, :2].T + inv[:, 2]
    out = np.zeros(ref_shape, np.uint8)
    if np.all(q[:, 2] > 0) or np.all(q[:, 2] < 0):  # no corner maps through infinity
        poly = q[:, :2] / q[:, 2:3]
        if np.all(np.isfinite(poly)) and np.abs(poly).max() < 1e7:
            shift = 4
            cv2.fillConvexPoly(out, np.rint(poly * (1 << shift)).astype(np.int32), 1, lineType=cv2.LINE_8, shift=shift)
            return cv2.erode(out, np.ones((3, 3), np.uint8)).astype(bool)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    size = (int(ref_shape[1]), int(ref_shape[0]))
    ones = np.ones((hm, wm), np.float32)
    cover = cv2.warpPerspective(ones, homography, size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return cover > 0.999
