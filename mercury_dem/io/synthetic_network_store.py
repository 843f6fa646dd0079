"""Synthetic networks streamed to disk, and the point-block reader of the blocked adjustment.

Layout of ``OUT`` (written under a temporary name, renamed when complete)::

    OUT/network/     a network store (mercury_dem.io.network_store: every column, readable by
                     open_network/read_network), plus
        geometry/    image_camera (K,), positions (K, 3) m, rotations (K, 3, 3) a-priori;
                     attrs "cameras": the distinct cameras (camera_to_dict)
        blocks/      point_offsets (B + 1,), measure_offsets (B + 1,): block b holds points
                     [point_offsets[b], point_offsets[b+1]) and their measures, contiguous
    OUT/truth/       true_rotations (K, 3, 3), pointing_error (K, 3), true_points (N, 3),
                     outlier (M,) -- kept apart; only validation reads it
    OUT/.complete

Blocks are generated one at a time (:func:`mercury_dem.network.synthetic.point_block`)
and appended to the Zarr arrays, so memory is bounded by one block, not the network.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.camera import camera_from_dict, camera_to_dict
from mercury_dem.io.atomic import COMPLETE_MARKER, atomic_directory, is_complete
from mercury_dem.io.network_store import CHUNK_ROWS, FORMAT_NAME, FORMAT_VERSION, NetworkStore, write_strings
from mercury_dem.network.blocks import BlockData, ImageTable
from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS, MeasureType, PointType
from mercury_dem.network.synthetic import SyntheticSpec, make_images, point_block


@dataclass(frozen=True)
class SynthSummary:
    """What :func:`write_synthetic_network` wrote."""

    path: Path
    images: int
    points: int
    measures: int
    blocks: int
    outliers: int
    seconds: float


def _empty(group: Any, name: str, dtype: str, trail: tuple[int, ...]) -> Any:
    return group.create_array(name, shape=(0, *trail), dtype=dtype, chunks=(CHUNK_ROWS, *(max(1, t) for t in trail)),
                              fill_value=np.nan if dtype.startswith("float") else 0)


class ColumnAppender:
    """Append-only Zarr columns, buffered to whole chunks so each chunk is written once."""

    def __init__(self, group: Any, columns: dict[str, tuple[str, tuple[int, ...]]]):
        self.arrays = {k: _empty(group, k, d, t) for k, (d, t) in columns.items()}
        self.buffers: dict[str, list[NDArray[Any]]] = {k: [] for k in columns}
        self.pending = 0

    def append(self, values: dict[str, NDArray[Any]]) -> None:
        for k, v in values.items():
            self.buffers[k].append(np.ascontiguousarray(v))
        self.pending += len(next(iter(values.values())))
        if self.pending >= CHUNK_ROWS:
            self.flush(whole_chunks_only=True)

    def flush(self, whole_chunks_only: bool = False) -> None:
        if self.pending == 0:
            return
        n = (self.pending // CHUNK_ROWS) * CHUNK_ROWS if whole_chunks_only else self.pending
        if n == 0:
            return
        for k, parts in self.buffers.items():
            data = np.concatenate(parts)
            self.arrays[k].append(data[:n])
            self.buffers[k] = [data[n:].copy()] if n < len(data) else []  # a copy: a view kept the whole alive
        self.pending -= n


def write_synthetic_network(
    spec: SyntheticSpec,
    out: str | Path,
    overwrite: bool = False,
    on_block: Callable[[int, int], None] | None = None,
) -> SynthSummary:
    """Generate the network of ``spec`` block by block into ``out`` (layout in the module docstring).

    Raises :class:`StoreError` when ``out`` exists and ``overwrite`` is False.
    ``on_block(done, total)`` is called after each block (progress).
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise StoreError(f"{out} already exists; remove it or pass --overwrite")
    t0 = time.perf_counter()
    images = make_images(spec)
    tree = cKDTree(images.target_unit)
    n_img = images.n_images
    with atomic_directory(out, overwrite=overwrite) as tmp:
        net = zarr.open_group(str(tmp / "network"), mode="w", zarr_format=3)
        truth = zarr.open_group(str(tmp / "truth"), mode="w", zarr_format=3)
        write_strings(net, "image_ids", np.array([f"SYN{i:07d}" for i in range(n_img)]))
        geo = net.create_group("geometry")
        geo.create_array("image_camera", data=images.image_camera)
        geo.create_array("positions", data=images.positions)
        geo.create_array("rotations", data=images.rotations)
        geo.attrs["cameras"] = [camera_to_dict(c) for c in images.cameras]
        truth.create_array("true_rotations", data=images.true_rotations)
        truth.create_array("pointing_error", data=images.pointing_error)
        point_cols = ColumnAppender(net, {"point_ids": ("int64", ()), **POINT_COLUMNS})
        measure_cols = ColumnAppender(net, MEASURE_COLUMNS)
        truth_pts = ColumnAppender(truth, {"true_points": ("float64", (3,))})
        truth_meas = ColumnAppender(truth, {"outlier": ("bool", ())})
        p_off, m_off = [0], [0]
        n_out = 0
        for b in range(spec.n_blocks):
            blk = point_block(spec, images, b, tree)
            n, m = blk.n_points, blk.n_measures
            start = p_off[-1]
            point_cols.append({
                "point_ids": np.arange(start, start + n, dtype=np.int64),
                "point_type": np.full(n, PointType.FREE, np.int8),
                "apriori_xyz": blk.apriori_points,
                "adjusted_xyz": np.full((n, 3), np.nan),
                "point_ignored": np.zeros(n, bool),
                "point_rejected": np.zeros(n, bool),
            })
            measure_cols.append({
                "measure_point": blk.measure_point + start,
                "measure_image": blk.measure_image,
                "sample": blk.measures[:, 0],
                "line": blk.measures[:, 1],
                "sigma": np.full((m, 2), spec.measure_sigma_px),
                "measure_type": np.full(m, MeasureType.REGISTERED_SUBPIXEL, np.int8),
                "measure_ignored": np.zeros(m, bool),
                "measure_rejected": np.zeros(m, bool),
                "residuals": np.full((m, 2), np.nan),
                "apriori_pixels": np.full((m, 2), np.nan),
            })
            truth_pts.append({"true_points": blk.true_points})
            truth_meas.append({"outlier": blk.outlier})
            n_out += int(blk.outlier.sum())
            p_off.append(start + n)
            m_off.append(m_off[-1] + m)
            if on_block is not None:
                on_block(b + 1, spec.n_blocks)
        for cols in (point_cols, measure_cols, truth_pts, truth_meas):
            cols.flush()
        blocks = net.create_group("blocks")
        blocks.create_array("point_offsets", data=np.array(p_off, np.int64))
        blocks.create_array("measure_offsets", data=np.array(m_off, np.int64))
        spec_attrs = {k: (list(v) if isinstance(v, tuple) else v) for k, v in spec.__dict__.items()}
        net.attrs.update({
            "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "n_images": n_img,
            "n_points": p_off[-1], "n_measures": m_off[-1], "point_id_kind": "int64", "optional_columns": [],
            "metadata": {"description": "synthetic network (mercury_dem.network.synthetic)", "seed": str(spec.seed)},
            "synthetic_spec": spec_attrs,
        })
        truth.attrs.update({"outliers": n_out, "synthetic_spec": spec_attrs})
        (tmp / "network" / COMPLETE_MARKER).write_text("complete\n")
    return SynthSummary(out, n_img, p_off[-1], m_off[-1], spec.n_blocks, n_out, time.perf_counter() - t0)


