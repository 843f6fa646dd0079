"""Merging control networks (tiles -> regions -> hemispheres -> globe).

Two points are the same when they share a measure: measures of the same image
within ``tolerance_px`` of each other (found with one kd-tree over all images,
:func:`mercury_dem.network.tracks.near_pairs`). This works in pixel space, so
the 0/360 longitude seam and the poles need no special case: two tiles that
meet at the seam see the same pixels of the same images.

Joined points form tracks (union-find) and conflicts — a merged point with
measures in one image that disagree by more than the tolerance — are resolved
as in :mod:`mercury_dem.network.tracks`: the ambiguous measures are dropped and
the joins recomputed without them; counts are reported.

A merged point takes: the id of its first constituent (networks in the given
order), the measure-count-weighted mean of the constituents' a-priori (and
adjusted) coordinates, the most constrained type, ignored/rejected only if all
constituents were, and the first constituent's covariances. A merged measure
takes the mean position of the measures it joins and the other columns of
the first of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import NetworkError
from mercury_dem.network.model import (
    MEASURE_COLUMNS,
    OPTIONAL_POINT_COLUMNS,
    ControlNetwork,
    concatenate_ids,
)
from mercury_dem.network.tracks import form_tracks, near_pairs


@dataclass(frozen=True)
class MergeStats:
    """Counts of one :func:`merge_networks` call."""

    n_networks: int
    n_images: int
    n_points_in: int
    n_measures_in: int
    n_points: int
    n_measures: int
    n_points_joined: int
    n_measures_collapsed: int
    n_conflicts: int
    n_conflict_measures: int
    n_points_dropped: int
    ids_renumbered: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class MergeResult(NamedTuple):
    """A merged network, and the counts of what the merge joined."""

    network: ControlNetwork
    stats: MergeStats


def _weighted_mean(
    values: NDArray[np.float64], weights: NDArray[np.float64], target: NDArray[np.int64], base: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per-target weighted mean of finite rows, as ``base + mean(values - base)``.

    Written as an offset from ``base`` (the first constituent's values) so that
    constituents that agree give exactly their value back. NaN where no
    constituent has finite values.
    """
    n = base.shape[0]
    ok = np.all(np.isfinite(values), axis=1) & (weights > 0)
    b = np.where(np.all(np.isfinite(base), axis=1)[:, None], base, 0.0)
    w = np.where(ok, weights, 0.0)
    v = np.where(ok[:, None], values - b[target], 0.0)
    tot = np.bincount(target, w, minlength=n)
    # bincount with weights is float64 (numpy's stubs say intp)
    sums: NDArray[np.float64] = np.stack([np.bincount(target, w * v[:, j], minlength=n)
                                          for j in range(values.shape[1])], axis=1).astype(np.float64, copy=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        out: NDArray[np.float64] = b + sums / tot[:, None]
    out[tot == 0] = np.nan
    return out


def _has_duplicates(values: NDArray[np.generic]) -> bool:
    """True when some value occurs twice (a sort: numpy 2's hash-based unique is far slower on ints)."""
    v = np.sort(values)
    return bool(np.any(v[1:] == v[:-1]))


def merge_networks(
    networks: Sequence[ControlNetwork],
    tolerance_px: float = 1.0,
    *,
    min_measures: int = 1,
    point_ids: Literal["auto", "keep", "renumber", "first"] = "auto",
) -> MergeResult:
    """Merge networks into one, joining points that share a measure.

    Parameters
    ----------
    networks : the networks, in priority order (earlier ones win ties)
    tolerance_px : measures of the same image closer than this are the same measure
    min_measures : merged points with fewer measures are dropped (points with no
        measure are always dropped)
    point_ids : "keep" — merged points keep their first constituent's id and
        colliding ids raise :class:`NetworkError`; "renumber" — ids 0..N-1;
        "auto" — keep when unique, else renumber (``stats.ids_renumbered``); "first" — the first
        constituent's id, unchecked (for a merge done by parts, which decides on the whole:
        :mod:`mercury_dem.network.streamed_merge`)

    Returns
    -------
    MergeResult(network, stats). The images table is the union of the inputs'
    (first appearance order); points are ordered by their first constituent,
    measures by (point, image). Metadata is the first network's.
    """
    nets = list(networks)
    if not nets:
        raise NetworkError("merge_networks needs at least one network")
    if point_ids not in ("auto", "keep", "renumber", "first"):
        raise NetworkError(
            f"merge_networks: point_ids must be 'auto', 'keep', 'renumber' or 'first', got {point_ids!r}")
    for i, net in enumerate(nets):
        if net.n_measures and (
            net.measure_point.min() < 0 or net.measure_point.max() >= net.n_points
            or net.measure_image.min() < 0 or net.measure_image.max() >= net.n_images
        ):
            raise NetworkError(
                f"merge_networks: network {i} ({net!r}) has dangling point or image indices; "
                f"run validate() on it and fix its source"
            )
    all_ids = np.concatenate([n.image_ids for n in nets])
    uniq, first_idx, inv = np.unique(all_ids, return_index=True, return_inverse=True)
    order = np.argsort(first_idx, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    image_ids = uniq[order]
    img_map = rank[inv.ravel()]
    img_off = np.concatenate([[0], np.cumsum([n.n_images for n in nets])])
    pt_off = np.concatenate([[0], np.cumsum([n.n_points for n in nets])]).astype(np.int64)
    n_in, m_in = int(pt_off[-1]), sum(n.n_measures for n in nets)
    mpoint = np.concatenate([n.measure_point + pt_off[i] for i, n in enumerate(nets)]).astype(np.int64)
    mimage = np.concatenate([img_map[img_off[i] + n.measure_image] for i, n in enumerate(nets)]).astype(np.int64)
    cols = {name: np.concatenate([getattr(n, name) for n in nets]) for name in MEASURE_COLUMNS if name not in ("measure_point", "measure_image")}
    sample, line = cols["sample"], cols["line"]
    # graph: one node per input point (its measures sit on it); an edge per pair of near measures
    pairs = near_pairs(mimage, sample, line, tolerance_px)
    pairs = pairs[mpoint[pairs[:, 0]] != mpoint[pairs[:, 1]]]
    tracks = form_tracks(n_in, mpoint[pairs], mimage, sample, line, mpoint, tolerance_px, min_measures,
                         node_of_obs=mpoint, edge_obs=pairs)
    n = tracks.n_tracks
    # track of each input point (-1 when all its measures were dropped)
    kept_obs = np.flatnonzero(tracks.obs_group >= 0)
    point_track = np.full(n_in, -1, np.int64)
    point_track[mpoint[kept_obs]] = tracks.group_track[tracks.obs_group[kept_obs]]
    constituents = np.flatnonzero(point_track >= 0)
    ct = point_track[constituents]
    per_point = np.bincount(mpoint, minlength=n_in).astype(np.float64)[constituents]
    n_const = np.bincount(ct, minlength=n)
    # representative constituent = smallest input point index per track
    rep = np.full(n, n_in, np.int64)
    np.minimum.at(rep, ct, constituents)
    pcat = {name: np.concatenate([getattr(net, name) for net in nets]) for name in
            ("point_type", "apriori_xyz", "adjusted_xyz", "point_ignored", "point_rejected")}
    pid_all = concatenate_ids([net.point_ids for net in nets])
    ptype = np.zeros(n, np.int8)
    np.maximum.at(ptype, ct, pcat["point_type"][constituents])
    ign = np.bincount(ct, pcat["point_ignored"][constituents], minlength=n) == n_const
    rej = np.bincount(ct, pcat["point_rejected"][constituents], minlength=n) == n_const
    apriori = _weighted_mean(pcat["apriori_xyz"][constituents], per_point, ct, pcat["apriori_xyz"][rep])
    adjusted = _weighted_mean(pcat["adjusted_xyz"][constituents], per_point, ct, pcat["adjusted_xyz"][rep])
    opt: dict[str, Any] = {}
    for name, (_, trail) in OPTIONAL_POINT_COLUMNS.items():
        parts = [getattr(net, name) for net in nets]
        if all(p_ is None for p_ in parts):
            opt[name] = None
        else:
            full = np.concatenate([p_ if p_ is not None else np.full((net.n_points, *trail), np.nan) for p_, net in zip(parts, nets)])
            opt[name] = full[rep]
    ids = pid_all[rep]
    renumbered = False
    if point_ids == "renumber" or (point_ids == "auto" and _has_duplicates(ids)):
        ids = np.arange(n, dtype=np.int64)
        renumbered = True
    elif point_ids == "keep" and _has_duplicates(ids):
        raise NetworkError(
            "merge_networks: merged point ids collide (the inputs reuse ids for different points); "
            "build each network with its own point_id_start, or pass point_ids='renumber'"
        )
    first = tracks.group_first
    merged = ControlNetwork(
        image_ids=image_ids,
        point_ids=ids,
        point_type=ptype,
        apriori_xyz=apriori,
        adjusted_xyz=adjusted,
        point_ignored=ign,
        point_rejected=rej,
        measure_point=tracks.group_track,
        measure_image=tracks.group_image,
        sample=tracks.sample,
        line=tracks.line,
        sigma=cols["sigma"][first],
        measure_type=cols["measure_type"][first],
        measure_ignored=cols["measure_ignored"][first],
        measure_rejected=cols["measure_rejected"][first],
        residuals=cols["residuals"][first],
        apriori_pixels=cols["apriori_pixels"][first],
        metadata=dict(nets[0].metadata),
        **opt,
    )
    stats = MergeStats(
        n_networks=len(nets),
        n_images=merged.n_images,
        n_points_in=n_in,
        n_measures_in=m_in,
        n_points=merged.n_points,
        n_measures=merged.n_measures,
        n_points_joined=int(n_const[n_const > 1].sum()),
        n_measures_collapsed=int((tracks.group_size - 1).sum()),
        n_conflicts=tracks.n_conflicts,
        n_conflict_measures=tracks.n_conflict_observations,
        n_points_dropped=int(n_in - constituents.size),
        ids_renumbered=renumbered,
    )
    return MergeResult(merged, stats)
