"""The mission store: the seam between where images come from and every stage.

A mission is the same on disk whether ``mercury-dem synth`` or ``mercury-dem ingest``
wrote it (both through :class:`MissionWriter`)::

    MISSION/
      mission.json      format, version, source, body, counts, the writer's facts
      cameras.json      the camera table: camera id -> camera fields (mercury_dem.mission.cameras)
      catalog.parquet   one row per image (mercury_dem.mission.catalog.CATALOG_COLUMNS): ids, camera id,
                        time, A-PRIORI pose, sun, centre, pixel scale, angles, tile, footprint, radiometry
      images.zarr/      one Zarr v3 array per image id (one chunk per image): uint8, uint16, int16
                        or float32; in float images NaN marks invalid (ISIS special) pixels
      sources.json      (ingested missions) image id -> the files it was read from
      altimetry/        (optional) laser-altimeter shots, Parquet partitioned by tile
                        (mercury_dem.altimetry.store): ``mission.altimetry``
      truth/            (synthetic missions) read only by validation: mercury_dem.mission.truth
      .complete         written last (mercury_dem.io.atomic)

Version 1 missions (synthetic, before the camera table) are read too: their cameras
are the MDIS presets named by instrument and size, their body Mercury, their pixels
12-bit DN.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import MERCURY, Body
from mercury_dem.geometry.camera import FramingCamera, camera_preset
from mercury_dem.io.atomic import COMPLETE_MARKER, atomic_write_json, is_complete
from mercury_dem.io.names import check_name, name_fault
from mercury_dem.io.tables import column_to_numpy, read_arrow_table, read_table
from mercury_dem.mission.cameras import camera_from_dict, camera_to_dict
from mercury_dem.mission.catalog import (
    CATALOG_COLUMNS,
    CATALOG_COLUMNS_V1,
    FOOTPRINT_COLUMNS,
    POSITION_COLUMNS,
    ROTATION_COLUMNS,
    SUN_COLUMNS,
)
from mercury_dem.mission.radiometry import DN12, Radiometry
from mercury_dem.mission.truth import SyntheticTruth, open_truth

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa

FORMAT = "mercury-dem-mission"
VERSION = 2
IMAGE_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.int16), np.dtype(np.float32))


# --------------------------------------------------------------------------- writing
class MissionWriter:
    """Writes a mission directory under construction (inside :func:`~mercury_dem.io.atomic.atomic_directory`).

    ``write_image`` is safe from parallel workers (one array per image);
    ``finish`` writes the tables last.
    """

    def __init__(self, root: str | Path) -> None:
        import zarr

        self.root = Path(root)
        zarr.open_group(str(self.root / "images.zarr"), mode="w")

    @staticmethod
    def write_image(root: str | Path, image_id: str, image: NDArray[Any]) -> None:
        """Write one image as ``images.zarr/<image_id>``; NaN marks invalid pixels of a float image."""
        write_image(root, image_id, image)

    def write_altimetry(self, table: pd.DataFrame, *, sources: Any, body: Body, tile_size_deg: float = 10.0,
                        extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Write the mission's altimetry store ``altimetry/`` (see :mod:`mercury_dem.altimetry.store`)."""
        from mercury_dem.altimetry.store import write_altimetry

        return write_altimetry(self.root / "altimetry", table, sources=sources, datum_radius_m=body.datum_radius_m,
                               tile_size_deg=tile_size_deg, extra=extra)

    def finish(
        self,
        meta: dict[str, Any],
        body: Body,
        cameras: dict[str, FramingCamera],
        catalog: pd.DataFrame,
        sources: dict[str, Any] | None = None,
    ) -> None:
        """Write cameras.json, catalog.parquet, sources.json and mission.json (last)."""
        missing = [c for c in CATALOG_COLUMNS if c not in catalog.columns]
        if missing:
            raise StoreError(f"catalog lacks columns {missing}; the mission would not be readable")
        unknown = sorted(set(catalog["camera_id"].astype(str)) - set(cameras))
        if unknown:
            raise StoreError(f"catalog names cameras {unknown} that are not in the camera table")
        atomic_write_json(self.root / "cameras.json", {k: camera_to_dict(c) for k, c in cameras.items()})
        extra = [c for c in catalog.columns if c not in CATALOG_COLUMNS]
        catalog[CATALOG_COLUMNS + extra].to_parquet(self.root / "catalog.parquet", index=False)
        if sources is not None:
            atomic_write_json(self.root / "sources.json", sources)
        atomic_write_json(self.root / "mission.json", {
            "format": FORMAT, "version": VERSION, **meta, "body": body.to_dict(), "n_images": int(len(catalog)),
        })