class BlockedNetwork:
    """A network store with image geometry and point blocks (as :func:`write_synthetic_network` writes).

    ``STORE`` may be the ``OUT`` directory (with ``network/`` and optionally ``truth/``)
    or the network group itself. Every fault is a :class:`StoreError` naming the store.
    """

    def __init__(self, path: str | Path):
        path = Path(path)
        self.root = path
        net_path = path / "network" if (path / "network").is_dir() else path
        self.store = NetworkStore(net_path)  # checks the completion marker, format and counts
        self.path = net_path
        g = self.store._group
        truth_path = net_path.parent / "truth" if net_path != path else path / "truth"
        self.truth_path = truth_path if truth_path.is_dir() and is_complete(net_path.parent) else None
        geo, blocks = self._group(g, "geometry"), self._group(g, "blocks")
        self.n_images, self.n_points, self.n_measures = self.store.n_images, self.store.n_points, self.store.n_measures
        try:
            cams = tuple(camera_from_dict(d) for d in geo.attrs["cameras"])
            if not cams:
                raise ValueError("no cameras")
        except Exception as exc:
            raise StoreError(f"network store {net_path}: geometry/cameras cannot be read: {exc}") from None
        ic = self._read(geo, "image_camera", "int64", (self.n_images,))
        if ic.size and (ic.min() < 0 or ic.max() >= len(cams)):
            raise StoreError(f"network store {net_path}: geometry/image_camera indexes a camera outside [0, {len(cams)})")
        self.images = ImageTable(cams, ic, self._read(geo, "positions", "float64", (self.n_images, 3)),
                                 self._read(geo, "rotations", "float64", (self.n_images, 3, 3)))
        bad = ~np.all(np.isfinite(self.images.positions), axis=1) | ~np.all(np.isfinite(self.images.rotations), axis=(1, 2))
        if bad.any():
            raise StoreError(f"network store {net_path}: the a-priori pose of {int(bad.sum())} images is NaN/inf "
                             f"(first image index {int(np.flatnonzero(bad)[0])})")
        self.point_offsets = self._read(blocks, "point_offsets", "int64", (None,))
        self.measure_offsets = self._read(blocks, "measure_offsets", "int64", (len(self.point_offsets),))
        for name, off, total in (("point_offsets", self.point_offsets, self.n_points),
                                 ("measure_offsets", self.measure_offsets, self.n_measures)):
            if len(off) < 2 or off[0] != 0 or off[-1] != total or np.any(np.diff(off) < 0):
                raise StoreError(f"network store {net_path}: blocks/{name} must rise from 0 to {total}")
        self.n_blocks = len(self.point_offsets) - 1
        self._truth: Any = None

    def _group(self, g: Any, name: str) -> Any:
        try:
            sub = g[name]
        except Exception:  # KeyError, or zarr's errors for damaged metadata (several types)
            sub = None
        if not isinstance(sub, zarr.Group):
            raise StoreError(f"network store {self.path} has no readable '{name}' group: adjust-network needs the image "
                             f"geometry and point blocks that synth-network writes (imported networks: not yet)")
        return sub

    def _read(self, group: Any, name: str, dtype: str, shape: tuple[int | None, ...], rows: slice | None = None) -> NDArray[Any]:
        try:
            arr = group[name]
        except Exception:  # KeyError, or zarr's errors for damaged metadata (several types)
            raise StoreError(f"network store {self.path}: no readable array '{group.path}/{name}'") from None
        ok = len(arr.shape) == len(shape) and all(e is None or a == e for a, e in zip(arr.shape, shape))
        if not isinstance(arr, zarr.Array) or arr.dtype != np.dtype(dtype) or not ok:
            raise StoreError(f"network store {self.path}: '{group.path}/{name}' is {getattr(arr, 'dtype', '?')} "
                             f"{getattr(arr, 'shape', '?')}, expected {dtype} {shape}")
        try:
            return np.asarray(arr[...] if rows is None else arr[rows])
        except Exception as exc:  # a damaged chunk: codec, size or decode errors of several types
            raise StoreError(f"network store {self.path}: '{group.path}/{name}' cannot be read: {exc}") from None

    def truth_images(self) -> NDArray[np.float64] | None:
        """True rotations (K, 3, 3), or None without truth."""
        if self.truth_path is None:
            return None
        return self._read(self._truth_group(), "true_rotations", "float64", (self.n_images, 3, 3))

    def _truth_group(self) -> Any:
        if self._truth is None:
            try:
                self._truth = zarr.open_group(str(self.truth_path), mode="r", zarr_format=3)
            except Exception as exc:  # zarr raises several types for a damaged group
                raise StoreError(f"truth of network store {self.path} ({self.truth_path}) cannot be opened: {exc}") from None
        return self._truth

    def read_block(self, b: int) -> BlockData:
        """Block ``b``'s points and measures (only the chunks holding them are read)."""
        if not 0 <= b < self.n_blocks:
            raise StoreError(f"network store {self.path}: block {b} outside [0, {self.n_blocks})")
        g = self.store._group
        p0, p1 = int(self.point_offsets[b]), int(self.point_offsets[b + 1])
        m0, m1 = int(self.measure_offsets[b]), int(self.measure_offsets[b + 1])
        ps, ms = slice(p0, p1), slice(m0, m1)
        n, m = self.n_points, self.n_measures
        mp = self._read(g, "measure_point", "int64", (m,), ms) - p0
        mi = self._read(g, "measure_image", "int64", (m,), ms)
        if mp.size and (mp.min() < 0 or mp.max() >= p1 - p0 or np.any(np.diff(mp) < 0)):
            raise StoreError(f"network store {self.path}: block {b}'s measures are not sorted by its points "
                             f"[{p0}, {p1}); the blocks table does not match the measures")
        if mi.size and (mi.min() < 0 or mi.max() >= self.n_images):
            raise StoreError(f"network store {self.path}: block {b} has measures of images outside [0, {self.n_images})")
        sig = self._read(g, "sigma", "float64", (m, 2), ms)
        # the adjustment's measures: as ControlNetwork.active_measures (not ignored, not rejected, nor their point)
        bad_point = self._read(g, "point_ignored", "bool", (n,), ps) | self._read(g, "point_rejected", "bool", (n,), ps)
        active = ~(self._read(g, "measure_ignored", "bool", (m,), ms) | self._read(g, "measure_rejected", "bool", (m,), ms)
                   | bad_point[mp])
        keep: slice | NDArray[np.intp] = slice(None) if active.all() else np.flatnonzero(active)
        mp, mi, sig = mp[keep], mi[keep], sig[keep]
        finite = np.isfinite(sig)
        count = finite.sum(axis=1)
        sigma = np.where(count > 0, np.where(finite, sig, 0.0).sum(axis=1) / np.maximum(count, 1), 1.0)  # as problem_from_network
        if np.any(sigma <= 0):
            raise StoreError(f"network store {self.path}: block {b} has measure sigmas <= 0 (must be positive pixels)")
        ap = self._read(g, "apriori_xyz", "float64", (n, 3), ps)
        meas = np.stack([self._read(g, "sample", "float64", (m,), ms), self._read(g, "line", "float64", (m,), ms)], axis=1)[keep]
        for what, arr in (("a-priori point coordinates", ap), ("measures (sample, line)", meas)):
            if not np.all(np.isfinite(arr)):
                raise StoreError(f"network store {self.path}: block {b} has NaN/inf {what}")
        outlier = true_points = None
        if self.truth_path is not None:
            t = self._truth_group()
            outlier = self._read(t, "outlier", "bool", (m,), ms)[keep]
            true_points = self._read(t, "true_points", "float64", (n, 3), ps)
        return BlockData(
            block=b, point_start=p0,
            apriori_points=ap, measure_image=mi, measure_point=mp, measures=meas,
            sigma=sigma,
            held_points=self._read(g, "point_type", "int8", (n,), ps) == PointType.FIXED,
            outlier=outlier, true_points=true_points,
        )


