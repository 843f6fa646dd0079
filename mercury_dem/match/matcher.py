"""Matching one pair and one tile: the chain that joins features, pre-transform, guidance, outliers and refinement.

Per pair (``match_pair``):

1. image checks (blank, saturated, textureless, wrong size) -> failed with the reason;
2. a-priori pair geometry (:func:`pair_geometry`): no overlap -> failed; incidence or
   sun-azimuth difference beyond the limits -> skipped with the reason;
3. the match image warped into the reference geometry (pre-transform), detected and described;
4. descriptor matching, guided by the a-priori prediction, then the outlier chain
   (ratio both ways, symmetry, fundamental RANSAC, homography RANSAC);
5. when that leaves fewer than ``min_matches``: the NCC fallback at reference corners
   within the guidance window, then the same geometric checks;
6. at most ``max_matches`` kept (best, spread), refined to sub-pixel, mapped back to
   original match pixels.

Per tile (``match_tile``): every image's features in its own geometry are computed once
(and reused by all pairs where it is the reference); pairs run on a thread pool
(OpenCV releases the GIL) with OpenCV's own threads set to 1 meanwhile.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.features import (
    Features,
    ImageQuality,
    detect_and_describe,
    image_quality,
    spread_best,
    stretch_to_8bit,
)
from mercury_dem.match.flow import Flow, base_position, dense_flow, flow_at
from mercury_dem.match.guided import candidate_mask, knn_both_ways, ncc_matches
from mercury_dem.match.outliers import (
    fundamental_inliers,
    homography_inliers,
    local_consistency,
    ratio_test,
    select_spread,
    symmetric_pairs,
)
from mercury_dem.match.pretransform import (
    ImageGeometry,
    PairGeometry,
    apply_homography,
    pair_geometry,
    warp_to_reference,
)
from mercury_dem.match.refine import local_normalize, refine_matches_adaptive
from mercury_dem.match.tracks import propagate_pair

#: Routes a pair can take (``PairReport.route``).
ROUTES = ("guided", "descriptor", "ncc", "none")
#: Statuses of a pair (``PairReport.status``).
STATUSES = ("matched", "failed", "skipped")

_DETECTION_BORDER_PX = 4  # keypoints this close to the edge of the warped data are not described


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
    return cv2.erode(valid.view(np.uint8), np.ones((2 * _DETECTION_BORDER_PX + 1,) * 2, np.uint8))


@dataclass
class PairReport:
    """One row of the tile's pair report (see ``docs/design/match.md`` for every field)."""

    ref_id: str = ""
    match_id: str = ""
    status: str = "failed"
    route: str = "none"
    reason: str = ""
    own_geometry: str = ""
    overlap_apriori: float = float("nan")
    scale_ratio: float = float("nan")
    match_px_per_ref_px: float = float("nan")
    incidence_ref_deg: float = float("nan")
    incidence_match_deg: float = float("nan")
    incidence_difference_deg: float = float("nan")
    sun_azimuth_difference_deg: float = float("nan")
    homography_fit_rms_px: float = float("nan")
    guidance_px: float = float("nan")
    convergence_deg: float = float("nan")
    n_keypoints_ref: int = 0
    n_keypoints_match: int = 0
    n_ratio: int = 0
    n_symmetry: int = 0
    n_fundamental: int = 0
    n_homography: int = 0
    n_ncc: int = 0
    n_ncc_fundamental: int = 0
    n_ncc_homography: int = 0
    n_kept: int = 0
    n_refined: int = 0
    n_local: int = 0
    n_flow: int = 0
    n_flow_dropped: int = 0
    n_propagated: int = 0
    n_matches: int = 0
    seconds: float = 0.0

    def as_row(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PairResult:
    """Matches of one pair in original pixels (0-based sample, line).

    Attributes
    ----------
    points_ref, points_match : ndarray (K, 2)
    feature_ref, feature_match : ndarray (K,) int64, keypoint id in that image's own features,
        -1 on the side that was warped (the finer image)
    score : ndarray (K,), NCC of the refined match (or the matching score when not refined)
    report : PairReport
    propagated : ndarray (K,) int8, 0 from the pair's own chain, 1 an anchor of the image kept in
        its own geometry propagated into the pair, 2 one of the warped image (``match_tile`` only);
        None = all 0
    """

    points_ref: NDArray[np.float64]
    points_match: NDArray[np.float64]
    feature_ref: NDArray[np.int64]
    feature_match: NDArray[np.int64]
    score: NDArray[np.float64]
    report: PairReport
    propagated: NDArray[np.int8] | None = None


@dataclass
class _PairState:
    """A pair after the chain, before mapping back: matches in the pair frame (base pixels).

    ``base`` is the image kept in its own geometry (the match image when ``swap``), ``other``
    the warped one; ``feat_base``/``feat_other`` are keypoint ids in each image's own features
    (-1 where the position is not a keypoint); ``pa`` base pixels, ``pb`` warped-frame pixels.
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
    warped: Any = None  # (warped partner, valid mask, its pattern or None, Flow or None) kept for the propagation
    flow_used: bool = False  # the pair's measures were read from the dense flow

    def take(self, keep: NDArray[Any]) -> None:
        if self.kind is None:
            self.kind = np.zeros(self.pa.shape[0], np.int8)
        for name in ("feat_base", "feat_other", "pa", "pb", "score", "kind"):
            setattr(self, name, getattr(self, name)[keep])
        if self.other_exact is not None:
            self.other_exact = self.other_exact[keep]


@dataclass(frozen=True)
class TileMatches:
    """All matches of a tile as aligned columns (the PairMatches table of the control network).

    Attributes
    ----------
    image_ids : tuple of str; ``image_a``/``image_b`` index into it
    image_a, image_b : ndarray (M,) int64, reference and match image of each match
    sample_a, line_a, sample_b, line_b : ndarray (M,) float64, 0-based pixels in the original images
    feature_a, feature_b : ndarray (M,) int64, keypoint id in that image's own features (stable across
        all pairs of the tile), -1 on the side that was warped (the finer image of the pair)
    score : ndarray (M,) float64, NCC of the refined match
    pair : ndarray (M,) int64, row of the pair report the match came from
    propagated : ndarray (M,) int8, see :class:`PairResult` (0 = from the pair's own chain)
    """

    image_ids: tuple[str, ...]
    image_a: NDArray[np.int64]
    image_b: NDArray[np.int64]
    sample_a: NDArray[np.float64]
    line_a: NDArray[np.float64]
    sample_b: NDArray[np.float64]
    line_b: NDArray[np.float64]
    feature_a: NDArray[np.int64]
    feature_b: NDArray[np.int64]
    score: NDArray[np.float64]
    pair: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    propagated: NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, np.int8))

    def __len__(self) -> int:
        return int(self.image_a.shape[0])

    def columns(self) -> dict[str, NDArray[Any]]:
        """The PairMatches arrays by name (image_a ... feature_b, score, pair)."""
        return {k: v for k, v in asdict(self).items() if k != "image_ids"}


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
    pattern = _pattern(f32, config)
    if not describe:
        return ImageFeatures(q, f32, empty, described=False, pattern=pattern, detect_mask=mask)
    feats = detect_and_describe(stretch_to_8bit(f32, q.low, q.high), config, mask)
    return ImageFeatures(q, f32, feats, pattern=pattern, detect_mask=mask)


def _pattern(image: NDArray[np.float32], config: MatchConfig) -> NDArray[np.float32] | None:
    """The image the refinement finds positions on (locally normalized), or None (on the DN)."""
    if not _pattern_on(config):
        return None
    return local_normalize(image, config.refine_normalize_sigma_px)


def _pattern_on(config: MatchConfig) -> bool:
    return bool(config.refine and config.refine_normalize_sigma_px > 0)


def _describe(im: ImageFeatures, config: MatchConfig) -> ImageFeatures:
    feats = detect_and_describe(stretch_to_8bit(im.image, im.quality.low, im.quality.high), config, im.detect_mask)
    return ImageFeatures(im.quality, im.image, feats, pattern=im.pattern, detect_mask=im.detect_mask)


def _fail(report: PairReport, reason: str, status: str = "failed") -> PairResult:
    report.status, report.reason = status, reason
    z = np.zeros((0, 2))
    return PairResult(z, z.copy(), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), report)


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
) -> PairResult:
    """Match one pair (see the module docstring for the steps).

    Parameters
    ----------
    ref_image, match_image : ndarray (lines, samples), 12-bit DN (uint16) or float; None = unreadable
    ref_geom, match_geom : a-priori geometry of each image
    config : MatchConfig
    ref_features, match_features : :func:`prepare_image` results to reuse (computed when None)
    ref_id, match_id : names used in the report

    Returns
    -------
    PairResult; expected failures are recorded in ``result.report`` (status, reason), never raised.
    """
    t0 = time.perf_counter()
    rep = PairReport(ref_id=ref_id, match_id=match_id)
    try:
        out = _match_pair(ref_image, match_image, ref_geom, match_geom, config, ref_features, match_features, rep)
        return out if isinstance(out, PairResult) else _finish(out, config, rep)
    finally:
        rep.seconds = time.perf_counter() - t0


def _match_pair(
    ref_image: NDArray[Any] | None,
    match_image: NDArray[Any] | None,
    ref_geom: ImageGeometry,
    match_geom: ImageGeometry,
    config: MatchConfig,
    rf: ImageFeatures | None,
    mf: ImageFeatures | None,
    rep: PairReport,
    keep_warped: bool = False,
) -> PairResult | _PairState:
    """The pair up to its matches in the pair frame (a :class:`_PairState`), or a failed/skipped result.

    ``keep_warped``: the state keeps the warped partner and its valid mask (for propagation).
    """
    cv2.setRNGSeed(config.ransac_seed)
    cam_r, cam_m = ref_geom.camera, match_geom.camera
    if rf is None:
        rf = prepare_image(ref_image, (cam_r.lines, cam_r.samples), config, describe=False)
    if not rf.quality.ok:
        return _fail(rep, f"reference image {rep.ref_id}: {rf.quality.reason}")
    if mf is None:
        mf = prepare_image(match_image, (cam_m.lines, cam_m.samples), config, describe=False)
    if not mf.quality.ok:
        return _fail(rep, f"match image {rep.match_id}: {mf.quality.reason}")

    pg = _pair_geometry(ref_geom, match_geom, config)
    if isinstance(pg, str):
        return _fail(rep, pg)
    _record_geometry(rep, pg)
    if rep.incidence_difference_deg > config.max_incidence_difference_deg:
        return _fail(rep, f"incidence differs by {rep.incidence_difference_deg:.0f} deg "
                     f"> max_incidence_difference_deg {config.max_incidence_difference_deg:g}", "skipped")
    if pg.sun_azimuth_difference_deg > config.max_sun_azimuth_difference_deg:
        return _fail(rep, f"sun azimuth differs by {pg.sun_azimuth_difference_deg:.0f} deg "
                     f"> max_sun_azimuth_difference_deg {config.max_sun_azimuth_difference_deg:g}", "skipped")
    if pg.convergence_deg > config.max_convergence_deg:
        return _fail(rep, f"views converge by {pg.convergence_deg:.0f} deg "
                     f"> max_convergence_deg {config.max_convergence_deg:g}", "skipped")

    # The coarser image stays in its own geometry; the finer one is warped (low-passed) onto it.
    swap = config.warp_finer and pg.match_px_per_ref_px < 1.0 / config.swap_scale_ratio
    if swap:
        pg2 = _pair_geometry(match_geom, ref_geom, config)
        if isinstance(pg2, str):
            return _fail(rep, pg2)
        pg, base, other, base_geom, other_geom = pg2, mf, rf, match_geom, ref_geom
        rep.own_geometry = "match"
    else:
        base, other, base_geom, other_geom = rf, mf, ref_geom, match_geom
        rep.own_geometry = "ref"
    if not base.described:
        base = _describe(base, config)
    if base.pattern is None and _pattern_on(config):  # features prepared elsewhere without it
        base = replace(base, pattern=_pattern(base.image, config))
    feat, pa, pb, score, warped = _match_core(base, other, base_geom, other_geom, pg, config, rep)
    return _PairState(swap, pg, base, other, other_geom, feat, np.full(feat.size, -1, np.int64), pa, pb, score,
                      warped=warped if keep_warped else None, flow_used=warped[3] is not None)


def _finish(st: _PairState, config: MatchConfig, rep: PairReport) -> PairResult:
    """Map a pair's matches back to original pixels; fewer than ``min_matches`` -> failed."""
    pm = apply_homography(st.pg.homography, st.pb)
    if st.other_exact is not None:  # anchors of the warped image: their keypoint exactly
        exact = st.feat_other >= 0
        pm[exact] = st.other_exact[exact]
    inside = st.other_geom.camera.in_image(pm) & np.isfinite(pm).all(axis=1)
    st.take(inside)
    pm = pm[inside]
    n = int(st.pa.shape[0])
    if n < config.min_matches:
        return _fail(rep, f"too few matches: {n} < min_matches {config.min_matches} "
                     f"(chain {rep.n_ratio}->{rep.n_symmetry}->{rep.n_fundamental}->{rep.n_homography}, "
                     f"ncc {rep.n_ncc}->{rep.n_ncc_homography})")
    rep.status, rep.n_matches = "matched", n
    pa, fa, fo, sc = st.pa.copy(), st.feat_base.astype(np.int64), st.feat_other.astype(np.int64), st.score.astype(np.float64)
    if st.swap:
        return PairResult(pm, pa, fo, fa, sc, rep, st.kind)
    return PairResult(pa, pm, fa, fo, sc, rep, st.kind)


def _pair_geometry(a: ImageGeometry, b: ImageGeometry, config: MatchConfig) -> PairGeometry | str:
    return pair_geometry(
        a, b, config.pretransform_grid, config.pointing_sigma_urad * 1e-6,
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
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], Any]:
    """Match ``other`` onto ``base`` (kept in its own geometry): base keypoint ids, base pixels,
    warped-frame pixels and scores of the matches, and (warped image, valid mask).
    """
    fa = base.features
    h = pg.homography
    warped, valid = warp_to_reference(other.image, h, base.image.shape, pg.match_px_per_ref_px, config.psf_sigma_px)
    wpat = _pattern(warped, config)
    if config.pretransform:
        w8 = stretch_to_8bit(warped, other.quality.low, other.quality.high)
        det_mask = cv2.erode(valid.view(np.uint8), np.ones((2 * _DETECTION_BORDER_PX + 1,) * 2, np.uint8))
        fb = detect_and_describe(w8, config, det_mask)
        predicted = fa.points
        window = pg.guidance_px
    else:
        if not other.described:
            other = _describe(other, config)
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
    pa, pb = fa.points[ia], fb.points[ib]
    quality = -ab.d1[ia]
    inl = fundamental_inliers(pa, pb, config.fundamental_tolerance_px, config.fundamental_confidence)
    rep.n_fundamental = int(inl.sum())
    feat, pa, pb, quality = ia[inl], pa[inl], pb[inl], quality[inl]
    inl, _ = homography_inliers(pa, pb, config.homography_tolerance_px)
    rep.n_homography = int(inl.sum())
    feat, pa, pb, quality = feat[inl], pa[inl], pb[inl], quality[inl]
    if not config.pretransform:  # into the warped frame, where refinement works
        pb = apply_homography(np.linalg.inv(h), pb)
    rep.route = "guided" if config.guided else "descriptor"

    # Keep the best, spread; refine; local consistency.
    keep = select_spread(pa, quality, config.max_matches, base.image.shape)
    feat, pa, pb, quality = feat[keep], pa[keep], pb[keep], quality[keep]
    rep.n_kept = int(feat.size)
    feat, pa, pb, score = _refine(base, warped, valid, wpat, feat, pa, pb, quality, config.refine_window_px | 1, config)
    rep.n_refined = int(feat.size)
    feat, pa, pb, score = _local(feat, pa, pb, score, config)
    rep.n_local = int(feat.size)

    # Area-based fallback, when the descriptors leave too few refined matches: NCC at corners
    # of the base within the guidance window, the same geometric checks, refined with (at most)
    # the template that found them (on a small warped patch a larger window leaves the data or
    # takes in shading the template did not see), added to the descriptor matches.
    if feat.size < config.min_matches and config.ncc_fallback:
        tpl = ncc_template_size(valid, config.ncc_template_px | 1, pg.guidance_px)
        c_feat, c_pa, c_pb, c_sc = _ncc_fallback(base, warped, valid, pg, tpl, config, rep, pa, pb)
        new = _away(pa, c_pa, _NCC_DEDUP_PX)
        c_feat, c_pa, c_pb, c_sc = c_feat[new], c_pa[new], c_pb[new], c_sc[new]
        n_kept = c_feat.size
        c_feat, c_pa, c_pb, c_sc = _refine(base, warped, valid, wpat, c_feat, c_pa, c_pb, c_sc, tpl, config)
        u_feat = np.concatenate([feat, c_feat])
        u_pa, u_pb, u_sc = np.concatenate([pa, c_pa]), np.concatenate([pb, c_pb]), np.concatenate([score, c_sc])
        u_feat, u_pa, u_pb, u_sc = _local(u_feat, u_pa, u_pb, u_sc, config)
        if u_feat.size > feat.size:
            rep.route = "ncc"
            rep.n_kept += n_kept
            rep.n_refined += int(c_feat.size)
            feat, pa, pb, score = u_feat, u_pa, u_pb, u_sc
            rep.n_local = int(feat.size)
    flow = None
    if _flow_on(config, pg) and feat.size and wpat is not None and base.pattern is not None:
        flow = _pair_flow(base.pattern, wpat, valid, pa, pb, config)
        if flow is not None:
            q, usable, agree = _read_flow(flow, pa, pb, config)
            if agree[usable].mean() < FLOW_MIN_AGREEMENT if usable.any() else True:
                flow = None  # the flow contradicts most refined measures: it failed, not they
            else:
                move, drop = usable & agree, usable & ~agree
                pb = np.where(move[:, None], q, pb)
                keep = ~drop
                feat, pa, pb, score = feat[keep], pa[keep], pb[keep], np.asarray(score)[keep]
                rep.n_flow, rep.n_flow_dropped = int(move.sum()), int(drop.sum())
    return feat.astype(np.int64), pa, pb, np.asarray(score, np.float64), (warped, valid, wpat, flow)


