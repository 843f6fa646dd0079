"""What matching returns: one pair's report row and matches, a tile's matches as columns.

Plain records (no computation but the tile's concatenation, :func:`tile_matches`); every
field of :class:`PairReport` is described in ``docs/design/match.md``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

#: Routes a pair can take (``PairReport.route``).
ROUTES = ("guided", "descriptor", "ncc", "none")
#: Statuses of a pair (``PairReport.status``).
STATUSES = ("matched", "failed", "skipped")


class PairFailure(StrEnum):
    """Why a pair gave no matches (``PairReport.failure``), set where the failure is found; the run counts pairs
    by it (a tile's ``pair_failures``) and nothing reads the human-readable ``reason`` to sort them.
    """

    IMAGE_MISSING = "image_missing"  # an image of the pair has no pixels or no geometry in the tile
    IMAGE_UNUSABLE = "image_unusable"  # blank, saturated, textureless, wrong size (ImageQuality)
    NO_PRETRANSFORM = "no_pretransform"  # the a-priori geometry gives no overlap or no homography
    INCIDENCE = "incidence"  # skipped: incidence angles differ by more than max_incidence_difference_deg
    SUN_AZIMUTH = "sun_azimuth"  # skipped: sun azimuths differ by more than max_sun_azimuth_difference_deg
    CONVERGENCE = "convergence"  # skipped: views converge by more than max_convergence_deg
    REDUNDANT = "redundant"  # skipped: a narrower route of matched pairs joins its images (match.selection)
    TOO_FEW_MATCHES = "too_few_matches"  # the chain kept fewer than min_matches

    @property
    def status(self) -> str:
        """The pair's ``status``: ``skipped`` (not tried, by a configured rule) or ``failed``."""
        return "skipped" if self in _SKIPPED else "failed"


_SKIPPED = frozenset({PairFailure.INCIDENCE, PairFailure.SUN_AZIMUTH, PairFailure.CONVERGENCE, PairFailure.REDUNDANT})


@dataclass
class PairReport:
    """One row of the tile's pair report (see ``docs/design/match.md`` for every field)."""

    ref_id: str = ""
    match_id: str = ""
    status: str = "failed"
    route: str = "none"
    reason: str = ""
    failure: str = ""  # a PairFailure's value ("" when matched): what kind of failure ``reason`` describes
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


class Matches(NamedTuple):
    """A pair's matches in the pair frame while the pair chain works on them (:mod:`mercury_dem.match.pair`),
    one row each.

    Attributes
    ----------
    feat : (N,) int64, the base image's keypoint id (-1: a corner the NCC fallback added)
    pa : (N, 2) base pixels
    pb : (N, 2) the partner's pixels in the warped (pair) frame
    score : (N,) the descriptor quality before refinement, the peak NCC after it
    """

    feat: NDArray[np.int64]
    pa: NDArray[np.float64]
    pb: NDArray[np.float64]
    score: NDArray[np.float64]

    def take(self, keep: NDArray[Any]) -> Matches:
        """The rows ``keep`` selects (a boolean mask or indices)."""
        return Matches(self.feat[keep], self.pa[keep], self.pb[keep], self.score[keep])

    @staticmethod
    def concat(first: Matches, second: Matches) -> Matches:
        """The rows of ``first`` then those of ``second``."""
        return Matches(*(np.concatenate([a, b]) for a, b in zip(first, second)))


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


def failed_result(report: PairReport, kind: PairFailure, reason: str) -> PairResult:
    """A pair without matches: ``report`` gets the kind's status (``failed`` or ``skipped``), the kind and the reason."""
    report.status, report.failure, report.reason = kind.status, kind.value, reason
    z = np.zeros((0, 2))
    return PairResult(z, z.copy(), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), report)


def tile_matches(
    ids: tuple[str, ...], index: Mapping[str, int], pairs: Sequence[tuple[str, str]], results: Sequence[PairResult]
) -> TileMatches:
    """The pairs' matches as one :class:`TileMatches`, grouped by pair in ``pairs`` order.

    ``ids`` are the tile's image ids, ``index`` their positions (a pair's image missing from it
    gets -1), ``results`` one per pair.
    """
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


def failure_counts(reports: Sequence[PairReport]) -> tuple[dict[str, int], int]:
    """How many pairs failed, by :class:`PairFailure` value (in order of first occurrence), and how many were
    skipped as redundant (not tried: a narrower route joins their images; counted apart from the failures).
    """
    failures: dict[str, int] = {}
    redundant = 0
    for r in reports:
        if r.status == "matched":
            continue
        if r.failure == PairFailure.REDUNDANT:
            redundant += 1
        else:
            failures[r.failure] = failures.get(r.failure, 0) + 1
    return failures, redundant
