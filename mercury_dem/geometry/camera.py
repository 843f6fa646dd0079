"""The framing camera: camera frame <-> image pixels, with MDIS-style distortion.

Frames and pixels (docs/conventions.md):

* camera frame: +Z the boresight (looking out of the camera), +X along increasing
  sample, +Y along increasing line; a point is visible when its Z > 0;
* focal plane: millimetres, ``x = f * X / Z``, ``y = f * Y / Z`` (undistorted);
* distortion: the CSM/ISIS "transverse" polynomial of MDIS, mapping undistorted
  focal-plane millimetres to distorted ones with the ten terms
  ``1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3``;
* pixels: 0-based, the centre of the first pixel at (sample, line) = (0, 0); ISIS
  is 1-based and CSM puts 0.5 at the first pixel centre: both are converted at the
  boundary only. ``sample = boresight_sample + x_d / p``, ``line = boresight_line + y_d / p``
  with ``p`` the pixel pitch times the summing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError

#: MDIS-NAC transverse distortion coefficients (NAIF kernel msgr_mdis_v160.ti,
#: INS-236820_OD_T_X / _Y, as carried by the CSM ISD of EN1072174528M).
MDIS_NAC_OD_T_X: tuple[float, ...] = (
    0.0, 1.001854269623802, 0.0, 0.0, -0.0005094440474941111, 0.0,
    1.004010471468856e-05, 0.0, 1.004010471468856e-05, 0.0,
)
MDIS_NAC_OD_T_Y: tuple[float, ...] = (
    0.0, 0.0, 1.0, 0.0009060010594996751, 0.0, 0.0003574842626620758,
    0.0, 1.004010471468856e-05, 0.0, 1.004010471468856e-05,
)


def _poly_terms(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ten transverse-polynomial terms, shape (..., 10)."""
    return np.stack(
        [np.ones_like(x), x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3], axis=-1
    )