def write_image(root: str | Path, image_id: str, image: NDArray[Any]) -> None:
    """Write one image as its own array ``images.zarr/<image_id>`` (safe from parallel workers)."""
    import zarr

    try:
        check_name(image_id, "image id")
    except ValueError as exc:
        raise StoreError(f"mission {root}: {exc}; nothing was written for it") from None
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype not in IMAGE_DTYPES:
        raise StoreError(f"image {image_id}: expected a 2-D array of {[str(d) for d in IMAGE_DTYPES]}, "
                         f"got {img.dtype} {img.shape}")
    arr = zarr.create_array(
        store=str(Path(root) / "images.zarr" / image_id), shape=img.shape, chunks=img.shape, dtype=img.dtype,
        overwrite=True,
    )
    arr[...] = img


# --------------------------------------------------------------------------- reading
class Mission:
    """A mission on disk: catalog, camera table, body, image reader; truth when synthetic.

    Use :func:`open_mission`. Attributes: ``path``, ``meta`` (mission.json), ``catalog``
    (DataFrame, a-priori geometry only), ``body`` (:class:`~mercury_dem.geometry.body.Body`),
    ``cameras`` (camera id -> camera), ``truth`` (:class:`SyntheticTruth` or None).

    The catalog is held as the Arrow table read from ``catalog.parquet``; :meth:`column` gives one
    column as a numpy array, and ``catalog`` (the pandas DataFrame, exactly what ``pd.read_parquet``
    gives) is read on first use. Why: pandas' import alone costs ~0.3 s CPU, more than everything else
    ``mercury-dem info`` does; the poses, ids and image sizes every stage needs come from the columns.
    """

    def __init__(self, path: Path, meta: dict[str, Any], catalog: pd.DataFrame | pa.Table,
                 cameras: dict[str, FramingCamera], body: Body) -> None:
        self.path = path
        self.meta = meta
        self.cameras = cameras
        self.body = body
        if hasattr(catalog, "to_pandas"):  # a pyarrow Table read from path/catalog.parquet
            self._table: pa.Table | None = catalog
            self._names = list(catalog.column_names)
            self._n = int(catalog.num_rows)
        else:
            self._table = None
            self.__dict__["catalog"] = catalog  # the cached_property's slot
            self._names = [str(c) for c in catalog.columns]
            self._n = len(catalog)
        self._columns: dict[str, NDArray[Any]] = {}
        self._ids = [str(i) for i in self.column("image_id")]
        self._row = {i: k for k, i in enumerate(self._ids)}
        self._pos = self._float_columns(POSITION_COLUMNS)
        self._rot = self._float_columns(ROTATION_COLUMNS).reshape(-1, 3, 3)
        self._sun = self._float_columns(SUN_COLUMNS)
        self._cam = np.array([str(c) for c in self.column("camera_id")], dtype=object)

    @cached_property
    def catalog(self) -> pd.DataFrame:
        """The catalog as a DataFrame (read from ``catalog.parquet`` on first use, as ``pd.read_parquet`` reads it)."""
        return read_table(self.path / "catalog.parquet", f"mission {self.path}")

    @property
    def catalog_columns(self) -> list[str]:
        """The catalog's column names (without reading it into pandas)."""
        return list(self._names)

    def column(self, name: str) -> NDArray[Any]:
        """One catalog column as a numpy array (strings as an object array; integers with nulls as float
        with NaN, as pandas gives them); KeyError when the catalog has no such column.
        """
        col = self._columns.get(name)
        if col is None:
            if name not in self._names:
                raise KeyError(name)
            if self._table is not None:
                col = column_to_numpy(self._table.column(name))
            else:
                col = self.catalog[name].to_numpy()
            col.flags.writeable = False
            self._columns[name] = col
        return col

    def _float_columns(self, names: list[str]) -> NDArray[np.float64]:
        if not names:
            return np.zeros((self._n, 0))
        return np.column_stack([np.asarray(self.column(c), dtype=np.float64) for c in names])

    def __repr__(self) -> str:
        return (f"Mission({str(self.path)!r}, {self._n} images, body={self.body.name}, "
                f"source={self.meta.get('source', 'synthetic')!r})")

    def __len__(self) -> int:
        return self._n

    @property
    def image_ids(self) -> list[str]:
        return list(self._ids)

    @property
    def pointing_sigma_urad(self) -> float | None:
        """How wrong the a-priori pointing may be, 1 sigma per axis (µrad), when the mission says
        (synth: the injected sigma; ingest: ``--pointing-sigma-urad``); None otherwise.
        """
        v = self.meta.get("pointing_sigma_urad")
        return None if v is None else float(v)

    def _index(self, image_id: str) -> int:
        try:
            return self._row[str(image_id)]
        except KeyError:
            raise StoreError(f"image {image_id!r} is not in the catalog of mission {self.path}") from None

    def camera(self, image_id: str) -> FramingCamera:
        """The camera model of an image (from the mission's camera table)."""
        return self.cameras[self._cam[self._index(image_id)]]

    def a_priori_pose(self, image_id: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position (3,) body-fixed m, rotation (3, 3) body->camera) as SPICE gives them."""
        k = self._index(image_id)
        return self._pos[k].copy(), self._rot[k].copy()

    def a_priori_poses(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """All a-priori positions (N, 3) and rotations (N, 3, 3), catalog order."""
        return self._pos.copy(), self._rot.copy()

    def sun_position(self, image_id: str) -> NDArray[np.float64]:
        """Sun position (3,) body-fixed metres at the image time."""
        return self._sun[self._index(image_id)].copy()

    def radiometry(self, image_id: str) -> Radiometry:
        """What the image's pixel values mean (kind, saturation, DN scale)."""
        k = self._index(image_id)
        return Radiometry(str(self.column("pixel_kind")[k]), float(self.column("saturation")[k]),
                          float(self.column("dn_scale")[k]))

    def read_image(self, image_id: str) -> NDArray[Any]:
        """Pixels (lines, samples) as stored (uint8/uint16/int16 DN or float32 with NaN = invalid).

        StoreError naming the image when the array is missing, corrupt or the wrong shape.
        """
        import zarr

        k = self._index(image_id)
        p = self.path / "images.zarr" / str(image_id)
        try:
            arr = zarr.open_array(str(p), mode="r")
            data = np.asarray(arr[...])
        except Exception as exc:  # zarr raises several types for missing/corrupt arrays
            raise StoreError(
                f"image {image_id}: cannot read {p} ({type(exc).__name__}: {exc}); "
                f"regenerate or re-ingest the mission"
            ) from None
        shape = (int(self.column("lines")[k]), int(self.column("samples")[k]))
        if data.ndim != 2 or data.dtype not in IMAGE_DTYPES:
            raise StoreError(f"image {image_id}: {p} holds {data.dtype} {data.shape}, expected a 2-D image")
        if data.shape != shape:
            raise StoreError(f"image {image_id}: {p} is {data.shape}, its camera is {shape} (lines, samples)")
        return data

    def read_image_masked(self, image_id: str) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        """(pixels as float32 with NaN at invalid pixels, validity mask) of an image."""
        data = self.read_image(image_id)
        f = data.astype(np.float32, copy=False)
        valid = np.isfinite(f)
        return f, valid

    @cached_property
    def altimetry(self) -> Any:
        """The mission's laser-altimeter shots (:class:`mercury_dem.altimetry.store.AltimetryStore`), or None.

        StoreError when ``altimetry/`` exists but is incomplete or corrupt.
        """
        from mercury_dem.altimetry.store import open_altimetry

        p = self.path / "altimetry"
        return open_altimetry(p) if p.exists() else None

    def read_altimetry(self, tile_id: int | None = None, columns: Any = None) -> pd.DataFrame:
        """Shots of the whole mission or of one tile; StoreError when the mission has no altimetry."""
        store = self.altimetry
        if store is None:
            raise StoreError(f"mission {self.path} has no altimetry; add it with 'mercury-dem ingest ... "
                             "--altimetry CSV...' (or a synth preset that simulates it)")
        return store.read(columns) if tile_id is None else store.read_tile(tile_id, columns)

    @cached_property
    def truth(self) -> SyntheticTruth | None:
        """The truth of a synthetic mission (validation only); None for real images."""
        return open_truth(self.path, self.image_ids)

    @property
    def has_truth(self) -> bool:
        return self.truth is not None

    def need_truth(self) -> SyntheticTruth:
        """The truth, or StoreError when the mission has none (real images)."""
        t = self.truth
        if t is None:
            raise StoreError(f"mission {self.path} has no truth/ (only synthetic missions do)")
        return t


