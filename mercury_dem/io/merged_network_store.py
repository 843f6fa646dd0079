"""A unit's merged network written straight from its children's stores, by parts (the streamed merge).

:func:`stream_merge` merges the stored networks of a unit's children as
:func:`~mercury_dem.network.merge.merge_networks` does, without ever holding the merged network, any child's
network or its adjustment problem: the children's columns are read in row chunks, spilled to a scratch
directory by image part (the join) and then by component part (the merge), each part merged on its own
(:mod:`mercury_dem.network.streamed_merge`) and appended to the output. The output is one store that is both

* the merged network (``OUT/network``: every column, readable by :func:`~mercury_dem.io.network_store.read_network`
  for ``export-isis``, ``cnetcheck``), and
* the blocked adjustment's input (its ``geometry`` and ``blocks`` groups, as
  :func:`~mercury_dem.io.synthetic_network_store.write_synthetic_network` writes them): point blocks cut as
  :func:`~mercury_dem.adjust.blocked_bundle.point_blocks` cuts the in-memory problem, read by each worker
  (:class:`~mercury_dem.io.synthetic_network_store.StoredBlocks`).

What the calling process holds whole is bookkeeping of a few bytes a point (each input point's part and
measure count, each merged point's id and measure count), the image table and the join's pairs; everything
measure-sized is one part at a time (``part_measures``). The parts are merged one after the other by
default; ``map_parts`` (e.g. a Dask client's ``map`` + ``gather`` in order) runs them elsewhere: each
part reads its spill files itself and returns its merged rows (bounded by ``part_measures``).

Written under a temporary name and moved into place when complete; the scratch directory is removed.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from numpy.typing import NDArray

from mercury_dem.exceptions import MercuryDemError, StoreError
from mercury_dem.geometry.camera import camera_to_dict
from mercury_dem.io.atomic import COMPLETE_MARKER, atomic_directory
from mercury_dem.io.network_store import CHUNK_ROWS, FORMAT_NAME, FORMAT_VERSION, NetworkStore, write_strings
from mercury_dem.io.synthetic_network_store import ColumnAppender
from mercury_dem.network.blocks import ImageTable
from mercury_dem.network.merge import MergeStats
from mercury_dem.network.model import (
    MEASURE_COLUMNS,
    OPTIONAL_POINT_COLUMNS,
    POINT_COLUMNS,
    ControlNetwork,
    concatenate_ids,
)
from mercury_dem.network.streamed_merge import (
    block_edges,
    ids_collide,
    join_edges,
    median_of_counts,
    merge_part,
    merge_partitions,
    part_starts,
    release_in_order,
)

#: measures per part (join and merge) when not given: the part bounds the calling process's peak (0.97 GB at 2.5e7
#: measures with this size, docs/benchmarks/cascade.md §5; 2e6 gave 1.6 GB at 1e7)
PART_MEASURES = 500_000


@dataclass
class StreamedMergeSummary:
    """What :func:`stream_merge` wrote: the counts of the merge as :func:`~mercury_dem.network.merge.merge_networks`
    gives them (``stats``, summed over the parts; its ``n_networks`` the children merged), and how it was streamed.
    """

    path: Path
    stats: MergeStats
    n_blocks: int
    image_parts: int
    merge_parts: int
    join_pairs: int
    #: the median of the active measures' sigmas (px), as ``bundle_adjust`` takes it for the rejection floor
    median_sigma_px: float
    seconds: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Flat, as the benchmark records have it: ``n_children`` and the merge's counts beside the streaming's."""
        counts = self.stats.to_dict()
        out: dict[str, Any] = {"path": str(self.path), "n_children": counts.pop("n_networks"), **counts}
        out.update({k: getattr(self, k) for k in ("n_blocks", "image_parts", "merge_parts", "join_pairs",
                                                   "median_sigma_px", "seconds")})
        return out


@dataclass(frozen=True)
class _Child:
    name: str
    store: NetworkStore
    point_offset: int
    image_map: NDArray[np.int64]
    optional: tuple[str, ...]


