"""Framing cameras of real instruments from the NAIF keywords of an ISIS cube.

:func:`camera_from_naif` builds a :class:`~mercury_dem.geometry.camera.FramingCamera`
from the ``INS<code>_...`` keywords that ``spiceinit`` copies into a cube's
``Object = NaifKeywords``, the way ISIS's camera class for the instrument does
(``MdisCamera``, ``ApolloMetricCamera``):

image pixel (a cropped/reduced cube: AlphaCube) -> parent ("alpha") pixel ->
detector pixel (summing, starting detector sample/line; ISIS ``CameraDetectorMap``)
-> centred on the detector origin -> focal-plane mm by ``TRANSX``/``TRANSY``
(ISIS ``CameraFocalPlaneMap``) -> undistorted focal plane (the distortion map) ->
look vector ``(x_u, y_u, z f)`` in the NAIF instrument frame, ``z = -1`` for the
Apollo Metric camera (its distortion map is built with a -Z look direction), +1
otherwise (ISIS ``CameraGroundMap``: ``x = z f X / Z``).

All the affine steps compose into the camera's one pixel -> focal-plane affine;
the -Z look becomes the fixed rotation ``instrument_to_camera`` returned with the
camera (a 180° turn that keeps +X along increasing sample), so that
``R_body->cam = instrument_to_camera @ R_body->instrument``.

Pixels here are 0-based (centre of the first pixel at 0); ISIS's 1-based detector
coordinates (``BORESIGHT_SAMPLE``, the starting detector sample) are converted
here and nowhere else. Written here, not by calling ISIS (a C++ installation with
SPICE data), because only these few keyword-driven maps are needed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.camera import FramingCamera, detector_affine, minus_z_turn
from mercury_dem.geometry.distortion import ApolloMetricDistortion

#: NAIF instrument codes of the Apollo 15/16/17 Metric cameras (ISIS ApolloMetricCamera).
APOLLO_METRIC_CODES = (-915240, -916240, -917240)
#: NAIF instrument code of MDIS-NAC, and of MDIS-WAC (its filters are -236800 - filter number).
MDIS_NAC_CODE = -236820
MDIS_WAC_CODE = -236800
#: Largest relative mismatch allowed between ITRANSS/ITRANSL and the inverse of TRANSX/TRANSY.
ITRANS_RTOL = 1e-6

_DISTORTION_SUFFIXES = ("OD_T_X", "OD_T_Y", "OD_K", "PP", "DECENTER")


@dataclass(frozen=True)
class AlphaCube:
    """Image pixel of a cropped/reduced cube -> pixel of the original ("alpha") cube.

    0-based centre convention: ``alpha = start + scale * (beta + 0.5) - 0.5`` per axis.

    Parameters
    ----------
    alpha_samples, alpha_lines : size of the original cube, pixels
    start_sample, start_line : alpha pixels before the first image pixel's left/top edge
    scale_sample, scale_line : alpha pixels per image pixel (> 1 for a reduced cube)
    """

    alpha_samples: int
    alpha_lines: int
    start_sample: float
    start_line: float
    scale_sample: float
    scale_line: float

    def __post_init__(self) -> None:
        if not (self.scale_sample > 0 and self.scale_line > 0):
            raise GeometryError(f"AlphaCube: scale_sample/scale_line must be > 0, got "
                                f"{self.scale_sample}, {self.scale_line}")

    @classmethod
    def from_isis(cls, group: Mapping[str, Any]) -> AlphaCube:
        """From the keywords of an ISIS ``Group = AlphaCube`` (1-based: ``alpha = slope (beta - 0.5) + start``)."""
        try:
            s0, s1 = float(group["AlphaStartingSample"]), float(group["AlphaEndingSample"])
            l0, l1 = float(group["AlphaStartingLine"]), float(group["AlphaEndingLine"])
            bs, bl = float(group["BetaSamples"]), float(group["BetaLines"])
            a_s, a_l = int(group["AlphaSamples"]), int(group["AlphaLines"])
        except KeyError as exc:
            raise GeometryError(f"AlphaCube group lacks keyword {exc.args[0]}") from None
        return cls(a_s, a_l, s0 - 0.5, l0 - 0.5, (s1 - s0) / bs, (l1 - l0) / bl)

    def beta_to_alpha(self, sample: ArrayLike, line: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Original-image (alpha) pixel of a pixel of this cube (beta); both 0-based, centre of the first pixel 0.

        The cube's outer edge (-0.5, size - 0.5) maps onto ISIS's AlphaStarting - 1 and AlphaEnding - 1.
        """
        s = np.asarray(sample, np.float64)
        ln = np.asarray(line, np.float64)
        return (self.start_sample + self.scale_sample * (s + 0.5) - 0.5,
                self.start_line + self.scale_line * (ln + 0.5) - 0.5)

    def alpha_to_beta(self, sample: ArrayLike, line: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inverse of :meth:`beta_to_alpha` (0-based both)."""
        s = np.asarray(sample, np.float64)
        ln = np.asarray(line, np.float64)
        return ((s + 0.5 - self.start_sample) / self.scale_sample - 0.5,
                (ln + 0.5 - self.start_line) / self.scale_line - 0.5)


def _number(keywords: Mapping[str, Any], key: str) -> float:
    if key not in keywords:
        raise GeometryError(f"NAIF keyword {key} is missing")
    v = keywords[key]
    if isinstance(v, (list, tuple)):
        v = v[0] if len(v) == 1 else v
    try:
        out = float(v)
    except (TypeError, ValueError):
        raise GeometryError(f"NAIF keyword {key} must be a number, got {v!r}") from None
    if not math.isfinite(out):
        raise GeometryError(f"NAIF keyword {key} must be finite, got {v!r}")
    return out


def _numbers(keywords: Mapping[str, Any], key: str, n: int) -> tuple[float, ...]:
    if key not in keywords:
        raise GeometryError(f"NAIF keyword {key} is missing")
    v = keywords[key]
    try:
        out = tuple(float(c) for c in v)
    except (TypeError, ValueError):
        raise GeometryError(f"NAIF keyword {key} must be {n} numbers, got {v!r}") from None
    if len(out) != n or not all(math.isfinite(c) for c in out):
        raise GeometryError(f"NAIF keyword {key} must be {n} finite numbers, got {v!r}")
    return out


def _distortion_model(keywords: Mapping[str, Any], prefix: str) -> str:
    present = {k[len(prefix):] for k in keywords if k.startswith(prefix)
               and (k[len(prefix):] in _DISTORTION_SUFFIXES or k[len(prefix):].startswith("OD_"))}
    if not present:
        return "none"
    if present == {"OD_T_X", "OD_T_Y"}:
        return "transverse"
    if present == {"OD_K", "PP", "DECENTER"}:
        return "apollo_metric"
    names = ", ".join(prefix + s for s in sorted(present))
    raise GeometryError(f"unknown distortion model: keys {names}; supported are transverse "
                        f"({prefix}OD_T_X + OD_T_Y) and apollo_metric ({prefix}OD_K + PP + DECENTER)")


def _focal_length(keywords: Mapping[str, Any], prefix: str, override: float | None,
                  temperature_c: float | None) -> float:
    """ISIS MdisCamera::computeFocalLength order: stored TempDependentFocalLength, the FL_TEMP_COEFFS
    polynomial at the focal-plane temperature, FOCAL_LENGTH.
    """
    if override is not None:
        return float(override)
    if "TempDependentFocalLength" in keywords:
        return _number(keywords, "TempDependentFocalLength")
    if temperature_c is not None and prefix + "FL_TEMP_COEFFS" in keywords:
        coeffs = _numbers(keywords, prefix + "FL_TEMP_COEFFS", len(keywords[prefix + "FL_TEMP_COEFFS"]))
        fl = 0.0
        for i, c in enumerate(coeffs):
            fl += c * math.pow(temperature_c, i)
        return fl
    return _number(keywords, prefix + "FOCAL_LENGTH")


def _check_itrans(keywords: Mapping[str, Any], prefix: str, t: NDArray[np.float64],
                  t0: NDArray[np.float64]) -> None:
    keys = [prefix + "ITRANSS", prefix + "ITRANSL"]
    if not all(k in keywords for k in keys):
        return
    its, itl = _numbers(keywords, keys[0], 3), _numbers(keywords, keys[1], 3)
    inv = np.array([[its[1], its[2]], [itl[1], itl[2]]])
    want = np.linalg.inv(t)
    off = np.array([its[0], itl[0]])
    scale = np.max(np.abs(want))
    if (np.max(np.abs(inv - want)) > ITRANS_RTOL * scale
            or np.max(np.abs(off + want @ t0)) > ITRANS_RTOL * scale * max(1.0, float(np.max(np.abs(t0))))):
        raise GeometryError(f"NAIF keywords {keys[0]}/{keys[1]} ({its}, {itl}) are not the inverse of "
                            f"{prefix}TRANSX/TRANSY (inverse {want.tolist()}): check the kernel")


def camera_from_naif(
    keywords: Mapping[str, Any],
    ik_code: int,
    samples: int,
    lines: int,
    *,
    name: str,
    summing: int = 1,
    start_detector_sample: float = 0.0,
    start_detector_line: float = 0.0,
    alpha: AlphaCube | Mapping[str, Any] | None = None,
    focal_length_mm: float | None = None,
    focal_plane_temperature_c: float | None = None,
) -> tuple[FramingCamera, NDArray[np.float64]]:
    """The camera of an image from its cube's NAIF keywords, as ISIS's camera class builds it.

    Parameters
    ----------
    keywords : the cube's ``NaifKeywords`` (``INS<code>_FOCAL_LENGTH``, ``_PIXEL_PITCH``,
        ``_TRANSX``, ``_TRANSY``, ``_ITRANSS``, ``_ITRANSL``, ``_BORESIGHT_SAMPLE``/``_LINE``
        (ISIS 1-based detector pixels), distortion keys; MDIS's ``TempDependentFocalLength``)
    ik_code : NAIF instrument code whose keys are used (MDIS-WAC: the filter's code)
    samples, lines : image size, pixels
    name : camera name, e.g. ``"MDIS-NAC"``
    summing : detector pixels per image pixel (MDIS: 2 when the label's ``FpuBinningMode`` is 1,
        times ``PixelBinningMode`` when that is non-zero)
    start_detector_sample, start_detector_line : 0-based detector pixel of the first image
        pixel's first detector pixel (ISIS's starting detector sample minus 1)
    alpha : the cube's AlphaCube (an :class:`AlphaCube` or the ISIS group's keywords), None for
        an uncropped cube
    focal_length_mm : overrides the focal length of the keywords, mm
    focal_plane_temperature_c : MDIS focal-plane temperature, °C: with ``FL_TEMP_COEFFS`` gives
        the temperature-dependent focal length when ``TempDependentFocalLength`` is absent

    Returns
    -------
    camera : the camera (its frame looks along +Z)
    instrument_to_camera : ndarray of shape (3, 3), the rotation from the NAIF instrument frame to
        the camera frame: identity for a +Z-looking instrument, a 180° turn (``diag(-1, 1, -1)`` for
        Apollo Metric) for a -Z-looking one

    Raises
    ------
    GeometryError : a missing or malformed keyword (named), an unknown set of distortion keys
        (``unknown distortion model: keys ...``), an instrument without a detector origin
    """
    prefix = f"INS{int(ik_code)}_"
    model = _distortion_model(keywords, prefix)
    if summing < 1:
        raise GeometryError(f"camera {name}: summing must be >= 1, got {summing}")
    if alpha is not None and not isinstance(alpha, AlphaCube):
        alpha = AlphaCube.from_isis(alpha)
    f_mm = _focal_length(keywords, prefix, focal_length_mm, focal_plane_temperature_c)
    pitch = _number(keywords, prefix + "PIXEL_PITCH")
    tx = _numbers(keywords, prefix + "TRANSX", 3)
    ty = _numbers(keywords, prefix + "TRANSY", 3)
    t = np.array([[tx[1], tx[2]], [ty[1], ty[2]]])
    t0 = np.array([tx[0], ty[0]])
    if not abs(np.linalg.det(t)) > 0:
        raise GeometryError(f"NAIF keywords {prefix}TRANSX/TRANSY ({tx}, {ty}) are singular")
    _check_itrans(keywords, prefix, t, t0)

    # detector origin, ISIS 1-based detector pixels
    parent_s = alpha.alpha_samples if alpha is not None else samples * summing
    parent_l = alpha.alpha_lines if alpha is not None else lines * summing
    bore_keys = [prefix + "BORESIGHT_SAMPLE", prefix + "BORESIGHT_LINE"]
    if MDIS_WAC_CODE - 12 <= ik_code < MDIS_WAC_CODE and not all(k in keywords for k in bore_keys):
        bore_keys = [f"INS{MDIS_WAC_CODE}_BORESIGHT_SAMPLE", f"INS{MDIS_WAC_CODE}_BORESIGHT_LINE"]
    if all(k in keywords for k in bore_keys):
        origin = (_number(keywords, bore_keys[0]), _number(keywords, bore_keys[1]))
    elif int(ik_code) in APOLLO_METRIC_CODES:
        origin = (parent_s / 2.0, parent_l / 2.0)  # ApolloMetricCamera: the centre of the parent frame
    else:
        raise GeometryError(f"NAIF keywords {bore_keys[0]}/{bore_keys[1]} are missing: the detector origin "
                            f"of instrument {ik_code} is unknown")

    # image pixel s (0-based) -> centred detector pixel c = a s + b, per axis
    def axis(a0: float, k: float, start0: float, org: float) -> tuple[float, float]:
        # alpha0 = a0 + k (s + 0.5) - 0.5; ISIS detector = alpha0 * summing + summing / 2 + 0.5 + start0
        return summing * k, summing * (a0 + 0.5 * k - 0.5) + summing / 2.0 + 0.5 + start0 - org

    if alpha is None:
        a_s, b_s = axis(0.0, 1.0, float(start_detector_sample), origin[0])
        a_l, b_l = axis(0.0, 1.0, float(start_detector_line), origin[1])
    else:
        a_s, b_s = axis(alpha.start_sample, alpha.scale_sample, float(start_detector_sample), origin[0])
        a_l, b_l = axis(alpha.start_line, alpha.scale_line, float(start_detector_line), origin[1])

    # -Z look: turn 180° about the focal-plane axis that keeps x along increasing sample
    instrument_to_camera = minus_z_turn(t) if model == "apollo_metric" else np.eye(3)
    sx, sy = float(instrument_to_camera[0, 0]), float(instrument_to_camera[1, 1])

    # our focal plane = S (t @ (a s + b) + t0) = S t (a s + b - c*), focal origin at c* = -t^-1 t0
    c_star = -np.linalg.solve(t, t0) if np.any(t0) else np.zeros(2)
    bore_s, bore_l, fmap = detector_affine(instrument_to_camera[:2, :2] @ t, c_star, (a_s, a_l), (b_s, b_l),
                                           square_mm=pitch * summing)

    dist_x: tuple[float, ...] = ()
    dist_y: tuple[float, ...] = ()
    apollo = None
    if model == "transverse":
        dist_x = _numbers(keywords, prefix + "OD_T_X", 10)
        dist_y = _numbers(keywords, prefix + "OD_T_Y", 10)
    elif model == "apollo_metric":
        pp = _numbers(keywords, prefix + "PP", 2)
        k = _numbers(keywords, prefix + "OD_K", 3)
        j1, j2, t0_rad = _numbers(keywords, prefix + "DECENTER", 3)
        # x -> sx x, y -> sy y: the decentering direction (-sin t0, cos t0) becomes (-sin t0', cos t0')
        if (sx, sy) == (-1.0, 1.0):
            t0_ours = -t0_rad
        elif (sx, sy) == (1.0, -1.0):
            t0_ours = math.pi - t0_rad
        else:
            t0_ours = t0_rad
        apollo = ApolloMetricDistortion((sx * pp[0], sy * pp[1]), (k[0], k[1], k[2]), (j1, j2, t0_ours))
    camera = FramingCamera(
        name=name,
        focal_length_mm=f_mm,
        pixel_pitch_mm=pitch,
        summing=int(summing),
        samples=int(samples),
        lines=int(lines),
        boresight_sample=float(bore_s),
        boresight_line=float(bore_l),
        distortion_x=dist_x,
        distortion_y=dist_y,
        focal_plane_map=fmap,
        apollo_distortion=apollo,
    )
    return camera, instrument_to_camera
