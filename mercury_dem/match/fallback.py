"""The NCC fallback of a pair: area correlation at base corners when the descriptors leave too few matches.

When the descriptor chain leaves fewer than ``min_matches`` refined matches (illumination
differs, a small warped patch, little texture), :func:`ncc_fallback` searches the warped
partner by normalized cross-correlation (:func:`mercury_dem.match.guided.ncc_matches`) at
corners of the base image within the guidance window, or around the position the matches so
far predict, and passes them through the same fundamental and homography checks. On a small
warped patch the template shrinks (:func:`ncc_template_size`) and Shi-Tomasi corners and grid
seeds are added to the base's keypoints. The pair chain (:mod:`mercury_dem.match.pair`) refines
the result and keeps it when it adds matches.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.features import spread_best, stretch_to_8bit
from mercury_dem.match.guided import ncc_matches
from mercury_dem.match.outliers import fundamental_inliers, homography_inliers, select_spread
from mercury_dem.match.prepare import ImageFeatures
from mercury_dem.match.pretransform import PairGeometry
from mercury_dem.match.result import Matches, PairReport
from mercury_dem.stats import NMAD_FACTOR

#: Shi-Tomasi corners added to the NCC fallback's candidates: quality level and spacing (pixels).
_EXTRA_CORNER_QUALITY = 0.005
_EXTRA_CORNER_SPACING_PX = 3


def _extra_corners(base: ImageFeatures, on: NDArray[np.bool_], have: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """Up to ``n`` more corners of the base (sample, line) where the fallback's template fits on the data.

    The base's own keypoints are capped over the whole image (``max_keypoints`` spread on a
    grid), so a small warped patch (the finer image of a 4x pair covers 1/16 of the coarser
    one) holds a few dozen of them: too few for 20 matches when the illumination differs.
    Shi-Tomasi corners (``cv2.goodFeaturesToTrack``, restricted to the usable area) fill the
    patch, at least ``_EXTRA_CORNER_SPACING_PX`` from each other and from the keypoints.
    Those are local maxima of the corner strength, one per ~6 px on these smooth images: a
    40-px patch gives 15-25. The rest is seeded on a grid (like ISIS autoseed): in every
    ``_EXTRA_GRID_CELL_PX`` cell of the usable area, its strongest pixel when its corner
    strength passes the same quality level, the strongest cells first.
    They carry no keypoint id (-1): the network joins them by position.
    """
    i8 = stretch_to_8bit(base.image, base.quality.low, base.quality.high)
    corners = cv2.goodFeaturesToTrack(i8, int(n) + have.shape[0], _EXTRA_CORNER_QUALITY, _EXTRA_CORNER_SPACING_PX,
                                      mask=on.view(np.uint8))
    pts: NDArray[np.float64] = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(np.float64)
    if pts.shape[0] + have.shape[0] < n:
        pts = np.concatenate([pts, _grid_seeds(i8, on)])
    return pts[_spaced(pts, have, _EXTRA_CORNER_SPACING_PX, int(n))]


def _spaced(pts: NDArray[np.float64], have: NDArray[np.float64], spacing: float, n: int) -> NDArray[np.int64]:
    """Indices of at most ``n`` of ``pts``, taken greedily in order, each at least ``spacing`` from
    ``have`` and from those taken before it (corners first, then the strongest grid cells).

    The neighbours closer than ``spacing`` are found once with kd-trees; the greedy pass then only
    marks them (a Python loop over the points, no tree rebuilt per point).
    """
    if pts.shape[0] == 0 or n <= 0:
        return np.zeros(0, np.int64)
    r = float(np.nextafter(spacing, 0.0))  # closer than spacing <=> within r (query_ball_point is <=)
    blocked = np.zeros(pts.shape[0], bool)
    if have.shape[0]:
        d, _ = cKDTree(have).query(pts, k=1)
        blocked = np.asarray(d) < spacing
    near = cKDTree(pts).query_ball_point(pts, r)
    keep: list[int] = []
    for k in range(pts.shape[0]):
        if blocked[k]:
            continue
        keep.append(k)
        if len(keep) >= n:
            break
        blocked[near[k]] = True
    return np.asarray(keep, np.int64)


#: Cell size of the NCC fallback's grid seeds on a patch with too few corners (pixels).
_EXTRA_GRID_CELL_PX = 4
#: Neighbourhood (pixels) of the grid seeds' corner strength (``cv2.cornerMinEigenVal`` blockSize):
#: 3, the smallest, as ``goodFeaturesToTrack``'s default for the corners it adds to.
_GRID_SEED_BLOCK_PX = 3


def _grid_seeds(i8: NDArray[np.uint8], on: NDArray[np.bool_]) -> NDArray[np.float64]:
    """The strongest pixel (min eigenvalue, Shi-Tomasi) of each grid cell of ``on`` above the quality level."""
    eig = np.where(on, cv2.cornerMinEigenVal(i8, _GRID_SEED_BLOCK_PX), 0.0)
    top = float(eig.max())
    if top <= 0:
        return np.zeros((0, 2))
    c = _EXTRA_GRID_CELL_PX
    hc, wc = eig.shape[0] // c, eig.shape[1] // c
    blk = eig[: hc * c, : wc * c].reshape(hc, c, wc, c).transpose(0, 2, 1, 3).reshape(hc, wc, c * c)
    arg, val = blk.argmax(axis=-1), blk.max(axis=-1)
    ys, xs = np.nonzero(val > _EXTRA_CORNER_QUALITY * top)
    order = np.argsort(-val[ys, xs], kind="stable")
    ys, xs = ys[order], xs[order]
    a = arg[ys, xs]
    return np.stack([xs * c + a % c, ys * c + a // c], axis=-1).astype(np.float64)


#: Smallest template of the NCC fallback on a small warped patch (pixels, odd).
NCC_MIN_TEMPLATE_PX = 9
#: A shrunk template is at most this fraction of the patch's side: 4, so that a few templates'
#: worth of corners fit across the patch (a 50-px patch with a +-10 px search gets 13 px).
_NCC_TEMPLATES_PER_SIDE = 4.0
#: Mask of the chessboard distance transform (``cv2.DIST_C``): 3, with which it is exact.
_DIST_MASK_PX = 3


def ncc_template_size(valid: NDArray[np.bool_], template_px: int, search_px: float) -> int:
    """Template size of the NCC fallback: ``template_px``, shrunk on a small warped patch.

    The fallback only searches where the whole template lies on the warped data, and a
    peak on the border of that area is rejected. When the finer image of a 4x pair is
    warped onto the coarser one it covers a ~64 pixel square: a 31-pixel template leaves
    a 33-pixel square of centres, less than the +-16 px guidance search around most
    corners, so nothing matches. On a patch whose side (of its inscribed square, the largest
    square fully on data, by a distance transform) is less than the search window plus two
    templates, the template is shrunk to what fits, and to at most a quarter of the side
    (odd, not below ``NCC_MIN_TEMPLATE_PX``): a 50-px patch with a +-10 px search gets 13 px.
    """
    t = int(template_px) | 1
    if not valid.any():
        return t
    dist = cv2.distanceTransform(valid.view(np.uint8), cv2.DIST_C, _DIST_MASK_PX)
    side = 2.0 * float(dist.max())  # the largest square fully on valid data
    want = 0.5 * (side - 2.0 * float(search_px))  # the template fits twice beside the search window
    fit = min(want, side / _NCC_TEMPLATES_PER_SIDE) if want < t else float(t)
    return int(max(NCC_MIN_TEMPLATE_PX, min(t, int(fit) | 1)))


#: NCC fallback candidates this close (base pixels) to a descriptor match are not added.
NCC_DEDUP_PX = 2.0


def _away(have: NDArray[np.float64], query: NDArray[np.float64], dist: float) -> NDArray[np.bool_]:
    """Which ``query`` points are farther than ``dist`` from every point of ``have``."""
    if have.shape[0] == 0 or query.shape[0] == 0:
        return np.ones(query.shape[0], bool)
    d, _ = cKDTree(have).query(query, k=1)
    return np.asarray(d) > dist


def ncc_fallback(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_], pg: PairGeometry,
                 tpl: int, config: MatchConfig, rep: PairReport, pa_have: NDArray[np.float64],
                 pb_have: NDArray[np.float64],
                 ) -> Matches:
    """The fallback's new matches: :func:`_ncc_search`'s, less those within ``NCC_DEDUP_PX`` of a
    match the pair has (``pa_have``, base pixels): base keypoint ids (-1 for added corners), base
    pixels, warped-frame pixels and peak NCC; ``rep`` gets the NCC counts.
    """
    c_feat, c_pa, c_pb, c_sc = _ncc_search(base, warped, valid, pg, tpl, config, rep, pa_have, pb_have)
    new = _away(pa_have, c_pa, NCC_DEDUP_PX)
    return Matches(c_feat[new], c_pa[new], c_pb[new], c_sc[new])


def _ncc_search(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_], pg: PairGeometry,
                tpl: int, config: MatchConfig, rep: PairReport, pa_have: NDArray[np.float64],
                pb_have: NDArray[np.float64],
                ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """NCC matches at base corners within the guidance window, through the fundamental and homography checks.

    Only corners whose template can lie on the warped data: when the warped image is a small
    patch of the base (the finer image of a 4x pair) a cap spread over the whole base would
    leave a handful of corners in it; Shi-Tomasi corners and grid seeds fill the patch when the
    keypoints are fewer than ``ncc_max_points`` there. Where the template lies is predicted:
    with at least ``_NCC_PREDICT_MIN`` matches so far (the descriptors' ``pa_have`` ->
    ``pb_have``, else a first pass over the guidance window) the corners are those whose template
    fits on the data at corner + their median displacement, searched within a few pixels of it
    (``_ncc_predicted_radius``): on a thin overlap the corners near its edge, whose true match
    the guidance window's corners (chosen at their own position) miss by the pointing offset,
    are then found too. The pass with more matches through the checks is kept. Returns base
    keypoint ids (-1 for the added corners), base pixels, warped-frame pixels and peak NCC.
    """
    on = cv2.erode(valid.view(np.uint8), np.ones((tpl, tpl), np.uint8)).astype(bool)
    best = None
    if pa_have.shape[0] < _NCC_PREDICT_MIN:
        best = _ncc_pass(base, warped, valid, on, (0.0, 0.0), pg.guidance_px, tpl, config)
        pa_have, pb_have = best[1], best[2]
    if pa_have.shape[0] >= _NCC_PREDICT_MIN:
        d = pb_have - pa_have
        offset = np.median(d, axis=0)
        radius = min(pg.guidance_px, _ncc_predicted_radius(d, offset))
        second = _ncc_pass(base, warped, valid, _shifted(on, offset), offset, radius, tpl, config)
        if best is None or second[0].size > best[0].size:
            best = second
    assert best is not None  # one of the two passes ran
    c_feat, c_pa, pts_w, sc, counts = best
    rep.n_ncc, rep.n_ncc_fundamental, rep.n_ncc_homography = counts
    return c_feat, c_pa, pts_w, sc


#: Matches needed to predict the NCC fallback's search position from their median displacement.
_NCC_PREDICT_MIN = 5
#: Search half-width around the predicted position: this many pixels plus ``_NCC_PREDICTED_SIGMAS``
#: robust sigmas of the displacements, the sigma at least ``_NCC_PREDICTED_MIN_SPREAD_PX`` (see
#: :func:`_ncc_predicted_radius`; the values the fallback was measured with, docs/design/match.md
#: step 9, not tuned one by one).
_NCC_PREDICTED_BASE_PX = 3.0
_NCC_PREDICTED_SIGMAS = 3.0
_NCC_PREDICTED_MIN_SPREAD_PX = 0.5


def _ncc_predicted_radius(d: NDArray[np.float64], offset: NDArray[np.float64]) -> float:
    """Search half-width around a predicted position: 3 px plus 3 robust sigmas of the displacements (at
    least 0.5 px: the first pass's integer peaks can all agree while relief parallax still varies).
    """
    spread = NMAD_FACTOR * float(np.median(np.linalg.norm(d - offset, axis=1)))
    return _NCC_PREDICTED_BASE_PX + _NCC_PREDICTED_SIGMAS * max(spread, _NCC_PREDICTED_MIN_SPREAD_PX)


def _shifted(mask: NDArray[np.bool_], offset: NDArray[np.float64]) -> NDArray[np.bool_]:
    """``out[y, x] = mask[y + oy, x + ox]`` (offset rounded), False where that leaves the mask."""
    ox, oy = (int(v) for v in np.rint(offset))
    h, w = mask.shape
    out = np.zeros_like(mask)
    ys, xs = slice(max(0, -oy), min(h, h - oy)), slice(max(0, -ox), min(w, w - ox))
    yd, xd = slice(max(0, oy), min(h, h + oy)), slice(max(0, ox), min(w, w + ox))
    if ys.stop > ys.start and xs.stop > xs.start:
        out[ys, xs] = mask[yd, xd]
    return out


def _ncc_pass(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_], on: NDArray[np.bool_],
              offset: Any, radius: float, tpl: int, config: MatchConfig) -> Any:
    """One NCC search at the corners usable in ``on``: ids, base and warped pixels, scores (after
    F and H) and the counts (NCC peaks, F inliers, H inliers).
    """
    fa = base.features
    ij = np.clip(np.rint(fa.points).astype(np.int64), 0, [on.shape[1] - 1, on.shape[0] - 1])
    usable = np.flatnonzero(on[ij[:, 1], ij[:, 0]]) if fa.size else np.zeros(0, np.int64)
    n_corner = min(config.ncc_max_points, usable.size)
    c_id = usable[spread_best(fa.points[usable], fa.response[usable], n_corner, base.image.shape, config.keypoint_grid)]
    c_pts = fa.points[c_id]
    if c_id.size < config.ncc_max_points and on.any():
        extra = _extra_corners(base, on, c_pts, config.ncc_max_points - c_id.size)
        c_id = np.concatenate([c_id, np.full(extra.shape[0], -1, np.int64)])
        c_pts = np.concatenate([c_pts, extra])
    idx, pts_w, sc = ncc_matches(base.image, warped, valid, c_pts, radius, tpl, config.ncc_min_score,
                                 (float(offset[0]), float(offset[1])))
    n_ncc = int(idx.size)
    c_feat, c_pa = c_id[idx], c_pts[idx]
    inl = fundamental_inliers(c_pa, pts_w, config.fundamental_tolerance_px, config.fundamental_confidence)
    n_f = int(inl.sum())
    c_feat, c_pa, pts_w, sc = c_feat[inl], c_pa[inl], pts_w[inl], sc[inl]
    inl, _ = homography_inliers(c_pa, pts_w, config.homography_tolerance_px)
    n_h = int(inl.sum())
    keep = np.flatnonzero(inl)
    keep = keep[select_spread(c_pa[keep], sc[keep], config.max_matches, base.image.shape)]
    return c_feat[keep].astype(np.int64), c_pa[keep], pts_w[keep], sc[keep], (n_ncc, n_f, n_h)