def _open_children(unit: str, children: Sequence[tuple[str, str | Path]]) -> list[NetworkStore]:
    out = []
    for name, path in children:
        try:
            out.append(NetworkStore(path))
        except MercuryDemError as exc:
            raise StoreError(f"{unit}: the network of child {name} cannot be merged: {exc}") from None
    return out


def _chunks(n: int, rows: int) -> Iterable[tuple[int, int]]:
    for r0 in range(0, n, rows):
        yield r0, min(n, r0 + rows)


def _read(unit: str, child: _Child, name: str, r0: int, r1: int) -> NDArray[Any]:
    try:
        return child.store.column_rows(name, r0, r1)
    except MercuryDemError as exc:
        raise StoreError(f"{unit}: the network of child {child.name} cannot be merged: {exc}") from None


def _save(path: Path, arrays: dict[str, NDArray[Any]]) -> None:
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, allow_pickle=False, **arrays)
    tmp.rename(path)


def _load_parts(paths: Sequence[Path]) -> dict[str, NDArray[Any]]:
    parts: dict[str, list[NDArray[Any]]] = {}
    for p in paths:
        with np.load(p, allow_pickle=False) as z:
            for k in z.files:
                parts.setdefault(k, []).append(z[k])
    return {k: np.concatenate(v) for k, v in parts.items()}


def _join_part(args: tuple[list[Path], float]) -> NDArray[np.int64]:
    paths, tol = args
    if not paths:
        return np.zeros((0, 2), np.int64)
    d = _load_parts(paths)
    return join_edges(d["point"], d["image"], d["sample"], d["line"], tol)


def _merge_one_part(args: tuple[list[tuple[list[Path], list[Path]]], list[int], NDArray[np.str_], dict[str, str],
                                float, int, tuple[str, ...]]) -> dict[str, Any]:
    """One merge part from its spill files: one sub-network per child, merged; its columns and counts.

    The sub-networks' point ids are the points' input indices (over all children), so the merged points'
    ids are their first constituent's input index (``key``: the whole merge's order); the real ids are
    looked up from it.
    """
    per_child, offsets, image_ids, metadata, tol, min_measures, optional = args
    nets = []
    index_parts, id_parts = [], []
    for (point_files, measure_files), off in zip(per_child, offsets):
        if not point_files:
            continue
        p = _load_parts(point_files)
        m = _load_parts(measure_files) if measure_files else {}
        local = p.pop("local")
        index_parts.append(local + off)
        id_parts.append(p.pop("point_ids"))
        mp = np.searchsorted(local, m["measure_point"]) if m else np.zeros(0, np.int64)
        cols: dict[str, Any] = {k: p[k] for k in POINT_COLUMNS}
        for name, (_, trail) in OPTIONAL_POINT_COLUMNS.items():
            cols[name] = p[name] if name in p else (np.full((local.size, *trail), np.nan) if name in optional else None)
        for name, (dtype, trail) in MEASURE_COLUMNS.items():
            cols[name] = m[name] if m else np.zeros((0, *trail), dtype)
        cols["measure_point"] = mp.astype(np.int64)
        nets.append(ControlNetwork(image_ids=image_ids, point_ids=index_parts[-1], metadata=metadata, **cols))
    if not nets:
        return {"n": 0}
    merged, stats = merge_part(nets, tol, min_measures)
    key = np.asarray(merged.point_ids, np.int64)
    index, ids = np.concatenate(index_parts), concatenate_ids(id_parts)  # index rises: children in order
    out: dict[str, Any] = {"n": merged.n_points, "stats": stats.to_dict(), "key": key,
                           "point_ids": ids[np.searchsorted(index, key)]}
    for name in (*POINT_COLUMNS, *MEASURE_COLUMNS):
        out[name] = getattr(merged, name)
    for name in optional:
        val = getattr(merged, name)
        out[name] = val if val is not None else np.full((merged.n_points, *OPTIONAL_POINT_COLUMNS[name][1]), np.nan)
    return out


