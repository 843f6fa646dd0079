"""The mission store: images, catalog and (for synthetic missions) the truth kept apart.

Layout of a mission directory::

    MISSION/
      mission.json         format, version, preset, seed, design, counts
      catalog.parquet      one row per image: id, instrument, size, time, A-PRIORI pose,
                           sun, pixel scale, centre lat/lon, angles, tile id
      images.zarr/         Zarr v3 group, one uint16 array per image id (one chunk per image)
      truth/               never read by the pipeline, only by validation
        poses.parquet      true positions and rotations, injected errors, design columns
        surface.json       SurfaceParams + datum radius (the truth Surface is rebuilt from it)
        dem.zarr/          reference truth DEM: height (lat, lon) on an equirectangular grid
      .complete            written last (see mercury_dem.io.atomic)

The directory is built under a temporary name and renamed when complete, so a
half-written mission is never mistaken for a complete one: :func:`open_mission`
raises :class:`StoreError` on it.

Truth DEM grid: ``ppd`` pixels per degree, pixel-is-area, north-up; pixel
centres at ``lat = lat_max - (i + 0.5) / ppd`` and ``lon = lon_min + (j + 0.5) / ppd``
(``lon_min`` may be negative for an area across the 0/360 seam: longitudes are
then continuous, e.g. -15..15, and mean ``lon mod 360``). Heights in metres above
the datum sphere ``datum_radius_m``.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.camera import FramingCamera, camera_preset
from mercury_dem.io.atomic import COMPLETE_MARKER, atomic_write_json, is_complete

FORMAT = "mercury-dem-mission"
VERSION = 1
ROTATION_COLUMNS = [f"rotation_{i}{j}" for i in range(3) for j in range(3)]
POSITION_COLUMNS = [f"position_{a}" for a in "xyz"]
SUN_COLUMNS = [f"sun_{a}" for a in "xyz"]
CATALOG_COLUMNS = (
    ["image_id", "instrument", "samples", "lines", "summing", "time"]
    + POSITION_COLUMNS + ROTATION_COLUMNS + SUN_COLUMNS
    + ["pixel_scale_m", "center_lat", "center_lon", "incidence_deg", "emission_deg", "phase_deg", "tile_id"]
)


# --------------------------------------------------------------------------- writing
def write_image(root: str | Path, image_id: str, image: NDArray[np.uint16]) -> None:
    """Write one image as its own array ``images.zarr/<image_id>`` (safe from parallel workers)."""
    import zarr

    img = np.asarray(image)
    if img.dtype != np.uint16 or img.ndim != 2:
        raise StoreError(f"image {image_id}: expected a 2-D uint16 array, got {img.dtype} {img.shape}")
    arr = zarr.create_array(
        store=str(Path(root) / "images.zarr" / image_id), shape=img.shape, chunks=img.shape, dtype="uint16",
        overwrite=True,
    )
    arr[...] = img


def init_store(root: str | Path) -> None:
    """Create the empty groups of a mission under construction."""
    import zarr

    root = Path(root)
    zarr.open_group(str(root / "images.zarr"), mode="w")
    (root / "truth").mkdir(exist_ok=True)


def write_tables(
    root: str | Path,
    meta: dict[str, Any],
    catalog: pd.DataFrame,
    truth_poses: pd.DataFrame | None,
    surface: dict[str, Any] | None,
) -> None:
    """Write mission.json, catalog.parquet and (if given) the truth tables."""
    root = Path(root)
    missing = [c for c in CATALOG_COLUMNS if c not in catalog.columns]
    if missing:
        raise StoreError(f"catalog lacks columns {missing}; the mission would not be readable")
    extra = [c for c in catalog.columns if c not in CATALOG_COLUMNS]
    catalog[CATALOG_COLUMNS + extra].to_parquet(root / "catalog.parquet", index=False)
    if truth_poses is not None:
        (root / "truth").mkdir(exist_ok=True)
        truth_poses.to_parquet(root / "truth" / "poses.parquet", index=False)
    if surface is not None:
        atomic_write_json(root / "truth" / "surface.json", surface)
    atomic_write_json(root / "mission.json", {"format": FORMAT, "version": VERSION, **meta})


def write_truth_dem(
    root: str | Path, height: NDArray[np.floating], lat_max: float, lon_min: float, ppd: float, datum_radius_m: float
) -> None:
    """Write the reference truth DEM (see the module docstring for the grid convention)."""
    import zarr

    g = zarr.open_group(str(Path(root) / "truth" / "dem.zarr"), mode="w")
    a = g.create_array("height", shape=height.shape, chunks=(min(1024, height.shape[0]), min(1024, height.shape[1])),
                       dtype="float32")
    a[...] = height.astype(np.float32)
    g.attrs.update({"lat_max": float(lat_max), "lon_min": float(lon_min), "ppd": float(ppd),
                    "datum_radius_m": float(datum_radius_m), "units": "m above datum",
                    "registration": "pixel-is-area, north-up"})


def dem_axes(lat_min: float, lat_max: float, lon_min: float, lon_max: float, ppd: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel-centre latitudes (north to south) and longitudes (west to east) of a DEM grid."""
    n_lat = int(round((lat_max - lat_min) * ppd))
    n_lon = int(round((lon_max - lon_min) * ppd))
    lat = lat_max - (np.arange(n_lat) + 0.5) / ppd
    lon = lon_min + (np.arange(n_lon) + 0.5) / ppd
    return lat, lon