#: Least share of a pair's measures (where the flow is usable) whose flow position agrees with the
#: refined one for the flow to be used: below it the flow is taken to have failed (e.g. a thin
#: strip where DIS lost the pointing offset) and the refined positions are kept.
FLOW_MIN_AGREEMENT = 0.5


def _pair_flow(base_pattern: NDArray[np.float32], warped_pattern: NDArray[np.float32], valid: NDArray[np.bool_],
               pa: NDArray[np.float64], pb: NDArray[np.float64], config: MatchConfig) -> Flow | None:
    """The pair's dense flow, started from its measures' median displacement."""
    return dense_flow(base_pattern, warped_pattern, valid, variational_iterations=config.flow_variational_iterations,
                      initial=np.median(pb - pa, axis=0))


def _read_flow(flow: Flow, base_pts: NDArray[np.float64], partner_pts: NDArray[np.float64], config: MatchConfig,
               ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Partner positions read from the flow at ``base_pts``, where the flow is usable, and where they
    agree with ``partner_pts`` within ``flow_tolerance_px``.
    """
    d, usable = flow_at(flow, base_pts)
    q = base_pts + d
    return q, usable, np.linalg.norm(q - partner_pts, axis=1) <= config.flow_tolerance_px


def _flow_on(config: MatchConfig, pg: PairGeometry) -> bool:
    """Whether the pair's measures are read from the dense flow (see ``MatchConfig.flow_refine``)."""
    return bool(config.flow_refine and _pattern_on(config) and not pg.convergence_deg < config.flow_min_convergence_deg)


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
    pts = cv2.goodFeaturesToTrack(i8, int(n) + have.shape[0], _EXTRA_CORNER_QUALITY, _EXTRA_CORNER_SPACING_PX,
                                  mask=on.view(np.uint8))
    pts = np.zeros((0, 2)) if pts is None else pts.reshape(-1, 2).astype(np.float64)
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
    from scipy.spatial import cKDTree

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


def _grid_seeds(i8: NDArray[np.uint8], on: NDArray[np.bool_]) -> NDArray[np.float64]:
    """The strongest pixel (min eigenvalue, Shi-Tomasi) of each grid cell of ``on`` above the quality level."""
    eig = np.where(on, cv2.cornerMinEigenVal(i8, 3), 0.0)
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
    dist = cv2.distanceTransform(valid.view(np.uint8), cv2.DIST_C, 3)
    side = 2.0 * float(dist.max())  # the largest square fully on valid data
    want = 0.5 * (side - 2.0 * float(search_px))  # the template fits twice beside the search window
    fit = min(want, side / 4.0) if want < t else float(t)
    return int(max(NCC_MIN_TEMPLATE_PX, min(t, int(fit) | 1)))


#: NCC fallback candidates this close (base pixels) to a descriptor match are not added.
_NCC_DEDUP_PX = 2.0


def _away(have: NDArray[np.float64], query: NDArray[np.float64], dist: float) -> NDArray[np.bool_]:
    if have.shape[0] == 0 or query.shape[0] == 0:
        return np.ones(query.shape[0], bool)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(have).query(query, k=1)
    return np.asarray(d) > dist


def _refine(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_],
            warped_pattern: NDArray[np.float32] | None, feat: NDArray[np.int64],
            pa: NDArray[np.float64], pb: NDArray[np.float64], quality: NDArray[np.float64], window: int,
            config: MatchConfig) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Sub-pixel refinement (when ``config.refine``): the accepted measures and their NCC."""
    if not config.refine or feat.size == 0:
        return feat, pa, pb, np.asarray(quality, np.float64)
    r = refine_matches_adaptive(
        base.image, warped, valid, pa, pb, window, config.refine_search_px,
        config.refine_iterations, config.refine_min_score, config.refine_max_shift_px,
        ref_pattern=base.pattern if warped_pattern is not None else None, warped_pattern=warped_pattern,
    )
    return feat[r.ok], pa[r.ok], r.points[r.ok], r.score[r.ok]


def _local(feat: NDArray[np.int64], pa: NDArray[np.float64], pb: NDArray[np.float64], score: NDArray[np.float64],
           config: MatchConfig) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    if config.local_tolerance_px <= 0:
        return feat, pa, pb, score
    ok = local_consistency(pa, pb, config.local_tolerance_px, config.local_neighbours)
    return feat[ok], pa[ok], pb[ok], score[ok]


def _ncc_fallback(base: ImageFeatures, warped: NDArray[np.float32], valid: NDArray[np.bool_], pg: PairGeometry,
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
    c_feat, c_pa, pts_w, sc, counts = best
    rep.n_ncc, rep.n_ncc_fundamental, rep.n_ncc_homography = counts
    return c_feat, c_pa, pts_w, sc


#: Matches needed to predict the NCC fallback's search position from their median displacement.
_NCC_PREDICT_MIN = 5


def _ncc_predicted_radius(d: NDArray[np.float64], offset: NDArray[np.float64]) -> float:
    """Search half-width around a predicted position: 3 px plus 3 robust sigmas of the displacements (at
    least 0.5 px: the first pass's integer peaks can all agree while relief parallax still varies).
    """
    spread = 1.4826 * float(np.median(np.linalg.norm(d - offset, axis=1)))
    return 3.0 + 3.0 * max(spread, 0.5)


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


def _record_geometry(rep: PairReport, pg: PairGeometry) -> None:
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


class _OpenCVThreads:
    """Context manager: OpenCV's own thread count set to ``n`` inside, restored after."""

    def __init__(self, n: int) -> None:
        self.n, self.old = n, cv2.getNumThreads()

    def __enter__(self) -> None:
        cv2.setNumThreads(self.n)

    def __exit__(self, *exc: object) -> None:
        cv2.setNumThreads(self.old)


def match_tile(
    images: Mapping[str, NDArray[Any] | None],
    geometry: Mapping[str, ImageGeometry],
    pairs: Sequence[tuple[str, str]],
    config: MatchConfig,
    tracks: bool = True,
    radiometry: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[TileMatches, list[PairReport]]:
    """Match every pair of a tile.

    Parameters
    ----------
    images : image id -> ndarray (lines, samples) of 12-bit DN (None = unreadable)
    geometry : image id -> a-priori :class:`ImageGeometry` (camera, position, rotation, sun)
    pairs : (ref_id, match_id) pairs, each matched once with the first as reference
    config : MatchConfig (``threads`` pairs run at once)
    tracks : after every pair is matched, propagate each image's matched keypoints (anchors)
        to all its other pairs and prefer multi-pair anchors when thinning to ``max_matches``
        (:mod:`mercury_dem.match.tracks`), so the network gets points of 3+ rays; needs
        ``config.refine``
    radiometry : image id -> (saturation, dn_scale) of its pixels (:func:`image_quality`); missing = 12-bit DN

    Returns
    -------
    matches : :class:`TileMatches`, indices into ``tuple(images)``, grouped by pair in ``pairs`` order
    reports : one :class:`PairReport` per pair, in ``pairs`` order
    """
    ids = tuple(images)
    index = {k: i for i, k in enumerate(ids)}
    needed: list[str] = []
    for a, b in pairs:
        for x in (a, b):
            if x in index and x in geometry and x not in needed:
                needed.append(x)

    def prep(image_id: str) -> ImageFeatures:
        cam = geometry[image_id].camera
        return prepare_image(images[image_id], (cam.lines, cam.samples), config,
                             radiometry=(radiometry or {}).get(image_id))

    def run(k: int) -> tuple[PairReport, PairResult | _PairState]:
        a, b = pairs[k]
        rep = PairReport(ref_id=a, match_id=b)
        missing = [x for x in (a, b) if x not in index or x not in geometry]
        if missing:
            return rep, _fail(rep, f"image {missing[0]} has no {'pixels' if missing[0] not in index else 'geometry'} in this tile")
        t0 = time.perf_counter()
        out = _match_pair(images[a], images[b], geometry[a], geometry[b], config, prepared[a], prepared[b], rep,
                          keep_warped=keep_warped)
        rep.seconds = time.perf_counter() - t0
        return rep, out

    propagate = tracks and config.refine
    # the warped partners are kept for the propagation when they all fit in the budget, else re-warped
    largest = max((geometry[x].camera.lines * geometry[x].camera.samples for x in needed), default=0)
    per_px = 5 + (4 if _pattern_on(config) else 0) + (9 if config.flow_refine else 0)  # (+ pattern, flow)
    keep_warped = propagate and len(pairs) * largest * per_px <= _KEEP_WARPED_BYTES
    anchors: dict[str, tuple[NDArray[np.int64], NDArray[np.int64]]] = {}

    def extend(k: int) -> None:
        rep, st = phase1[k]
        if isinstance(st, _PairState):
            t0 = time.perf_counter()
            _propagate(st, anchors.get(_base_id(pairs[k], st), _NO_ANCHORS),
                       anchors.get(_other_id(pairs[k], st), _NO_ANCHORS), config, rep)
            rep.seconds += time.perf_counter() - t0

    def finish(k: int) -> PairResult:
        rep, st = phase1[k]
        if isinstance(st, PairResult):
            return st
        t0 = time.perf_counter()
        st.warped = None
        if propagate and st.pa.shape[0] > config.max_matches:
            _thin(st, priority[k], config, rep)
        out = _finish(st, config, rep)
        rep.seconds += time.perf_counter() - t0
        return out

    threads = max(1, config.threads)
    # ``threads`` is the whole tile's budget: OpenCV's own threads are set to 1 in either case (at
    # threads == 1 its default pool of one thread per core cost 4-15 % more CPU for ~nothing on a
    # shared machine: docs/benchmarks/match.md, session 11)
    with _OpenCVThreads(1), ThreadPoolExecutor(max_workers=threads) as pool:
        pmap: Any = pool.map if threads > 1 else map  # threads == 1: all in the calling thread
        prepared = dict(zip(needed, pmap(prep, needed)))
        phase1 = list(pmap(run, range(len(pairs))))
        if propagate:
            anchors = _anchors(pairs, [st for _, st in phase1])
            list(pmap(extend, range(len(pairs))))
        priority = _priorities(pairs, [st for _, st in phase1], index) if propagate else []
        results = list(pmap(finish, range(len(pairs))))
    return _collect(ids, index, pairs, results), [r.report for r in results]


_NONE = np.zeros(0, np.int64)
#: Memory the warped partners (float32 + bool mask + float32 pattern) of a tile may take between phases 1 and 2.
_KEEP_WARPED_BYTES = 256 * 2**20
_NO_ANCHORS = (_NONE, _NONE)
#: Lowest NCC of a propagated match: measured on the tiny mission, propagated matches with a
#: refined NCC of 0.5-0.7 had a median true error of 0.6-0.9 px (0.2-0.4 px above 0.8).
PROPAGATE_MIN_SCORE = 0.7
#: Integer search radius of propagation: the start is predicted from the pair's own matches.
PROPAGATE_SEARCH_PX = 2
#: Smallest refinement window of a propagated anchor near the edge of a small overlap (as phase 1's).
PROPAGATE_MIN_WINDOW_PX = 11
#: Pairs with fewer matches after the chain neither give anchors nor receive them.
_PROPAGATE_MIN_MATCHES = 8


def _base_id(pair: tuple[str, str], st: _PairState) -> str:
    return pair[1] if st.swap else pair[0]


def _other_id(pair: tuple[str, str], st: _PairState) -> str:
    return pair[0] if st.swap else pair[1]


def _anchors(pairs: Sequence[tuple[str, str]], states: Sequence[Any]) -> dict[str, tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Image id -> (keypoint ids, sorted; in how many pairs each survived the chain) for the keypoints
    that survived in at least one pair where the image is the base.
    """
    found: dict[str, list[NDArray[np.int64]]] = {}
    for pair, st in zip(pairs, states):
        if isinstance(st, _PairState) and st.pa.shape[0] >= _PROPAGATE_MIN_MATCHES:
            found.setdefault(_base_id(pair, st), []).append(st.feat_base[st.feat_base >= 0])
    out = {}
    for k, v in found.items():
        ids, counts = np.unique(np.concatenate(v), return_counts=True)
        out[k] = (ids, counts.astype(np.int64))
    return out


def _propagate(st: _PairState, base_anchors: tuple[NDArray[np.int64], NDArray[np.int64]],
               other_anchors: tuple[NDArray[np.int64], NDArray[np.int64]], config: MatchConfig, rep: PairReport) -> None:
    """Add the base's and the partner's anchors this pair does not have yet (see :mod:`.tracks`).

    Each direction refines at most the pair's free room below ``max_matches`` plus
    ``propagate_extra`` x ``max_matches`` (default an eighth; for a full pair: 50 anchors that may replace single-pair matches in the
    thinning), those matched in more pairs first, spread: the cost stays bounded by about one
    more refinement pass (a full pair: a quarter of one).
    """
    if st.pa.shape[0] < _PROPAGATE_MIN_MATCHES or not st.base.described or not st.other.described:
        return
    new = ~np.isin(base_anchors[0], st.feat_base)
    fwd, fwd_count = base_anchors[0][new], base_anchors[1][new]
    rev, rev_count = other_anchors
    cap = max(config.max_matches - st.pa.shape[0], 0) + int(round(config.max_matches * config.propagate_extra))
    if (fwd.size == 0 and rev.size == 0) or cap <= 0:  # (propagate_pair reads 0 as "no cap")
        return
    h = st.pg.homography
    rev_orig = st.other.features.points[rev]
    rev_pair = apply_homography(np.linalg.inv(h), rev_orig) if rev.size else np.zeros((0, 2))
    flow: Flow | None = None
    if st.warped is not None:
        warped, valid, wpat, flow = st.warped
        st.warped = None
    else:
        warped, valid = warp_to_reference(st.other.image, h, st.base.image.shape, st.pg.match_px_per_ref_px,
                                          config.psf_sigma_px)
        wpat = _pattern(warped, config)
        if st.flow_used and wpat is not None and st.base.pattern is not None:
            flow = _pair_flow(st.base.pattern, wpat, valid, st.pa, st.pb, config)
    bpat = st.base.pattern if wpat is not None else None
    prop = propagate_pair(
        st.base.image, warped, valid, st.pa, st.pb, st.base.features.points[fwd], rev_pair,
        config.refine_window_px | 1, min(config.refine_search_px, PROPAGATE_SEARCH_PX), config.refine_iterations,
        max(config.refine_min_score, PROPAGATE_MIN_SCORE), config.local_tolerance_px if config.local_tolerance_px > 0 else 1.0,
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
        return
    if st.other_exact is None:
        st.other_exact = np.full((st.pa.shape[0], 2), np.nan)
    st.feat_base = np.concatenate([st.feat_base, fwd[prop.forward], np.full(nr, -1, np.int64)])
    st.feat_other = np.concatenate([st.feat_other, np.full(nf, -1, np.int64), rev[prop.reverse]])
    st.pa = np.concatenate([st.pa, st.base.features.points[fwd[prop.forward]], prop.reverse_points])
    st.pb = np.concatenate([st.pb, prop.forward_points, rev_pair[prop.reverse]])
    st.score = np.concatenate([st.score, prop.forward_score, prop.reverse_score])
    st.other_exact = np.concatenate([st.other_exact, np.full((nf, 2), np.nan), rev_orig[prop.reverse]])
    kind = st.kind if st.kind is not None else np.zeros(st.pa.shape[0] - nf - nr, np.int8)
    st.kind = np.concatenate([kind, np.ones(nf, np.int8), np.full(nr, 2, np.int8)])
    rep.n_propagated = nf + nr


def _propagated_on_flow(prop: Any, flow: Flow, fwd_pts: NDArray[np.float64], rev_pts: NDArray[np.float64],
                        config: MatchConfig, rep: PairReport) -> Any:
    """Propagated matches read from the pair's flow as phase 1's are: the partner position of a
    forward anchor (base side fixed) at ``base + flow(base)``, the base position of a reverse one
    (partner side fixed) where ``base + flow(base)`` reaches it; those the flow contradicts by more
    than ``flow_tolerance_px`` dropped, those where it is not usable kept as refined.
    """
    qf, uf, af = _read_flow(flow, fwd_pts[prop.forward], prop.forward_points, config)
    qr, ur = base_position(flow, rev_pts[prop.reverse], prop.reverse_points)
    ar = np.linalg.norm(qr - prop.reverse_points, axis=1) <= config.flow_tolerance_px
    kf, kr = ~(uf & ~af), ~(ur & ~ar)
    rep.n_flow += int((uf & af).sum() + (ur & ar).sum())
    rep.n_flow_dropped += int((~kf).sum() + (~kr).sum())
    fp = np.where((uf & af)[:, None], qf, prop.forward_points)
    rp = np.where((ur & ar)[:, None], qr, prop.reverse_points)
    return type(prop)(prop.forward[kf], fp[kf], prop.forward_score[kf], prop.reverse[kr], rp[kr], prop.reverse_score[kr])


def _priorities(pairs: Sequence[tuple[str, str]], states: Sequence[Any], index: Mapping[str, int]) -> list[NDArray[np.int64]]:
    """Per pair, for every match: in how many pairs of the tile its anchor (image, keypoint) is matched."""
    keys: list[NDArray[np.int64]] = []
    big = 1 << 32
    for pair, st in zip(pairs, states):
        if not isinstance(st, _PairState):
            keys.append(_NONE)
            continue
        kb = index[_base_id(pair, st)] * big + st.feat_base
        ko = index[_other_id(pair, st)] * big + st.feat_other
        keys.append(np.where(st.feat_base >= 0, kb, np.where(st.feat_other >= 0, ko, -1)))
    allk = np.concatenate(keys) if keys else _NONE
    u, c = np.unique(allk[allk >= 0], return_counts=True)
    out = []
    for k in keys:
        pos = np.clip(np.searchsorted(u, k), 0, max(u.size - 1, 0))
        out.append(np.where((k >= 0) & (u.size > 0), c[pos] if u.size else 0, 0).astype(np.int64))
    return out


def _thin(st: _PairState, priority: NDArray[np.int64], config: MatchConfig, rep: PairReport) -> None:
    """At most ``max_matches``: anchors matched in more pairs first, then the score, spread."""
    keep = select_spread(st.pa, 2.0 * priority + st.score, config.max_matches, st.base.image.shape)
    st.take(keep)


def _collect(
    ids: tuple[str, ...], index: Mapping[str, int], pairs: Sequence[tuple[str, str]], results: Sequence[PairResult]
) -> TileMatches:
    counts = np.array([r.feature_ref.size for r in results], dtype=np.int64)

    def cat(get: Any, dtype: Any) -> NDArray[Any]:
        parts = [np.asarray(get(r), dtype=dtype) for r in results]
        return np.concatenate(parts) if parts else np.zeros(0, dtype)

    ia = np.array([index.get(a, -1) for a, _ in pairs], np.int64)
    ib = np.array([index.get(b, -1) for _, b in pairs], np.int64)
    pair = np.repeat(np.arange(len(results), dtype=np.int64), counts)
    pr = cat(lambda r: r.points_ref.reshape(-1, 2), np.float64).reshape(-1, 2)
    pm = cat(lambda r: r.points_match.reshape(-1, 2), np.float64).reshape(-1, 2)
    return TileMatches(
        image_ids=ids,
        image_a=ia[pair],
        image_b=ib[pair],
        sample_a=pr[:, 0].copy(),
        line_a=pr[:, 1].copy(),
        sample_b=pm[:, 0].copy(),
        line_b=pm[:, 1].copy(),
        feature_a=cat(lambda r: r.feature_ref, np.int64),
        feature_b=cat(lambda r: r.feature_match, np.int64),
        score=cat(lambda r: r.score, np.float64),
        pair=pair,
        propagated=cat(lambda r: r.propagated if r.propagated is not None else np.zeros(r.score.size), np.int8),
    )


def iter_rows(reports: Sequence[PairReport]) -> Iterator[dict[str, Any]]:
    """Report rows as plain dicts (for a DataFrame or JSON)."""
    for r in reports:
        yield r.as_row()
