"""The framing camera: camera frame <-> image pixels, with lens distortion.

Frames and pixels (docs/conventions.md):

* camera frame: +Z the boresight (looking out of the camera), +X along increasing
  sample, +Y along increasing line; a point is visible when its Z > 0. An
  instrument whose NAIF frame looks along -Z (Apollo Metric) is turned into this
  frame by the fixed rotation that :func:`mercury_dem.geometry.naif_camera.camera_from_naif`
  returns with the camera;
* focal plane: millimetres, ``x = f * X / Z``, ``y = f * Y / Z`` (undistorted);
* distortion (:attr:`FramingCamera.distortion_model`): ``transverse``, the CSM/ISIS
  polynomial of MDIS mapping undistorted focal-plane millimetres to distorted ones
  with the ten terms ``1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3``;
  ``apollo_metric``, ISIS's radial + decentering model about a principal point
  (:class:`mercury_dem.geometry.distortion.ApolloMetricDistortion`); the other models of
  usgscsm's frame sensor (``radial``, ``cahvor``, ``dawnfc``, ``radtan``, ``lrolrocnac``,
  ``kaguyalism``: :class:`mercury_dem.geometry.distortion.CsmDistortion`); or ``none``;
* pixels: 0-based, the centre of the first pixel at (sample, line) = (0, 0); ISIS
  is 1-based and CSM puts 0.5 at the first pixel centre: both are converted at the
  boundary only. Image pixel -> distorted focal plane is one 2-D affine map,
  ``(x_d, y_d) = L @ (sample - boresight_sample, line - boresight_line)``; ``L`` is
  ``p * I`` with ``p`` the pixel pitch times the summing (the MDIS presets, computed
  as ``sample = boresight_sample + x_d / p``) unless ``focal_plane_map`` gives a
  general ``L`` (a detector with a reversed or rotated axis, a cropped/reduced cube).

Written here rather than taken from ISIS or usgscsm (C++ libraries with SPICE
dependencies): the adjustment needs vectorised projections and their analytic
Jacobians, which neither exposes, and only a few fixed models are needed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.distortion import (
    CSM_DISTORTION_SIZES,
    ApolloMetricDistortion,
    CsmDistortion,
    newton_inverse,
)

#: The distortion models a :class:`FramingCamera` can carry.
DISTORTION_MODELS = ("none", "transverse", "apollo_metric", *CSM_DISTORTION_SIZES)

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
    focal_length_mm : focal length, millimetres (positive; the camera looks along +Z)
    pixel_pitch_mm : detector pixel pitch before summing, millimetres
    summing : on-chip pixel summing (1, 2, 4, ...); the image pixel is ``summing`` detector pixels
    samples, lines : image size in pixels (after summing)
    boresight_sample, boresight_line : image pixel (0-based centre convention) of the origin of the
        distorted focal plane: the translation part of the pixel -> focal-plane affine. It is the
        optical axis when the distortion has no constant term (MDIS); for ``apollo_metric`` the
        optical axis is at the distorted point ``principal_point_mm`` instead.
    distortion_x, distortion_y : ``transverse`` polynomial coefficients (10 each) or empty
    focal_plane_map : empty, or the linear part ``L`` of image pixel -> distorted focal plane
        as four numbers ``(dx/ds, dx/dl, dy/ds, dy/dl)``, mm per image pixel (row-major 2 x 2).
        Empty means ``L = pixel_size_mm * I`` (square pixels, x along samples, y along lines).
    apollo_distortion : the ``apollo_metric`` model, or None
    csm_distortion : one of usgscsm's other models (:class:`~mercury_dem.geometry.distortion.CsmDistortion`),
        or None

    Notes
    -----
    The whole image pixel -> distorted focal plane map is the affine
    ``(x_d, y_d) = L @ (s - boresight_sample, l - boresight_line)``
    (:attr:`pixel_to_focal_affine`). For a general ``L``, :attr:`pixel_size_mm` is
    ``sqrt(|det L|)`` (the side of the square of equal area) and :attr:`ifov_rad`
    that over the focal length; ``pixel_pitch_mm`` and ``summing`` then only
    describe the detector (a reduced cube's pixel is larger than pitch x summing).
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
    focal_plane_map: tuple[float, ...] = field(default=())
    apollo_distortion: ApolloMetricDistortion | None = None
    csm_distortion: CsmDistortion | None = None

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
        if sum((bool(self.distortion_x), self.apollo_distortion is not None, self.csm_distortion is not None)) > 1:
            raise GeometryError(f"camera {self.name}: give one distortion model (transverse distortion_x/_y, "
                                "apollo_distortion or csm_distortion), not several")
        if self.focal_plane_map:
            m = self.focal_plane_map
            if len(m) != 4 or not all(math.isfinite(float(c)) for c in m):
                raise GeometryError(f"camera {self.name}: focal_plane_map needs 4 finite numbers "
                                    f"(dx/ds, dx/dl, dy/ds, dy/dl), got {m!r}")
            if not abs(m[0] * m[3] - m[1] * m[2]) > 0:
                raise GeometryError(f"camera {self.name}: focal_plane_map {m!r} is singular")

    # -- derived quantities -------------------------------------------------
    @property
    def pixel_size_mm(self) -> float:
        """Size of one image pixel in the focal plane, millimetres.

        Pitch x summing; ``sqrt(|det L|)`` for a general ``focal_plane_map``.
        """
        if self.focal_plane_map:
            m = self.focal_plane_map
            return math.sqrt(abs(m[0] * m[3] - m[1] * m[2]))
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
    def distortion_model(self) -> str:
        """One of :data:`DISTORTION_MODELS`: ``"transverse"``, ``"apollo_metric"``, a usgscsm model name or ``"none"``."""
        if len(self.distortion_x) == 10:
            return "transverse"
        if self.apollo_distortion is not None:
            return "apollo_metric"
        if self.csm_distortion is not None:
            return self.csm_distortion.model
        return "none"

    @property
    def has_distortion(self) -> bool:
        return self.distortion_model != "none"

    @property
    def pixel_to_focal_affine(self) -> NDArray[np.float64]:
        """Image pixel (s, l, 1) -> distorted focal plane (x_d, y_d) mm, shape (2, 3)."""
        lin = self.pixel_to_focal_matrix()
        b = np.array([self.boresight_sample, self.boresight_line])
        return np.concatenate([lin, -(lin @ b)[:, None]], axis=1)

    def pixel_to_focal_matrix(self) -> NDArray[np.float64]:
        """The linear part ``L`` of :attr:`pixel_to_focal_affine`, mm per pixel, shape (2, 2)."""
        if self.focal_plane_map:
            return np.array(self.focal_plane_map, dtype=np.float64).reshape(2, 2)
        return np.eye(2) * self.pixel_size_mm

    def focal_to_pixel_matrix(self) -> NDArray[np.float64]:
        """``L^-1``, pixels per mm, shape (2, 2): d(sample, line)/d(x_d, y_d)."""
        if not self.focal_plane_map:
            return np.eye(2) / self.pixel_size_mm
        a, b, c, d = self.focal_plane_map
        det = a * d - b * c
        return np.array([[d / det, -b / det], [-c / det, a / det]])

    def with_size(self, samples: int) -> FramingCamera:
        """The same camera read out at ``samples`` x ``samples`` by on-chip summing.

        The detector is ``samples * summing`` pixels wide; a smaller readout sums
        more detector pixels (MDIS sums 2x2 to make 512 x 512 images). A general
        ``focal_plane_map`` is scaled by the change of summing.
        """
        detector = self.samples * self.summing
        if samples < 1 or detector % samples:
            raise GeometryError(
                f"camera {self.name}: image size {samples} does not divide the {detector}-pixel detector"
            )
        summing = detector // samples
        fmap = self.focal_plane_map
        if fmap:
            fmap = tuple(float(c) * summing / self.summing for c in fmap)
        return replace(
            self,
            summing=summing,
            samples=samples,
            lines=samples,
            boresight_sample=(self.boresight_sample + 0.5) * self.summing / summing - 0.5,
            boresight_line=(self.boresight_line + 0.5) * self.summing / summing - 0.5,
            focal_plane_map=fmap,
        )

    # -- distortion ---------------------------------------------------------
    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Undistorted focal-plane mm -> distorted focal-plane mm.

        Closed form for ``transverse``; a Newton iteration for ``apollo_metric``; as
        :meth:`CsmDistortion.distort <mercury_dem.geometry.distortion.CsmDistortion.distort>` says for the others.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.apollo_distortion is not None:
            return self.apollo_distortion.distort(x, y)
        if self.csm_distortion is not None:
            return self.csm_distortion.distort(x, y)
        if not self.has_distortion:
            return x, y
        t = _poly_terms(x, y)
        return t @ np.asarray(self.distortion_x), t @ np.asarray(self.distortion_y)

    def distortion_jacobian(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """d(x_d, y_d)/d(x, y) at undistorted points (x, y) mm, shape (..., 2, 2). Analytic."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.apollo_distortion is not None:
            return self.apollo_distortion.distort_jacobian(x, y)
        if self.csm_distortion is not None:
            return self.csm_distortion.distort_jacobian(x, y)
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
        """Distorted -> undistorted focal-plane mm.

        ``transverse``: Newton iteration on :meth:`distort` (to ``tol_mm``, at most
        ``max_iter`` steps); ``apollo_metric``: closed form.
        """
        xd = np.asarray(xd, dtype=np.float64)
        yd = np.asarray(yd, dtype=np.float64)
        if self.apollo_distortion is not None:
            return self.apollo_distortion.undistort(xd, yd)
        if self.csm_distortion is not None:
            return self.csm_distortion.undistort(xd, yd)
        if not self.has_distortion:
            return xd, yd
        return newton_inverse(self.distort, self.distortion_jacobian, xd, yd, xd, yd, tol_mm, max_iter)

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
        if self.focal_plane_map:
            m = self.focal_to_pixel_matrix()
            return np.stack([self.boresight_sample + (m[0, 0] * xd + m[0, 1] * yd),
                             self.boresight_line + (m[1, 0] * xd + m[1, 1] * yd)], axis=-1)
        p = self.pixel_size_mm
        return np.stack([self.boresight_sample + xd / p, self.boresight_line + yd / p], axis=-1)

    def pixel_to_camera(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Unit camera-frame look vectors (..., 3) of pixels (sample, line) (..., 2)."""
        px = np.asarray(pixels, dtype=np.float64)
        if self.focal_plane_map:
            a, b, c, d = self.focal_plane_map
            ds, dl = px[..., 0] - self.boresight_sample, px[..., 1] - self.boresight_line
            xd, yd = a * ds + b * dl, c * ds + d * dl
        else:
            p = self.pixel_size_mm
            xd = (px[..., 0] - self.boresight_sample) * p
            yd = (px[..., 1] - self.boresight_line) * p
        x, y = self.undistort(xd, yd)
        v = np.stack([x, y, np.full_like(x, self.focal_length_mm)], axis=-1)
        out: NDArray[np.float64] = v / np.linalg.norm(v, axis=-1, keepdims=True)
        return out

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


def detector_affine(
    detector_to_focal: ArrayLike,
    focal_origin: ArrayLike,
    scale: tuple[float, float],
    offset: tuple[float, float],
    square_mm: float | None = None,
) -> tuple[float, float, tuple[float, ...]]:
    """The image pixel -> distorted focal plane affine of a detector, as :class:`FramingCamera` holds it.

    The one place where a detector's affine (NAIF ``TRANSX``/``TRANSY`` of a cube, a CSM ISD's
    ``focal2pixel_samples``/``_lines``) becomes the camera's ``boresight_sample``/``_line`` and
    ``focal_plane_map``. Per axis, the detector pixel centred on the detector origin is
    ``c = scale * p + offset`` for our 0-based image pixel ``p``; the focal plane is
    ``(x, y) = T (c - c0)`` with ``T = detector_to_focal`` and ``c0 = focal_origin``.

    Parameters
    ----------
    detector_to_focal : (2, 2) ``T``, mm per centred detector pixel (any invertible matrix:
        mirrored, rotated, non-square pixels)
    focal_origin : (2,) ``c0``, the centred detector (sample, line) of the focal-plane origin
    scale, offset : per axis (sample, line), image pixel -> centred detector pixel
    square_mm : when ``T diag(scale)`` equals ``square_mm * I`` to 1e-12 (relative), the camera
        keeps the square-pixel form (empty ``focal_plane_map``) with this pixel size

    Returns
    -------
    boresight_sample, boresight_line : our pixel of the focal-plane origin
    focal_plane_map : ``T diag(scale)`` as 4 numbers, or empty for the square-pixel form

    Raises
    ------
    GeometryError : ``T`` singular or not finite, or a zero scale
    """
    t = np.asarray(detector_to_focal, dtype=np.float64).reshape(2, 2)
    c0 = np.asarray(focal_origin, dtype=np.float64).reshape(2)
    det = float(t[0, 0] * t[1, 1] - t[0, 1] * t[1, 0])
    if not (np.all(np.isfinite(t)) and math.isfinite(det) and det != 0.0):
        raise GeometryError(f"the detector -> focal plane map {t.tolist()} is singular")
    if not all(math.isfinite(a) and a != 0 for a in scale):
        raise GeometryError(f"the image -> detector pixel scale {scale} must be finite and non-zero")
    bore_s = (c0[0] - offset[0]) / scale[0]
    bore_l = (c0[1] - offset[1]) / scale[1]
    lin = t @ np.diag(scale)
    if square_mm is not None and np.all(np.abs(lin - square_mm * np.eye(2)) <= 1e-12 * abs(square_mm)):
        return float(bore_s), float(bore_l), ()
    return float(bore_s), float(bore_l), tuple(float(c) for c in lin.ravel())


def minus_z_turn(detector_to_focal: ArrayLike) -> NDArray[np.float64]:
    """The rotation from a -Z-looking instrument frame to our +Z-looking camera frame, (3, 3).

    A 180° turn, ``diag(sx, -sx, -1)``, about the focal-plane axis chosen so that our +x keeps
    running along increasing sample where the detector's x does (``sx = -1`` when
    ``dx/dsample < 0``). Cubes (ISIS's Apollo Metric camera) and ISDs with a negative focal
    length (usgscsm's way of writing a -Z look) are turned by it.
    """
    t = np.asarray(detector_to_focal, dtype=np.float64).reshape(2, 2)
    sx = -1.0 if t[0, 0] < 0 else 1.0
    return np.diag([sx, -sx, -1.0])


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


# -- serialisation ----------------------------------------------------------------

_INT_FIELDS = ("summing", "samples", "lines")
_FLOAT_FIELDS = ("focal_length_mm", "pixel_pitch_mm", "boresight_sample", "boresight_line")


def camera_to_dict(cam: FramingCamera) -> dict[str, Any]:
    """A JSON-safe dict of a camera (plain ints, floats, lists, str); :func:`camera_from_dict` inverts it.

    Floats are Python floats, which JSON writes with ``repr``: the round trip is exact.
    """
    d: dict[str, Any] = {"name": str(cam.name)}
    d.update({k: int(getattr(cam, k)) for k in _INT_FIELDS})
    d.update({k: float(getattr(cam, k)) for k in _FLOAT_FIELDS})
    d["focal_plane_map"] = [float(c) for c in cam.focal_plane_map] or None
    model = cam.distortion_model
    dist: dict[str, Any] = {"model": model}
    if model == "transverse":
        dist["x"] = [float(c) for c in cam.distortion_x]
        dist["y"] = [float(c) for c in cam.distortion_y]
    elif model == "apollo_metric":
        a = cam.apollo_distortion
        assert a is not None
        dist["principal_point_mm"] = [float(c) for c in a.principal_point_mm]
        dist["radial"] = [float(c) for c in a.radial]
        dist["decentering"] = [float(c) for c in a.decentering]
    elif cam.csm_distortion is not None:
        m = cam.csm_distortion
        dist["coefficients"] = [float(c) for c in m.coefficients]
        dist["focal_length_mm"] = float(m.focal_length_mm)
        dist["axes"] = [float(c) for c in m.axes]
    d["distortion"] = dist
    return d


def _dict_numbers(d: Mapping[str, Any], key: str, n: int | None, where: str) -> tuple[float, ...]:
    v = d.get(key)
    if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n) or not all(
        isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in v
    ):
        want = f"a list of {n} finite numbers" if n is not None else "a list of finite numbers"
        raise GeometryError(f"camera dict: field '{where}{key}' must be {want}, got {v!r}")
    return tuple(float(c) for c in v)


def camera_from_dict(d: Mapping[str, Any]) -> FramingCamera:
    """The camera of :func:`camera_to_dict`; a missing or malformed field raises GeometryError naming it."""
    if not isinstance(d, Mapping):
        raise GeometryError(f"camera dict: expected a mapping, got {type(d).__name__}")
    known = {"name", "focal_plane_map", "distortion", *_INT_FIELDS, *_FLOAT_FIELDS}
    unknown = sorted(set(d) - known)
    if unknown:
        raise GeometryError(f"camera dict: unknown field(s) {unknown}")
    for key in sorted(known - {"focal_plane_map"}):
        if key not in d:
            raise GeometryError(f"camera dict: field '{key}' is missing")
    if not isinstance(d["name"], str):
        raise GeometryError(f"camera dict: field 'name' must be a string, got {d['name']!r}")
    kw: dict[str, Any] = {"name": d["name"]}
    for key in _INT_FIELDS:
        v = d[key]
        if not isinstance(v, int) or isinstance(v, bool):
            raise GeometryError(f"camera dict: field '{key}' must be an integer, got {v!r}")
        kw[key] = v
    for key in _FLOAT_FIELDS:
        v = d[key]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise GeometryError(f"camera dict: field '{key}' must be a finite number, got {v!r}")
        kw[key] = float(v)
    if d.get("focal_plane_map") is not None:
        kw["focal_plane_map"] = _dict_numbers(d, "focal_plane_map", 4, "")
    dist = d["distortion"]
    if not isinstance(dist, Mapping) or dist.get("model") not in DISTORTION_MODELS:
        raise GeometryError(f"camera dict: field 'distortion.model' must be one of {list(DISTORTION_MODELS)}, "
                            f"got {dist.get('model') if isinstance(dist, Mapping) else dist!r}")
    if dist["model"] == "transverse":
        kw["distortion_x"] = _dict_numbers(dist, "x", 10, "distortion.")
        kw["distortion_y"] = _dict_numbers(dist, "y", 10, "distortion.")
    elif dist["model"] == "apollo_metric":
        pp = _dict_numbers(dist, "principal_point_mm", 2, "distortion.")
        k = _dict_numbers(dist, "radial", 3, "distortion.")
        j = _dict_numbers(dist, "decentering", 3, "distortion.")
        kw["apollo_distortion"] = ApolloMetricDistortion((pp[0], pp[1]), (k[0], k[1], k[2]), (j[0], j[1], j[2]))
    elif dist["model"] in CSM_DISTORTION_SIZES:
        coeffs = _dict_numbers(dist, "coefficients", CSM_DISTORTION_SIZES[dist["model"]], "distortion.")
        (f,) = _dict_numbers({"f": [dist.get("focal_length_mm")]}, "f", 1, "distortion.focal_length_mm")
        axes = _dict_numbers(dist, "axes", 2, "distortion.")
        kw["csm_distortion"] = CsmDistortion(dist["model"], coeffs, f, (axes[0], axes[1]))
    return FramingCamera(**kw)
