"""Multi-image tracks inside a tile: anchors propagated to every pair of their image.

Pairwise matching alone gives mostly 2-ray points: a reference keypoint that
survives the descriptor chain in pair (R, A) rarely also survives it in (R, B)
(both need FAST to fire at the same corner of the warped image and the ratio
test to pass). The control network links observations by (image, keypoint id),
so a keypoint matched in several pairs of its image becomes one point of 3+ rays.

After every pair of the tile has been matched (phase 1), each image's *anchors*
are the keypoints of its own features (ids stable across the tile) that
survived in at least one pair. Phase 2 tries every anchor of an image in every
other matched pair of that image, by area correlation only:

* **forward** (the image is the pair's base, kept in its own geometry): the
  anchor is the template, searched in the warped partner around the position
  predicted by the pair's own matches (median displacement of the nearest ones);
* **reverse** (the image is the warped side): the template is cut from the
  warped image at the anchor's pre-transformed position and searched in the base.

Either way the anchor stays exactly on its keypoint (its id is carried to the
network) and only the partner moves, refined to sub-pixel by the same
vectorized correlation + Gauss-Newton as phase 1 (:func:`refine_matches`). A
propagated match is kept only when its correlation passes, its peak is not on
the search border, and its displacement agrees with the pair's phase-1 matches
around it (the local-consistency rule of :func:`local_consistency`, against the
pair's own matches, which are not changed). Anchors within ``dedup_px`` of a
match the pair already has are not tried (they would give a second measure of
the same feature, a conflict in the network).

Phase 3 keeps at most ``max_matches`` per pair, preferring matches whose anchor
is matched in more pairs (so every pair keeps the same anchors), then the
correlation score, spread over the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.match.features import spread_best
from mercury_dem.match.refine import _box_count, integral_image, refine_matches

#: Neighbours (pair matches) whose median displacement predicts a propagated anchor's position.
PREDICT_NEIGHBOURS = 6
#: Anchors closer than this (pixels of the pair frame) to a match the pair has are not tried.
DEDUP_PX = 2.0


@dataclass(frozen=True)
class Propagated:
    """Matches added to one pair by propagation, in the pair frame (the base image's pixels).

    Attributes
    ----------
    forward : ndarray (F,) int64, index into the forward candidates that matched
    forward_points : ndarray (F, 2), their refined positions in the warped frame
    forward_score : ndarray (F,)
    reverse : ndarray (R,) int64, index into the reverse candidates that matched
    reverse_points : ndarray (R, 2), their refined positions in the base image
    reverse_score : ndarray (R,)
    """

    forward: NDArray[np.int64]
    forward_points: NDArray[np.float64]
    forward_score: NDArray[np.float64]
    reverse: NDArray[np.int64]
    reverse_points: NDArray[np.float64]
    reverse_score: NDArray[np.float64]


def predict_displacement(
    points: NDArray[np.float64], displacement: NDArray[np.float64], query: NDArray[np.float64], k: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Median displacement (Q, 2) of the ``k`` nearest ``points`` of each query, and its robust spread (Q,).

    The spread is 1.4826 x the median distance of those neighbours' displacements from
    their median (pixels): how well the neighbourhood agrees.
    """
    k = int(min(k, points.shape[0]))
    _, idx = cKDTree(points).query(query, k=k)
    idx = np.asarray(idx).reshape(query.shape[0], k)
    nb = displacement[idx]
    med = np.median(nb, axis=1)
    spread = 1.4826 * np.median(np.linalg.norm(nb - med[:, None, :], axis=-1), axis=1)
    return med, spread


def _away_from(existing: NDArray[np.float64], query: NDArray[np.float64], dist: float) -> NDArray[np.bool_]:
    if existing.shape[0] == 0 or query.shape[0] == 0:
        return np.ones(query.shape[0], bool)
    d, _ = cKDTree(existing).query(query, k=1)
    return np.asarray(d) > dist


def _window_on(valid: NDArray[np.bool_], pts: NDArray[np.float64], half: int,
               integral: NDArray[np.int32] | None = None) -> NDArray[np.bool_]:
    """Points whose (2 half + 3)^2 window lies entirely on ``valid`` pixels (``integral``: its integral image)."""
    h, w = valid.shape
    f = np.nan_to_num(pts, nan=-1e9)
    lo = np.floor(f).astype(np.int64) - half - 1
    hi = np.ceil(f).astype(np.int64) + half + 1
    ok = (lo[:, 0] >= 0) & (lo[:, 1] >= 0) & (hi[:, 0] < w) & (hi[:, 1] < h)
    ok &= _box_count(valid, lo, hi, integral) == (hi - lo + 1).prod(axis=1)
    return ok


def propagate_pair(
    base: NDArray[np.float32],
    warped: NDArray[np.float32],
    valid: NDArray[np.bool_],
    pa: NDArray[np.float64],
    pb: NDArray[np.float64],
    forward: NDArray[np.float64],
    reverse: NDArray[np.float64],
    window: int,
    search: int,
    iterations: int,
    min_score: float,
    tolerance_px: float,
    neighbours: int = PREDICT_NEIGHBOURS,
    dedup_px: float = DEDUP_PX,
    max_candidates: int = 0,
    forward_priority: NDArray[np.float64] | None = None,
    reverse_priority: NDArray[np.float64] | None = None,
    base_pattern: NDArray[np.float32] | None = None,
    warped_pattern: NDArray[np.float32] | None = None,
    min_window: int = 0,
) -> Propagated:
    """Match anchors into one pair whose own matches ``pa`` <-> ``pb`` give the displacement field.

    Parameters
    ----------
    base : ndarray (lines, samples) float32, the image kept in its own geometry
    warped, valid : the partner resampled in the base geometry, and where it has data
    pa, pb : ndarray (K, 2), the pair's matches (base pixels, warped-frame pixels); K >= 4
    forward : ndarray (F, 2), anchors of the base image (base pixels) to find in ``warped``
    reverse : ndarray (R, 2), anchors of the partner, pre-transformed into the warped frame,
        to find in ``base``
    window, search, iterations, min_score : refinement settings (as :func:`refine_matches`)
    tolerance_px : local-consistency tolerance; the accepted deviation from the predicted
        displacement is 3 robust sigmas of the neighbours' spread, bounded to 1-2 x this
    neighbours : matches whose median displacement predicts each anchor
    dedup_px : anchors this close to an existing match are skipped
    max_candidates : when > 0, at most this many anchors of each direction are refined (those
        on the partner's data, the highest ``*_priority`` first, spread over an 8 x 8 grid)
    forward_priority, reverse_priority : (F,), (R,) larger first (default: equal)
    base_pattern, warped_pattern : the images positions are found on (as the ``*_pattern`` of
        :func:`refine_matches`, both or neither); None = ``base``, ``warped``
    min_window : anchors whose ``window`` (template or search area) leaves the data are refined
        with windows ~30 % smaller down to this size, as :func:`refine_matches_adaptive` does in
        phase 1 (0 = ``window`` only)

    Returns
    -------
    :class:`Propagated`
    """
    empty = np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0)
    if pa.shape[0] < 4:
        return Propagated(*empty, *empty)
    d_pair = pb - pa
    everywhere = np.ones(base.shape, bool)
    # the two masks' integral images, once per pair (each window test and refinement asked for them anew)
    ii = {id(valid): integral_image(valid), id(everywhere): integral_image(everywhere)}
    # window sizes tried, largest first (as refine_matches_adaptive: ~30 % smaller down to min_window)
    sizes = [int(window) | 1]
    while 0 < min_window < sizes[-1]:
        sizes.append(max(int(min_window) | 1, int(round(sizes[-1] * 0.7)) | 1))

    def run(fixed_img, moving_img, moving_valid, fixed_valid, fixed, field, taken, sign, prio, fixed_pat, moving_pat):
        if fixed.shape[0] == 0:
            return empty
        cand = np.flatnonzero(_away_from(taken, fixed, dedup_px) & _window_on(fixed_valid, fixed, sizes[-1] // 2 + 1,
                                                                                ii[id(fixed_valid)]))
        if cand.size == 0:
            return empty
        # the displacement field (warped - base) around each anchor, from the pair's matches on
        # the anchor's own side (base positions for forward anchors, warped ones for reverse)
        med, spread = predict_displacement(field, d_pair, fixed[cand], neighbours)
        start = fixed[cand] + sign * med
        # each anchor gets the largest window whose template and whole search area are on data
        # (near the edge of a small overlap only the smaller ones fit); the others are not refined
        size = np.zeros(cand.size, np.int64)
        for wsz in sizes:
            fits = (size == 0) & _window_on(moving_valid, start, wsz // 2 + search + 1, ii[id(moving_valid)])
            fits &= _window_on(fixed_valid, fixed[cand], wsz // 2 + 1, ii[id(fixed_valid)])
            size[fits] = wsz
        reach = size > 0
        cand, start, spread, size = cand[reach], start[reach], spread[reach], size[reach]
        if cand.size == 0:
            return empty
        if 0 < max_candidates < cand.size:
            p = np.zeros(cand.size) if prio is None else np.asarray(prio, np.float64)[cand]
            keep = spread_best(start, p, max_candidates, base.shape, 8)
            cand, start, spread, size = cand[keep], start[keep], spread[keep], size[keep]
        points, score, ok = np.zeros((cand.size, 2)), np.zeros(cand.size), np.zeros(cand.size, bool)
        for wsz in np.unique(size):
            g = np.flatnonzero(size == wsz)
            r = refine_matches(fixed_img, moving_img, moving_valid, fixed[cand[g]], start[g], int(wsz), search,
                               iterations, min_score, float(search), fixed_pat, moving_pat, ii[id(moving_valid)])
            points[g], score[g], ok[g] = r.points, r.score, r.ok
        dev = np.linalg.norm(points - start, axis=1)
        ok &= dev <= np.clip(3.0 * spread, tolerance_px, 2.0 * tolerance_px)
        return cand[ok], points[ok], score[ok]

    fwd = run(base, warped, valid, everywhere, forward, pa, pa, +1, forward_priority, base_pattern, warped_pattern)
    # a partner anchor at a feature just matched forward would be a second measure of it
    rev = run(warped, base, everywhere, valid, reverse, pb, np.concatenate([pb, fwd[1]]), -1, reverse_priority,
              warped_pattern, base_pattern)
    return Propagated(*fwd, *rev)
