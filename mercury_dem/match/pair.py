"""Matching one pair: the chain that joins features, pre-transform, guidance, outliers and refinement.

Per pair (``match_pair``):

1. image checks (blank, saturated, textureless, wrong size) -> failed with the reason;
2. a-priori pair geometry (:func:`pair_geometry`): no overlap -> failed; incidence or
   sun-azimuth difference beyond the limits -> skipped with the reason;
3. the match image warped into the reference geometry (pre-transform), detected and described;
4. descriptor matching, guided by the a-priori prediction, then the outlier chain
   (ratio both ways, symmetry, fundamental RANSAC, homography RANSAC);
5. when that leaves fewer than ``min_matches``: the NCC fallback at reference corners
   within the guidance window, then the same geometric checks (:mod:`mercury_dem.match.fallback`);
6. at most ``max_matches`` kept (best, spread), refined to sub-pixel, mapped back to
   original match pixels.

The tile (:mod:`mercury_dem.match.tile`) runs steps 1-5 of every pair (:func:`match_in_pair_frame`),
propagates anchors between them (:mod:`mercury_dem.match.propagation`) and then maps each back
(:func:`finish_pair`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.fallback import ncc_fallback, ncc_template_size
from mercury_dem.match.features import detect_and_describe, stretch_to_8bit
from mercury_dem.match.flow import Flow, dense_flow, flow_at
from mercury_dem.match.guided import candidate_mask, knn_both_ways
from mercury_dem.match.outliers import (
    fundamental_inliers,
    homography_inliers,
    local_consistency,
    ratio_test,
    select_spread,
    symmetric_pairs,
)
from mercury_dem.match.prepare import (
    DETECTION_BORDER_PX,
    ImageFeatures,
    pattern_on,
    prepare_image,
    refine_pattern,
    with_features,
)
from mercury_dem.match.pretransform import (
    ImageGeometry,
    PairGeometry,
    apply_homography,
    pair_geometry,
    warp_to_reference,
)
from mercury_dem.match.refine import refine_matches_adaptive
from mercury_dem.match.result import Matches, PairFailure, PairReport, PairResult, failed_result


@dataclass(frozen=True)
class WarpedPartner:
    """The pair's warped image in the base geometry, as the chain left it (kept for the propagation).

    Attributes
    ----------
    image : ndarray (lines, samples) float32, the partner resampled into the base geometry
    valid : ndarray (lines, samples) bool, where it has data
    pattern : ndarray float32 or None, ``image`` locally normalized (:func:`refine_pattern`);
        None when the refinement works on the DN
    flow : Flow or None, the pair's dense flow when its measures were read from it
    """

    image: NDArray[np.float32]
    valid: NDArray[np.bool_]
    pattern: NDArray[np.float32] | None
    flow: Flow | None


@dataclass(frozen=True)
class PairState:
    """A pair after the chain, before mapping back: matches in the pair frame (base pixels).

    ``base`` is the image kept in its own geometry (the match image when ``swap``), ``other``
    the warped one; ``feat_base``/``feat_other`` are keypoint ids in each image's own features
    (-1 where the position is not a keypoint); ``pa`` base pixels, ``pb`` warped-frame pixels.
    Frozen: each step (propagation, thinning, mapping back) returns a new state
    (:meth:`take`, :func:`dataclasses.replace`); the tile keeps the current one per pair.
    """

    swap: bool
    pg: PairGeometry
    base: ImageFeatures
    other: ImageFeatures
    other_geom: ImageGeometry
    feat_base: NDArray[np.int64]
    feat_other: NDArray[np.int64]
    pa: NDArray[np.float64]
    pb: NDArray[np.float64]
    score: NDArray[np.float64]
    other_exact: NDArray[np.float64] | None = None  # (K, 2) original pixels where feat_other >= 0
    kind: NDArray[np.int8] | None = None  # (K,) PairResult.propagated; None = all 0
    warped: WarpedPartner | None = None  # kept for the propagation (None: it warps again)
    flow_used: bool = False  # the pair's measures were read from the dense flow

    def take(self, keep: NDArray[Any]) -> PairState:
        """The state with only the matches ``keep`` (a boolean mask or indices); ``kind`` becomes an array."""
        kind = self.kind if self.kind is not None else np.zeros(self.pa.shape[0], np.int8)
        return replace(
            self, feat_base=self.feat_base[keep], feat_other=self.feat_other[keep], pa=self.pa[keep], pb=self.pb[keep],
            score=self.score[keep], kind=kind[keep],
            other_exact=self.other_exact[keep] if self.other_exact is not None else None,
        )


def match_pair(
    ref_image: NDArray[Any] | None,
    match_image: NDArray[Any] | None,
    ref_geom: ImageGeometry,
    match_geom: ImageGeometry,
    config: MatchConfig,
    ref_features: ImageFeatures | None = None,
    match_features: ImageFeatures | None = None,
    ref_id: str = "ref",
    match_id: str = "match",
    *,
    pointing_sigma_urad: float,
) -> PairResult:
    """Match one pair (see the module docstring for the steps).

    Parameters
    ----------
    ref_image, match_image : ndarray (lines, samples), 12-bit DN (uint16) or float; None = unreadable
    ref_geom, match_geom : a-priori geometry of each image
    config : MatchConfig
    ref_features, match_features : :func:`prepare_image` results to reuse (computed when None)
    ref_id, match_id : names used in the report
    pointing_sigma_urad : how wrong the a-priori pointing may be, per axis and image (1 sigma, µrad): it sizes
        the guidance window (:func:`configured_pair_geometry`)

    Returns
    -------
    PairResult; expected failures are recorded in ``result.report`` (status, reason), never raised.
    """
    t0 = time.perf_counter()
    rep = PairReport(ref_id=ref_id, match_id=match_id)
    try:
        out = match_in_pair_frame(ref_image, match_image, ref_geom, match_geom, config, ref_features, match_features, rep,
                                  pointing_sigma_urad=pointing_sigma_urad)
        return out if isinstance(out, PairResult) else finish_pair(out, config, rep)
    finally:
        rep.seconds = time.perf_counter() - t0


def match_in_pair_frame(
    ref_image: NDArray[Any] | None,
    match_image: NDArray[Any] | None,
    ref_geom: ImageGeometry,
    match_geom: ImageGeometry,
    config: MatchConfig,
    rf: ImageFeatures | None,
    mf: ImageFeatures | None,
    rep: PairReport,
    keep_warped: bool = False,
    *,
    pointing_sigma_urad: float,
) -> PairResult | PairState:
    """The pair up to its matches in the pair frame (a :class:`PairState`), or a failed/skipped result.
    ``pointing_sigma_urad``: as :func:`match_pair`.

    ``keep_warped``: the state keeps the warped partner and its valid mask (for propagation).
    """
    cv2.setRNGSeed(config.ransac_seed)
    cam_r, cam_m = ref_geom.camera, match_geom.camera
    if rf is None:
        rf = prepare_image(ref_image, (cam_r.lines, cam_r.samples), config, describe=False)
    if not rf.quality.ok:
        return failed_result(rep, PairFailure.IMAGE_UNUSABLE, f"reference image {rep.ref_id}: {rf.quality.reason}")
    if mf is None:
        mf = prepare_image(match_image, (cam_m.lines, cam_m.samples), config, describe=False)
    if not mf.quality.ok:
        return failed_result(rep, PairFailure.IMAGE_UNUSABLE, f"match image {rep.match_id}: {mf.quality.reason}")

    pg = configured_pair_geometry(ref_geom, match_geom, config, pointing_sigma_urad)
    if isinstance(pg, str):
        return failed_result(rep, PairFailure.NO_PRETRANSFORM, pg)
    record_geometry(rep, pg)
    if rep.incidence_difference_deg > config.max_incidence_difference_deg:
        return failed_result(rep, PairFailure.INCIDENCE, f"incidence differs by {rep.incidence_difference_deg:.0f} deg "
                     f"> max_incidence_difference_deg {config.max_incidence_difference_deg:g}")
    if pg.sun_azimuth_difference_deg > config.max_sun_azimuth_difference_deg:
        return failed_result(rep, PairFailure.SUN_AZIMUTH, f"sun azimuth differs by {pg.sun_azimuth_difference_deg:.0f} deg "
                     f"> max_sun_azimuth_difference_deg {config.max_sun_azimuth_difference_deg:g}")
    if pg.convergence_deg > config.max_convergence_deg:
        return failed_result(rep, PairFailure.CONVERGENCE, f"views converge by {pg.convergence_deg:.0f} deg "
                     f"> max_convergence_deg {config.max_convergence_deg:g}")

    # The coarser image stays in its own geometry; the finer one is warped (low-passed) onto it.
    swap = config.warp_finer and pg.match_px_per_ref_px < 1.0 / config.swap_scale_ratio
    if swap:
        pg2 = configured_pair_geometry(match_geom, ref_geom, config, pointing_sigma_urad)
        if isinstance(pg2, str):
            return failed_result(rep, PairFailure.NO_PRETRANSFORM, pg2)
        pg, base, other, base_geom, other_geom = pg2, mf, rf, match_geom, ref_geom
        rep.own_geometry = "match"
    else:
        base, other, base_geom, other_geom = rf, mf, ref_geom, match_geom
        rep.own_geometry = "ref"
    if not base.described:
        base = with_features(base, config)
    if base.pattern is None and pattern_on(config):  # features prepared elsewhere without it
        base = replace(base, pattern=refine_pattern(base.image, config))
    m, partner = _match_core(base, other, base_geom, other_geom, pg, config, rep)
    return PairState(swap, pg, base, other, other_geom, m.feat, np.full(m.feat.size, -1, np.int64), m.pa, m.pb, m.score,
                     warped=partner if keep_warped else None, flow_used=partner.flow is not None)


def finish_pair(st: PairState, config: MatchConfig, rep: PairReport) -> PairResult:
    """Map a pair's matches back to original pixels; fewer than ``min_matches`` -> failed."""
    pm = apply_homography(st.pg.homography, st.pb)
    if st.other_exact is not None:  # anchors of the warped image: their keypoint exactly
        exact = st.feat_other >= 0
        pm[exact] = st.other_exact[exact]
    inside = st.other_geom.camera.in_image(pm) & np.isfinite(pm).all(axis=1)
    st = st.take(inside)
    pm = pm[inside]
    n = int(st.pa.shape[0])
    if n < config.min_matches:
        return failed_result(rep, PairFailure.TOO_FEW_MATCHES, f"too few matches: {n} < min_matches {config.min_matches} "
                     f"(chain {rep.n_ratio}->{rep.n_symmetry}->{rep.n_fundamental}->{rep.n_homography}, "
                     f"ncc {rep.n_ncc}->{rep.n_ncc_homography})")
    rep.status, rep.n_matches = "matched", n
    pa, fa, fo, sc = st.pa.copy(), st.feat_base.astype(np.int64), st.feat_other.astype(np.int64), st.score.astype(np.float64)
    if st.swap:
        return PairResult(pm, pa, fo, fa, sc, rep, st.kind)
    return PairResult(pa, pm, fa, fo, sc, rep, st.kind)


