"""Propagation inside a tile: anchors propagated to every pair of their image, then each pair thinned.

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

:func:`propagate_pair` is the correlation search of one pair (arrays in and out); the tile's
steps around it work on the pairs' :class:`~mercury_dem.match.pair.PairState`: which anchors
each image has (:func:`anchors_of`), the search into one pair (:func:`propagate_into`), in how
many pairs each match's anchor is matched (:func:`priorities`) and the thinning (:func:`thin`).
(Not to be confused with :mod:`mercury_dem.network.tracks`, which joins a tile's matches into
the control network's points.)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import cast

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.features import spread_best
from mercury_dem.match.flow import Flow, base_position
from mercury_dem.match.outliers import select_spread
from mercury_dem.match.pair import PairState, pair_flow, read_flow
from mercury_dem.match.prepare import refine_pattern
from mercury_dem.match.pretransform import apply_homography, warp_to_reference
from mercury_dem.match.refine import box_count, integral_image, refine_matches
from mercury_dem.match.result import PairReport, PairResult
from mercury_dem.stats import NMAD_FACTOR

#: Neighbours (pair matches) whose median displacement predicts a propagated anchor's position.
PREDICT_NEIGHBOURS = 6
#: Anchors closer than this (pixels of the pair frame) to a match the pair has are not tried.
DEDUP_PX = 2.0
_NONE = np.zeros(0, np.int64)
#: An image's anchors: (keypoint ids in its own features, sorted; in how many pairs each survived the chain).
Anchors = tuple[NDArray[np.int64], NDArray[np.int64]]
#: The anchors of an image that has none.
NO_ANCHORS: Anchors = (_NONE, _NONE)
#: Lowest NCC of a propagated match: measured on the tiny mission, propagated matches with a
#: refined NCC of 0.5-0.7 had a median true error of 0.6-0.9 px (0.2-0.4 px above 0.8).
PROPAGATE_MIN_SCORE = 0.7
#: Integer search radius of propagation: the start is predicted from the pair's own matches.
PROPAGATE_SEARCH_PX = 2
#: Smallest refinement window of a propagated anchor near the edge of a small overlap (as phase 1's).
PROPAGATE_MIN_WINDOW_PX = 11
#: Pairs with fewer matches after the chain neither give anchors nor receive them.
_PROPAGATE_MIN_MATCHES = 8
#: Window sizes a propagated anchor tries shrink by this factor per step down to ``min_window``
#: (~30 %, as :func:`mercury_dem.match.refine.refine_matches_adaptive` does in phase 1).
WINDOW_SHRINK = 0.7
#: Cells per side of the grid over which ``max_candidates`` anchors are spread (the keypoints'
#: ``keypoint_grid`` default, 8): candidates from the whole overlap, not one corner of it.
CANDIDATE_GRID = 8
#: A propagated match is kept when its position is within this many robust sigmas of the
#: neighbours' spread of the predicted one, the limit bounded to 1-``ACCEPT_MAX_TOLERANCES`` x
#: the local-consistency tolerance (a smooth neighbourhood cannot make it stricter than phase 1's
#: check, a rough one not looser than twice it).
ACCEPT_SIGMAS = 3.0
ACCEPT_MAX_TOLERANCES = 2.0
#: The tolerance used when the local-consistency check is switched off (``local_tolerance_px`` 0).
_TOLERANCE_WITHOUT_LOCAL_PX = 1.0
#: Priority weight of the thinning (:func:`thin`): ``weight x pairs + score``. Two refined NCC
#: scores differ by less than 2 (at the default ``refine_min_score`` 0.5, by at most 0.5), so
#: an anchor matched in more pairs comes before one in fewer, the score deciding among equals
#: (then :func:`select_spread` spreads them over the image).
THIN_PRIORITY_WEIGHT = 2.0
#: (image index, keypoint id) packed into one int64 key as ``index x stride + id`` (keypoint
#: ids are below 2^32).
_IMAGE_KEY_STRIDE = 1 << 32
#: Stands for a NaN position in the window test: far off every image, so it fails the bounds.
_OFF_IMAGE = -1e9


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
    spread = NMAD_FACTOR * np.median(np.linalg.norm(nb - med[:, None, :], axis=-1), axis=1)
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
    f = np.nan_to_num(pts, nan=_OFF_IMAGE)
    lo = np.floor(f).astype(np.int64) - half - 1
    hi = np.ceil(f).astype(np.int64) + half + 1
    ok = (lo[:, 0] >= 0) & (lo[:, 1] >= 0) & (hi[:, 0] < w) & (hi[:, 1] < h)
    ok &= box_count(valid, lo, hi, integral) == (hi - lo + 1).prod(axis=1)
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
        sizes.append(max(int(min_window) | 1, int(round(sizes[-1] * WINDOW_SHRINK)) | 1))

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
            keep = spread_best(start, p, max_candidates, base.shape, CANDIDATE_GRID)
            cand, start, spread, size = cand[keep], start[keep], spread[keep], size[keep]
        points, score, ok = np.zeros((cand.size, 2)), np.zeros(cand.size), np.zeros(cand.size, bool)
        for wsz in np.unique(size):
            g = np.flatnonzero(size == wsz)
            r = refine_matches(fixed_img, moving_img, moving_valid, fixed[cand[g]], start[g], int(wsz), search,
                               iterations, min_score, float(search), fixed_pat, moving_pat, ii[id(moving_valid)])
            points[g], score[g], ok[g] = r.points, r.score, r.ok
        dev = np.linalg.norm(points - start, axis=1)
        ok &= dev <= np.clip(ACCEPT_SIGMAS * spread, tolerance_px, ACCEPT_MAX_TOLERANCES * tolerance_px)
        return cand[ok], points[ok], score[ok]

    fwd = run(base, warped, valid, everywhere, forward, pa, pa, +1, forward_priority, base_pattern, warped_pattern)
    # a partner anchor at a feature just matched forward would be a second measure of it
    rev = run(warped, base, everywhere, valid, reverse, pb, np.concatenate([pb, fwd[1]]), -1, reverse_priority,
              warped_pattern, base_pattern)
    return Propagated(*fwd, *rev)


def base_id(pair: tuple[str, str], st: PairState) -> str:
    """The id of the pair's image kept in its own geometry (the base)."""
    return pair[1] if st.swap else pair[0]


