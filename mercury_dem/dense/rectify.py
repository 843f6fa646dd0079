"""Rectifying a chip of a stereo pair with the adjusted cameras, and its disparity search range.

S2P rectifies each ~800 px tile of a pushbroom pair with an *affine* fundamental matrix: over a small
tile of a narrow-field camera the epipolar lines are parallel. Our images are frame cameras of wider
field (the MDIS WAC sees 10.5 deg), whose epipolar lines fan out from an epipole a few thousand pixels
away, so an affine map of the right image leaves vertical disparities of pixels where the terrain
departs from the surface it was fitted on. The chip is therefore rectified about the *current surface
estimate* (the sparse DEM, or the tie points' heights), which is what the adjusted cameras and that
surface predict:

1. a grid of the left chip's pixels (collar included) is intersected with the current surface, and
   each ground point is also moved up and down its local vertical by ``height_margin_m``;
2. the homography ``S`` mapping left pixels to right pixels on the surface is fitted to the grid
   (``cv2.findHomography``, least squares: a homography is exact for a plane seen by two pinholes and
   within a small fraction of a pixel for a chip's curved, rough surface);
3. the parallax of the raised/lowered points, with the right image brought into the left frame by
   ``S^-1``, gives the local epipolar direction; one rotation ``R`` (the same for both images) makes
   it the +x axis. A disparity ``d = u_right - u_left`` along x is then height above the surface,
   positive up, with ``parallax_px_per_m`` pixels per metre at the chip centre.

Both images are resampled into the rectified frame (the left one by the rotation only, the right one
by ``S^-1`` and the rotation: :func:`mercury_dem.match.pretransform.warp_to_reference`, which also
low-pass filters a finer right image; a coarser right image has the left chip low-pass filtered instead,
so both show the ground at the coarser resolution). The maps back to each original image are kept exactly
(``to_left``, ``to_right``), so triangulation uses the original cameras, not the rectification's
approximation; what the approximation costs is only a residual vertical disparity
(``vertical_rms_px``, measured on the grid over the search range: the rectification error, S2P's
"about 1/10 pixel").

The search range is the height margin converted to disparity, plus the largest epipolar residual of the
surface homography on the grid (the surface is not a plane), plus a stated pixel margin, rounded
to OpenCV's multiple of 16, so SGM's memory (``width x height x disparities`` 16-bit costs, twice) is
bounded and stated per chip (:attr:`RectifiedChip.sgm_memory_bytes`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.pose import HeightFunction, image_to_ground, project
from mercury_dem.match.pretransform import ImageGeometry, apply_homography, warp_to_reference

#: Ground-grid points per side over the chip for the fits.
RECTIFY_GRID = 9


@dataclass(frozen=True)
class Chip:
    """A window of the left image: the interior ``[x0, x0 + width) x [y0, y0 + height)`` pixels (0-based
    sample, line) whose disparities are kept, and a ``collar`` of context pixels on every side.
    """

    x0: int
    y0: int
    width: int
    height: int
    collar: int = 32

    @property
    def shape(self) -> tuple[int, int]:
        """(lines, samples) of the chip with its collar in the left image.

        The rectified frame (``RectifiedChip.left.shape``) is larger when the rectification rotates the chip.
        """
        return self.height + 2 * self.collar, self.width + 2 * self.collar

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(s0, l0, s1, l1): the interior's outer pixel edges in the left image (end-exclusive)."""
        return self.x0 - 0.5, self.y0 - 0.5, self.x0 + self.width - 0.5, self.y0 + self.height - 0.5

    @property
    def centre(self) -> NDArray[np.float64]:
        """The interior's centre, left-image pixels (sample, line)."""
        return np.array([self.x0 + (self.width - 1) / 2.0, self.y0 + (self.height - 1) / 2.0])