# --------------------------------------------------------------------------- reading
class Mission:
    """A mission on disk. Use :func:`open_mission`.

    Attributes
    ----------
    path : the mission directory
    meta : the contents of mission.json
    catalog : DataFrame, one row per image (a-priori geometry only)
    """

    def __init__(self, path: Path, meta: dict[str, Any], catalog: pd.DataFrame) -> None:
        self.path = path
        self.meta = meta
        self.catalog = catalog
        self._row = {str(i): k for k, i in enumerate(catalog["image_id"])}
        self._pos = catalog[POSITION_COLUMNS].to_numpy(np.float64)
        self._rot = catalog[ROTATION_COLUMNS].to_numpy(np.float64).reshape(-1, 3, 3)
        self._sun = catalog[SUN_COLUMNS].to_numpy(np.float64)
        self._cameras: dict[tuple[str, int], FramingCamera] = {}

    def __repr__(self) -> str:
        return f"Mission({str(self.path)!r}, {len(self.catalog)} images, preset={self.meta.get('preset')!r})"

    def __len__(self) -> int:
        return len(self.catalog)

    @property
    def image_ids(self) -> list[str]:
        return [str(i) for i in self.catalog["image_id"]]

    def _index(self, image_id: str) -> int:
        try:
            return self._row[str(image_id)]
        except KeyError:
            raise StoreError(f"image {image_id!r} is not in the catalog of mission {self.path}") from None

    def camera(self, image_id: str) -> FramingCamera:
        """The camera model of an image (cached per instrument and size)."""
        k = self._index(image_id)
        key = (str(self.catalog["instrument"].iat[k]), int(self.catalog["samples"].iat[k]))
        if key not in self._cameras:
            self._cameras[key] = camera_preset(*key)
        return self._cameras[key]

    def a_priori_pose(self, image_id: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position (3,) body-fixed m, rotation (3, 3) body->camera) as SPICE would give them."""
        k = self._index(image_id)
        return self._pos[k].copy(), self._rot[k].copy()

    def a_priori_poses(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """All a-priori positions (N, 3) and rotations (N, 3, 3), catalog order."""
        return self._pos.copy(), self._rot.copy()

    def sun_position(self, image_id: str) -> NDArray[np.float64]:
        """Sun position (3,) body-fixed metres at the image time."""
        return self._sun[self._index(image_id)].copy()

    def read_image(self, image_id: str) -> NDArray[np.uint16]:
        """Pixels (lines, samples) uint16, 12-bit DN. StoreError naming the image if unreadable."""
        import zarr

        self._index(image_id)
        p = self.path / "images.zarr" / str(image_id)
        try:
            arr = zarr.open_array(str(p), mode="r")
            data = np.asarray(arr[...])
        except Exception as exc:  # zarr raises several types for missing/corrupt arrays
            raise StoreError(
                f"image {image_id}: cannot read {p} ({type(exc).__name__}: {exc}); regenerate the mission"
            ) from None
        if data.dtype != np.uint16 or data.ndim != 2:
            raise StoreError(f"image {image_id}: {p} holds {data.dtype} {data.shape}, expected 2-D uint16")
        return data

    # -- truth ----------------------------------------------------------------
    @property
    def has_truth(self) -> bool:
        return (self.path / "truth" / "poses.parquet").is_file()

    def _need_truth(self) -> None:
        if not self.has_truth:
            raise StoreError(f"mission {self.path} has no truth/ (only synthetic missions do)")

    @cached_property
    def truth_poses(self) -> pd.DataFrame:
        """The truth table: image_id, true_position_*, true_rotation_*, pointing_error_* (rad), ..."""
        self._need_truth()
        t = pd.read_parquet(self.path / "truth" / "poses.parquet")
        return t.set_index("image_id").loc[self.catalog["image_id"]].reset_index()

    @cached_property
    def _true_arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t = self.truth_poses
        c = t[["true_" + c for c in POSITION_COLUMNS]].to_numpy(np.float64)
        r = t[["true_" + c for c in ROTATION_COLUMNS]].to_numpy(np.float64).reshape(-1, 3, 3)
        return c, r

    def true_pose(self, image_id: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position (3,), rotation (3, 3)) the image was rendered from. Validation only."""
        k = self._index(image_id)
        c, r = self._true_arrays
        return c[k].copy(), r[k].copy()

    def true_poses(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """All true positions (N, 3) and rotations (N, 3, 3), catalog order."""
        c, r = self._true_arrays
        return c.copy(), r.copy()

    @cached_property
    def _surface(self) -> Any:
        from mercury_dem.synth.terrain import Surface, SurfaceParams

        self._need_truth()
        d = json.loads((self.path / "truth" / "surface.json").read_text())
        return Surface(SurfaceParams.from_dict(d["params"]), radius_m=d["radius_m"])

    def surface(self) -> Any:
        """The truth :class:`~mercury_dem.synth.terrain.Surface` (rebuilt once, then cached)."""
        return self._surface

    def truth_dem(
        self, bounds: tuple[float, float, float, float] | None = None, ppd: float | None = None
    ) -> Any:
        """Reference truth DEM as an ``xarray.DataArray`` (lat, lon), metres above the datum.

        Without arguments, the stored DEM. With ``bounds`` (lat_min, lat_max, lon_min, lon_max)
        and/or ``ppd``, a DEM computed from the truth surface on that grid (same convention).
        """
        import xarray as xr
        import zarr

        self._need_truth()
        g = zarr.open_group(str(self.path / "truth" / "dem.zarr"), mode="r")
        attrs = dict(g.attrs)
        if bounds is None and ppd is None:
            h = np.asarray(g["height"][...])
            p = attrs["ppd"]
            lat = attrs["lat_max"] - (np.arange(h.shape[0]) + 0.5) / p
            lon = attrs["lon_min"] + (np.arange(h.shape[1]) + 0.5) / p
        else:
            p = float(ppd or attrs["ppd"])
            if bounds is None:
                n_lat, n_lon = g["height"].shape
                bounds = (attrs["lat_max"] - n_lat / attrs["ppd"], attrs["lat_max"],
                          attrs["lon_min"], attrs["lon_min"] + n_lon / attrs["ppd"])
            lat, lon = dem_axes(*bounds, p)
            la, lo = np.meshgrid(lat, lon, indexing="ij")
            h = self.surface().height(la, lo, resolution_m=None)
            attrs = {**attrs, "ppd": p, "lat_max": bounds[1], "lon_min": bounds[2]}
        return xr.DataArray(h, coords={"lat": lat, "lon": lon}, dims=("lat", "lon"), name="height", attrs=attrs)


def open_mission(path: str | Path) -> Mission:
    """Open a complete mission directory.

    Raises
    ------
    StoreError
        when the directory is missing, was not written to completion (interrupted
        generation), is not a mission, or its catalog lacks required columns.
    """
    p = Path(path)
    if not p.exists():
        raise StoreError(f"mission {p} does not exist; create one with 'mercury-dem synth {p}'")
    if not p.is_dir():
        raise StoreError(f"mission {p} is not a directory")
    if not is_complete(p):
        raise StoreError(
            f"mission {p} is incomplete (no {COMPLETE_MARKER} marker: its writing was interrupted); "
            "delete it and generate it again"
        )
    try:
        meta = json.loads((p / "mission.json").read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"mission {p}: cannot read mission.json ({exc})") from None
    if meta.get("format") != FORMAT:
        raise StoreError(f"{p} is not a mercury-dem mission (mission.json format {meta.get('format')!r})")
    if int(meta.get("version", -1)) > VERSION:
        raise StoreError(f"mission {p} has format version {meta.get('version')}, newer than this reader ({VERSION})")
    try:
        catalog = pd.read_parquet(p / "catalog.parquet")
    except Exception as exc:  # pyarrow raises its own error types
        raise StoreError(f"mission {p}: cannot read catalog.parquet ({exc})") from None
    missing = [c for c in CATALOG_COLUMNS if c not in catalog.columns]
    if missing:
        raise StoreError(f"mission {p}: catalog.parquet lacks columns {missing}")
    if catalog["image_id"].duplicated().any():
        dup = catalog["image_id"][catalog["image_id"].duplicated()].tolist()[:5]
        raise StoreError(f"mission {p}: duplicate image ids in the catalog, e.g. {dup}")
    return Mission(p, meta, catalog)
