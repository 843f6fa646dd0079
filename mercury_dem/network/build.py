"""Building a control network from pairwise matches.

Every match of two images gives two observations (image, pixel, keypoint id).
Observations of the same keypoint, of the two sides of a match, and (when the
keypoint id is unknown) of the same image within ``tolerance_px``, are one
ground feature: a track (:mod:`mercury_dem.network.tracks`, which also resolves
conflicts). Each track becomes a point with one measure per image, and its
a-priori coordinates come from the a-priori geometry by least-squares
intersection of the measures' rays; points seen by one ray, or by rays that
converge by less than ``min_convergence_deg`` (where the intersection is
dominated by pointing errors), or whose intersection lands absurdly far from
the datum, are placed where their rays meet the datum sphere instead.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix

from mercury_dem.exceptions import NetworkError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays
from mercury_dem.network.model import ControlNetwork, MeasureType, PointType, as_string_array
from mercury_dem.network.tracks import components, form_tracks, near_pairs

_MATCH_FIELDS = ("image_a", "image_b", "sample_a", "line_a", "sample_b", "line_b")


@dataclass(frozen=True)
class PairMatches:
    """Matches between image pairs, one row per match (P rows).

    Attributes
    ----------
    image_a, image_b : (P,) int64 image indices (into the ``image_ids`` of :func:`build_network`)
    sample_a, line_a, sample_b, line_b : (P,) float64 pixels, 0-based
    feature_a, feature_b : (P,) int64 keypoint ids within their image, -1 when unknown
    """

    image_a: NDArray[np.int64]
    image_b: NDArray[np.int64]
    sample_a: NDArray[np.float64]
    line_a: NDArray[np.float64]
    sample_b: NDArray[np.float64]
    line_b: NDArray[np.float64]
    feature_a: NDArray[np.int64] | None = None
    feature_b: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        p = np.shape(self.image_a)[0] if np.ndim(self.image_a) == 1 else -1
        for name in _MATCH_FIELDS + ("feature_a", "feature_b"):
            val = getattr(self, name)
            if val is None:
                val = np.full(max(p, 0), -1, np.int64)
            dtype = np.float64 if name.startswith(("sample", "line")) else np.int64
            arr = np.asarray(val, dtype=dtype)
            if arr.shape != (p,):
                raise NetworkError(f"PairMatches.{name} has shape {arr.shape}, expected ({p},) like image_a")
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.image_a.shape[0])

    @classmethod
    def concatenate(cls, parts: Sequence[PairMatches]) -> PairMatches:
        """All rows of several tables, in order."""
        if not parts:
            z = np.zeros(0)
            return cls(z.astype(np.int64), z.astype(np.int64), z, z, z, z)
        return cls(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in _MATCH_FIELDS + ("feature_a", "feature_b")})


def as_pair_matches(matches: Any) -> PairMatches:
    """A :class:`PairMatches` from one, from any object with its attributes, or from a mapping."""
    if isinstance(matches, PairMatches):
        return matches
    def get(k: str) -> Any:
        return matches.get(k) if isinstance(matches, Mapping) else getattr(matches, k, None)

    cols: dict[str, Any] = {k: get(k) for k in _MATCH_FIELDS + ("feature_a", "feature_b")}
    missing = [k for k in _MATCH_FIELDS if cols[k] is None]
    if missing:
        raise NetworkError(f"matches lack the column(s) {missing}; expected a PairMatches table")
    return PairMatches(**cols)


@dataclass(frozen=True)
class BuildStats:
    """Counts of one :func:`build_network` call (a report records ``asdict``)."""

    n_matches: int
    n_matches_invalid: int
    n_observations: int
    n_links_pruned: int
    n_conflicts: int
    n_conflict_observations: int
    n_short_tracks: int
    n_points: int
    n_measures: int
    n_triangulated: int
    n_on_datum: int
    n_no_ground: int

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


class BuildResult(NamedTuple):
    """A network built from tracks, and the counts of how it was built."""

    network: ControlNetwork
    stats: BuildStats


def _cameras_list(cameras: FramingCamera | Sequence[FramingCamera], k: int) -> Sequence[FramingCamera]:
    if isinstance(cameras, FramingCamera):
        return [cameras] * k
    cams = list(cameras)
    if len(cams) != k:
        raise NetworkError(f"build_network: {len(cams)} cameras for {k} images; give one per image (or one for all)")
    return cams


def triangulate_points(
    measure_point: NDArray[np.int64],
    measure_image: NDArray[np.int64],
    pixels: NDArray[np.float64],
    cameras: FramingCamera | Sequence[FramingCamera],
    positions: ArrayLike,
    rotations: ArrayLike,
    n_points: int,
    min_convergence_deg: float = 1.0,
    max_height_m: float = 50_000.0,
    *,
    datum_radius_m: float,
) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """A-priori point coordinates from measures and poses.

    Least-squares intersection of the measures' rays: minimise the sum of the
    squared distances to the rays, i.e. solve ``sum(I - d d^T) X = sum(I - d d^T) C``
    per point (3 x 3 normal equations assembled with ``bincount``, solved batched).

    Parameters
    ----------
    measure_point, measure_image : (M,) indices
    pixels : (M, 2) sample, line (0-based)
    cameras : one camera per image, or one for all
    positions : (K, 3) body-fixed camera positions, m
    rotations : (K, 3, 3) body -> camera rotations
    n_points : N

    Returns
    -------
    xyz : (N, 3) body-fixed metres (NaN when no ray meets the body)
    method : (N,) int8: 2 intersected, 1 on the datum, 0 none
    """
    positions = np.asarray(positions, np.float64)
    rotations = np.asarray(rotations, np.float64)
    k = positions.shape[0]
    cams = _cameras_list(cameras, k)
    m = measure_point.size
    origins = np.empty((m, 3))
    dirs = np.empty((m, 3))
    order = np.argsort(measure_image, kind="stable")
    bounds = np.searchsorted(measure_image[order], np.arange(k + 1))
    for img in np.flatnonzero(np.diff(bounds)):  # loop over images, vectorized within each
        sel = order[bounds[img] : bounds[img + 1]]
        o, d = pixel_rays(cams[int(img)], positions[img], rotations[img], pixels[sel])
        origins[sel], dirs[sel] = o, d
    n = n_points
    cnt = np.bincount(measure_point, minlength=n).astype(np.float64)
    # normal equations, 6 unique entries of A and 3 of b
    a = np.empty((n, 3, 3))
    b = np.empty((n, 3))
    proj_o = origins - dirs * np.sum(dirs * origins, axis=1, keepdims=True)  # (I - d d^T) o
    for r in range(3):
        b[:, r] = np.bincount(measure_point, proj_o[:, r], minlength=n)
        for c in range(r, 3):
            w = (1.0 if r == c else 0.0) - dirs[:, r] * dirs[:, c]
            a[:, r, c] = a[:, c, r] = np.bincount(measure_point, w, minlength=n)
    # convergence: largest angle between a ray and the point's first ray
    first = np.full(n, -1, np.int64)
    first[measure_point[::-1]] = np.arange(m)[::-1]
    cos = np.sum(dirs * dirs[first[measure_point]], axis=1)
    min_cos = np.ones(n)
    np.minimum.at(min_cos, measure_point, cos)
    converge = np.degrees(np.arccos(np.clip(min_cos, -1.0, 1.0)))
    good = (cnt >= 2) & (converge >= min_convergence_deg)
    xyz = np.full((n, 3), np.nan)
    if good.any():
        xyz[good] = np.linalg.solve(a[good], b[good][..., None])[..., 0]
        r = np.linalg.norm(xyz, axis=1)
        good &= np.abs(r - datum_radius_m) <= max_height_m
    # datum fallback: mean of the rays' datum hits, put back on the datum
    ground, hit = intersect_sphere(origins, dirs, datum_radius_m)
    hits = np.bincount(measure_point[hit], minlength=n).astype(np.float64)
    # float64 explicitly: bincount of an empty selection returns int64
    mean = np.stack(
        [np.bincount(measure_point[hit], ground[hit, j], minlength=n) for j in range(3)], axis=1
    ).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean /= hits[:, None]
        mean *= datum_radius_m / np.linalg.norm(mean, axis=1, keepdims=True)
    fallback = ~good & (hits > 0)
    xyz[~good] = np.nan
    xyz[fallback] = mean[fallback]
    method = np.where(good, 2, np.where(fallback, 1, 0)).astype(np.int8)
    return xyz, method


def _prune_unsupported_links(
    n_nodes: int,
    identity: NDArray[np.int64],
    links: NDArray[np.int64],
    image: NDArray[np.int64],
    sample: NDArray[np.float64],
    line: NDArray[np.float64],
    tolerance_px: float,
) -> tuple[NDArray[np.int64], int]:
    """Remove matches that hold a conflicting track together without support.

    Observations joined by identity edges (same keypoint, same pixel) are one
    feature. A match between features u and v is *supported* when some third
    feature is matched to both (a triangle). A wrong match that fuses two
    ground features typically has no triangle, while the true matches of a
    point seen in three or more images all do. Only tracks with a conflict
    (two features of one image further apart than the tolerance) are touched,
    and only their unsupported matches are removed; what remains of a conflict
    is dropped later by :func:`form_tracks`. Order-independent and vectorized.

    Returns the kept links and how many were removed.
    """
    n_obs = image.size
    if links.size == 0:
        return links, 0
    feat = components(n_nodes, identity)[:n_obs]
    _, feat = np.unique(feat, return_inverse=True)
    feat = feat.ravel()
    nf = int(feat.max()) + 1
    fu, fv = feat[links[:, 0]], feat[links[:, 1]]
    adj = coo_matrix((np.ones(fu.size * 2), (np.r_[fu, fv], np.r_[fv, fu])), shape=(nf, nf)).tocsr()
    adj.data[:] = 1.0  # binary, duplicates collapsed
    track_of_feat = components(nf, np.column_stack([fu, fv]))
    track = track_of_feat[feat]
    # conflicting tracks: observations of one image spread beyond the tolerance
    order = np.lexsort((image, track))
    new = np.r_[True, (np.diff(track[order]) != 0) | (np.diff(image[order]) != 0)]
    starts = np.flatnonzero(new)
    spread = np.hypot(
        np.maximum.reduceat(sample[order], starts) - np.minimum.reduceat(sample[order], starts),
        np.maximum.reduceat(line[order], starts) - np.minimum.reduceat(line[order], starts),
    )
    bad_tracks = np.unique(track[order[starts[~(spread <= tolerance_px)]]])
    if bad_tracks.size == 0:
        return links, 0
    in_bad = np.isin(track_of_feat[fu], bad_tracks) & (fu != fv)
    sel = np.flatnonzero(in_bad)
    support = np.asarray(adj[fu[sel]].multiply(adj[fv[sel]]).sum(axis=1)).ravel()
    drop = sel[support == 0]
    keep = np.ones(links.shape[0], bool)
    keep[drop] = False
    return links[keep], int(drop.size)


def convergence_sigma_factor(
    convergence_deg: ArrayLike, from_deg: float = 45.0, max_factor: float = 10.0
) -> NDArray[np.float64]:
    """Sigma factor of a match from its pair's convergence angle: ``tan(c) / tan(from_deg)``, in [1, max_factor].

    Between convergent views an area match carries a per-pair offset that grows with the
    angle (median offset of a pair's errors on two tiny missions: ~0.09 coarser-image px up
    to 55 deg, 0.2 at 55-65, 0.35 at 65-75, 0.9 at 75-90; docs/benchmarks/match.md, issue 21),
    about as ``tan`` of the angle. Views converging by 90 deg or more get ``max_factor``;
    NaN (unknown) gives 1; ``from_deg`` >= 90 turns the weighting off (all 1).

    Parameters
    ----------
    convergence_deg : (P,) angle between the two views' rays, degrees
    from_deg : angle up to which the factor is 1
    max_factor : the largest factor

    Returns
    -------
    ndarray (P,) float64, >= 1
    """
    c = np.asarray(convergence_deg, np.float64)
    out = np.ones(c.shape)
    if from_deg >= 90.0:
        return out
    ok = np.isfinite(c)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.tan(np.radians(np.clip(c, 0.0, 89.999))) / np.tan(np.radians(max(from_deg, 1e-6)))
    f = np.where(c >= 90.0, max_factor, f)
    out[ok] = np.clip(f[ok], 1.0, max_factor)
    return out


def build_network(
    image_ids: Sequence[str] | NDArray[np.str_],
    matches: PairMatches | Any,
    cameras: FramingCamera | Sequence[FramingCamera],
    positions: ArrayLike,
    rotations: ArrayLike,
    tolerance_px: float = 1.0,
    *,
    min_measures: int = 2,
    point_id_start: int = 0,
    sigma_px: float = np.nan,
    min_convergence_deg: float = 1.0,
    max_height_m: float = 50_000.0,
    datum_radius_m: float,
    metadata: Mapping[str, str] | None = None,
    sigma_factor: ArrayLike | None = None,
) -> BuildResult:
    """A control network from pairwise matches.

    Parameters
    ----------
    image_ids : (K,) image ids; the images table of the network, in this order
    matches : a :class:`PairMatches` table (or an object/mapping with its columns)
    cameras : one :class:`FramingCamera` per image, or one for all
    positions : (K, 3) a-priori body-fixed camera positions, m
    rotations : (K, 3, 3) a-priori body -> camera rotations
    tolerance_px : observations of one image closer than this are the same
        feature when keypoint ids are unknown; a track's observations in one
        image must lie within it, else they are a conflict (dropped, counted)
    min_measures : tracks with fewer measures (images) are dropped
    point_id_start : point ids are ``point_id_start + 0..N-1`` (give each tile
        its own range so merged networks keep unique ids)
    sigma_px : the measures' sample and line sigma (NaN: the adjustment's default)
    min_convergence_deg, max_height_m, datum_radius_m : see :func:`triangulate_points`
    metadata : network metadata
    sigma_factor : (P,) optional factor (>= 1) on ``sigma_px`` per match (e.g.
        :func:`convergence_sigma_factor` of its pair), given to the match's measured side
        (the side without a keypoint id; both sides when both or neither have one). A
        measure is the mean of its observations, so its sigma gets the RMS of their
        factors (the keypoint side's observations count 1)

    Returns
    -------
    BuildResult(network, stats): points ordered by their first match, measures
    by (point, image), measure type RegisteredSubPixel.
    """
    ids = as_string_array(np.asarray(image_ids), "image_ids")
    k = ids.size
    mt = as_pair_matches(matches)
    positions = np.asarray(positions, np.float64)
    rotations = np.asarray(rotations, np.float64)
    if positions.shape != (k, 3) or rotations.shape != (k, 3, 3):
        raise NetworkError(
            f"build_network: positions {positions.shape} / rotations {rotations.shape} must be ({k}, 3) / ({k}, 3, 3)"
        )
    p = len(mt)
    for name in ("image_a", "image_b"):
        arr = getattr(mt, name)
        if p and (arr.min() < 0 or arr.max() >= k):
            bad = int(np.flatnonzero((arr < 0) | (arr >= k))[0])
            raise NetworkError(f"build_network: match {bad} has {name}={arr[bad]}, outside the {k} images")
    valid = (
        np.isfinite(mt.sample_a) & np.isfinite(mt.line_a) & np.isfinite(mt.sample_b) & np.isfinite(mt.line_b)
        & (mt.image_a != mt.image_b)
    )
    sel = np.flatnonzero(valid)
    q = sel.size
    image = np.concatenate([mt.image_a[sel], mt.image_b[sel]])
    sample = np.concatenate([mt.sample_a[sel], mt.sample_b[sel]])
    line = np.concatenate([mt.line_a[sel], mt.line_b[sel]])
    assert mt.feature_a is not None and mt.feature_b is not None  # PairMatches.__post_init__ fills them with -1
    feature = np.concatenate([mt.feature_a[sel], mt.feature_b[sel]])
    n_obs = 2 * q
    obs = np.arange(n_obs, dtype=np.int64)
    edges = [np.column_stack([obs[:q], obs[q:]])]
    known = feature >= 0
    n_nodes = n_obs
    if known.any():
        key = image[known] * (int(feature.max()) + 1) + feature[known]
        _, node = np.unique(key, return_inverse=True)
        edges.append(np.column_stack([obs[known], n_obs + node.ravel()]))
        n_nodes += int(node.max()) + 1
    if (~known).any():
        pairs = near_pairs(image, sample, line, tolerance_px)
        if pairs.size:
            pairs = pairs[(feature[pairs[:, 0]] < 0) | (feature[pairs[:, 1]] < 0)]
            edges.append(pairs)
    identity = np.concatenate(edges[1:]) if len(edges) > 1 else np.zeros((0, 2), np.int64)
    links, n_pruned = _prune_unsupported_links(n_nodes, identity, edges[0], image, sample, line, tolerance_px)
    tracks = form_tracks(n_nodes, np.concatenate([links, identity]), image, sample, line, obs, tolerance_px, min_measures)
    n = tracks.n_tracks
    mp = tracks.group_track
    xyz, method = triangulate_points(
        mp, tracks.group_image, np.column_stack([tracks.sample, tracks.line]), cameras, positions, rotations, n,
        min_convergence_deg, max_height_m, datum_radius_m=datum_radius_m,
    )
    g = mp.size
    net = ControlNetwork.from_arrays(
        ids,
        point_id_start + np.arange(n, dtype=np.int64),
        mp,
        tracks.group_image,
        tracks.sample,
        tracks.line,
        point_type=np.full(n, PointType.FREE, np.int8),
        apriori_xyz=xyz,
        sigma=np.repeat(float(sigma_px) * _group_factor(sigma_factor, sel, feature, tracks, p)[:, None], 2, axis=1),
        measure_type=np.full(g, MeasureType.REGISTERED_SUBPIXEL, np.int8),
        metadata=dict(metadata or {}),
    )
    no_ground = method == 0
    if no_ground.any():
        net = net.take_points(~no_ground)
    stats = BuildStats(
        n_matches=p,
        n_matches_invalid=int(p - q),
        n_observations=n_obs,
        n_links_pruned=n_pruned,
        n_conflicts=tracks.n_conflicts,
        n_conflict_observations=tracks.n_conflict_observations,
        n_short_tracks=tracks.n_short_tracks,
        n_points=net.n_points,
        n_measures=net.n_measures,
        n_triangulated=int((method == 2).sum()),
        n_on_datum=int((method == 1).sum()),
        n_no_ground=int(no_ground.sum()),
    )
    return BuildResult(net, stats)


def _group_factor(sigma_factor: ArrayLike | None, sel: NDArray[np.int64], feature: NDArray[np.int64],
                  tracks: Any, p: int) -> NDArray[np.float64]:
    """Per measure (track group): RMS of its observations' sigma factors (see ``build_network``)."""
    g = tracks.group_track.size
    if sigma_factor is None:
        return np.ones(g)
    f = np.asarray(sigma_factor, np.float64).reshape(-1)
    if f.size != p or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise NetworkError(f"build_network: sigma_factor must be {p} finite positive values (one per match), "
                           f"got {f.size}{'' if f.size != p else ' with non-finite or non-positive ones'}")
    q = sel.size
    fa, fb = feature[:q], feature[q:]
    measured_a = (fa < 0) | ((fa >= 0) == (fb >= 0))
    measured_b = (fb < 0) | ((fa >= 0) == (fb >= 0))
    obs_f = np.concatenate([np.where(measured_a, f[sel], 1.0), np.where(measured_b, f[sel], 1.0)])
    grp = tracks.obs_group
    use = grp >= 0
    sq = np.bincount(grp[use], weights=obs_f[use] ** 2, minlength=g)
    cnt = np.bincount(grp[use], minlength=g)
    return np.sqrt(sq / np.maximum(cnt, 1))
