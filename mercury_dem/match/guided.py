"""Descriptor matching (optionally guided by the a-priori geometry) and the area-based fallback.

Guided matching: after the pre-transform a true match lies at the reference
keypoint's own position up to the pointing error and relief parallax, so
candidates are restricted to a square window of half-width ``window_px``
around the predicted position. The restriction is passed to OpenCV's
brute-force ``knnMatch`` as its mask (query x train, uint8), so the ratio test
compares only plausible candidates -- which is what lets true matches through
under strong illumination differences.

Area-based fallback (the equivalent of ISIS autoseed + pointreg): normalized
cross-correlation of a template around each reference corner over the
guidance window of the warped match image (``cv2.matchTemplate``,
``TM_CCOEFF_NORMED``). It loops over at most ``ncc_max_points`` corners per
pair -- a seeding step, not a per-measure hot path -- because a vectorized
search over a window this large would need far more memory than OpenCV's
per-template correlation.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.match.features import Features
from mercury_dem.match.outliers import KnnResult, knn_from_opencv


def candidate_mask(
    predicted: NDArray[np.float64], points_b: NDArray[np.float64], window_px: float, transposed: bool = False
) -> Any:
    """uint8 mask (Na, Nb): 1 where keypoint b lies within ``window_px`` (per axis) of a's predicted position.

    With ``transposed`` the pair (mask, its transpose as a C-contiguous (Nb, Na) array) is
    returned, as :func:`knn_both_ways` needs both (the k-d tree route writes the transpose
    directly instead of copying a transposed view).

    The test is made in float32. When the window is small against the spread of the b points
    (the usual case: a 13-px window on a 512^2 image) the candidate pairs are first found with
    a k-d tree (Chebyshev distance, a little wider than the window) and only they are tested;
    the dense all-pairs test (1500 x 1500 keypoints: ~12 ms, ~10 % of the bare OpenCV work of
    a pair) is kept for wide windows, where most pairs are candidates. Both give the same mask.
    """
    pa = predicted.astype(np.float32)
    pb = points_b.astype(np.float32)
    w = np.float32(window_px)
    fin_a, fin_b = np.isfinite(pa).all(axis=1), np.isfinite(pb).all(axis=1)
    if fin_b.sum() >= 2 and fin_a.any():
        extent = np.ptp(pb[fin_b], axis=0).astype(np.float64) + 2.0 * float(w)
        sparse = (2.0 * float(w)) ** 2 < _SPARSE_MASK_SHARE * float(extent[0] * extent[1])
    else:
        sparse = False
    if not sparse:
        close = np.abs(pa[:, None, 0] - pb[None, :, 0]) <= w
        close &= np.abs(pa[:, None, 1] - pb[None, :, 1]) <= w
        dense = close.view(np.uint8)
        return (dense, np.ascontiguousarray(dense.T)) if transposed else dense
    ia, ib = np.flatnonzero(fin_a), np.flatnonzero(fin_b)
    # float32 rounding of the coordinates' difference: the exact test below decides
    scale = float(max(np.abs(pa[ia]).max(), np.abs(pb[ib]).max(), float(w)))
    slack = 1e-3 + 1e-5 * scale
    near = cKDTree(pa[ia].astype(np.float64)).sparse_distance_matrix(
        cKDTree(pb[ib].astype(np.float64)), float(w) + slack, p=np.inf, output_type="ndarray")
    i, j = ia[near["i"]], ib[near["j"]]
    keep = (np.abs(pa[i, 0] - pb[j, 0]) <= w) & (np.abs(pa[i, 1] - pb[j, 1]) <= w)
    out = np.zeros((pa.shape[0], pb.shape[0]), np.uint8)
    out[i[keep], j[keep]] = 1
    if not transposed:
        return out
    out_t = np.zeros((pb.shape[0], pa.shape[0]), np.uint8)
    out_t[j[keep], i[keep]] = 1
    return out, out_t


#: The k-d tree route of :func:`candidate_mask` is taken when the window's area is below this
#: share of the b points' extent (measured: 3.5 vs 14 ms at 1.7 %, 26 vs 16 ms at 15 %).
_SPARSE_MASK_SHARE = 0.05


def knn_both_ways(
    fa: Features, fb: Features, mask: NDArray[np.uint8] | None = None, matcher: str = "BF",
    mask_t: NDArray[np.uint8] | None = None,
) -> tuple[KnnResult, KnnResult]:
    """k=2 nearest neighbours a -> b and b -> a (brute force, or FLANN for float descriptors).

    ``mask_t``: the C-contiguous transpose of ``mask`` when the caller has it (else copied here).
    """
    if fa.size == 0 or fb.size == 0:
        empty_a = KnnResult(np.full(fa.size, -1, np.int64), np.full(fa.size, np.inf), np.full(fa.size, np.inf))
        empty_b = KnnResult(np.full(fb.size, -1, np.int64), np.full(fb.size, np.inf), np.full(fb.size, np.inf))
        return empty_a, empty_b
    if matcher == "FLANN" and fa.norm == cv2.NORM_L2 and mask is None:
        m = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    else:
        m = cv2.BFMatcher(fa.norm, crossCheck=False)
    if mask is None:
        ab = m.knnMatch(fa.descriptors, fb.descriptors, k=2)
        ba = m.knnMatch(fb.descriptors, fa.descriptors, k=2)
    else:
        ab = m.knnMatch(fa.descriptors, fb.descriptors, k=2, mask=mask)
        ba = m.knnMatch(fb.descriptors, fa.descriptors, k=2, mask=np.ascontiguousarray(mask.T) if mask_t is None else mask_t)
    return knn_from_opencv(ab, fa.size), knn_from_opencv(ba, fb.size)


def ncc_matches(
    ref: NDArray[np.float32],
    warped: NDArray[np.float32],
    valid: NDArray[np.bool_],
    corners: NDArray[np.float64],
    window_px: float,
    template_px: int,
    min_score: float,
    offset: tuple[float, float] = (0.0, 0.0),
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Area-based matches of reference corners in the warped match image.

    Parameters
    ----------
    ref : ndarray (lines, samples) float32, reference DN
    warped : ndarray (lines, samples) float32, match image in the reference geometry
    valid : ndarray bool, where ``warped`` is inside the match image
    corners : ndarray (K, 2), reference corner positions (sample, line)
    window_px : search half-width around each corner's own position (plus ``offset``)
    template_px : odd template size
    min_score : lowest NCC peak accepted
    offset : (sample, line) displacement predicted for every corner (rounded to whole pixels),
        e.g. from the pair's matches so far; the search window is centred on corner + offset

    Returns
    -------
    index : ndarray (M,) int64, which corners matched
    points : ndarray (M, 2), integer-pixel peak positions in the warped frame
    score : ndarray (M,), NCC peak values
    """
    half = template_px // 2
    r = int(np.ceil(window_px))
    ox, oy = (int(v) for v in np.rint(np.asarray(offset, np.float64)))
    h, w = ref.shape
    # Template centres whose whole template lies on valid warped data.
    centre_ok = cv2.erode(valid.view(np.uint8), np.ones((template_px, template_px), np.uint8)).astype(bool)
    idx: list[int] = []
    pts: list[tuple[float, float]] = []
    scores: list[float] = []
    for k, (s, l) in enumerate(np.rint(corners).astype(np.int64)):
        if s - half < 0 or l - half < 0 or s + half >= w or l + half >= h:
            continue
        t = ref[l - half : l + half + 1, s - half : s + half + 1]
        if float(t.std()) <= 1e-6:
            continue
        s0, s1 = max(s + ox - r - half, 0), min(s + ox + r + half + 1, w)
        l0, l1 = max(l + oy - r - half, 0), min(l + oy + r + half + 1, h)
        if s1 - s0 < template_px + 2 or l1 - l0 < template_px + 2:
            continue
        res = cv2.matchTemplate(warped[l0:l1, s0:s1], t, cv2.TM_CCOEFF_NORMED)
        ok = centre_ok[l0 + half : l1 - half, s0 + half : s1 - half]
        if not ok.any():
            continue
        res = np.where(ok, res, -2.0).astype(np.float32)
        _, peak, _, loc = cv2.minMaxLoc(res)
        if not np.isfinite(peak) or peak < min_score:
            continue
        # Reject peaks on the edge of the searchable area (the true peak may be outside it).
        y, x = loc[1], loc[0]
        if x in (0, res.shape[1] - 1) or y in (0, res.shape[0] - 1):
            continue
        if not (ok[y - 1, x] and ok[y + 1, x] and ok[y, x - 1] and ok[y, x + 1]):
            continue
        idx.append(k)
        pts.append((float(s0 + x + half), float(l0 + y + half)))
        scores.append(float(peak))
    if not idx:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0)
    return np.asarray(idx, np.int64), np.asarray(pts, np.float64), np.asarray(scores, np.float64)