def _active_sigma(cols: dict[str, Any]) -> NDArray[np.float64]:
    """The sigma of each active measure as ``problem_from_network`` takes it (mean of the finite ones, else 1)."""
    bad_point = cols["point_ignored"] | cols["point_rejected"]
    active = ~(cols["measure_ignored"] | cols["measure_rejected"] | bad_point[cols["measure_point"]])
    sig = np.asarray(cols["sigma"], np.float64)[active]
    finite = np.isfinite(sig)
    count = finite.sum(axis=1)
    out: NDArray[np.float64] = np.where(count > 0, np.where(finite, sig, 0.0).sum(axis=1) / np.maximum(count, 1), 1.0)
    return out


def stream_merge(
    unit: str,
    children: Sequence[tuple[str, str | Path]],
    out: str | Path,
    geometry: Callable[[NDArray[np.str_]], ImageTable],
    *,
    tolerance_px: float = 1.0,
    min_measures: int = 1,
    block_points: int = 25_000,
    part_measures: int = PART_MEASURES,
    overwrite: bool = False,
    map_parts: Callable[[Callable[[Any], Any], list[Any]], Iterable[Any]] | None = None,
    scratch: str | Path | None = None,
    clear_rejections: bool = False,
) -> StreamedMergeSummary:
    """Merge the children's stored networks into ``out`` by parts (the module docstring says how).

    Parameters
    ----------
    unit : the unit's name, for errors ("hemisphere 0")
    children : (name, network store path) of each child, in merge priority order (as ``merge_networks``)
    out : the output directory (``out/network``: the merged network with geometry and point blocks)
    geometry : the a-priori image table of the merged image ids (union of the children's, first appearance
        order): the caller's camera system
    tolerance_px, min_measures : as :func:`~mercury_dem.network.merge.merge_networks`
    block_points : points per block of the adjustment (as ``adjust.blocked_block_points``)
    part_measures : measures per part of the join and of the merge (memory of one part)
    map_parts : ``map_parts(function, items)`` gives the results in order (default: one after the other here)
    scratch : where the spill files go (default: next to ``out``; removed at the end)
    clear_rejections : the children's ``measure_rejected`` and ``point_rejected`` read as False (an adjusted
        child re-judged at the next level: :func:`~mercury_dem.adjust.cascade.rejudged_network`)

    Raises
    ------
    StoreError : a child's store missing, incomplete or damaged (naming the unit and the child); ``out``
        exists without ``overwrite``.
    """
    t_all = time.perf_counter()
    out = Path(out)
    if out.exists() and not overwrite:
        raise StoreError(f"{unit}: the merged network store {out} already exists; remove it or pass overwrite=True")
    if not children:
        raise StoreError(f"{unit}: no child network to merge")
    run_map: Callable[[Callable[[Any], Any], list[Any]], Iterable[Any]] = map_parts or (lambda f, xs: map(f, xs))
    stores = _open_children(unit, children)
    seconds: dict[str, float] = {}
    # the image table: union of the children's, in first appearance order (as merge_networks)
    all_ids = np.concatenate([s.image_ids for s in stores])
    uniq, first_idx, inv = np.unique(all_ids, return_index=True, return_inverse=True)
    order = np.argsort(first_idx, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    image_ids = uniq[order]
    img_off = np.concatenate([[0], np.cumsum([s.n_images for s in stores])])
    pt_off = np.concatenate([[0], np.cumsum([s.n_points for s in stores])]).astype(np.int64)
    kids = [_Child(name, s, int(pt_off[i]), rank[inv.ravel()[img_off[i]:img_off[i + 1]]].astype(np.int64),
                   tuple(s.attrs.get("optional_columns", [])))
            for i, ((name, _), s) in enumerate(zip(children, stores))]
    optional = tuple(n for n in OPTIONAL_POINT_COLUMNS if any(n in k.optional for k in kids))
    n_in = int(pt_off[-1])
    m_in = sum(s.n_measures for s in stores)
    n_img_parts = max(1, -(-m_in // max(1, part_measures)))
    rows = max(1, min(CHUNK_ROWS, part_measures))
    out.parent.mkdir(parents=True, exist_ok=True)
    scratch_dir = Path(tempfile.mkdtemp(prefix=f".{out.name}.spill-", dir=str(scratch or out.parent)))
    try:
        # 1. join: measures by image part; each part's pairs of input points sharing a near measure
        t0 = time.perf_counter()
        point_measures = np.zeros(n_in, np.int64)
        join_files: list[list[Path]] = [[] for _ in range(n_img_parts)]
        for c, kid in enumerate(kids):
            n_pts, n_img = kid.store.n_points, kid.store.n_images
            for r0, r1 in _chunks(kid.store.n_measures, rows):
                mp = _read(unit, kid, "measure_point", r0, r1)
                mi = _read(unit, kid, "measure_image", r0, r1)
                if mp.size and (mp.min() < 0 or mp.max() >= n_pts or mi.min() < 0 or mi.max() >= n_img):
                    raise StoreError(f"{unit}: the network of child {kid.name} ({kid.store.path}) has measures of "
                                     f"points or images outside its tables (rows {r0}-{r1}); re-run that child")
                gp = mp + kid.point_offset
                point_measures[kid.point_offset:kid.point_offset + n_pts] += np.bincount(mp, minlength=n_pts)
                gi = kid.image_map[mi]
                smp, lin = _read(unit, kid, "sample", r0, r1), _read(unit, kid, "line", r0, r1)
                part = gi % n_img_parts
                for q in np.unique(part):
                    sel = part == q
                    f = scratch_dir / f"join-{q}-{c}-{r0}.npz"
                    _save(f, {"point": gp[sel], "image": gi[sel], "sample": smp[sel], "line": lin[sel]})
                    join_files[int(q)].append(f)
        seconds["spill_join"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        edge_parts = list(run_map(_join_part, [(files, float(tolerance_px)) for files in join_files]))
        edges = np.concatenate(edge_parts) if edge_parts else np.zeros((0, 2), np.int64)
        del edge_parts
        for paths in join_files:
            for f in paths:
                f.unlink()
        seconds["join"] = time.perf_counter() - t0
        # 2. group: whole components into parts, in the order of their first input point
        t0 = time.perf_counter()
        point_part, n_parts = merge_partitions(point_measures, edges, part_measures)
        starts = part_starts(point_part, n_parts)
        n_pairs = int(len(edges))
        del edges, point_measures
        seconds["group"] = time.perf_counter() - t0
        # 3. spill every column by merge part (points with their child-local index; measures as stored)
        t0 = time.perf_counter()
        files: list[list[tuple[list[Path], list[Path]]]] = [[([], []) for _ in kids] for _ in range(n_parts)]
        for c, kid in enumerate(kids):
            n_pts = kid.store.n_points
            pcols = ("point_ids", *POINT_COLUMNS, *(n for n in optional if n in kid.optional))
            for r0, r1 in _chunks(n_pts, rows):
                part = point_part[kid.point_offset + r0:kid.point_offset + r1]
                data = {name: _read(unit, kid, name, r0, r1) for name in pcols}
                if clear_rejections:
                    data["point_rejected"] = np.zeros_like(data["point_rejected"])
                local = np.arange(r0, r1, dtype=np.int64)
                for q in np.unique(part):
                    sel = part == q
                    f = scratch_dir / f"points-{q}-{c}-{r0}.npz"
                    _save(f, {"local": local[sel], **{k: v[sel] for k, v in data.items()}})
                    files[int(q)][c][0].append(f)
            for r0, r1 in _chunks(kid.store.n_measures, rows):
                data = {name: _read(unit, kid, name, r0, r1) for name in MEASURE_COLUMNS}
                if clear_rejections:
                    data["measure_rejected"] = np.zeros_like(data["measure_rejected"])
                data["measure_image"] = kid.image_map[data["measure_image"]]
                part = point_part[kid.point_offset + data["measure_point"]]
                for q in np.unique(part):
                    sel = part == q
                    f = scratch_dir / f"measures-{q}-{c}-{r0}.npz"
                    _save(f, {k: v[sel] for k, v in data.items()})
                    files[int(q)][c][1].append(f)
        del point_part
        seconds["spill_merge"] = time.perf_counter() - t0
        # 4. merge the parts in order and append them to the output
        t0 = time.perf_counter()
        metadata = dict(stores[0].metadata)
        images = geometry(image_ids)
        if images.n_images != len(image_ids):
            raise StoreError(f"{unit}: the image geometry has {images.n_images} images for {len(image_ids)} merged ids")
        totals = dict.fromkeys(("n_points_joined", "n_measures_collapsed", "n_conflicts", "n_conflict_measures",
                                "n_points_dropped"), 0)
        ids_parts: list[NDArray[Any]] = []
        counts_parts: list[NDArray[np.int64]] = []
        sig_vals: dict[float, int] = {}
        n_out = m_out = 0
        with atomic_directory(out, overwrite=overwrite) as tmp:
            net = zarr.open_group(str(tmp / "network"), mode="w", zarr_format=3)
            write_strings(net, "image_ids", image_ids)
            point_cols = ColumnAppender(net, {**POINT_COLUMNS, **{n: OPTIONAL_POINT_COLUMNS[n] for n in optional}})
            measure_cols = ColumnAppender(net, MEASURE_COLUMNS)
            offsets = [k.point_offset for k in kids]
            items = [(files[q], offsets, image_ids, metadata, float(tolerance_px), int(min_measures), optional)
                     for q in range(n_parts)]
            pnames = ("point_ids", *POINT_COLUMNS, *optional)
            carry: dict[str, Any] | None = None
            for q, part in enumerate(run_map(_merge_one_part, items)):
                if part["n"] == 0:
                    continue
                for k in totals:
                    totals[k] += int(part["stats"][k])
                sig = _active_sigma(part)
                res, carry = release_in_order(carry, part, int(starts[q + 1]), pnames, tuple(MEASURE_COLUMNS))
                del part
                v, cnt = np.unique(sig, return_counts=True)
                for a, b in zip(v.tolist(), cnt.tolist()):
                    sig_vals[a] = sig_vals.get(a, 0) + int(b)
                point_cols.append({k: res[k] for k in (*POINT_COLUMNS, *optional)})
                mcols = {k: res[k] for k in MEASURE_COLUMNS}
                mcols["measure_point"] = mcols["measure_point"] + n_out
                measure_cols.append(mcols)
                ids_parts.append(res["point_ids"])
                counts_parts.append(np.bincount(res["measure_point"], minlength=len(res["key"])).astype(np.int64))
                n_out += len(res["key"])
                m_out += len(mcols["measure_point"])
                del res, mcols
            if carry is not None:
                raise StoreError(f"{unit}: the streamed merge left {len(carry['key'])} points unplaced (a bug)")
            point_cols.flush()
            measure_cols.flush()
            seconds["merge"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            ids = concatenate_ids(ids_parts)
            del ids_parts
            renumbered = bool(ids.size) and ids_collide(ids)
            if renumbered:
                ids = np.arange(n_out, dtype=np.int64)
            if ids.dtype.kind == "U":
                write_strings(net, "point_ids", ids)
                kind = "str"
            else:
                net.create_array("point_ids", data=ids.astype(np.int64), chunks=(max(1, min(CHUNK_ROWS, n_out)),))
                kind = "int64"
            del ids
            counts = np.concatenate(counts_parts) if counts_parts else np.zeros(0, np.int64)
            edges_b = block_edges(n_out, block_points)
            m_cum = np.concatenate([[0], np.cumsum(counts)])
            blocks = net.create_group("blocks")
            blocks.create_array("point_offsets", data=edges_b)
            blocks.create_array("measure_offsets", data=m_cum[edges_b].astype(np.int64))
            geo = net.create_group("geometry")
            geo.create_array("image_camera", data=np.asarray(images.image_camera, np.int64))
            geo.create_array("positions", data=np.asarray(images.positions, np.float64))
            geo.create_array("rotations", data=np.asarray(images.rotations, np.float64))
            geo.attrs["cameras"] = [camera_to_dict(cam) for cam in images.cameras]
            vals = np.array(sorted(sig_vals), np.float64)
            median_sigma = median_of_counts(vals, np.array([sig_vals[v] for v in sorted(sig_vals)], np.int64))
            net.attrs.update({
                "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "n_images": len(image_ids),
                "n_points": n_out, "n_measures": m_out, "point_id_kind": kind, "optional_columns": list(optional),
                "metadata": metadata,
                "streamed_merge": {"unit": unit, "children": [name for name, _ in children],
                                   "median_sigma_px": median_sigma, "block_points": int(block_points)},
            })
            (tmp / "network" / COMPLETE_MARKER).write_text("complete\n")
            seconds["finish"] = time.perf_counter() - t0
    finally:
        shutil.rmtree(scratch_dir, ignore_errors=True)
    seconds["total"] = time.perf_counter() - t_all
    stats = MergeStats(n_networks=len(kids), n_images=len(image_ids), n_points_in=n_in, n_measures_in=m_in,
                       n_points=n_out, n_measures=m_out, ids_renumbered=renumbered, **totals)
    return StreamedMergeSummary(
        path=out, stats=stats, n_blocks=len(edges_b) - 1, image_parts=n_img_parts, merge_parts=n_parts,
        join_pairs=n_pairs, median_sigma_px=median_sigma, seconds={k: round(v, 3) for k, v in seconds.items()},
    )


def stream_merged_network(
    unit: str,
    children: Sequence[tuple[str, str | Path]],
    scratch: str | Path,
    geometry: Callable[[NDArray[np.str_]], ImageTable],
    *,
    tolerance_px: float = 1.0,
    part_measures: int = PART_MEASURES,
    block_points: int = 25_000,
    clear_rejections: bool = False,
) -> tuple[ControlNetwork, StreamedMergeSummary]:
    """The children's merged network as :func:`~mercury_dem.network.merge.merge_networks` gives it (every image
    of the children kept, as ``MergeResult.network``), made by :func:`stream_merge` into ``scratch`` and read back.

    The merge itself holds one part at a time; what this returns is the whole merged network (one copy, never
    the children's networks beside it), for an adjustment that still needs it in memory. ``scratch`` is
    replaced if a failed attempt left it and removed once read. Raises :class:`StoreError` as ``stream_merge``.
    """
    from mercury_dem.io.network_store import read_network

    scratch = Path(scratch)
    try:
        summary = stream_merge(unit, children, scratch, geometry, tolerance_px=tolerance_px,
                               part_measures=part_measures, block_points=block_points, overwrite=True,
                               clear_rejections=clear_rejections)
        network = read_network(scratch / "network")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return network, summary


def stored_singular_parts(path: str | Path, limit: int = 20, rows: int = CHUNK_ROWS) -> dict[str, Any]:
    """:func:`~mercury_dem.network.check.singular_parts` of a stored merged network, read by row chunks.

    ``images_without_measures`` (sorted ids) and ``single_measure_points`` (count, the first ``limit`` ids), as
    ``singular_parts(merged_all, merged_all.drop_unused_images())`` gives them; what this holds is one count per
    image and per point (8 B a point), never the network. For a unit adjusted from its merged store.
    """
    store = NetworkStore(path)
    per_image = np.zeros(store.n_images, np.int64)
    per_point = np.zeros(store.n_points, np.int64)
    for r0, r1 in _chunks(store.n_measures, max(1, rows)):
        per_image += np.bincount(store.column_rows("measure_image", r0, r1), minlength=store.n_images)
        per_point += np.bincount(store.column_rows("measure_point", r0, r1), minlength=store.n_points)
    single = np.flatnonzero(per_point == 1)
    ids = [store.column_rows("point_ids", int(k), int(k) + 1)[0] for k in single[:limit]]
    return {
        "images_without_measures": sorted(str(i) for i in store.image_ids[per_image == 0]),
        "single_measure_points": {"count": int(single.size), "ids": [p.item() if hasattr(p, "item") else p for p in ids]},
    }
