"""The merge of :mod:`mercury_dem.network.merge`, done by parts (a sort-merge in partitions): the pure steps.

:func:`~mercury_dem.network.merge.merge_networks` joins two points when they share a measure (measures of one
image within the tolerance) and resolves conflicts per joined group. Both are local: a pair of near measures
lies in one image, and a joined group (a connected component of input points) is resolved on its own. So the
merge of networks too large for one process splits in three steps, each over bounded parts, and only
point-sized bookkeeping (a label and a count per input point) is held whole:

1. **join** (:func:`join_edges`): the children's measures partitioned by image (every measure of an image in
   one part); each part gives the pairs of distinct input points that share a near measure;
2. **group** (:func:`merge_partitions`): the connected components of those pairs over all input points, dealt
   into parts of whole components, in the order of their first input point, each part at most
   ``max_measures`` measures (one component larger than that is a part of its own);
3. **merge** (:func:`merge_part`): each part's points and measures, one sub-network per child, merged by
   :func:`~mercury_dem.network.merge.merge_networks` itself (``point_ids="first"``), so a part's merged points
   and measures are exactly the whole merge's (the same arithmetic on the same values in the same order).

The parts' merged points come out in the whole merge's order (by their first constituent); a piece that a
conflict split off a component and that starts after the next part's first point waits for its place
(:func:`release_in_order`), so the merged table is the whole merge's, row for row. Point ids are decided
on the whole by the caller (:func:`ids_collide`), as ``point_ids="auto"`` does. The driver that reads the
children's stores and writes the merged one is :mod:`mercury_dem.io.merged_network_store`.

Why our own: the join is a sort-merge on the stored columns; a Dask dataframe shuffle would move every column
of every measure through the scheduler's shuffle for what one image-keyed pass and one point-keyed pass do.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.network.merge import MergeResult, merge_networks
from mercury_dem.network.model import ControlNetwork
from mercury_dem.network.tracks import components, near_pairs


def join_edges(point: NDArray[np.int64], image: NDArray[np.int64], sample: NDArray[np.float64],
               line: NDArray[np.float64], tolerance_px: float) -> NDArray[np.int64]:
    """The pairs (E, 2) of distinct input points that share a measure, from one image part's measures.

    ``point`` is each measure's input point (global over the children), ``image`` its image (global); every
    measure of an image must be in this part. Rows are unique, each pair ``(a, b)`` with ``a < b``.
    """
    pairs = near_pairs(np.asarray(image, np.int64), np.asarray(sample, np.float64), np.asarray(line, np.float64),
                       tolerance_px)
    e = np.asarray(point, np.int64)[pairs].reshape(-1, 2)
    e = e[e[:, 0] != e[:, 1]]
    e.sort(axis=1)
    out: NDArray[np.int64] = np.unique(e, axis=0) if e.size else np.zeros((0, 2), np.int64)
    return out


def merge_partitions(point_measures: NDArray[np.int64], edges: NDArray[np.int64],
                     max_measures: int) -> tuple[NDArray[np.int32], int]:
    """The part of every input point: whole components, in the order of their first point, of bounded size.

    Parameters
    ----------
    point_measures : (N,) measures of each input point (input points numbered over the children in order)
    edges : (E, 2) input-point pairs that share a measure (:func:`join_edges` of every image part)
    max_measures : a part holds components up to this many measures (at least one component)

    Returns
    -------
    (part of each input point (N,) int32, number of parts). Parts are contiguous in the order of the
    components' first points, so merging the parts in order gives the whole merge's point order.
    """
    n = int(point_measures.size)
    if n == 0:
        return np.zeros(0, np.int32), 0
    label = components(n, np.asarray(edges, np.int64).reshape(-1, 2))
    n_comp = int(label.max()) + 1
    first = np.full(n_comp, n, np.int64)
    np.minimum.at(first, label, np.arange(n, dtype=np.int64))
    comp_measures = np.bincount(label, weights=point_measures, minlength=n_comp).astype(np.int64)
    order = np.argsort(first, kind="stable")  # components by their first input point
    rank = np.empty(n_comp, np.int64)
    rank[order] = np.arange(n_comp)
    cum = np.cumsum(comp_measures[order])
    # greedy cut: a part ends before the component that would take it past max_measures
    part_of_rank = np.zeros(n_comp, np.int32)
    part, start_total = 0, 0
    cap = max(1, int(max_measures))
    # cut points found by searchsorted from each part's start (parts are few: one pass per part)
    i = 0
    while i < n_comp:
        j = int(np.searchsorted(cum, start_total + cap, side="right"))
        j = max(j, i + 1)  # at least one component
        part_of_rank[i:j] = part
        start_total = int(cum[j - 1])
        part += 1
        i = j
    out: NDArray[np.int32] = part_of_rank[rank[label]]
    return out, part


def part_starts(point_part: NDArray[np.int32], n_parts: int) -> NDArray[np.int64]:
    """The first input point of each part (its first component's first point), and N at the end: (n_parts + 1,)."""
    n = int(point_part.size)
    out = np.full(n_parts + 1, n, np.int64)
    np.minimum.at(out, point_part.astype(np.int64), np.arange(n, dtype=np.int64))
    return out


def release_in_order(carry: dict[str, NDArray[Any]] | None, part: dict[str, NDArray[Any]], bound: int,
                     point_columns: Sequence[str], measure_columns: Sequence[str]
                     ) -> tuple[dict[str, NDArray[Any]], dict[str, NDArray[Any]] | None]:
    """The merged points of the whole merge's order so far, and those that must wait for later parts.

    A part's merged points carry ``key`` (the input index of their first constituent: the whole merge orders
    its points by it). A piece split off a component by a conflict can start after the next part's first
    point: it waits (``carry``) and is released among the later parts' points at its place. ``part`` and
    ``carry`` hold the point columns (with ``key``) and measure columns (``measure_point`` indexing their own
    points); the points with ``key < bound`` (the next part's first input point) are released, with their
    measures, in key order, measures grouped by point in their own order.
    """
    key = part["key"]
    if carry is None and (key.size == 0 or (key[-1] < bound and bool(np.all(key[1:] > key[:-1])))):
        return part, None  # the usual case: nothing waits, nothing to reorder (no copy)
    both = part if carry is None else _concat_rows(carry, part, point_columns, measure_columns)
    key = both["key"]
    order = np.argsort(key, kind="stable")
    n_rel = int(np.searchsorted(key[order], bound, side="left"))
    rel, rest = _take_points(both, order[:n_rel], point_columns, measure_columns), None
    if n_rel < order.size:
        rest = _take_points(both, order[n_rel:], point_columns, measure_columns)
    return rel, rest


def _concat_rows(a: dict[str, NDArray[Any]], b: dict[str, NDArray[Any]], point_columns: Sequence[str],
                 measure_columns: Sequence[str]) -> dict[str, NDArray[Any]]:
    out = {k: np.concatenate([a[k], b[k]]) for k in (*point_columns, "key", *measure_columns)}
    out["measure_point"] = np.concatenate([a["measure_point"], b["measure_point"] + len(a["key"])])
    return out


def _take_points(cols: dict[str, NDArray[Any]], points: NDArray[np.int64], point_columns: Sequence[str],
                 measure_columns: Sequence[str]) -> dict[str, NDArray[Any]]:
    """The points ``points`` (in that order) and their measures, renumbered; measures by point, stable."""
    new = np.full(len(cols["key"]), -1, np.int64)
    new[points] = np.arange(points.size)
    mp = new[cols["measure_point"]]
    keep = np.flatnonzero(mp >= 0)
    m_order = keep[np.argsort(mp[keep], kind="stable")]
    out = {k: cols[k][points] for k in (*point_columns, "key")}
    out.update({k: cols[k][m_order] for k in measure_columns})
    out["measure_point"] = mp[m_order]
    return out


def merge_part(networks: Sequence[ControlNetwork], tolerance_px: float, min_measures: int = 1) -> MergeResult:
    """One part's merge: its sub-networks (one per child that has points in it, children in order).

    Each sub-network must carry the whole merged image table (same ids, same order) so that the parts'
    image indices agree; its points in their child's order. Point ids are the first constituent's (the
    caller decides on renumbering over all parts: :func:`ids_collide`).
    """
    return merge_networks(networks, tolerance_px=tolerance_px, min_measures=min_measures, point_ids="first")


def ids_collide(ids: NDArray[np.generic]) -> bool:
    """True when a point id occurs twice (``point_ids="auto"`` then renumbers 0..N-1)."""
    v = np.sort(ids)
    return bool(np.any(v[1:] == v[:-1]))


def block_edges(n_points: int, block_points: int) -> NDArray[np.int64]:
    """Block edges over ``n_points`` points, as :func:`~mercury_dem.adjust.blocked_bundle.point_blocks` cuts them."""
    n_blocks = max(1, -(-n_points // max(1, int(block_points))))
    out: NDArray[np.int64] = np.linspace(0, n_points, n_blocks + 1).astype(np.int64)
    return out


def median_of_counts(values: NDArray[np.float64], counts: NDArray[np.int64]) -> float:
    """``np.median`` of the multiset where ``values[i]`` occurs ``counts[i]`` times (values sorted, unique).

    The exact median of the measures' sigmas without holding them: the parts give their value counts
    (a network's sigmas take few distinct values).
    """
    total = int(counts.sum())
    if total == 0:
        return float("nan")
    cum = np.cumsum(counts)
    lo = float(values[int(np.searchsorted(cum, (total - 1) // 2, side="right"))])
    hi = float(values[int(np.searchsorted(cum, total // 2, side="right"))])
    return lo if total % 2 else (lo + hi) / 2.0