@dataclass(frozen=True)
class StoredBlocks:
    """Point blocks ``ids`` of the store at ``path``, read one at a time as they are iterated.

    What a :class:`~mercury_dem.adjust.blocked.BlockShard` is given when it is to read its own blocks (a Dask
    worker's actor): small to send, and only one block's raw data is held at a time (read, turned into its
    state by the shard, dropped).
    """

    path: str
    ids: tuple[int, ...]
    #: applied to every block as it is read (picklable: it goes to the workers), e.g. a unit's point prior
    #: centre and image renumbering (:class:`mercury_dem.adjust.unit_streamed.UnitBlockPrior`); None: as stored
    transform: Callable[[BlockData], BlockData] | None = None

    def __iter__(self) -> Iterator[BlockData]:
        net = BlockedNetwork(self.path)
        if self.transform is None:
            return (net.read_block(b) for b in self.ids)
        fn = self.transform
        return (fn(net.read_block(b)) for b in self.ids)

    def subset(self, ids: tuple[int, ...]) -> StoredBlocks:
        """The same store's blocks ``ids`` with the same transform (one worker's run of them)."""
        return StoredBlocks(self.path, tuple(int(b) for b in ids), self.transform)

    def __len__(self) -> int:
        return len(self.ids)


def split_synthetic_network(src: str | Path, outs: list[str | Path], overlap_blocks: int = 1, seed: int = 0,
                            jitter_px: float = 0.05, jitter_m: float = 1.0, overwrite: bool = False) -> list[int]:
    """Cut a synthetic network (:func:`write_synthetic_network`) into overlapping children: plain network stores.

    Child ``k`` of ``len(outs)`` takes an equal run of the point blocks, widened by ``overlap_blocks`` blocks on
    each side, so neighbouring children share the points of ``2 * overlap_blocks`` blocks (as neighbouring
    units share their border's points). A shared point's copy in the later child has its measures moved by
    N(0, ``jitter_px``) and its a-priori coordinates by N(0, ``jitter_m``) (seeded): a merge must join them
    (within its tolerance) and average them. Copied one block at a time (memory: one block).
    Returns the measures of each child.
    """
    net = BlockedNetwork(src)
    g = net.store._group
    rng = np.random.default_rng(seed)
    cuts = np.linspace(0, net.n_blocks, len(outs) + 1).round().astype(int)
    written = []
    for k, out in enumerate(outs):
        b0, b1 = max(0, cuts[k] - overlap_blocks), min(net.n_blocks, cuts[k + 1] + overlap_blocks)
        shared_until = cuts[k] + overlap_blocks if k > 0 else 0  # blocks shared with the previous child
        p_start = int(net.point_offsets[b0])
        m_total = 0
        with atomic_directory(Path(out), overwrite=overwrite) as tmp:
            grp = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            write_strings(grp, "image_ids", net.store.image_ids)
            pcols = ColumnAppender(grp, {"point_ids": ("int64", ()), **POINT_COLUMNS})
            mcols = ColumnAppender(grp, MEASURE_COLUMNS)
            for b in range(b0, b1):
                ps = slice(int(net.point_offsets[b]), int(net.point_offsets[b + 1]))
                ms = slice(int(net.measure_offsets[b]), int(net.measure_offsets[b + 1]))
                pv = {name: net._read(g, name, d, (net.n_points, *t), ps) for name, (d, t) in
                      {"point_ids": ("int64", ()), **POINT_COLUMNS}.items()}
                mv = {name: net._read(g, name, d, (net.n_measures, *t), ms) for name, (d, t) in MEASURE_COLUMNS.items()}
                mv["measure_point"] = mv["measure_point"] - p_start
                if b < shared_until:
                    pv["apriori_xyz"] = pv["apriori_xyz"] + rng.normal(0.0, jitter_m, pv["apriori_xyz"].shape)
                    for c in ("sample", "line"):
                        mv[c] = mv[c] + rng.normal(0.0, jitter_px, mv[c].shape)
                pcols.append(pv)
                mcols.append(mv)
                m_total += len(mv["measure_point"])
            pcols.flush()
            mcols.flush()
            grp.attrs.update({
                "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "n_images": net.n_images,
                "n_points": int(net.point_offsets[b1]) - p_start, "n_measures": m_total, "point_id_kind": "int64",
                "optional_columns": [], "metadata": {"description": f"child {k} of {src}"},
            })
        written.append(m_total)
    return written
