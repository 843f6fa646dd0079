"""Tracks: observations joined into points, shared by building and merging networks.

An *observation* is one pixel in one image. Observations are nodes of a graph
whose edges say "same ground feature" (a match, the same keypoint, the same
existing point, or two pixels of one image within the tolerance). A track is a
connected component (union-find, done by
:func:`scipy.sparse.csgraph.connected_components`, vectorized).

Within a track, all observations in one image must agree: if they lie within
``tolerance_px`` of each other (the diagonal of their bounding box) they become
one measure at their mean position; otherwise the (track, image) group is a
*conflict* — two different features of the image claim the same point. Every
observation of a conflicting group is dropped, the edges through them
removed, and the components recomputed, so a track that was only held together
through the ambiguous image splits into the parts that are matched directly.
Removing nodes only splits components, so one pass removes every conflict.
The rule is deterministic (no dependence on input order beyond the tie-break
of which track comes first) and the counts are reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def near_pairs(
    image: NDArray[np.int64], sample: NDArray[np.float64], line: NDArray[np.float64], tolerance_px: float
) -> NDArray[np.int64]:
    """Pairs (P, 2) of observations in the same image within ``tolerance_px`` (Euclidean).

    One kd-tree over all images at once: images are laid side by side along
    the sample axis with a gap wider than the tolerance, so no pair spans two
    images. Non-finite pixels never pair.
    """
    ok = np.flatnonzero(np.isfinite(sample) & np.isfinite(line))
    if ok.size < 2 or tolerance_px <= 0:
        return np.zeros((0, 2), np.int64)
    s, ln, im = sample[ok], line[ok], image[ok]
    s0 = s.min()
    span = (s.max() - s0) + 2.0 * tolerance_px + 1.0
    x = (s - s0) + im.astype(np.float64) * span
    tree = cKDTree(np.column_stack([x, ln]), balanced_tree=False, compact_nodes=False)
    pairs = tree.query_pairs(float(tolerance_px), output_type="ndarray")
    return ok[pairs].astype(np.int64) if pairs.size else np.zeros((0, 2), np.int64)


@dataclass(frozen=True)
class Tracks:
    """Measures formed from observations (G groups, T tracks).

    Attributes
    ----------
    group_track : (G,) track index of each measure, tracks numbered 0..T-1 by their smallest rank
    group_image : (G,) image index
    group_first : (G,) the observation that represents the group (smallest rank, then index)
    group_size : (G,) number of observations merged into the measure
    sample, line : (G,) measure position: mean of the group's observations
    obs_group : (n_obs,) group of each observation, -1 when dropped
    n_tracks : T
    n_conflicts : (track, image) groups dropped as conflicts
    n_conflict_observations : observations dropped with them
    n_short_tracks : tracks dropped for having fewer than ``min_measures`` measures
    """

    group_track: NDArray[np.int64]
    group_image: NDArray[np.int64]
    group_first: NDArray[np.int64]
    group_size: NDArray[np.int64]
    sample: NDArray[np.float64]
    line: NDArray[np.float64]
    obs_group: NDArray[np.int64]
    n_tracks: int
    n_conflicts: int
    n_conflict_observations: int
    n_short_tracks: int


def components(n_nodes: int, edges: NDArray[np.int64]) -> NDArray[np.int64]:
    """Weakly connected component label of each of ``n_nodes`` nodes joined by ``edges`` (E, 2) (scipy.sparse.csgraph)."""
    if edges.size == 0:
        return np.arange(n_nodes, dtype=np.int64)
    g = coo_matrix((np.ones(edges.shape[0], np.int8), (edges[:, 0], edges[:, 1])), shape=(n_nodes, n_nodes)).tocsr()
    _, labels = connected_components(g, directed=True, connection="weak")
    out: NDArray[np.int64] = labels.astype(np.int64)
    return out


def _groups(label: NDArray[np.int64], image: NDArray[np.int64], rank: NDArray[np.int64],
            obs: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Sort observations ``obs`` by (label, image, rank, index); return order and group starts.

    One stable sort of the composite key ``label * K + image`` over the
    observations pre-ordered by (rank, index) (no pre-sort needed when the
    ranks are already non-decreasing, as for build and for point-sorted merges).
    """
    if obs.size and np.any(np.diff(rank[obs]) < 0):
        obs = obs[np.argsort(rank[obs], kind="stable")]
    k = int(image.max()) + 1 if image.size else 1
    key = label[obs] * k + image[obs]
    perm = np.argsort(key, kind="stable")
    order, ks = obs[perm], key[perm]
    new = np.ones(order.size, bool)
    new[1:] = ks[1:] != ks[:-1]
    return order, np.flatnonzero(new)


def _spread(values: NDArray[np.float64], starts: NDArray[np.int64]) -> NDArray[np.float64]:
    return np.maximum.reduceat(values, starts) - np.minimum.reduceat(values, starts)