def configured_pair_geometry(a: ImageGeometry, b: ImageGeometry, config: MatchConfig,
                             pointing_sigma_urad: float) -> PairGeometry | str:
    """:func:`pair_geometry` with the configuration's grid, position sigma and guidance and the a-priori
    pointing sigma ``pointing_sigma_urad`` (µrad per axis).
    """
    return pair_geometry(
        a, b, config.pretransform_grid, pointing_sigma_urad,
        config.guidance_sigmas, config.guidance_margin_px, config.position_sigma_m,
    )


def _match_core(
    base: ImageFeatures,
    other: ImageFeatures,
    base_geom: ImageGeometry,
    other_geom: ImageGeometry,
    pg: PairGeometry,
    config: MatchConfig,
    rep: PairReport,
) -> tuple[Matches, WarpedPartner]:
    """Match ``other`` onto ``base`` (kept in its own geometry): the matches (base keypoint ids, base pixels,
    warped-frame pixels and scores) and the warped partner.
    """
    fa = base.features
    h = pg.homography
    warped, valid = warp_to_reference(other.image, h, base.image.shape, pg.match_px_per_ref_px, config.psf_sigma_px)
    wpat = refine_pattern(warped, config)
    if config.pretransform:
        w8 = stretch_to_8bit(warped, other.quality.low, other.quality.high)
        det_mask = cast(NDArray[np.uint8],
                        cv2.erode(valid.view(np.uint8), np.ones((2 * DETECTION_BORDER_PX + 1,) * 2, np.uint8)))
        fb = detect_and_describe(w8, config, det_mask)
        predicted = fa.points
        window = pg.guidance_px
    else:
        if not other.described:
            other = with_features(other, config)
        fb = other.features
        predicted = apply_homography(h, fa.points)
        window = pg.guidance_px * pg.match_px_per_ref_px
    rep.n_keypoints_ref, rep.n_keypoints_match = fa.size, fb.size

    # Descriptor route.
    mask, mask_t = candidate_mask(predicted, fb.points, window, transposed=True) if config.guided else (None, None)
    ab, ba = knn_both_ways(fa, fb, mask, config.matcher, mask_t)
    ok_ab, ok_ba = ratio_test(ab, config.ratio), ratio_test(ba, config.ratio)
    rep.n_ratio = int(ok_ab.sum())
    ia, ib = symmetric_pairs(ab, ba, ok_ab, ok_ba)
    rep.n_symmetry = int(ia.size)
    m = Matches(ia, fa.points[ia], fb.points[ib], -ab.d1[ia])  # score: the descriptor quality until refined
    inl = fundamental_inliers(m.pa, m.pb, config.fundamental_tolerance_px, config.fundamental_confidence)
    rep.n_fundamental = int(inl.sum())
    m = m.take(inl)
    inl, _ = homography_inliers(m.pa, m.pb, config.homography_tolerance_px)
    rep.n_homography = int(inl.sum())
    m = m.take(inl)
    if not config.pretransform:  # into the warped frame, where refinement works
        m = m._replace(pb=apply_homography(cast(NDArray[np.float64], np.linalg.inv(h)), m.pb))
    rep.route = "guided" if config.guided else "descriptor"

    # Keep the best, spread; refine; local consistency.
    m = m.take(select_spread(m.pa, m.score, config.max_matches, base.image.shape))
    rep.n_kept = int(m.feat.size)
    m = _refine(base, warped, valid, wpat, m, config.refine_window_px | 1, config)
    rep.n_refined = int(m.feat.size)
    m = _local(m, config)
    rep.n_local = int(m.feat.size)

    # Area-based fallback, when the descriptors leave too few refined matches: NCC at corners
    # of the base within the guidance window, the same geometric checks, refined with (at most)
    # the template that found them (on a small warped patch a larger window leaves the data or
    # takes in shading the template did not see), added to the descriptor matches.
    if m.feat.size < config.min_matches and config.ncc_fallback:
        tpl = ncc_template_size(valid, config.ncc_template_px | 1, pg.guidance_px)
        c = ncc_fallback(base, warped, valid, pg, tpl, config, rep, m.pa, m.pb)
        n_kept = c.feat.size
        c = _refine(base, warped, valid, wpat, c, tpl, config)
        u = _local(Matches.concat(m, c), config)
        if u.feat.size > m.feat.size:
            rep.route = "ncc"
            rep.n_kept += n_kept
            rep.n_refined += int(c.feat.size)
            m = u
            rep.n_local = int(m.feat.size)
    flow = None
    if flow_on(config, pg) and m.feat.size and wpat is not None and base.pattern is not None:
        flow = pair_flow(base.pattern, wpat, valid, m.pa, m.pb, config)
        if flow is not None:
            q, usable, agree = read_flow(flow, m.pa, m.pb, config)
            if agree[usable].mean() < FLOW_MIN_AGREEMENT if usable.any() else True:
                flow = None  # the flow contradicts most refined measures: it failed, not they
            else:
                move, drop = usable & agree, usable & ~agree
                m = m._replace(pb=np.where(move[:, None], q, m.pb), score=np.asarray(m.score)).take(~drop)
                rep.n_flow, rep.n_flow_dropped = int(move.sum()), int(drop.sum())
    m = Matches(m.feat.astype(np.int64), m.pa, m.pb, np.asarray(m.score, np.float64))
    return m, WarpedPartner(warped, valid, wpat, flow)