def _v1_cameras(catalog: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, FramingCamera]]:
    """Camera table and radiometry of a version-1 (synthetic) catalog: MDIS presets, 12-bit DN."""
    cat = catalog.copy()
    keys = [f"{i}@{int(s)}" for i, s in zip(cat["instrument"].astype(str), cat["samples"])]
    cameras = {}
    for key in sorted(set(keys)):
        inst, _, samples = key.partition("@")
        cameras[key] = camera_preset(inst, int(samples))
    cat["camera_id"] = keys
    for k in FOOTPRINT_COLUMNS:
        cat[k] = np.nan
    cat["pixel_kind"], cat["saturation"], cat["dn_scale"] = DN12.pixel_kind, DN12.saturation, DN12.dn_scale
    return cat, cameras


def open_mission(path: str | Path) -> Mission:
    """Open a complete mission directory.

    Raises
    ------
    StoreError
        when the directory is missing, was not written to completion (interrupted
        generation), is not a mission, or its tables are missing or inconsistent.
        ``path`` may be an object-store URL (``s3://bucket/mission``): the mission is
        read from its local cached copy (:func:`mercury_dem.io.remote.fetch_mission`).
    """
    from mercury_dem.io.location import resolve_location

    loc = resolve_location(path, "mission")
    if isinstance(loc, str):
        from mercury_dem.io.remote import fetch_mission

        loc = fetch_mission(loc)
    p = loc
    if not p.exists():
        raise StoreError(f"mission {p} does not exist; create one with 'mercury-dem synth {p}' "
                         f"or 'mercury-dem ingest {p} FILE...'")
    if not p.is_dir():
        raise StoreError(f"mission {p} is not a directory")
    if not is_complete(p):
        raise StoreError(
            f"mission {p} is incomplete (no {COMPLETE_MARKER} marker: its writing was interrupted); "
            "delete it and write it again"
        )
    try:
        meta = json.loads((p / "mission.json").read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"mission {p}: cannot read mission.json ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise StoreError(f"{p} is not a mercury-dem mission (mission.json format "
                         f"{meta.get('format') if isinstance(meta, dict) else None!r})")
    try:
        version = int(meta.get("version", -1))
    except (TypeError, ValueError):
        version = -1
    if version > VERSION or version < 1:
        raise StoreError(f"mission {p} has format version {meta.get('version')!r}; this reader reads 1..{VERSION}")
    # An Arrow table, not pandas (StoreError; never unpickles): see Mission
    arrow = read_arrow_table(p / "catalog.parquet", f"mission {p}")
    need = CATALOG_COLUMNS if version >= 2 else CATALOG_COLUMNS_V1
    missing = [c for c in need if c not in arrow.column_names]
    if missing:
        raise StoreError(f"mission {p}: catalog.parquet lacks columns {missing}")
    image_ids = arrow.column("image_id").to_pylist()
    for image_id in image_ids:
        fault = name_fault(image_id)
        if fault is not None:
            raise StoreError(f"mission {p}: catalog.parquet image id {image_id!r} {fault}, so it cannot name its "
                             "array in images.zarr; re-ingest or regenerate the mission")
    dup = [i for i, n in Counter(image_ids).items() if n > 1]
    if dup:
        raise StoreError(f"mission {p}: duplicate image ids in the catalog, e.g. {dup[:5]}")
    for key in ("pointing_sigma_urad", "position_sigma_m", "tile_size_deg"):
        v = meta.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0):
            raise StoreError(f"mission {p}: mission.json {key} must be a positive number, got {v!r}")
    if version == 1:
        catalog, cameras = _v1_cameras(read_table(p / "catalog.parquet", f"mission {p}"))
        body = MERCURY
    else:
        try:
            table = json.loads((p / "cameras.json").read_text())
        except (OSError, ValueError) as exc:
            raise StoreError(f"mission {p}: cannot read cameras.json ({exc})") from None
        if not isinstance(table, dict):
            raise StoreError(f"mission {p}: cameras.json is not an object of camera id -> camera")
        cameras = {str(k): camera_from_dict(v, f"mission {p}: cameras.json camera {k!r}") for k, v in table.items()}
        catalog = arrow
        try:
            body = Body.from_dict(meta["body"])
        except (KeyError, TypeError, ValueError) as exc:
            raise StoreError(f"mission {p}: mission.json has no valid body ({exc})") from None
    try:
        mission = Mission(p, meta, catalog, cameras, body)
    except (TypeError, ValueError) as exc:  # e.g. a damaged file whose pose columns are not numbers
        raise StoreError(f"mission {p}: catalog.parquet is inconsistent ({type(exc).__name__}: {exc}); "
                         "re-ingest or regenerate the mission") from None
    unknown = sorted(set(mission._cam) - set(cameras))
    if unknown:
        raise StoreError(f"mission {p}: catalog names cameras {unknown[:5]} that cameras.json lacks")
    _check_image_sizes(p, mission, cameras)
    return mission


def _check_image_sizes(p: Path, mission: Mission, cameras: dict[str, FramingCamera]) -> None:
    """Each image's (lines, samples) in the catalog is its camera's (a damaged catalog row is refused
    here, not when a worker reads the image; found by the mission store fuzz test at 2000 inputs).
    """
    ids = [str(c) for c in mission._cam]
    want = np.array([(cameras[c].lines, cameras[c].samples) for c in ids], dtype=np.float64).reshape(-1, 2)
    try:
        got = mission._float_columns(["lines", "samples"])
    except (TypeError, ValueError) as exc:
        raise StoreError(f"mission {p}: catalog.parquet lines/samples are not numbers ({exc}); "
                         "re-ingest or regenerate the mission") from None
    bad = np.flatnonzero(np.any(got != want, axis=1))
    if bad.size:
        k = int(bad[0])
        raise StoreError(
            f"mission {p}: catalog.parquet gives image {mission.image_ids[k]!r} {got[k, 0]:g} x {got[k, 1]:g} "
            f"pixels (lines x samples) but its camera {ids[k]!r} is {want[k, 0]:g} x {want[k, 1]:g} "
            f"({bad.size} images disagree); re-ingest or regenerate the mission"
        )
