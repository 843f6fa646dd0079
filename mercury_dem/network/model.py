"""The control network: columnar images, points and measures tables.

A control network ties image measurements (measures) of the same ground
feature together (a point). It is held as a few aligned numpy arrays, never as
per-point Python objects, so that 10^7 points and 10^8 measures fit and every
operation is vectorized.

Conventions
-----------
* Images are identified by strings (our image ids, or ISIS serial numbers);
  everywhere else an image is its position in :attr:`ControlNetwork.image_ids`.
* Points carry an id (``int64`` for our networks, strings for ISIS ones such as
  ``"AS15_000031172"``); everywhere else a point is its position in
  :attr:`ControlNetwork.point_ids`.
* Coordinates are body-fixed metres; pixels are 0-based with the centre of the
  first pixel at (sample, line) = (0, 0). ISIS is 1-based (ISIS = ours + 1) and
  is converted in :mod:`mercury_dem.network.isis` only.
* NaN means "unknown" for every float column (adjusted coordinates before an
  adjustment, residuals, sigmas, a-priori pixels).
* Point and measure types use the ISIS enumeration values, so files map 1:1.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import NetworkError


class PointType(IntEnum):
    """Point types, with the values ISIS uses in its files."""

    FREE = 2
    CONSTRAINED = 3
    FIXED = 4


class MeasureType(IntEnum):
    """Measure types, with the values ISIS uses in its files."""

    CANDIDATE = 0
    MANUAL = 1
    REGISTERED_PIXEL = 2
    REGISTERED_SUBPIXEL = 3


#: Columns of the points table: name -> (dtype, trailing shape).
POINT_COLUMNS: dict[str, tuple[str, tuple[int, ...]]] = {
    "point_type": ("int8", ()),
    "apriori_xyz": ("float64", (3,)),
    "adjusted_xyz": ("float64", (3,)),
    "point_ignored": ("bool", ()),
    "point_rejected": ("bool", ()),
}
#: Optional columns of the points table (None when absent): upper-triangle
#: covariances (xx, xy, xz, yy, yz, zz) in m^2, NaN rows where unknown.
OPTIONAL_POINT_COLUMNS: dict[str, tuple[str, tuple[int, ...]]] = {
    "apriori_covariance": ("float64", (6,)),
    "adjusted_covariance": ("float64", (6,)),
}
#: Columns of the measures table.
MEASURE_COLUMNS: dict[str, tuple[str, tuple[int, ...]]] = {
    "measure_point": ("int64", ()),
    "measure_image": ("int64", ()),
    "sample": ("float64", ()),
    "line": ("float64", ()),
    "sigma": ("float64", (2,)),
    "measure_type": ("int8", ()),
    "measure_ignored": ("bool", ()),
    "measure_rejected": ("bool", ()),
    "residuals": ("float64", (2,)),
    "apriori_pixels": ("float64", (2,)),
}


def as_string_array(values: ArrayLike, what: str) -> NDArray[np.str_]:
    """A 1-D numpy unicode array of ``values`` (ids), raising on a bad shape."""
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise NetworkError(f"{what} must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        return np.zeros(0, dtype="U1")
    if arr.dtype.kind != "U":
        arr = arr.astype(str)
    return arr


def _as_point_ids(values: ArrayLike) -> NDArray[Any]:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise NetworkError(f"point_ids must be 1-D, got shape {arr.shape}")
    if arr.dtype.kind in "iu":
        return arr.astype(np.int64, copy=False)
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    return as_string_array(arr, "point_ids")


def _frozen(a: NDArray[Any]) -> NDArray[Any]:
    a = np.ascontiguousarray(a)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class ControlNetwork:
    """A control network as aligned columns (K images, N points, M measures).

    Build one with :meth:`from_arrays` (defaults for every optional column);
    the constructor itself takes every column and checks shapes and dtypes.
    Arrays are stored read-only: derive new networks with :meth:`replace`,
    :meth:`select_measures`, :meth:`subset_images`, ... never by mutation.

    Attributes
    ----------
    image_ids : ndarray of str, shape (K,)
        Image identifiers (our image ids or ISIS serial numbers); index = position.
    point_ids : ndarray of int64 or str, shape (N,)
    point_type : ndarray of int8, shape (N,)
        :class:`PointType` values (Free 2, Constrained 3, Fixed 4).
    apriori_xyz : ndarray of float64, shape (N, 3)
        A-priori body-fixed coordinates, metres (NaN when unknown).
    adjusted_xyz : ndarray of float64, shape (N, 3)
        Adjusted body-fixed coordinates, metres (NaN before an adjustment).
    point_ignored, point_rejected : ndarray of bool, shape (N,)
    measure_point : ndarray of int64, shape (M,)
        Point index of each measure.
    measure_image : ndarray of int64, shape (M,)
        Image index of each measure.
    sample, line : ndarray of float64, shape (M,)
        Measured pixel, 0-based, centre of the first pixel at (0, 0).
    sigma : ndarray of float64, shape (M, 2)
        Sample and line standard deviations, pixels (NaN: use the adjustment default).
    measure_type : ndarray of int8, shape (M,)
        :class:`MeasureType` values.
    measure_ignored, measure_rejected : ndarray of bool, shape (M,)
    residuals : ndarray of float64, shape (M, 2)
        Sample and line residuals (measured - computed) of the last adjustment, pixels (NaN before).
    apriori_pixels : ndarray of float64, shape (M, 2)
        Sample, line before registration (ISIS apriorisample/aprioriline), 0-based (NaN when unknown).
    apriori_covariance, adjusted_covariance : ndarray of float64, shape (N, 6), or None
        Upper triangle (xx, xy, xz, yy, yz, zz) of the point covariance, m^2.
    metadata : mapping of str to str
        Network-level text (network_id, target_name, description, ...).
    """

    image_ids: NDArray[np.str_]
    point_ids: NDArray[Any]
    point_type: NDArray[np.int8]
    apriori_xyz: NDArray[np.float64]
    adjusted_xyz: NDArray[np.float64]
    point_ignored: NDArray[np.bool_]
    point_rejected: NDArray[np.bool_]
    measure_point: NDArray[np.int64]
    measure_image: NDArray[np.int64]
    sample: NDArray[np.float64]
    line: NDArray[np.float64]
    sigma: NDArray[np.float64]
    measure_type: NDArray[np.int8]
    measure_ignored: NDArray[np.bool_]
    measure_rejected: NDArray[np.bool_]
    residuals: NDArray[np.float64]
    apriori_pixels: NDArray[np.float64]
    apriori_covariance: NDArray[np.float64] | None = None
    adjusted_covariance: NDArray[np.float64] | None = None
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "image_ids", _frozen(as_string_array(self.image_ids, "image_ids")))
        set_(self, "point_ids", _frozen(_as_point_ids(self.point_ids)))
        n, m = self.point_ids.shape[0], np.shape(self.measure_point)[0] if np.ndim(self.measure_point) else -1
        cols = {**POINT_COLUMNS, **MEASURE_COLUMNS}
        for name, (dtype, trail) in cols.items():
            rows = n if name in POINT_COLUMNS else m
            arr = np.asarray(getattr(self, name))
            if name in ("measure_point", "measure_image") and arr.size and arr.dtype.kind not in "iu":
                raise NetworkError(f"column '{name}' must hold integer indices, got dtype {arr.dtype}")
            if arr.shape != (rows, *trail):
                raise NetworkError(
                    f"column '{name}' has shape {arr.shape}, expected {(rows, *trail)} "
                    f"({'one row per point' if name in POINT_COLUMNS else 'one row per measure'})"
                )
            set_(self, name, _frozen(arr.astype(dtype, copy=False)))
        for name, (dtype, trail) in OPTIONAL_POINT_COLUMNS.items():
            val = getattr(self, name)
            if val is None:
                continue
            arr = np.asarray(val, dtype=dtype)
            if arr.shape != (n, *trail):
                raise NetworkError(f"column '{name}' has shape {arr.shape}, expected {(n, *trail)}")
            set_(self, name, _frozen(arr))
        set_(self, "metadata", {str(k): str(v) for k, v in dict(self.metadata).items()})

    # -- construction -----------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        image_ids: ArrayLike,
        point_ids: ArrayLike,
        measure_point: ArrayLike,
        measure_image: ArrayLike,
        sample: ArrayLike,
        line: ArrayLike,
        **columns: Any,
    ) -> ControlNetwork:
        """A network from the required columns; every other column gets its default.

        Defaults: Free points, NaN coordinates/sigmas/residuals/a-priori pixels,
        no flags set, measures of type RegisteredSubPixel, no covariances,
        empty metadata. Pass any column by name to override.
        """
        n = np.shape(point_ids)[0]
        m = np.shape(measure_point)[0]
        unknown = set(columns) - {f.name for f in fields(cls)}
        if unknown:
            raise NetworkError(f"unknown network column(s): {sorted(unknown)}")
        defaults: dict[str, Any] = {
            "point_type": np.full(n, PointType.FREE, np.int8),
            "apriori_xyz": np.full((n, 3), np.nan),
            "adjusted_xyz": np.full((n, 3), np.nan),
            "point_ignored": np.zeros(n, bool),
            "point_rejected": np.zeros(n, bool),
            "sigma": np.full((m, 2), np.nan),
            "measure_type": np.full(m, MeasureType.REGISTERED_SUBPIXEL, np.int8),
            "measure_ignored": np.zeros(m, bool),
            "measure_rejected": np.zeros(m, bool),
            "residuals": np.full((m, 2), np.nan),
            "apriori_pixels": np.full((m, 2), np.nan),
        }
        defaults.update(columns)
        return cls(
            image_ids=image_ids,  # type: ignore[arg-type]
            point_ids=point_ids,  # type: ignore[arg-type]
            measure_point=measure_point,  # type: ignore[arg-type]
            measure_image=measure_image,  # type: ignore[arg-type]
            sample=sample,  # type: ignore[arg-type]
            line=line,  # type: ignore[arg-type]
            **defaults,
        )

    @classmethod
    def empty(cls, image_ids: ArrayLike = ()) -> ControlNetwork:
        """A network with images but no points or measures."""
        z = np.zeros(0)
        return cls.from_arrays(image_ids, np.zeros(0, np.int64), z.astype(np.int64), z.astype(np.int64), z, z)

    def replace(self, **changes: Any) -> ControlNetwork:
        """A copy with some columns replaced (shapes re-checked)."""
        return replace(self, **changes)

    # -- sizes and lookups ------------------------------------------------
    @property
    def n_images(self) -> int:
        return int(self.image_ids.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.point_ids.shape[0])

    @property
    def n_measures(self) -> int:
        return int(self.measure_point.shape[0])

    def __repr__(self) -> str:
        return (
            f"ControlNetwork({self.n_images} images, {self.n_points} points, {self.n_measures} measures"
            f"{', ' + repr(self.metadata.get('network_id')) if self.metadata.get('network_id') else ''})"
        )

    def image_index(self, images: ArrayLike) -> NDArray[np.int64]:
        """Positions of image ids in the images table (raises naming unknown ids)."""
        return _lookup(self.image_ids, as_string_array(np.atleast_1d(images), "images"), "image")

    def point_index(self, ids: ArrayLike) -> NDArray[np.int64]:
        """Positions of point ids in the points table (raises naming unknown ids)."""
        q = np.atleast_1d(np.asarray(ids))
        if self.point_ids.dtype.kind == "U":
            q = q.astype(str)
        return _lookup(self.point_ids, q, "point")

    def _image_position(self, image: int | str) -> int:
        if isinstance(image, (str, np.str_)):
            return int(self.image_index([image])[0])
        i = int(image)
        if not 0 <= i < self.n_images:
            raise NetworkError(f"image index {i} out of range (network has {self.n_images} images)")
        return i

    def measures_of_image(self, image: int | str) -> NDArray[np.int64]:
        """Indices of the measures in one image (given by index or id), ascending."""
        return np.flatnonzero(self.measure_image == self._image_position(image))

    def measures_of_point(self, point: int) -> NDArray[np.int64]:
        """Indices of the measures of point ``point`` (a position), ascending."""
        return np.flatnonzero(self.measure_point == int(point))

    def measures_per_point(self, active_only: bool = False) -> NDArray[np.int64]:
        """Number of measures of each point, shape (N,)."""
        mp = self.measure_point[self.active_measures()] if active_only else self.measure_point
        return np.bincount(mp, minlength=self.n_points).astype(np.int64)

    def measures_per_image(self, active_only: bool = False) -> NDArray[np.int64]:
        """Number of measures in each image, shape (K,)."""
        mi = self.measure_image[self.active_measures()] if active_only else self.measure_image
        return np.bincount(mi, minlength=self.n_images).astype(np.int64)

    def active_measures(self) -> NDArray[np.bool_]:
        """Measures an adjustment uses: not ignored, not rejected, and their point neither."""
        bad_point = self.point_ignored | self.point_rejected
        return ~(self.measure_ignored | self.measure_rejected | bad_point[self.measure_point])

    def pixels(self) -> NDArray[np.float64]:
        """Measured pixels (M, 2): sample, line (0-based)."""
        return np.stack([self.sample, self.line], axis=-1)

    def point_latlon(self, adjusted: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Planetocentric latitude, east longitude [0, 360) (degrees) and radius (m) of the points."""
        xyz = self.adjusted_xyz if adjusted else self.apriori_xyz
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        with np.errstate(over="ignore"):  # coordinates past ~1e154 m (a damaged file): r by hypot below
            r = np.sqrt(x * x + y * y + z * z)
        big = np.isinf(r) & np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        if big.any():
            with np.errstate(over="ignore"):  # inf only when the radius itself exceeds float64
                r = np.where(big, np.hypot(np.hypot(x, y), z), r)
        lat = np.degrees(np.arctan2(z, np.hypot(x, y)))
        lon = np.mod(np.degrees(np.arctan2(y, x)), 360.0)
        return lat, np.where(lon >= 360.0, 0.0, lon), r

    # -- derived networks -------------------------------------------------
    def take_points(self, points: ArrayLike, keep_images: bool = True) -> ControlNetwork:
        """The network restricted to some points (indices in the wanted order, or a bool mask).

        Measures of the other points are dropped. Images are kept unless
        ``keep_images`` is False, in which case images left without measures
        are dropped too.
        """
        idx = _as_index(points, self.n_points, "points")
        new_of_old = np.full(self.n_points, -1, np.int64)
        new_of_old[idx] = np.arange(idx.size)
        mpos = new_of_old[self.measure_point]
        order = np.flatnonzero(mpos >= 0)
        if np.any(np.diff(idx) <= 0):  # points reordered: group measures in the new point order
            order = order[np.argsort(mpos[order], kind="stable")]
        cols = _take_points_columns(self, idx)
        cols.update(take_measure_columns(self, order))
        cols["measure_point"] = mpos[order]
        net = replace(self, **cols)
        return net if keep_images else net.drop_unused_images()

    def select_measures(self, mask: ArrayLike, min_measures: int = 1, keep_images: bool = True) -> ControlNetwork:
        """The network with only the measures in ``mask`` (bool (M,) or indices).

        Points left with fewer than ``min_measures`` measures are dropped.
        """
        idx = _as_index(mask, self.n_measures, "measures")
        net = replace(self, **take_measure_columns(self, idx))
        counts = np.bincount(net.measure_point, minlength=self.n_points)
        if min_measures > 0 or not keep_images:
            net = net.take_points(np.flatnonzero(counts >= min_measures), keep_images=keep_images)
        return net

    def subset_images(self, images: ArrayLike, min_measures: int = 1) -> ControlNetwork:
        """The network seen by some images (ids, indices or a bool mask over the images table).

        The images table becomes the selected images (in the given order);
        measures in other images are dropped, then points left with fewer than
        ``min_measures`` measures.
        """
        arr = np.asarray(images)
        if arr.dtype.kind in "US":
            idx = self.image_index(arr)
        else:
            idx = _as_index(arr, self.n_images, "images")
        new_of_old = np.full(self.n_images, -1, np.int64)
        new_of_old[idx] = np.arange(idx.size)
        mi = new_of_old[self.measure_image]
        keep = mi >= 0
        net = replace(self, image_ids=self.image_ids[idx], **take_measure_columns(self, np.flatnonzero(keep)))
        net = replace(net, measure_image=mi[keep])
        counts = np.bincount(net.measure_point, minlength=net.n_points)
        return net.take_points(np.flatnonzero(counts >= min_measures))

    def drop_unused_images(self) -> ControlNetwork:
        """The network without images that have no measure (order of the rest kept)."""
        used = np.bincount(self.measure_image, minlength=self.n_images) > 0
        if used.all():
            return self
        new_of_old = np.cumsum(used) - 1
        return replace(self, image_ids=self.image_ids[used], measure_image=new_of_old[self.measure_image])

    def sorted(self) -> ControlNetwork:
        """The same network with measures ordered by (point, image), a canonical order."""
        order = np.lexsort((self.measure_image, self.measure_point))
        if np.array_equal(order, np.arange(order.size)):
            return self
        return replace(self, **take_measure_columns(self, order))

    def with_adjustment(
        self,
        adjusted_xyz: ArrayLike,
        residuals: ArrayLike,
        measure_rejected: ArrayLike | None = None,
        adjusted_covariance: ArrayLike | None = None,
    ) -> ControlNetwork:
        """The network with the results of a bundle adjustment recorded."""
        changes: dict[str, Any] = {"adjusted_xyz": adjusted_xyz, "residuals": residuals}
        if measure_rejected is not None:
            changes["measure_rejected"] = measure_rejected
        if adjusted_covariance is not None:
            changes["adjusted_covariance"] = adjusted_covariance
        return replace(self, **changes)

    # -- comparison and export ----------------------------------------------
    def equals(self, other: ControlNetwork, check_metadata: bool = False, atol: float = 0.0) -> bool:
        """True when both networks hold the same columns (NaN equal to NaN)."""
        return not self.differences(other, check_metadata=check_metadata, atol=atol)

    def differences(self, other: ControlNetwork, check_metadata: bool = False, atol: float = 0.0) -> list[str]:
        """Names of the columns that differ (empty when the networks are equal)."""
        out = []
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if f.name == "metadata":
                if check_metadata and dict(a) != dict(b):
                    out.append(f.name)
                continue
            if a is None or b is None:  # an absent optional column equals an all-NaN one
                present = b if a is None else a
                if present is not None and not np.all(np.isnan(present)):
                    out.append(f.name)
                continue
            if a.shape != b.shape:
                out.append(f.name)
            elif a.dtype.kind == "f":
                if not np.allclose(a, b, rtol=0.0, atol=atol, equal_nan=True):
                    out.append(f.name)
            elif a.dtype.kind != b.dtype.kind or not np.array_equal(a, b):
                out.append(f.name)
        return out

    def points_frame(self) -> Any:
        """The points table as a pandas DataFrame (one row per point)."""
        import pandas as pd

        lat, lon, r = self.point_latlon()
        return pd.DataFrame(
            {
                "point_id": self.point_ids, "type": self.point_type,
                "apriori_x": self.apriori_xyz[:, 0], "apriori_y": self.apriori_xyz[:, 1],
                "apriori_z": self.apriori_xyz[:, 2], "lat": lat, "lon": lon, "radius": r,
                "adjusted_x": self.adjusted_xyz[:, 0], "adjusted_y": self.adjusted_xyz[:, 1],
                "adjusted_z": self.adjusted_xyz[:, 2], "ignored": self.point_ignored,
                "rejected": self.point_rejected, "n_measures": self.measures_per_point(),
            }
        )

    def measures_frame(self) -> Any:
        """The measures table as a pandas DataFrame (one row per measure, ids resolved)."""
        import pandas as pd

        return pd.DataFrame(
            {
                "point": self.measure_point, "point_id": self.point_ids[self.measure_point],
                "image": self.measure_image, "image_id": self.image_ids[self.measure_image],
                "sample": self.sample, "line": self.line,
                "sigma_sample": self.sigma[:, 0], "sigma_line": self.sigma[:, 1],
                "type": self.measure_type, "ignored": self.measure_ignored, "rejected": self.measure_rejected,
                "residual_sample": self.residuals[:, 0], "residual_line": self.residuals[:, 1],
            }
        )


