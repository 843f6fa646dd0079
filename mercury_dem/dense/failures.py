"""Why a stereo pair or chip of the dense stage gave no points: a kind set where the failure is caught.

The dense stage's tile task records each failed pair or chip with its human-readable ``error`` and its
:class:`DenseFailure` (``failure``); the report counts them by kind (``dense.failures_by_kind``) the way it
counts units by :class:`mercury_dem.pipeline.results.UnitFailure`, matched pairs by
:class:`mercury_dem.match.result.PairFailure` and stereo candidates by
:class:`mercury_dem.dense.pairs.PairRejection`; nothing parses ``error``. An entry of an older run has no
kind (counted as ``unrecorded``).
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from mercury_dem.exceptions import GeometryError, MercuryDemError

__all__ = ["DenseFailure", "chip_failure_of", "pair_failure_of"]


class DenseFailure(StrEnum):
    """Why a pair (``chip`` None in its entry) or a chip of a pair gave no points."""

    NO_POSE = "no_pose"  # an image of the pair has no adjusted pose (the global adjustment did not control it)
    IMAGE_UNREADABLE = "image_unreadable"  # an image of the pair could not be read from the mission
    CHIP_GEOMETRY = "chip_geometry"  # the chip could not be rectified: its rays miss the surface, the right
    #                                  camera does not see its ground, no homography (GeometryError)
    CHIP_ERROR = "chip_error"  # another of the package's errors, or a numerical one, while matching the chip
    UNEXPECTED = "unexpected"  # an exception of another library (OpenCV's cv2.error, ...): possibly a bug


def pair_failure_of(exc: BaseException) -> DenseFailure:
    """The kind of an exception raised while taking a pair's poses and images: a missing pose (``KeyError`` of
    the adjusted geometry) or an unreadable image (anything else).
    """
    return DenseFailure.NO_POSE if isinstance(exc, KeyError) else DenseFailure.IMAGE_UNREADABLE


def chip_failure_of(exc: BaseException) -> DenseFailure:
    """The kind of an exception raised by :func:`mercury_dem.dense.chip.dense_chip`, by its type."""
    if isinstance(exc, GeometryError):
        return DenseFailure.CHIP_GEOMETRY
    if isinstance(exc, (MercuryDemError, ValueError, np.linalg.LinAlgError)):
        return DenseFailure.CHIP_ERROR
    return DenseFailure.UNEXPECTED