def other_id(pair: tuple[str, str], st: PairState) -> str:
    """The id of the pair's warped image."""
    return pair[0] if st.swap else pair[1]


def anchors_of(pairs: Sequence[tuple[str, str]], states: Sequence[PairResult | PairState]) -> dict[str, Anchors]:
    """Image id -> (keypoint ids, sorted; in how many pairs each survived the chain) for the keypoints
    that survived in at least one pair where the image is the base.
    """
    found: dict[str, list[NDArray[np.int64]]] = {}
    for pair, st in zip(pairs, states):
        if isinstance(st, PairState) and st.pa.shape[0] >= _PROPAGATE_MIN_MATCHES:
            found.setdefault(base_id(pair, st), []).append(st.feat_base[st.feat_base >= 0])
    out: dict[str, Anchors] = {}
    for k, v in found.items():
        ids, counts = np.unique(np.concatenate(v), return_counts=True)
        out[k] = (ids, counts.astype(np.int64))
    return out


def propagate_into(st: PairState, base_anchors: Anchors, other_anchors: Anchors, config: MatchConfig,
                   rep: PairReport) -> PairState:
    """The pair with the base's and the partner's anchors it does not have yet added (see the module docstring).

    Each direction refines at most the pair's free room below ``max_matches`` plus
    ``propagate_extra`` x ``max_matches`` (default an eighth; for a full pair: 50 anchors that may replace single-pair matches in the
    thinning), those matched in more pairs first, spread: the cost stays bounded by about one
    more refinement pass (a full pair: a quarter of one). The returned state no longer holds the
    warped partner once it has been used; ``rep.n_propagated`` (and the flow counts) are set.
    """
    if st.pa.shape[0] < _PROPAGATE_MIN_MATCHES or not st.base.described or not st.other.described:
        return st
    new = ~np.isin(base_anchors[0], st.feat_base)
    fwd, fwd_count = base_anchors[0][new], base_anchors[1][new]
    rev, rev_count = other_anchors
    cap = max(config.max_matches - st.pa.shape[0], 0) + int(round(config.max_matches * config.propagate_extra))
    if (fwd.size == 0 and rev.size == 0) or cap <= 0:  # (propagate_pair reads 0 as "no cap")
        return st
    h = st.pg.homography
    rev_orig = st.other.features.points[rev]
    rev_pair = apply_homography(cast(NDArray[np.float64], np.linalg.inv(h)), rev_orig) if rev.size else np.zeros((0, 2))
    flow: Flow | None = None
    if st.warped is not None:
        warped, valid, wpat, flow = st.warped.image, st.warped.valid, st.warped.pattern, st.warped.flow
        st = replace(st, warped=None)
    else:
        warped, valid = warp_to_reference(st.other.image, h, st.base.image.shape, st.pg.match_px_per_ref_px,
                                          config.psf_sigma_px)
        wpat = refine_pattern(warped, config)
        if st.flow_used and wpat is not None and st.base.pattern is not None:
            flow = pair_flow(st.base.pattern, wpat, valid, st.pa, st.pb, config)
    bpat = st.base.pattern if wpat is not None else None
    prop = propagate_pair(
        st.base.image, warped, valid, st.pa, st.pb, st.base.features.points[fwd], rev_pair,
        config.refine_window_px | 1, min(config.refine_search_px, PROPAGATE_SEARCH_PX), config.refine_iterations,
        max(config.refine_min_score, PROPAGATE_MIN_SCORE), config.local_tolerance_px if config.local_tolerance_px > 0 else _TOLERANCE_WITHOUT_LOCAL_PX,
        max_candidates=cap,
        forward_priority=fwd_count.astype(np.float64),
        reverse_priority=rev_count.astype(np.float64),
        base_pattern=bpat, warped_pattern=wpat if bpat is not None else None,
        min_window=PROPAGATE_MIN_WINDOW_PX,
    )
    if flow is not None:
        prop = _propagated_on_flow(prop, flow, st.base.features.points[fwd], rev_pair, config, rep)
    nf, nr = prop.forward.size, prop.reverse.size
    if nf + nr == 0:
        return st
    n = st.pa.shape[0]
    other_exact = st.other_exact if st.other_exact is not None else np.full((n, 2), np.nan)
    kind = st.kind if st.kind is not None else np.zeros(n, np.int8)
    rep.n_propagated = nf + nr
    return replace(
        st,
        feat_base=np.concatenate([st.feat_base, fwd[prop.forward], np.full(nr, -1, np.int64)]),
        feat_other=np.concatenate([st.feat_other, np.full(nf, -1, np.int64), rev[prop.reverse]]),
        pa=np.concatenate([st.pa, st.base.features.points[fwd[prop.forward]], prop.reverse_points]),
        pb=np.concatenate([st.pb, prop.forward_points, rev_pair[prop.reverse]]),
        score=np.concatenate([st.score, prop.forward_score, prop.reverse_score]),
        other_exact=np.concatenate([other_exact, np.full((nf, 2), np.nan), rev_orig[prop.reverse]]),
        kind=np.concatenate([kind, np.ones(nf, np.int8), np.full(nr, 2, np.int8)]),
    )