@dataclass(frozen=True)
class RectifiedChip:
    """A rectified chip pair and what it takes to go back to the images.

    Attributes
    ----------
    left, right : ndarray of shape ``chip.shape``, float32 DN, rectified
    left_valid, right_valid : ndarray of shape ``chip.shape``, bool: the sample lies inside its image
    to_left : ndarray (3, 3), rectified pixel (u, v, 1) -> left image pixel (an affine map)
    to_right : ndarray (3, 3), rectified pixel -> right image pixel (a homography)
    disparity_min_px, disparity_max_px : search range of ``d = u_right - u_left``, rectified pixels
    parallax_px_per_m : disparity per metre of height above the current surface at the chip centre
    vertical_rms_px : RMS vertical disparity the rectification leaves on the grid over the search range
    surface_fit_rms_px : RMS of the surface homography fit, right-image pixels
    interior : (v0, v1, u0, u1) slice bounds of the rectified pixels whose left pixel is in the chip's interior
        (its bounding box: the interior is a rotated rectangle in the rectified frame, :meth:`interior_mask`)
    left_bounds : the chip interior's pixel edges in the left image (:attr:`Chip.bounds`)
    sgm_memory_bytes : upper bound of SGM's cost-volume memory for this chip (2 int16 volumes)
    right_px_per_rect_px : linear scale of the right image in the rectified frame at the chip centre
        (below 1: the right image is coarser, and both chips are at its resolution)
    """

    left: NDArray[np.float32]
    right: NDArray[np.float32]
    left_valid: NDArray[np.bool_]
    right_valid: NDArray[np.bool_]
    to_left: NDArray[np.float64]
    to_right: NDArray[np.float64]
    disparity_min_px: float
    disparity_max_px: float
    parallax_px_per_m: float
    vertical_rms_px: float
    surface_fit_rms_px: float
    interior: tuple[int, int, int, int]
    sgm_memory_bytes: int
    right_px_per_rect_px: float = 1.0
    left_bounds: tuple[float, float, float, float] = (-np.inf, -np.inf, np.inf, np.inf)

    def interior_mask(self) -> NDArray[np.bool_]:
        """Rectified pixels whose left-image pixel lies in the chip's interior, shape of the chips.

        Chips of :func:`mercury_dem.dense.chip.chip_grid` have disjoint interiors, so every left pixel is
        kept by exactly one chip, whatever the rotation.
        """
        hh, ww = self.left.shape
        vv, uu = np.mgrid[0:hh, 0:ww]
        lp = apply_homography(self.to_left, np.stack([uu.ravel(), vv.ravel()], -1).astype(np.float64))
        s0, l0, s1, l1 = self.left_bounds
        inside = (lp[:, 0] >= s0) & (lp[:, 0] < s1) & (lp[:, 1] >= l0) & (lp[:, 1] < l1)
        return np.asarray(inside.reshape(hh, ww), bool)

    @property
    def coarser_px(self) -> float:
        """Rectified pixels per pixel of the coarser image (>= 1): the chips' common resolution."""
        return float(max(1.0, 1.0 / self.right_px_per_rect_px))

    @property
    def disparity_count(self) -> int:
        """Number of integer disparities searched, a multiple of 16 (OpenCV's requirement)."""
        n = int(np.ceil(self.disparity_max_px) - np.floor(self.disparity_min_px)) + 1
        return int(16 * np.ceil(n / 16))


def _raise(points: NDArray[np.float64], dh: float) -> NDArray[np.float64]:
    """Points moved ``dh`` metres along their local vertical (the sphere normal)."""
    return np.asarray(points + dh * points / np.linalg.norm(points, axis=-1, keepdims=True), np.float64)