# -- helpers shared by the network modules -------------------------------------


def _lookup(table: NDArray[Any], query: NDArray[Any], what: str) -> NDArray[np.int64]:
    if table.size == 0:
        if query.size:
            raise NetworkError(f"{what} id {query[0]!r} not in the network (it has no {what}s)")
        return np.zeros(0, np.int64)
    order = np.argsort(table, kind="stable")
    pos = np.searchsorted(table[order], query)
    pos = np.minimum(pos, table.size - 1)
    found = table[order][pos] == query
    if not np.all(found):
        missing = query[~found]
        raise NetworkError(
            f"{missing.size} {what} id(s) not in the network, e.g. {missing[0]!r}; "
            f"check the ids (or the serial-number mapping)"
        )
    return order[pos].astype(np.int64)


def _as_index(sel: ArrayLike, n: int, what: str) -> NDArray[np.int64]:
    arr = np.asarray(sel)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise NetworkError(f"{what} mask has shape {arr.shape}, expected ({n},)")
        return np.flatnonzero(arr)
    idx = arr.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise NetworkError(f"{what} index out of range [0, {n})")
    return idx


def _take_points_columns(net: ControlNetwork, idx: NDArray[np.int64]) -> dict[str, Any]:
    cols: dict[str, Any] = {"point_ids": net.point_ids[idx]}
    for name in POINT_COLUMNS:
        cols[name] = getattr(net, name)[idx]
    for name in OPTIONAL_POINT_COLUMNS:
        val = getattr(net, name)
        cols[name] = None if val is None else val[idx]
    return cols


def take_measure_columns(net: ControlNetwork, idx: NDArray[np.int64]) -> dict[str, Any]:
    """Every measure column of ``net`` (``MEASURE_COLUMNS``) at the measures ``idx``, by column name."""
    return {name: getattr(net, name)[idx] for name in MEASURE_COLUMNS}


def concatenate_ids(id_arrays: Sequence[NDArray[Any]]) -> NDArray[Any]:
    """Concatenate point-id arrays; mixing int and str ids gives str ids."""
    if not id_arrays:
        return np.zeros(0, np.int64)
    if all(a.dtype.kind in "iu" for a in id_arrays):
        return np.concatenate([a.astype(np.int64) for a in id_arrays])
    return np.concatenate([a.astype(str) for a in id_arrays])