#: Least share of a pair's measures (where the flow is usable) whose flow position agrees with the
#: refined one for the flow to be used: below it the flow is taken to have failed (e.g. a thin
#: strip where DIS lost the pointing offset) and the refined positions are kept.
FLOW_MIN_AGREEMENT = 0.5


def pair_flow(base_pattern: NDArray[np.float32], warped_pattern: NDArray[np.float32], valid: NDArray[np.bool_],
               pa: NDArray[np.float64], pb: NDArray[np.float64], config: MatchConfig) -> Flow | None:
    """The pair's dense flow, started from its measures' median displacement."""
    return dense_flow(base_pattern, warped_pattern, valid, variational_iterations=config.flow_variational_iterations,
                      initial=np.median(pb - pa, axis=0))


def read_flow(flow: Flow, base_pts: NDArray[np.float64], partner_pts: NDArray[np.float64], config: MatchConfig,
               ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Partner positions read from the flow at ``base_pts``, where the flow is usable, and where they
    agree with ``partner_pts`` within ``flow_tolerance_px``.
    """
    d, usable = flow_at(flow, base_pts)
    q = base_pts + d
    return q, usable, np.linalg.norm(q - partner_pts, axis=1) <= config.flow_tolerance_px


def flow_on(config: MatchConfig, pg: PairGeometry) -> bool:
    """Whether the pair's measures are read from the dense flow (see ``MatchConfig.flow_refine``)."""
    return bool(config.flow_refine and pattern_on(config) and not pg.convergence_deg < config.flow_min_convergence_deg)


def _refine(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_],
            warped_pattern: NDArray[np.float32] | None, m: Matches, window: int, config: MatchConfig) -> Matches:
    """Sub-pixel refinement (when ``config.refine``): the accepted measures, scored by their NCC."""
    if not config.refine or m.feat.size == 0:
        return m._replace(score=np.asarray(m.score, np.float64))
    r = refine_matches_adaptive(
        base.image, warped, valid, m.pa, m.pb, window, config.refine_search_px,
        config.refine_iterations, config.refine_min_score, config.refine_max_shift_px,
        ref_pattern=base.pattern if warped_pattern is not None else None, warped_pattern=warped_pattern,
    )
    return Matches(m.feat[r.ok], m.pa[r.ok], r.points[r.ok], r.score[r.ok])


def _local(m: Matches, config: MatchConfig) -> Matches:
    """The matches that agree with their neighbours (``local_tolerance_px``; all when it is 0)."""
    if config.local_tolerance_px <= 0:
        return m
    return m.take(local_consistency(m.pa, m.pb, config.local_tolerance_px, config.local_neighbours))


def record_geometry(rep: PairReport, pg: PairGeometry) -> None:
    """Put what the a-priori geometry says about the pair (overlap, scale, illumination, convergence) in its report."""
    rep.overlap_apriori = pg.overlap
    rep.scale_ratio = pg.scale_ratio
    rep.match_px_per_ref_px = pg.match_px_per_ref_px
    rep.incidence_ref_deg = pg.incidence_ref_deg
    rep.incidence_match_deg = pg.incidence_match_deg
    rep.incidence_difference_deg = abs(pg.incidence_ref_deg - pg.incidence_match_deg)
    rep.sun_azimuth_difference_deg = pg.sun_azimuth_difference_deg
    rep.homography_fit_rms_px = pg.fit_rms_px
    rep.guidance_px = pg.guidance_px
    rep.convergence_deg = pg.convergence_deg

