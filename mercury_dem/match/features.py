"""Image preparation and feature detection/description with OpenCV.

12-bit DN images are converted to 8 bit for the detectors with a robust
percentile stretch; images that are blank, saturated or textureless are
reported as such (:class:`ImageQuality`), never raised. Keypoints are capped
to the strongest ones spread over a grid, because describing every FAST corner
with SIFT costs far more than detecting it (ECOSYSTEM-NOTES: 4000 FAST points
take 0.3-0.65 s to describe).

Pixel convention: 0-based (sample, line), the centre of the first pixel at (0, 0)
-- the same as OpenCV's keypoint coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig


@dataclass(frozen=True)
class ImageQuality:
    """Whether an image can be matched, and the stretch that maps its DN to 8 bit.

    Attributes
    ----------
    ok : False when the image is unusable; ``reason`` then says why
    reason : '' or e.g. 'blank (all pixels 0 DN)'
    low, high : DN mapped to 0 and 255 by the stretch
    saturated_fraction : share of pixels at or above the saturation DN
    """

    ok: bool
    reason: str
    low: float
    high: float
    saturated_fraction: float


@dataclass(frozen=True)
class Features:
    """Keypoints and descriptors of one image (in the frame they were detected in).

    Attributes
    ----------
    points : ndarray (N, 2) float64, keypoint (sample, line), pixels
    response : ndarray (N,) float32, detector response (larger is stronger)
    descriptors : ndarray (N, D), float32 (SIFT) or uint8 (binary descriptors)
    norm : OpenCV norm type for the descriptors (cv2.NORM_L2 or cv2.NORM_HAMMING)

    The row index is the keypoint id (``feature_a`` of the matches).
    """

    points: NDArray[np.float64]
    response: NDArray[np.float32]
    descriptors: NDArray[Any]
    norm: int

    @property
    def size(self) -> int:
        return int(self.points.shape[0])


def image_quality(image: NDArray[Any], config: MatchConfig, saturation: float | None = None,
                  dn_scale: float = 1.0) -> ImageQuality:
    """Robust DN range of an image and whether it is usable for matching.

    The percentiles are taken on every second pixel of every second line (a
    statistic, not the detector input), which is 4x cheaper and the same to
    within a DN on real-sized images.

    ``saturation`` (the image's own saturation value, in its units; NaN = none; None =
    ``config.saturated_dn``) and ``dn_scale`` (image units per 12-bit DN of the config's
    thresholds) are the image's radiometry (:mod:`mercury_dem.mission.radiometry`).
    """
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        return ImageQuality(False, f"not a 2-D image (shape {img.shape})", 0.0, 0.0, 0.0)
    sub = img[::2, ::2] if min(img.shape) >= 64 else img
    sub = sub.astype(np.float32, copy=False)
    finite = np.isfinite(sub)
    if not finite.all():
        if not finite.any():
            return ImageQuality(False, "blank (no finite pixels)", 0.0, 0.0, 0.0)
        sub = sub[finite]
    sat_value = float(config.saturated_dn) if saturation is None else float(saturation)
    sat = float(np.mean(sub >= sat_value)) if np.isfinite(sat_value) else 0.0
    lo, hi = np.percentile(sub, [config.stretch_low_percentile, config.stretch_high_percentile])
    lo, hi = float(lo), float(hi)
    if float(sub.max()) == float(sub.min()):
        return ImageQuality(False, f"blank (all pixels {float(sub.min()):g} DN)", lo, hi, sat)
    if sat > config.max_saturated_fraction:
        return ImageQuality(False, f"saturated ({100 * sat:.0f}% of pixels >= {sat_value:g})", lo, hi, sat)
    if hi - lo < config.min_dynamic_range_dn * dn_scale:
        return ImageQuality(
            False, f"textureless (robust range {hi - lo:.4g} < {config.min_dynamic_range_dn * dn_scale:.4g}, "
            f"{config.min_dynamic_range_dn:g} DN of 12 bits)", lo, hi, sat
        )
    return ImageQuality(True, "", lo, hi, sat)


def stretch_to_8bit(image: NDArray[Any], low: float, high: float) -> NDArray[np.uint8]:
    """Linear stretch of DN (any dtype; NaN -> 0) so that ``low`` -> 0 and ``high`` -> 255, clipped."""
    scale = 255.0 / max(high - low, 1e-6)
    out = cv2.convertScaleAbs(np.nan_to_num(np.asarray(image, dtype=np.float32)), alpha=scale, beta=-low * scale)
    return out


def _detector(config: MatchConfig) -> Any:
    name = config.detector
    if name == "FAST":
        return cv2.FastFeatureDetector_create(threshold=config.fast_threshold, nonmaxSuppression=True)
    if name == "SIFT":
        return cv2.SIFT_create(nfeatures=config.max_keypoints)
    if name == "ORB":
        return cv2.ORB_create(nfeatures=config.max_keypoints, fastThreshold=config.fast_threshold)
    if name == "AKAZE":
        return cv2.AKAZE_create()
    if name == "BRISK":
        return cv2.BRISK_create(thresh=config.fast_threshold)
    raise ValueError(f"unknown detector {name!r}")  # unreachable: MatchConfig validates the name


def _descriptor(config: MatchConfig) -> tuple[Any, int]:
    name = config.descriptor
    if name == "SIFT":
        return cv2.SIFT_create(), cv2.NORM_L2
    if name == "ORB":
        return cv2.ORB_create(), cv2.NORM_HAMMING
    if name == "AKAZE":
        return cv2.AKAZE_create(), cv2.NORM_HAMMING
    if name == "BRISK":
        return cv2.BRISK_create(), cv2.NORM_HAMMING
    raise ValueError(f"unknown descriptor {name!r}")


def spread_best(points: NDArray[np.float64], score: NDArray[Any], n: int, shape: tuple[int, int], grid: int) -> NDArray[np.int64]:
    """Indices of at most ``n`` points, the best by ``score`` (larger is better) spread over a grid.

    Points are binned into ``grid`` x ``grid`` cells over an image of ``shape``
    (lines, samples) and taken round-robin: every cell's best first, then every
    cell's second best, and so on (vectorized: sort by (rank within cell, -score)).
    """
    m = points.shape[0]
    if m <= n:
        return np.arange(m, dtype=np.int64)
    h, w = shape
    cx = np.clip((points[:, 0] * grid / max(w, 1)).astype(np.int64), 0, grid - 1)
    cy = np.clip((points[:, 1] * grid / max(h, 1)).astype(np.int64), 0, grid - 1)
    cell = cy * grid + cx
    order = np.lexsort((-np.asarray(score, dtype=np.float64), cell))  # by cell, then best first
    sorted_cell = cell[order]
    starts = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(m) - starts
    pick = np.lexsort((-np.asarray(score, dtype=np.float64)[order], rank))[:n]
    return np.sort(order[pick])


def detect_and_describe(
    image8: NDArray[np.uint8], config: MatchConfig, mask: NDArray[np.uint8] | None = None
) -> Features:
    """Detect keypoints (capped, spread) and describe them.

    Parameters
    ----------
    image8 : ndarray (lines, samples) uint8, the stretched image
    config : detector/descriptor names, FAST threshold, keypoint cap
    mask : optional uint8 mask (lines, samples); keypoints only where non-zero
    """
    det = _detector(config)
    kps = det.detect(image8, mask)
    if len(kps) == 0:
        return _empty_features(config)
    pts = cv2.KeyPoint_convert(kps).astype(np.float64)
    resp = np.fromiter((k.response for k in kps), dtype=np.float32, count=len(kps))
    keep = spread_best(pts, resp, config.max_keypoints, image8.shape[:2], config.keypoint_grid)
    kps = [kps[i] for i in keep]
    if config.detector == "FAST" and config.keypoint_size_px > 0:
        for k in kps:  # FAST has no scale: the descriptor support is set by the configured size
            k.size = config.keypoint_size_px
    desc_ex, norm = _descriptor(config)
    kps, desc = desc_ex.compute(image8, kps)
    if desc is None or len(kps) == 0:
        return _empty_features(config)
    pts = cv2.KeyPoint_convert(kps).astype(np.float64)
    resp = np.fromiter((k.response for k in kps), dtype=np.float32, count=len(kps))
    return Features(points=pts, response=resp, descriptors=desc, norm=norm)


def _empty_features(config: MatchConfig) -> Features:
    _, norm = _descriptor(config)
    width, dtype = (128, np.float32) if norm == cv2.NORM_L2 else (32, np.uint8)
    return Features(np.zeros((0, 2)), np.zeros(0, np.float32), np.zeros((0, width), dtype), norm)