def _propagated_on_flow(prop: Propagated, flow: Flow, fwd_pts: NDArray[np.float64], rev_pts: NDArray[np.float64],
                        config: MatchConfig, rep: PairReport) -> Propagated:
    """Propagated matches read from the pair's flow as phase 1's are: the partner position of a
    forward anchor (base side fixed) at ``base + flow(base)``, the base position of a reverse one
    (partner side fixed) where ``base + flow(base)`` reaches it; those the flow contradicts by more
    than ``flow_tolerance_px`` dropped, those where it is not usable kept as refined.
    """
    qf, uf, af = read_flow(flow, fwd_pts[prop.forward], prop.forward_points, config)
    qr, ur = base_position(flow, rev_pts[prop.reverse], prop.reverse_points)
    ar = np.linalg.norm(qr - prop.reverse_points, axis=1) <= config.flow_tolerance_px
    kf, kr = ~(uf & ~af), ~(ur & ~ar)
    rep.n_flow += int((uf & af).sum() + (ur & ar).sum())
    rep.n_flow_dropped += int((~kf).sum() + (~kr).sum())
    fp = np.where((uf & af)[:, None], qf, prop.forward_points)
    rp = np.where((ur & ar)[:, None], qr, prop.reverse_points)
    return Propagated(prop.forward[kf], fp[kf], prop.forward_score[kf], prop.reverse[kr], rp[kr], prop.reverse_score[kr])


def priorities(pairs: Sequence[tuple[str, str]], states: Sequence[PairResult | PairState],
               index: Mapping[str, int]) -> list[NDArray[np.int64]]:
    """Per pair, for every match: in how many pairs of the tile its anchor (image, keypoint) is matched."""
    keys: list[NDArray[np.int64]] = []
    for pair, st in zip(pairs, states):
        if not isinstance(st, PairState):
            keys.append(_NONE)
            continue
        kb = index[base_id(pair, st)] * _IMAGE_KEY_STRIDE + st.feat_base
        ko = index[other_id(pair, st)] * _IMAGE_KEY_STRIDE + st.feat_other
        keys.append(np.where(st.feat_base >= 0, kb, np.where(st.feat_other >= 0, ko, -1)))
    allk = np.concatenate(keys) if keys else _NONE
    u, c = np.unique(allk[allk >= 0], return_counts=True)
    out = []
    for k in keys:
        pos = np.clip(np.searchsorted(u, k), 0, max(u.size - 1, 0))
        out.append(np.where((k >= 0) & (u.size > 0), c[pos] if u.size else 0, 0).astype(np.int64))
    return out


def thin(st: PairState, priority: NDArray[np.int64], config: MatchConfig) -> PairState:
    """At most ``max_matches``: anchors matched in more pairs first, then the score, spread."""
    keep = select_spread(st.pa, THIN_PRIORITY_WEIGHT * priority + st.score, config.max_matches, st.base.image.shape)
    return st.take(keep)
