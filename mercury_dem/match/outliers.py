"""The outlier chain of Becker et al. (2016), one step per function, each returning a keep mask.

Order: (1) ratio test in both directions, (2) symmetry (mutual best) test,
(3) fundamental-matrix RANSAC, (4) homography RANSAC; then at most
``max_matches`` matches are kept, the best and spatially spread. The matcher
records how many survive each step.

Nearest-neighbour results are held as arrays: for every query descriptor the
index of its best train descriptor (-1 if none) and the distances to the best
and second-best (inf when missing).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.match.features import spread_best
from mercury_dem.stats import NMAD_FACTOR


@dataclass(frozen=True)
class KnnResult:
    """k=2 nearest neighbours of every query descriptor.

    Attributes
    ----------
    best : ndarray (Q,) int64, index of the nearest train descriptor (-1 when none was allowed)
    d1, d2 : ndarray (Q,) float64, distance to the nearest and second-nearest (inf when missing)
    """

    best: NDArray[np.int64]
    d1: NDArray[np.float64]
    d2: NDArray[np.float64]


def knn_from_opencv(knn: Sequence[Sequence[Any]], n_query: int) -> KnnResult:
    """Arrays from OpenCV's ``knnMatch`` output (a list of lists of DMatch).

    With a mask OpenCV returns an empty list for a query with no allowed train
    descriptor, and a one-element list when only one was allowed.
    """
    best = np.full(n_query, -1, dtype=np.int64)
    d1 = np.full(n_query, np.inf)
    d2 = np.full(n_query, np.inf)
    rows = [(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance if len(m) > 1 else np.inf) for m in knn if m]
    if rows:
        arr = np.array(rows, dtype=np.float64)
        q = arr[:, 0].astype(np.int64)
        best[q] = arr[:, 1].astype(np.int64)
        d1[q] = arr[:, 2]
        d2[q] = arr[:, 3]
    return KnnResult(best, d1, d2)


def ratio_test(knn: KnnResult, ratio: float) -> NDArray[np.bool_]:
    """Queries whose best distance is below ``ratio`` x the second best (Lowe's test)."""
    return (knn.best >= 0) & (knn.d1 < ratio * knn.d2)


def symmetric_pairs(
    ab: KnnResult, ba: KnnResult, ok_ab: NDArray[np.bool_], ok_ba: NDArray[np.bool_]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Index pairs (ia, ib) that passed the ratio test both ways and are each other's best."""
    ia = np.flatnonzero(ok_ab)
    ib = ab.best[ia]
    back = ba.best[ib]
    keep = (back == ia) & ok_ba[ib]
    return ia[keep], ib[keep]


def fundamental_inliers(
    pa: NDArray[np.float64], pb: NDArray[np.float64], tolerance_px: float, confidence: float
) -> NDArray[np.bool_]:
    """Inliers of a fundamental matrix found by RANSAC (all False below 8 matches or on failure)."""
    n = pa.shape[0]
    if n < 8:
        return np.zeros(n, dtype=bool)
    f, mask = cv2.findFundamentalMat(
        pa.astype(np.float64), pb.astype(np.float64), cv2.FM_RANSAC, tolerance_px, confidence, 2000
    )
    if f is None or mask is None:
        return np.zeros(n, dtype=bool)
    return mask.ravel().astype(bool)[:n]


def homography_inliers(
    pa: NDArray[np.float64], pb: NDArray[np.float64], tolerance_px: float
) -> tuple[NDArray[np.bool_], NDArray[np.float64] | None]:
    """Inliers of a homography found by RANSAC, and the homography (None below 4 matches or on failure)."""
    n = pa.shape[0]
    if n < 4:
        return np.zeros(n, dtype=bool), None
    h, mask = cv2.findHomography(pa.astype(np.float64), pb.astype(np.float64), cv2.RANSAC, tolerance_px, maxIters=2000, confidence=0.995)
    if h is None or mask is None:
        return np.zeros(n, dtype=bool), None
    return mask.ravel().astype(bool)[:n], h


def select_spread(
    points: NDArray[np.float64], quality: NDArray[np.float64], n: int, shape: tuple[int, int], grid: int = 0
) -> NDArray[np.int64]:
    """Indices of at most ``n`` matches, best ``quality`` (larger is better) first, spread over the image.

    ``grid`` cells per side default to about sqrt(n) / 2 so every cell can
    contribute several matches.
    """
    g = grid if grid > 0 else max(2, int(round(np.sqrt(n) / 2)))
    return spread_best(points, quality, n, shape, g)


def local_consistency(
    points_a: NDArray[np.float64], points_b: NDArray[np.float64], tolerance_px: float, neighbours: int = 8
) -> NDArray[np.bool_]:
    """Matches whose displacement agrees with the median displacement of their nearest neighbours.

    After the pre-transform the displacement ``points_b - points_a`` is the pointing
    error plus relief parallax: smooth over tens of pixels. A match that deviates
    from the median of its ``neighbours`` nearest matches (in ``points_a``, itself
    excluded) by more than ``tolerance_px`` is an outlier the global F/H checks
    cannot see (their tolerances must admit the parallax across the whole image).
    The tolerance is 3 robust sigmas (1.4826 MAD) of the neighbours' own deviations
    from their median, bounded to ``tolerance_px`` .. 2 x ``tolerance_px``.
    With fewer than ``neighbours + 1`` matches every match is kept.
    """
    n = points_a.shape[0]
    if n < neighbours + 1:
        return np.ones(n, dtype=bool)
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points_a).query(points_a, k=neighbours + 1)
    d = points_b - points_a
    nb = d[idx[:, 1:]]  # (N, k, 2)
    med = np.median(nb, axis=1)
    # Where the neighbours themselves disagree (sparse matches over varying parallax) the
    # tolerance widens to 3 robust sigmas of their spread.
    spread = NMAD_FACTOR * np.median(np.linalg.norm(nb - med[:, None, :], axis=-1), axis=1)
    return np.linalg.norm(d - med, axis=1) <= np.clip(3.0 * spread, tolerance_px, 2.0 * tolerance_px)