def rectify_chip(
    left_image: NDArray[np.float32],
    right_image: NDArray[np.float32],
    left: ImageGeometry,
    right: ImageGeometry,
    chip: Chip,
    surface_height: HeightFunction | None = None,
    height_margin_m: float = 1000.0,
    margin_px: float = 2.0,
    psf_sigma_px: float = 0.6,
) -> RectifiedChip:
    """Rectify one chip of a pair about the current surface (module docstring).

    Parameters
    ----------
    left_image, right_image : ndarray (lines, samples) float32, DN
    left, right : the adjusted geometry of each image
    chip : the window of the left image
    surface_height : the current surface, height (m) above the datum at (lat, lon) degrees (the sparse
        DEM sampled, or a constant from the tie points); the datum when None
    height_margin_m : how far the true surface may lie above or below ``surface_height`` here (from the
        tie points' scatter about it); sets the search range
    margin_px : disparity pixels added to each end of the search range
    psf_sigma_px : the images' point-spread sigma (own pixels), for the anti-aliasing of a finer right image

    Returns
    -------
    :class:`RectifiedChip`

    Raises
    ------
    GeometryError
        when the chip does not see the body or is not seen by the right image
    """
    ch, cw = chip.shape
    t = np.linspace(0.0, 1.0, RECTIFY_GRID)
    gs, gl = np.meshgrid(chip.x0 - chip.collar + t * (cw - 1), chip.y0 - chip.collar + t * (ch - 1))
    px1 = np.stack([gs.ravel(), gl.ravel()], axis=-1)
    ground, hit = image_to_ground(left.camera, left.position, left.rotation, px1, height=surface_height,
                                  datum_radius_m=left.datum_radius_m)
    if hit.sum() < 8:
        raise GeometryError(f"chip at ({chip.x0}, {chip.y0}): fewer than 8 of its grid rays reach the surface")
    px1, ground = px1[hit], ground[hit]
    px2, depth = project(right.camera, right.position, right.rotation, ground)
    ok = (depth > 0) & np.all(np.isfinite(px2), axis=-1)
    if ok.sum() < 8:
        raise GeometryError(f"chip at ({chip.x0}, {chip.y0}): the right camera does not see its ground")
    px1, ground, px2 = px1[ok], ground[ok], px2[ok]
    s12, _ = cv2.findHomography(px1, px2, 0)
    if s12 is None or not np.all(np.isfinite(s12)):
        raise GeometryError(f"chip at ({chip.x0}, {chip.y0}): the surface homography could not be fitted")
    fit_rms = float(np.sqrt(np.mean(np.sum((apply_homography(s12, px1) - px2) ** 2, axis=-1))))
    s21 = np.linalg.inv(s12)

    # Parallax of raised / lowered points, the right image brought into the left frame by S^-1.
    dh = float(height_margin_m) if height_margin_m > 0 else 100.0
    par = []
    for sign in (-1.0, 1.0):
        g = _raise(ground, sign * dh)
        a, _ = project(left.camera, left.position, left.rotation, g)
        b, _ = project(right.camera, right.position, right.rotation, g)
        par.append(apply_homography(s21, b) - a)
    per_m = (par[1] - par[0]) / (2.0 * dh)  # left px per metre of height, per grid point
    mean = per_m.mean(axis=0)
    theta = float(np.arctan2(mean[1], mean[0]))
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, s], [-s, c]])  # left px offset -> rectified (the parallax direction to +x)
    vertical = np.concatenate([p @ rot[1] for p in par])
    vertical_rms = float(np.sqrt(np.mean(vertical**2)))
    # the homography is exact for a plane only: on the current surface itself (curved over a chip of a
    # coarse image, rough) it leaves a residual whose epipolar part is a disparity offset the search range
    # must hold (on the tiny mission's whole-image chips 2-9 px, which the margin alone did not cover)
    along = (apply_homography(s21, px2) - px1) @ rot[0]
    offset_px = float(np.max(np.abs(along))) if along.size else 0.0
    # Parallax at the chip centre (nearest grid point to it).
    k = int(np.argmin(np.sum((px1 - chip.centre) ** 2, axis=-1)))
    rate = float(per_m[k] @ rot[0])

    # the rectified frame holds the rotated interior plus the collar on every side; it grows by whole pixels
    # on both sides (the chip's parity kept), so an unrotated chip samples the left image at its own pixel
    # centres instead of between them (a half-pixel bilinear resampling is a low-pass filter: it changed
    # the noise the refinement's precision assumes, and 10 % of the points of the test pair)
    need_w = np.ceil(abs(c) * chip.width + abs(s) * chip.height - 1e-9) + 2 * chip.collar
    need_h = np.ceil(abs(s) * chip.width + abs(c) * chip.height - 1e-9) + 2 * chip.collar
    ww = cw + 2 * int(np.ceil(max(0.0, need_w - cw) / 2))
    hh = ch + 2 * int(np.ceil(max(0.0, need_h - ch) / 2))
    u_c = np.array([(ww - 1) / 2.0, (hh - 1) / 2.0])
    to_left = np.eye(3)
    to_left[:2, :2] = rot.T
    to_left[:2, 2] = chip.centre - rot.T @ u_c
    to_right = s12 @ to_left
    to_right /= to_right[2, 2]

    shape = (hh, ww)
    # right pixels per rectified (= left) pixel: above 1 the right image is finer and warp_to_reference blurs
    # it to the left's resolution; below 1 it is coarser and the left chip is blurred to the right's instead
    # (the same rule in the other direction), so both chips show the ground at one resolution
    scale = _linear_scale(to_right, u_c)
    lr, lv = warp_to_reference(np.asarray(left_image, np.float32), to_left, shape, 1.0, psf_sigma_px)
    if scale < 1.0 / 1.05:
        lr = np.asarray(cv2.GaussianBlur(lr, (0, 0), sigmaX=psf_sigma_px * float(np.sqrt(1.0 / scale**2 - 1.0))),
                        np.float32)
    rr, rv = warp_to_reference(np.asarray(right_image, np.float32), to_right, shape, scale, psf_sigma_px)
    span = abs(rate) * dh + offset_px + margin_px
    dmin, dmax = -span, span
    n = int(16 * np.ceil((int(np.ceil(dmax) - np.floor(dmin)) + 1) / 16))
    memory = 2 * 2 * hh * ww * n
    rect = RectifiedChip(lr, rr, lv, rv, to_left, to_right, dmin, dmax, rate, vertical_rms, fit_rms,
                         (0, hh, 0, ww), memory, scale, chip.bounds)
    rows, cols = np.nonzero(rect.interior_mask())
    interior = (int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1)
    return replace(rect, interior=interior)


def _linear_scale(h: NDArray[np.float64], p: NDArray[np.float64]) -> float:
    """sqrt |det J| of a homography at a point: source pixels per destination pixel."""
    pts = np.array([p, p + [1.0, 0.0], p + [0.0, 1.0]])
    q = apply_homography(h, pts)
    return float(np.sqrt(abs(np.linalg.det(np.stack([q[1] - q[0], q[2] - q[0]], axis=-1)))))


def rectified_to_images(rect: RectifiedChip, u: NDArray[np.float64], v: NDArray[np.float64],
                        disparity: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Left and right image pixels (N, 2) of rectified left pixels (u, v) (N,) and their disparities (N,)."""
    ones = np.ones_like(u)
    a = np.stack([u, v, ones], axis=-1)
    b = np.stack([u + disparity, v, ones], axis=-1)
    return apply_homography(rect.to_left, a[:, :2]), apply_homography(rect.to_right, b[:, :2])