def form_tracks(
    n_nodes: int,
    edges: NDArray[np.int64],
    image: NDArray[np.int64],
    sample: NDArray[np.float64],
    line: NDArray[np.float64],
    rank: NDArray[np.int64],
    tolerance_px: float,
    min_measures: int = 2,
    node_of_obs: NDArray[np.int64] | None = None,
    edge_obs: NDArray[np.int64] | None = None,
) -> Tracks:
    """Connected components of observations, conflicts removed, groups merged into measures.

    Parameters
    ----------
    n_nodes : number of graph nodes; the first ``n_obs = image.size`` are the
        observations, the rest are glue nodes (keypoints, existing points)
    edges : (E, 2) node pairs
    image, sample, line : (n_obs,) observation image index and pixel
    rank : (n_obs,) ordering key: tracks are numbered by their smallest rank and
        a group is represented by its smallest-rank observation
    tolerance_px : observations of one track in one image further apart than
        this (bounding-box diagonal) are a conflict
    min_measures : tracks with fewer measures (distinct images) are dropped
    node_of_obs : (n_obs,) optional node of each observation, when several
        observations share a node (merge: the node is the input point); default:
        observation i is node i
    edge_obs : (E, 2) with ``node_of_obs``: the observation behind each end of
        each edge, -1 for none; an edge goes when an observation behind it is
        dropped. Default: the ends that are observations.
    """
    n_obs = image.size
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    if node_of_obs is None:
        node_of_obs = np.arange(n_obs, dtype=np.int64)
        edge_obs = np.where(edges < n_obs, edges, -1)
    elif edge_obs is None:
        raise ValueError("form_tracks: edge_obs is required with node_of_obs")
    label = components(n_nodes, edges)[node_of_obs]
    obs = np.arange(n_obs, dtype=np.int64)
    order, starts = _groups(label, image, rank, obs)
    n_conflicts = n_conflict_obs = 0
    if order.size:
        spread = np.hypot(_spread(sample[order], starts), _spread(line[order], starts))
        bad = ~(spread <= tolerance_px)  # NaN spreads (NaN pixels) count as conflicts
        # groups of a single observation are never conflicts, even with NaN pixels
        sizes = np.diff(np.append(starts, order.size))
        bad &= sizes > 1
        if bad.any():
            n_conflicts = int(bad.sum())
            dropped = np.zeros(n_obs + 1, bool)  # the extra slot stands for "no observation" (-1)
            dropped[order[np.repeat(bad, sizes)]] = True
            n_conflict_obs = int(dropped.sum())
            keep_edge = ~(dropped[edge_obs[:, 0]] | dropped[edge_obs[:, 1]])
            label = components(n_nodes, edges[keep_edge])[node_of_obs]
            obs = np.flatnonzero(~dropped[:n_obs])
            order, starts = _groups(label, image, rank, obs)
    if order.size == 0:
        e = np.zeros(0, np.int64)
        return Tracks(e, e, e, e, np.zeros(0), np.zeros(0), np.full(n_obs, -1, np.int64), 0,
                      n_conflicts, n_conflict_obs, 0)
    sizes = np.diff(np.append(starts, order.size)).astype(np.int64)
    glabel = label[order[starts]]
    # measures per track and the tracks kept
    tnew = np.ones(starts.size, bool)
    tnew[1:] = glabel[1:] != glabel[:-1]
    tstart = np.flatnonzero(tnew)
    per_track = np.diff(np.append(tstart, starts.size))
    keep_track = per_track >= min_measures
    n_short = int((~keep_track).sum())
    # number kept tracks by their smallest rank (ties by label)
    min_rank = np.minimum.reduceat(rank[order], starts)
    track_min_rank = np.minimum.reduceat(min_rank, tstart) if tstart.size else np.zeros(0, np.int64)
    kept_t = np.flatnonzero(keep_track)
    # tracks are in label order already: a stable sort by rank breaks ties by label
    t_order = kept_t[np.argsort(track_min_rank[kept_t], kind="stable")]
    track_number = np.full(tstart.size, -1, np.int64)
    track_number[t_order] = np.arange(t_order.size)
    g_track_all = np.repeat(track_number, per_track)
    # group positions: first + mean offset (exact when all observations agree)
    first_in_group = order[starts]
    s_first = np.repeat(sample[first_in_group], sizes)
    l_first = np.repeat(line[first_in_group], sizes)
    ds = np.add.reduceat(sample[order] - s_first, starts) / sizes
    dl = np.add.reduceat(line[order] - l_first, starts) / sizes
    g_sample = sample[first_in_group] + np.where(sizes > 1, ds, 0.0)
    g_line = line[first_in_group] + np.where(sizes > 1, dl, 0.0)
    # groups of kept tracks, by (track, image): within a track the groups are already by image,
    # so lay the tracks' group ranges out in track order (no sort)
    counts = per_track[t_order]
    total = int(counts.sum())
    begin = np.cumsum(counts) - counts
    gsel = np.repeat(tstart[t_order] - begin, counts) + np.arange(total)
    group_of_old = np.full(starts.size, -1, np.int64)
    group_of_old[gsel] = np.arange(gsel.size)
    obs_group = np.full(n_obs, -1, np.int64)
    obs_group[order] = np.repeat(group_of_old, sizes)
    return Tracks(
        group_track=g_track_all[gsel],
        group_image=image[first_in_group[gsel]],
        group_first=first_in_group[gsel],
        group_size=sizes[gsel],
        sample=g_sample[gsel],
        line=g_line[gsel],
        obs_group=obs_group,
        n_tracks=int(t_order.size),
        n_conflicts=n_conflicts,
        n_conflict_observations=n_conflict_obs,
        n_short_tracks=n_short,
    )
