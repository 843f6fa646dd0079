"""An image prepared once per tile for matching: quality check, float DN, refinement pattern, features.

:func:`prepare_image` runs once per image of a tile (the tile's pairs share the result):
the quality check (blank, saturated, textureless, wrong size), the float32 image, the
locally normalized image the refinement finds positions on (:func:`refine_pattern`) and,
when asked, the features in the image's own geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.features import (
    Features,
    ImageQuality,
    detect_and_describe,
    image_quality,
    stretch_to_8bit,
)
from mercury_dem.match.refine import local_normalize

#: Keypoints this close (pixels) to the edge of the valid data (of an image or of a warped
#: partner) are not described: their descriptor window would take in the edge.
DETECTION_BORDER_PX = 4


@dataclass(frozen=True)
class ImageFeatures:
    """An image prepared once per tile: quality, float DN and features in its own geometry.

    ``described`` is False when the features were not computed (yet); ``pattern`` is the image
    locally normalized for the refinement (:func:`local_normalize`), None when not used.
    """

    quality: ImageQuality
    image: NDArray[np.float32]
    features: Features
    described: bool = True
    pattern: NDArray[np.float32] | None = None
    detect_mask: NDArray[np.uint8] | None = None  # where keypoints may be; None = everywhere


def _detect_mask(image: NDArray[Any]) -> NDArray[np.uint8] | None:
    """Valid pixels (finite, i.e. not ISIS special pixels) shrunk by the detection border; None when all are."""
    if image.dtype.kind != "f":
        return None
    valid = np.isfinite(image)
    if valid.all():
        return None
    return cast(NDArray[np.uint8], cv2.erode(valid.view(np.uint8), np.ones((2 * DETECTION_BORDER_PX + 1,) * 2, np.uint8)))


def prepare_image(
    image: NDArray[Any] | None, camera_shape: tuple[int, int], config: MatchConfig, describe: bool = True,
    radiometry: tuple[float, float] | None = None,
) -> ImageFeatures:
    """Quality check, float conversion and (if ``describe``) features in the image's own geometry.

    ``camera_shape`` is (lines, samples) of the image's camera; a different array
    shape (truncated or corrupt image) or ``None`` (unreadable) gives a failed quality.
    ``radiometry`` is the image's (saturation, dn_scale) (see :func:`image_quality`); None = 12-bit DN.
    """
    empty = Features(np.zeros((0, 2)), np.zeros(0, np.float32), np.zeros((0, 128), np.float32), cv2.NORM_L2)
    if image is None:
        return ImageFeatures(ImageQuality(False, "unreadable", 0, 0, 0), np.zeros((0, 0), np.float32), empty)
    arr = np.asarray(image)
    if arr.shape != tuple(camera_shape):
        reason = f"shape {arr.shape} does not match its camera {tuple(camera_shape)} (truncated or corrupt)"
        return ImageFeatures(ImageQuality(False, reason, 0, 0, 0), np.zeros((0, 0), np.float32), empty)
    q = image_quality(arr, config) if radiometry is None else image_quality(arr, config, *radiometry)
    mask = _detect_mask(arr)
    f32 = np.nan_to_num(arr.astype(np.float32, copy=False))
    if not q.ok:
        return ImageFeatures(q, f32, empty, described=False)
    pattern = refine_pattern(f32, config)
    if not describe:
        return ImageFeatures(q, f32, empty, described=False, pattern=pattern, detect_mask=mask)
    feats = detect_and_describe(stretch_to_8bit(f32, q.low, q.high), config, mask)
    return ImageFeatures(q, f32, feats, pattern=pattern, detect_mask=mask)


def refine_pattern(image: NDArray[np.float32], config: MatchConfig) -> NDArray[np.float32] | None:
    """The image the refinement finds positions on (locally normalized), or None (on the DN)."""
    if not pattern_on(config):
        return None
    return local_normalize(image, config.refine_normalize_sigma_px)


def pattern_on(config: MatchConfig) -> bool:
    """Whether the refinement finds positions on locally normalized images (``refine_normalize_sigma_px`` > 0)."""
    return bool(config.refine and config.refine_normalize_sigma_px > 0)


def with_features(im: ImageFeatures, config: MatchConfig) -> ImageFeatures:
    """``im`` with its features in its own geometry computed (``described``)."""
    feats = detect_and_describe(stretch_to_8bit(im.image, im.quality.low, im.quality.high), config, im.detect_mask)
    return ImageFeatures(im.quality, im.image, feats, pattern=im.pattern, detect_mask=im.detect_mask)


def pixel_faults(pixels: dict[str, NDArray[Any] | None], radiometry: dict[str, tuple[float, float]],
                 config: MatchConfig) -> dict[str, str]:
    """Images whose pixels cannot be matched at all (blank, saturated, textureless), by id, with why and what to do.

    The matcher's own quality check (:func:`~mercury_dem.match.features.image_quality`) decides; the tile
    stage runs it once more per image read (a percentile on every 4th pixel, ~1 ms per 256^2 image) so the
    tile's summary names the image and its fault, not only the pairs that failed because of it. Unreadable
    images (``None``) are skipped: the reader's error already names them.

    Parameters
    ----------
    pixels : image id -> DN array (None when it could not be read)
    radiometry : image id -> (saturation value, DN scale), as :func:`image_quality` takes them
    config : the matcher's configuration (its stretch percentiles and quality thresholds)
    """
    out: dict[str, str] = {}
    for image_id, image in pixels.items():
        if image is None:
            continue
        q = image_quality(image, config, *radiometry[image_id])
        if not q.ok:
            out[image_id] = (f"image {image_id}: {q.reason}; its pixels carry nothing to match, so it is left out "
                             "of matching and stays uncontrolled — check the source image and its calibration, "
                             "or remove it from the mission")
    return out
