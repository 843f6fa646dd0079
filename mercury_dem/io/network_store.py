"""Control networks on disk as a Zarr v3 group.

Layout of a network group (every column of :class:`ControlNetwork` is one array)::

    NET/                       zarr.json attributes: format, format_version, counts, metadata, point_id_kind
      image_ids/data  uint8    UTF-8 bytes of all image ids, back to back
      image_ids/offsets int64  (K + 1,) start of each id in data
      point_ids        int64   (N,)            -- integer ids, or
      point_ids/data, /offsets                 -- string ids (ISIS), as for image_ids
      point_type, apriori_xyz, ..., measure_point, sample, ...  one array per column
      .complete                written last (see mercury_dem.io.atomic)

Strings are stored as bytes plus offsets (:mod:`mercury_dem.network.strings`) rather than as a Zarr string dtype:
fixed-width and variable-length string types are not part of the Zarr v3 core
spec (zarr-python warns about them) and bytes + offsets are compact and fast.

Writes are atomic: the group is written under a temporary sibling name and
renamed into place when complete. :func:`open_network` reads only the group's
attributes and the images table; columns load on demand.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
import zarr
from numpy.typing import NDArray

from mercury_dem.exceptions import NetworkError, StoreError
from mercury_dem.io.atomic import atomic_directory, is_complete
from mercury_dem.network.model import (
    MEASURE_COLUMNS,
    OPTIONAL_POINT_COLUMNS,
    POINT_COLUMNS,
    ControlNetwork,
)
from mercury_dem.network.strings import decode_strings, encode_strings

FORMAT_NAME = "mercury_dem.control_network"
FORMAT_VERSION = 1
#: Rows per chunk of the points and measures columns.
CHUNK_ROWS = 1 << 20


def _chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    return (max(1, min(CHUNK_ROWS, shape[0])),) + tuple(max(1, s) for s in shape[1:])


def _write_array(group: Any, name: str, arr: NDArray[Any]) -> None:
    group.create_array(name, data=np.ascontiguousarray(arr), chunks=_chunks(arr.shape))


def write_strings(group: Any, name: str, values: NDArray[Any]) -> None:
    """A string column as the subgroup ``name`` of ``group``: arrays ``data`` (UTF-8 bytes) and ``offsets``."""
    data, offsets = encode_strings(values)
    sub = group.create_group(name)
    _write_array(sub, "data", data)
    _write_array(sub, "offsets", offsets)


def write_network(network: ControlNetwork, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``network`` as a Zarr v3 group at ``path``, atomically.

    Raises :class:`StoreError` when ``path`` exists and ``overwrite`` is False.
    Returns the path.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise StoreError(f"network store {path} already exists; remove it or pass overwrite=True")
    with atomic_directory(path, overwrite=overwrite) as tmp:
        g = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        write_strings(g, "image_ids", network.image_ids)
        if network.point_ids.dtype.kind == "U":
            write_strings(g, "point_ids", network.point_ids)
            kind = "str"
        else:
            _write_array(g, "point_ids", network.point_ids)
            kind = "int64"
        for name in (*POINT_COLUMNS, *MEASURE_COLUMNS):
            _write_array(g, name, getattr(network, name))
        present = []
        for name in OPTIONAL_POINT_COLUMNS:
            val = getattr(network, name)
            if val is not None:
                _write_array(g, name, val)
                present.append(name)
        g.attrs.update(
            {
                "format": FORMAT_NAME,
                "format_version": FORMAT_VERSION,
                "n_images": network.n_images,
                "n_points": network.n_points,
                "n_measures": network.n_measures,
                "point_id_kind": kind,
                "optional_columns": present,
                "metadata": dict(network.metadata),
            }
        )
    return path


class NetworkStore:
    """A network group opened for reading; columns load on demand.

    Attributes ``n_images``, ``n_points``, ``n_measures`` and ``metadata`` come
    from the group attributes; :attr:`image_ids` and :meth:`column` read arrays.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_dir():
            raise StoreError(f"network store {self.path} does not exist")
        if not is_complete(self.path):
            raise StoreError(
                f"network store {self.path} is incomplete (no completion marker): it was not fully "
                f"written; re-run the step that writes it"
            )
        try:
            self._group = zarr.open_group(str(self.path), mode="r", zarr_format=3)
            attrs: dict[str, Any] = dict(self._group.attrs)
        except Exception as exc:  # zarr raises several types for a damaged group
            raise StoreError(f"network store {self.path} cannot be opened as Zarr: {exc}") from exc
        if attrs.get("format") != FORMAT_NAME:
            raise StoreError(f"{self.path} is not a control network store (format {attrs.get('format')!r})")
        version = attrs.get("format_version")
        if not _is_count(version):
            raise StoreError(f"network store {self.path}: attribute format_version is {version!r}, not an integer")
        if version > FORMAT_VERSION:
            raise StoreError(
                f"network store {self.path} has format version {attrs['format_version']}, newer than this "
                f"mercury_dem reads ({FORMAT_VERSION}); upgrade mercury_dem"
            )
        for key in ("n_images", "n_points", "n_measures"):
            if not _is_count(attrs.get(key)):
                raise StoreError(f"network store {self.path}: attribute {key} is {attrs.get(key)!r}, not a count")
        metadata, optional = attrs.get("metadata", {}), attrs.get("optional_columns", [])
        if not isinstance(metadata, dict):
            raise StoreError(f"network store {self.path}: attribute metadata is not a mapping")
        if not (isinstance(optional, list) and all(isinstance(c, str) for c in optional)):
            raise StoreError(f"network store {self.path}: attribute optional_columns is not a list of names")
        if attrs.get("point_id_kind") not in ("int64", "str"):
            raise StoreError(f"network store {self.path}: attribute point_id_kind is {attrs.get('point_id_kind')!r}")
        self.attrs = attrs
        self.n_images = int(attrs["n_images"])
        self.n_points = int(attrs["n_points"])
        self.n_measures = int(attrs["n_measures"])
        self.metadata: dict[str, str] = {str(k): str(v) for k, v in metadata.items()}
        self._image_ids: NDArray[np.str_] | None = None

    def __repr__(self) -> str:
        return f"NetworkStore({str(self.path)!r}: {self.n_images} images, {self.n_points} points, {self.n_measures} measures)"

    @property
    def image_ids(self) -> NDArray[np.str_]:
        if self._image_ids is None:
            self._image_ids = self._strings("image_ids", self.n_images)
        return self._image_ids

    def _array(self, name: str, dtype: str, shape: tuple[int | None, ...], rows: slice | None = None) -> NDArray[Any]:
        """One array (``rows`` of it), checked against the dtype and shape (None: any length) it must have before it is read."""
        try:
            arr = self._group[name]
        except KeyError:
            raise StoreError(f"network store {self.path} has no column '{name}'") from None
        except Exception as exc:  # zarr raises many types for damaged metadata
            raise StoreError(f"network store {self.path}: column '{name}' cannot be opened: {exc}") from exc
        if not isinstance(arr, zarr.Array):
            raise StoreError(f"network store {self.path}: '{name}' is not an array")
        ok_shape = len(arr.shape) == len(shape) and all(e is None or a == e for a, e in zip(arr.shape, shape))
        if arr.dtype != np.dtype(dtype) or not ok_shape:
            want = tuple("n" if e is None else e for e in shape)
            raise StoreError(f"network store {self.path}: column '{name}' is {arr.dtype} {arr.shape}, "
                             f"expected {dtype} {want}")
        try:
            return np.asarray(arr[...] if rows is None else arr[rows])
        except Exception as exc:  # a damaged chunk: codec, size or decode errors of several types
            raise StoreError(f"network store {self.path}: column '{name}' cannot be read: {exc}") from exc

    def _strings(self, name: str, n: int) -> NDArray[np.str_]:
        offsets = self._array(f"{name}/offsets", "int64", (n + 1,))
        if offsets[0] != 0 or np.any(np.diff(offsets) < 0):
            raise StoreError(f"network store {self.path}: '{name}/offsets' are not increasing from 0")
        data = self._array(f"{name}/data", "uint8", (int(offsets[-1]),))
        try:
            return decode_strings(data, offsets)
        except UnicodeDecodeError as exc:
            raise StoreError(f"network store {self.path}: '{name}' is not UTF-8 ({exc.reason})") from None

    def column_rows(self, name: str, start: int, stop: int) -> NDArray[Any]:
        """Rows ``[start, stop)`` of a point or measure column (integer ``point_ids`` too): only their chunks are read.

        For readers that stream a network by parts (:mod:`mercury_dem.io.merged_network_store`). String point
        ids are read whole (their offsets index one byte array) and sliced.
        """
        if name == "point_ids":
            if self.attrs.get("point_id_kind") == "str":
                return self._strings("point_ids", self.n_points)[start:stop]
            return self._array(name, "int64", (self.n_points,), slice(start, stop))
        for table, n in ((POINT_COLUMNS, self.n_points), (OPTIONAL_POINT_COLUMNS, self.n_points),
                         (MEASURE_COLUMNS, self.n_measures)):
            if name in table:
                dtype, trail = table[name]
                return self._array(name, dtype, (n, *trail), slice(start, stop))
        raise StoreError(f"network store {self.path} has no column '{name}'")

    def column(self, name: str) -> NDArray[Any]:
        """One column as a numpy array (``point_ids`` and ``image_ids`` decoded)."""
        if name == "image_ids":
            return self.image_ids
        if name == "point_ids":
            if self.attrs.get("point_id_kind") == "str":
                return self._strings("point_ids", self.n_points)
            return self._array(name, "int64", (self.n_points,))
        for table, rows in ((POINT_COLUMNS, self.n_points), (OPTIONAL_POINT_COLUMNS, self.n_points),
                            (MEASURE_COLUMNS, self.n_measures)):
            if name in table:
                dtype, trail = table[name]
                return self._array(name, dtype, (rows, *trail))
        raise StoreError(f"network store {self.path} has no column '{name}'")

    def load(self) -> ControlNetwork:
        """The whole network in memory."""
        cols: dict[str, Any] = {name: self.column(name) for name in (*POINT_COLUMNS, *MEASURE_COLUMNS)}
        for name in OPTIONAL_POINT_COLUMNS:
            cols[name] = self.column(name) if name in self.attrs.get("optional_columns", []) else None
        for name, n in (("measure_point", self.n_points), ("measure_image", self.n_images)):
            if cols[name].size and (cols[name].min() < 0 or cols[name].max() >= n):
                raise StoreError(f"network store {self.path}: column '{name}' has an index outside [0, {n})")
        try:
            return ControlNetwork(
                image_ids=self.image_ids, point_ids=self.column("point_ids"), metadata=self.metadata, **cols
            )
        except NetworkError as exc:
            raise StoreError(f"network store {self.path}: {exc}") from None


def _is_count(v: Any) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**62


def open_network(path: str | Path) -> NetworkStore:
    """Open a network store lazily (attributes only)."""
    return NetworkStore(path)


def read_network(path: str | Path) -> ControlNetwork:
    """Read a whole network written by :func:`write_network`."""
    return NetworkStore(path).load()
