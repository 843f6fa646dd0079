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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Any, Iterator, Mapping, Sequence

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
from mercury_dem.match.refine import refine_matches

#: Routes a pair can take (``PairReport.route``).
ROUTES = ("guided", "descriptor", "ncc", "none")
#: Statuses of a pair (``PairReport.status``).
STATUSES = ("matched", "failed", "skipped")

_DETECTION_BORDER_PX = 4  # keypoints this close to the edge of the warped data are not described


@dataclass(frozen=True)
class ImageFeatures:
    """An image prepared once per tile: quality, float DN and features in its own geometry.

    ``described`` is False when the features were not computed (yet).
    """

    quality: ImageQuality
    image: NDArray[np.float32]
    features: Features
    described: bool = True


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
    incidence_ref_deg: float = float("nan")
    incidence_match_deg: float = float("nan")
    incidence_difference_deg: float = float("nan")
    sun_azimuth_difference_deg: float = float("nan")
    homography_fit_rms_px: float = float("nan")
    guidance_px: float = float("nan")
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
    """

    points_ref: NDArray[np.float64]
    points_match: NDArray[np.float64]
    feature_ref: NDArray[np.int64]
    feature_match: NDArray[np.int64]
    score: NDArray[np.float64]
    report: PairReport


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

    def __len__(self) -> int:
        return int(self.image_a.shape[0])

    def columns(self) -> dict[str, NDArray[Any]]:
        """The PairMatches arrays by name (image_a ... feature_b, score, pair)."""
        return {k: v for k, v in asdict(self).items() if k != "image_ids"}


def prepare_image(
    image: NDArray[Any] | None, camera_shape: tuple[int, int], config: MatchConfig, describe: bool = True
) -> ImageFeatures:
    """Quality check, float conversion and (if ``describe``) features in the image's own geometry.

    ``camera_shape`` is (lines, samples) of the image's camera; a different array
    shape (truncated or corrupt image) or ``None`` (unreadable) gives a failed quality.
    """
    empty = Features(np.zeros((0, 2)), np.zeros(0, np.float32), np.zeros((0, 128), np.float32), cv2.NORM_L2)
    if image is None:
        return ImageFeatures(ImageQuality(False, "unreadable", 0, 0, 0), np.zeros((0, 0), np.float32), empty)
    arr = np.asarray(image)
    if arr.shape != tuple(camera_shape):
        reason = f"shape {arr.shape} does not match its camera {tuple(camera_shape)} (truncated or corrupt)"
        return ImageFeatures(ImageQuality(False, reason, 0, 0, 0), np.zeros((0, 0), np.float32), empty)
    q = image_quality(arr, config)
    f32 = np.nan_to_num(arr.astype(np.float32, copy=False))
    if not q.ok or not describe:
        return ImageFeatures(q, f32, empty, described=q.ok and describe)
    feats = detect_and_describe(stretch_to_8bit(f32, q.low, q.high), config)
    return ImageFeatures(q, f32, feats)


def _describe(im: ImageFeatures, config: MatchConfig) -> ImageFeatures:
    feats = detect_and_describe(stretch_to_8bit(im.image, im.quality.low, im.quality.high), config)
    return ImageFeatures(im.quality, im.image, feats)


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
        return _match_pair(ref_image, match_image, ref_geom, match_geom, config, ref_features, match_features, rep)
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
) -> PairResult:
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
    out = _match_core(base, other, base_geom, other_geom, pg, config, rep)
    if isinstance(out, str):
        return _fail(rep, out)
    p_base, p_other, feat, score = out
    rep.status, rep.n_matches = "matched", int(feat.size)
    none = np.full(feat.size, -1, np.int64)
    if swap:
        return PairResult(p_other, p_base, none, feat, score, rep)
    return PairResult(p_base, p_other, feat, none, score, rep)


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
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]] | str:
    """Match ``other`` onto ``base`` (kept in its own geometry); points in original pixels of each."""
    fa = base.features
    h = pg.homography
    warped, valid = warp_to_reference(other.image, h, base.image.shape, pg.match_px_per_ref_px, config.psf_sigma_px)
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
    mask = candidate_mask(predicted, fb.points, window) if config.guided else None
    ab, ba = knn_both_ways(fa, fb, mask, config.matcher)
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

    # Area-based fallback.
    if feat.size < config.min_matches and config.ncc_fallback:
        n_corner = min(config.ncc_max_points, fa.size)
        corners_id = spread_best(fa.points, fa.response, n_corner, base.image.shape, config.keypoint_grid)
        idx, pts_w, sc = ncc_matches(
            base.image, warped, valid, fa.points[corners_id], pg.guidance_px,
            config.ncc_template_px | 1, config.ncc_min_score,
        )
        rep.n_ncc = int(idx.size)
        c_feat, c_pa = corners_id[idx], fa.points[corners_id[idx]]
        inl = fundamental_inliers(c_pa, pts_w, config.fundamental_tolerance_px, config.fundamental_confidence)
        rep.n_ncc_fundamental = int(inl.sum())
        c_feat, c_pa, pts_w, sc = c_feat[inl], c_pa[inl], pts_w[inl], sc[inl]
        inl, _ = homography_inliers(c_pa, pts_w, config.homography_tolerance_px)
        rep.n_ncc_homography = int(inl.sum())
        if inl.sum() > feat.size:
            feat, pa, pb, quality = c_feat[inl], c_pa[inl], pts_w[inl], sc[inl]
            rep.route = "ncc"

    # Keep the best, spread; refine; map back.
    keep = select_spread(pa, quality, config.max_matches, base.image.shape)
    feat, pa, pb, quality = feat[keep], pa[keep], pb[keep], quality[keep]
    rep.n_kept = int(feat.size)
    score = quality
    if config.refine and feat.size:
        r = refine_matches(
            base.image, warped, valid, pa, pb, config.refine_window_px | 1, config.refine_search_px,
            config.refine_iterations, config.refine_min_score, config.refine_max_shift_px,
        )
        feat, pa, pb, score = feat[r.ok], pa[r.ok], r.points[r.ok], r.score[r.ok]
    rep.n_refined = int(feat.size)
    if config.local_tolerance_px > 0:
        ok = local_consistency(pa, pb, config.local_tolerance_px, config.local_neighbours)
        feat, pa, pb, score = feat[ok], pa[ok], pb[ok], score[ok]
    rep.n_local = int(feat.size)
    pm = apply_homography(h, pb)
    inside = other_geom.camera.in_image(pm) & np.isfinite(pm).all(axis=1)
    feat, pa, pm, score = feat[inside], pa[inside], pm[inside], score[inside]
    if feat.size < config.min_matches:
        return (f"too few matches: {feat.size} < min_matches {config.min_matches} "
                f"(chain {rep.n_ratio}->{rep.n_symmetry}->{rep.n_fundamental}->{rep.n_homography}, "
                f"ncc {rep.n_ncc}->{rep.n_ncc_homography})")
    return pa, pm, feat.astype(np.int64), score.astype(np.float64)


def _record_geometry(rep: PairReport, pg: PairGeometry) -> None:
    rep.overlap_apriori = pg.overlap
    rep.scale_ratio = pg.scale_ratio
    rep.incidence_ref_deg = pg.incidence_ref_deg
    rep.incidence_match_deg = pg.incidence_match_deg
    rep.incidence_difference_deg = abs(pg.incidence_ref_deg - pg.incidence_match_deg)
    rep.sun_azimuth_difference_deg = pg.sun_azimuth_difference_deg
    rep.homography_fit_rms_px = pg.fit_rms_px
    rep.guidance_px = pg.guidance_px


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
) -> tuple[TileMatches, list[PairReport]]:
    """Match every pair of a tile.

    Parameters
    ----------
    images : image id -> ndarray (lines, samples) of 12-bit DN (None = unreadable)
    geometry : image id -> a-priori :class:`ImageGeometry` (camera, position, rotation, sun)
    pairs : (ref_id, match_id) pairs, each matched once with the first as reference
    config : MatchConfig (``threads`` pairs run at once)

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
        return prepare_image(images[image_id], (cam.lines, cam.samples), config)

    def run(k: int) -> PairResult:
        a, b = pairs[k]
        missing = [x for x in (a, b) if x not in index or x not in geometry]
        if missing:
            rep = PairReport(ref_id=a, match_id=b)
            return _fail(rep, f"image {missing[0]} has no {'pixels' if missing[0] not in index else 'geometry'} in this tile")
        return match_pair(
            images[a], images[b], geometry[a], geometry[b], config,
            ref_features=prepared[a], match_features=prepared[b], ref_id=a, match_id=b,
        )

    threads = max(1, config.threads)
    if threads == 1:  # in the calling thread, OpenCV's own threads as they are
        prepared = {k: prep(k) for k in needed}
        results = [run(k) for k in range(len(pairs))]
    else:
        with _OpenCVThreads(1), ThreadPoolExecutor(max_workers=threads) as pool:
            prepared = dict(zip(needed, pool.map(prep, needed)))
            results = list(pool.map(run, range(len(pairs))))
    return _collect(ids, index, pairs, results), [r.report for r in results]


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
    )


def iter_rows(reports: Sequence[PairReport]) -> Iterator[dict[str, Any]]:
    """Report rows as plain dicts (for a DataFrame or JSON)."""
    for r in reports:
        yield r.as_row()
