"""Which controlled images make stereo pairs for dense matching, and why the others do not.

A dense pair needs enough parallax for height (the parallax/height ratio), images of similar pixel
scale (a matcher compares windows of the same ground size), similar illumination (the same shading and
shadows) and overlap. The literature's bands (docs/design/dense.md, the anchors in
``shared/references/dense-stereo-anchors.md``): parallax/height 0.1--1, best 0.4--0.6; pixel-scale
ratio <= 2.5; similar incidence and sun azimuth.

The geometry of each candidate comes from the matching stage's own a-priori pair geometry
(:func:`mercury_dem.match.pretransform.pair_geometry`: overlap, scale ratio, incidences, sun-azimuth
difference, convergence, all at the overlap centre), evaluated here with the *adjusted* cameras; this
module adds only the parallax/height ratio there and the selection rule. Pure functions: geometry in,
a table of candidates out (one :class:`StereoCandidate` per pair, selected or with the reason it was
not), which the dense stage writes into the run's report.

Parallax/height ratio
---------------------
For a ground point ``g`` with local vertical ``n`` seen along unit vectors ``v_i`` (ground -> camera
``i``), raising the point by ``dh`` moves its image on the datum by ``-dh * p_i`` with
``p_i = (v_i - (v_i . n) n) / (v_i . n)`` (the horizontal part of the ray over its vertical part,
``tan(emission) * azimuth``). The parallax between the two images is ``dh * |p_1 - p_2|``:
``|p_1 - p_2|`` is the parallax/height ratio (the base/height ratio of a vertical pair; ``2 tan(c/2)``
for a pair symmetric about nadir converging by ``c``). It, not the convergence angle, sets the
height precision: ``sigma_h = sigma_parallax / ratio``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from enum import StrEnum
from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.pose import pixel_scale_m
from mercury_dem.match.pretransform import ImageGeometry, PairGeometry, pair_geometry

#: Status of a candidate in :class:`StereoCandidate`.
SELECTED, REJECTED = "selected", "rejected"


class PairRejection(StrEnum):
    """Why a stereo candidate was rejected, set where the test fails (the keys of the report's
    ``dense.pairs.rejected_by_reason``; nothing parses the human-readable ``reason``).
    """

    PARALLAX_HEIGHT = "parallax_height"
    SCALE_RATIO = "scale_ratio"
    INCIDENCE = "incidence"  # the incidence difference, or the larger incidence over its limit
    SUN_AZIMUTH = "sun_azimuth"
    OVERLAP = "overlap"
    CAP = "cap"  # per image (here) or per tile (:func:`mercury_dem.dense.rules.cap_per_tile`)
    TILE_SUBSET = "tile_subset"
    NO_GEOMETRY = "no_geometry"  # an image without an adjusted pose
    PAIR_GEOMETRY = "pair_geometry"  # the pair's geometry could not be computed (no overlap, degenerate)


@dataclass(frozen=True)
class StereoPairCriteria:
    """The stereo-pair rule (the dense stage's configuration section will carry these fields).

    Attributes
    ----------
    min_parallax_height, max_parallax_height : accepted band of the parallax/height ratio (literature: 0.1--1)
    best_parallax_height : (low, high) of the preferred band (0.4--0.6); ranking prefers pairs inside it
    max_scale_ratio : largest ground-pixel-scale ratio, coarser over finer (<= 2.5)
    max_incidence_difference_deg : largest difference of the two images' solar incidence at the overlap centre
    max_sun_azimuth_difference_deg : largest difference of the local sun azimuths (0..180)
    max_incidence_deg : largest incidence of either image (beyond it most of the overlap is in shadow)
    min_overlap : smallest share of the first image's datum grid seen by the second (0..1)
    max_pairs_per_image : cap on selected pairs an image takes part in (the best-ranked first)
    """

    min_parallax_height: float = 0.1
    max_parallax_height: float = 1.0
    best_parallax_height: tuple[float, float] = (0.4, 0.6)
    max_scale_ratio: float = 2.5
    max_incidence_difference_deg: float = 20.0
    max_sun_azimuth_difference_deg: float = 30.0
    max_incidence_deg: float = 80.0
    min_overlap: float = 0.2
    max_pairs_per_image: int = 4

    def __post_init__(self) -> None:
        lo, hi = self.best_parallax_height
        if not (0 < self.min_parallax_height <= lo <= hi <= self.max_parallax_height):
            raise ValueError("stereo pair criteria: need 0 < min_parallax_height <= best low <= best high "
                             f"<= max_parallax_height, got {self.min_parallax_height}, {self.best_parallax_height}, "
                             f"{self.max_parallax_height}")
        if self.max_scale_ratio < 1 or not 0 <= self.min_overlap <= 1 or self.max_pairs_per_image < 1:
            raise ValueError("stereo pair criteria: max_scale_ratio >= 1, 0 <= min_overlap <= 1 and "
                             "max_pairs_per_image >= 1 are required")


@dataclass(frozen=True)
class StereoCandidate:
    """One candidate pair: its geometry, its status and why (a row of the report's table).

    Attributes
    ----------
    left, right : image ids (``left`` is the reference of the pair geometry)
    status : ``"selected"`` or ``"rejected"``
    reason : empty when selected; else what failed, with the values and the limit
    rank : 1-based rank among the selected pairs (best first), 0 when rejected
    score : ranking score (higher is better), NaN when the geometry could not be computed
    parallax_height : parallax/height ratio at the overlap centre
    convergence_deg : angle between the two rays at the overlap centre
    scale_ratio : ground-pixel-scale ratio (>= 1) at the overlap centre
    pixel_scale_left_m, pixel_scale_right_m : slant range x IFOV at the overlap centre, metres
    incidence_left_deg, incidence_right_deg : solar incidence at the overlap centre (sphere normal)
    sun_azimuth_difference_deg : difference of the local sun azimuths, 0..180
    overlap : share of the left image's datum grid inside the right image
    rejections : the :class:`PairRejection` values of every test it failed (empty when selected)
    """

    left: str
    right: str
    status: str
    reason: str
    rank: int
    score: float
    parallax_height: float
    convergence_deg: float
    scale_ratio: float
    pixel_scale_left_m: float
    pixel_scale_right_m: float
    incidence_left_deg: float
    incidence_right_deg: float
    sun_azimuth_difference_deg: float
    overlap: float
    rejections: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The row as JSON-ready values (NaN stays NaN; the report writer maps it to null)."""
        return asdict(self)


def parallax_height_ratio(ground: NDArray[np.float64], camera_a: NDArray[np.float64],
                          camera_b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Parallax/height ratio ``|p_a - p_b|`` (module docstring) of ground points seen from two positions.

    Parameters
    ----------
    ground : ndarray of shape (..., 3), body-fixed metres (the local vertical is the sphere normal)
    camera_a, camera_b : ndarray of shape (3,) or (..., 3), camera positions, body-fixed metres

    Returns
    -------
    ndarray of shape (...,): dimensionless; NaN where a camera is at or below the horizon
    """
    g = np.asarray(ground, dtype=np.float64)
    n = g / np.linalg.norm(g, axis=-1, keepdims=True)

    def horizontal_over_vertical(c: NDArray[np.float64]) -> NDArray[np.float64]:
        v = np.asarray(c, dtype=np.float64) - g
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        up = np.sum(v * n, axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(up > 1e-9, (v - up * n) / up, np.nan)

    return np.asarray(np.linalg.norm(horizontal_over_vertical(camera_a) - horizontal_over_vertical(camera_b),
                                     axis=-1), np.float64)


def _nan_row(left: str, right: str, reason: str, kind: PairRejection) -> StereoCandidate:
    nan = float("nan")
    return StereoCandidate(left, right, REJECTED, reason, 0, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan,
                           (kind.value,))


def _geometry_row(left: str, right: str, a: ImageGeometry, b: ImageGeometry,
                  pg: PairGeometry) -> StereoCandidate:
    g = pg.overlap_centre_m
    assert g is not None  # pair_geometry always sets it
    ph = float(parallax_height_ratio(g, a.position, b.position))
    return StereoCandidate(
        left, right, SELECTED, "", 0, float("nan"), ph, float(pg.convergence_deg), float(pg.scale_ratio),
        float(pixel_scale_m(a.camera, np.linalg.norm(g - a.position))),
        float(pixel_scale_m(b.camera, np.linalg.norm(g - b.position))),
        float(pg.incidence_ref_deg), float(pg.incidence_match_deg), float(pg.sun_azimuth_difference_deg),
        float(pg.overlap),
    )


def failed_tests(c: StereoCandidate, criteria: StereoPairCriteria) -> list[tuple[PairRejection, str]]:
    """Every test of the rule a candidate's geometry fails: (its kind, what failed with the value and the limit)."""
    k = criteria
    why: list[tuple[PairRejection, str]] = []
    if not (k.min_parallax_height <= c.parallax_height <= k.max_parallax_height):
        why.append((PairRejection.PARALLAX_HEIGHT, f"parallax/height {c.parallax_height:.3f} outside "
                    f"[{k.min_parallax_height:g}, {k.max_parallax_height:g}]"))
    if not c.scale_ratio <= k.max_scale_ratio:
        why.append((PairRejection.SCALE_RATIO, f"pixel-scale ratio {c.scale_ratio:.2f} > {k.max_scale_ratio:g}"))
    d_inc = abs(c.incidence_left_deg - c.incidence_right_deg)
    if not d_inc <= k.max_incidence_difference_deg:
        why.append((PairRejection.INCIDENCE,
                    f"incidence difference {d_inc:.1f} deg > {k.max_incidence_difference_deg:g}"))
    if not c.sun_azimuth_difference_deg <= k.max_sun_azimuth_difference_deg:
        why.append((PairRejection.SUN_AZIMUTH, f"sun-azimuth difference {c.sun_azimuth_difference_deg:.1f} deg > "
                    f"{k.max_sun_azimuth_difference_deg:g}"))
    inc = max(c.incidence_left_deg, c.incidence_right_deg)
    if not inc <= k.max_incidence_deg:
        why.append((PairRejection.INCIDENCE, f"incidence {inc:.1f} deg > {k.max_incidence_deg:g}"))
    if not c.overlap >= k.min_overlap:
        why.append((PairRejection.OVERLAP, f"overlap {c.overlap:.2f} < {k.min_overlap:g}"))
    return why


def rejection_reason(c: StereoCandidate, criteria: StereoPairCriteria) -> str:
    """Why a candidate's geometry fails the rule (every failed test, ``; ``-joined), or ``""``."""
    return "; ".join(text for _, text in failed_tests(c, criteria))


def pair_score(c: StereoCandidate, criteria: StereoPairCriteria) -> float:
    """Ranking score of an acceptable pair, in (0, 1]: higher is better.

    The product of four factors, each 1 at its best: the parallax/height ratio (1 inside the best band,
    falling linearly to 0.5 at the accepted band's edges), the overlap, the pixel-scale ratio
    (``1 / scale_ratio``) and the illumination (``cos`` of the incidence difference and of half the
    sun-azimuth difference). A stated heuristic, not a model of the DEM's error.
    """
    lo, hi = criteria.best_parallax_height
    ph = c.parallax_height
    if ph < lo:
        f_ph = 1.0 - 0.5 * (lo - ph) / max(lo - criteria.min_parallax_height, 1e-12)
    elif ph > hi:
        f_ph = 1.0 - 0.5 * (ph - hi) / max(criteria.max_parallax_height - hi, 1e-12)
    else:
        f_ph = 1.0
    f_illum = (np.cos(np.radians(abs(c.incidence_left_deg - c.incidence_right_deg)))
               * np.cos(np.radians(0.5 * c.sun_azimuth_difference_deg)))
    return float(f_ph * c.overlap / c.scale_ratio * f_illum)


def select_stereo_pairs(
    geometry: Mapping[str, ImageGeometry],
    criteria: StereoPairCriteria = StereoPairCriteria(),
    candidates: Sequence[tuple[str, str]] | None = None,
) -> list[StereoCandidate]:
    """Evaluate, filter, rank and cap the stereo pairs of a set of controlled images.

    Parameters
    ----------
    geometry : image id -> its adjusted camera, pose and sun (:class:`ImageGeometry`)
    criteria : the rule
    candidates : pairs to consider (e.g. the overlap graph's edges); every unordered pair of ``geometry``
        (sorted ids) when None

    Returns
    -------
    list of :class:`StereoCandidate`, one per candidate in input order: the selected ones with their
    rank (1 = best), the others with the reason. An acceptable pair loses to the cap when one of its
    images already has ``max_pairs_per_image`` better-ranked pairs; its reason names the image.
    """
    pairs = list(candidates) if candidates is not None else list(combinations(sorted(geometry), 2))
    rows: list[StereoCandidate] = []
    for a, b in pairs:
        if a not in geometry or b not in geometry:
            rows.append(_nan_row(a, b, f"no adjusted geometry for {a if a not in geometry else b}",
                                 PairRejection.NO_GEOMETRY))
            continue
        pg = pair_geometry(geometry[a], geometry[b])
        if isinstance(pg, str):
            rows.append(_nan_row(a, b, pg, PairRejection.PAIR_GEOMETRY))
            continue
        row = _geometry_row(a, b, geometry[a], geometry[b], pg)
        why = failed_tests(row, criteria)
        if why:
            rows.append(replace(row, status=REJECTED, reason="; ".join(t for _, t in why),
                                rejections=tuple(k.value for k, _ in why)))
        else:
            rows.append(replace(row, score=pair_score(row, criteria)))
    order = sorted((i for i, r in enumerate(rows) if r.status == SELECTED), key=lambda i: (-rows[i].score, i))
    used: dict[str, int] = {}
    rank = 0
    for i in order:
        r = rows[i]
        full = [x for x in (r.left, r.right) if used.get(x, 0) >= criteria.max_pairs_per_image]
        if full:
            rows[i] = replace(r, status=REJECTED, reason=f"cap: image {full[0]} is already in "
                                                          f"{criteria.max_pairs_per_image} better-ranked pairs",
                              rejections=(PairRejection.CAP.value,))
            continue
        rank += 1
        rows[i] = replace(r, rank=rank)
        used[r.left] = used.get(r.left, 0) + 1
        used[r.right] = used.get(r.right, 0) + 1
    return rows


def candidate_table(rows: Sequence[StereoCandidate]) -> dict[str, NDArray[Any]]:
    """The candidates as columns (name -> array of len(rows)), e.g. for a Parquet/Zarr table; ``rejections``
    as one string per row, its kinds ``;``-joined.
    """
    fields = list(StereoCandidate.__dataclass_fields__)
    return {f: np.array([";".join(r.rejections) if f == "rejections" else getattr(r, f) for r in rows])
            for f in fields}