def _poly_terms_dx(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    z, o = np.zeros_like(x), np.ones_like(x)
    return np.stack([z, o, z, 2 * x, y, z, 3 * x * x, 2 * x * y, y * y, z], axis=-1)


def _poly_terms_dy(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    z, o = np.zeros_like(x), np.ones_like(x)
    return np.stack([z, z, o, z, x, 2 * y, z, x * x, 2 * x * y, 3 * y * y], axis=-1)


@dataclass(frozen=True)
class FramingCamera:
    """A frame camera's interior orientation.

    Parameters
    ----------
    name : instrument name, e.g. ``"MDIS-NAC"``
    focal_length_mm : focal length, millimetres
    pixel_pitch_mm : detector pixel pitch before summing, millimetres
    summing : on-chip pixel summing (1, 2, 4, ...); the image pixel is ``summing`` detector pixels
    samples, lines : image size in pixels (after summing)
    boresight_sample, boresight_line : image pixel (0-based centre convention) of the optical axis
    distortion_x, distortion_y : transverse polynomial coefficients (10 each) or empty for none
    """

    name: str
    focal_length_mm: float
    pixel_pitch_mm: float
    summing: int
    samples: int
    lines: int
    boresight_sample: float
    boresight_line: float
    distortion_x: tuple[float, ...] = field(default=())
    distortion_y: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        if not (self.focal_length_mm > 0 and np.isfinite(self.focal_length_mm)):
            raise GeometryError(f"camera {self.name}: focal_length_mm must be > 0, got {self.focal_length_mm}")
        if not (self.pixel_pitch_mm > 0):
            raise GeometryError(f"camera {self.name}: pixel_pitch_mm must be > 0, got {self.pixel_pitch_mm}")
        if self.summing < 1 or self.samples < 1 or self.lines < 1:
            raise GeometryError(f"camera {self.name}: summing, samples and lines must be >= 1")
        if len(self.distortion_x) not in (0, 10) or len(self.distortion_x) != len(self.distortion_y):
            raise GeometryError(
                f"camera {self.name}: distortion_x/distortion_y need 10 coefficients each (or none)"
            )

    # -- derived quantities -------------------------------------------------
    @property
    def pixel_size_mm(self) -> float:
        """Size of one image pixel in the focal plane (pitch x summing), millimetres."""
        return self.pixel_pitch_mm * self.summing

    @property
    def ifov_rad(self) -> float:
        """Instantaneous field of view of one image pixel at the boresight, radians."""
        return self.pixel_size_mm / self.focal_length_mm

    @property
    def focal_length_px(self) -> float:
        """Focal length in image pixels."""
        return self.focal_length_mm / self.pixel_size_mm

    @property
    def has_distortion(self) -> bool:
        return len(self.distortion_x) == 10

    def with_size(self, samples: int) -> "FramingCamera":
        """The same camera read out at ``samples`` x ``samples`` by on-chip summing.

        The detector is ``samples * summing`` pixels wide; a smaller readout sums
        more detector pixels (MDIS sums 2x2 to make 512 x 512 images).
        """
        detector = self.samples * self.summing
        if samples < 1 or detector % samples:
            raise GeometryError(
                f"camera {self.name}: image size {samples} does not divide the {detector}-pixel detector"
            )
        summing = detector // samples
        return replace(
            self,
            summing=summing,
            samples=samples,
            lines=samples,
            boresight_sample=(self.boresight_sample + 0.5) * self.summing / summing - 0.5,
            boresight_line=(self.boresight_line + 0.5) * self.summing / summing - 0.5,
        )

    # -- distortion ---------------------------------------------------------
    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Undistorted focal-plane mm -> distorted focal-plane mm."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if not self.has_distortion:
            return x, y
        t = _poly_terms(x, y)
        return t @ np.asarray(self.distortion_x), t @ np.asarray(self.distortion_y)

    def distortion_jacobian(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """d(x_d, y_d)/d(x, y), shape (..., 2, 2)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        jac = np.zeros(x.shape + (2, 2))
        if not self.has_distortion:
            jac[..., 0, 0] = 1.0
            jac[..., 1, 1] = 1.0
            return jac
        tx, ty = _poly_terms_dx(x, y), _poly_terms_dy(x, y)
        cx, cy = np.asarray(self.distortion_x), np.asarray(self.distortion_y)
        jac[..., 0, 0], jac[..., 0, 1] = tx @ cx, ty @ cx
        jac[..., 1, 0], jac[..., 1, 1] = tx @ cy, ty @ cy
        return jac

    def undistort(
        self, xd: ArrayLike, yd: ArrayLike, tol_mm: float = 1e-12, max_iter: int = 20
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Distorted -> undistorted focal-plane mm by Newton iteration on :meth:`distort`."""
        xd = np.asarray(xd, dtype=np.float64)
        yd = np.asarray(yd, dtype=np.float64)
        if not self.has_distortion:
            return xd, yd
        x, y = xd.copy(), yd.copy()
        for _ in range(max_iter):
            fx, fy = self.distort(x, y)
            rx, ry = fx - xd, fy - yd
            j = self.distortion_jacobian(x, y)
            det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
            dx = (j[..., 1, 1] * rx - j[..., 0, 1] * ry) / det
            dy = (-j[..., 1, 0] * rx + j[..., 0, 0] * ry) / det
            x, y = x - dx, y - dy
            if np.all(np.abs(dx) < tol_mm) and np.all(np.abs(dy) < tol_mm):
                break
        return x, y

    # -- camera frame <-> pixels -------------------------------------------
    def camera_to_pixel(self, v_cam: ArrayLike) -> NDArray[np.float64]:
        """Pixels (sample, line), shape (..., 2), of camera-frame vectors (..., 3).

        Vectors with Z <= 0 (behind the camera) give NaN.
        """
        v = np.asarray(v_cam, dtype=np.float64)
        z = v[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            zsafe = np.where(z > 0, z, np.nan)
            x = self.focal_length_mm * v[..., 0] / zsafe
            y = self.focal_length_mm * v[..., 1] / zsafe
        xd, yd = self.distort(x, y)
        p = self.pixel_size_mm
        return np.stack([self.boresight_sample + xd / p, self.boresight_line + yd / p], axis=-1)

    def pixel_to_camera(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Unit camera-frame look vectors (..., 3) of pixels (sample, line) (..., 2)."""
        px = np.asarray(pixels, dtype=np.float64)
        p = self.pixel_size_mm
        xd = (px[..., 0] - self.boresight_sample) * p
        yd = (px[..., 1] - self.boresight_line) * p
        x, y = self.undistort(xd, yd)
        v = np.stack([x, y, np.full_like(x, self.focal_length_mm)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def edge_pixels(self, per_side: int = 8) -> NDArray[np.float64]:
        """Pixels around the image border, counter-clockwise from the first pixel, shape (4*per_side, 2).

        The outer edge of the outer pixels (-0.5 and size - 0.5) is used, so a
        footprint covers the whole image.
        """
        s0, s1 = -0.5, self.samples - 0.5
        l0, l1 = -0.5, self.lines - 0.5
        t = np.linspace(0.0, 1.0, per_side, endpoint=False)
        top = np.stack([s0 + t * (s1 - s0), np.full_like(t, l0)], axis=-1)
        right = np.stack([np.full_like(t, s1), l0 + t * (l1 - l0)], axis=-1)
        bottom = np.stack([s1 - t * (s1 - s0), np.full_like(t, l1)], axis=-1)
        left = np.stack([np.full_like(t, s0), l1 - t * (l1 - l0)], axis=-1)
        return np.concatenate([top, right, bottom, left])

    def in_image(self, pixels: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """True for pixels inside the image (pixel centres from 0 to size-1, widened by half a pixel)."""
        px = np.asarray(pixels, dtype=np.float64)
        s, l = px[..., 0], px[..., 1]
        lo = -0.5 + margin
        return (s >= lo) & (l >= lo) & (s <= self.samples - 0.5 - margin) & (l <= self.lines - 0.5 - margin)


def mdis_nac(samples: int = 1024, distortion: bool = True) -> FramingCamera:
    """MESSENGER MDIS narrow-angle camera (f = 549.1 mm, 1024^2 pixels of 14 um).

    ``samples`` < 1024 means on-chip summing (512 = MDIS's 2x2 summing).
    ``distortion`` adds the real NAC transverse distortion polynomial.
    """
    cam = FramingCamera(
        name="MDIS-NAC",
        focal_length_mm=549.1178195372703,
        pixel_pitch_mm=0.014,
        summing=1,
        samples=1024,
        lines=1024,
        boresight_sample=511.5,
        boresight_line=511.5,
        distortion_x=MDIS_NAC_OD_T_X if distortion else (),
        distortion_y=MDIS_NAC_OD_T_Y if distortion else (),
    )
    return cam if samples == 1024 else cam.with_size(samples)


def mdis_wac(samples: int = 1024) -> FramingCamera:
    """MESSENGER MDIS wide-angle camera, G filter (f ~ 78 mm, 1024^2 pixels of 14 um).

    Its distortion (a radial model in the kernels) is not represented: the
    synthetic missions render and adjust WAC images with an ideal pinhole.
    """
    cam = FramingCamera(
        name="MDIS-WAC",
        focal_length_mm=78.25,
        pixel_pitch_mm=0.014,
        summing=1,
        samples=1024,
        lines=1024,
        boresight_sample=511.5,
        boresight_line=511.5,
    )
    return cam if samples == 1024 else cam.with_size(samples)


PRESETS = {"MDIS-NAC": mdis_nac, "MDIS-WAC": mdis_wac}


def camera_preset(name: str, samples: int = 1024) -> FramingCamera:
    """A preset camera by name (``MDIS-NAC`` or ``MDIS-WAC``) at an image size."""
    try:
        return PRESETS[name](samples)
    except KeyError:
        raise GeometryError(f"unknown camera preset {name!r}; choose one of {sorted(PRESETS)}") from None
