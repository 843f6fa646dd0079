"""The truth of a synthetic mission: what the images were really made from.

A separate, optional object (``mission.truth`` is ``None`` for real images): the
pipeline's stages never read it; validation and reports do. Stored under
``MISSION/truth/``::

    poses.parquet   true positions and rotations, injected errors, design columns
    altimetry_profiles.parquet  (when the mission has simulated altimetry) the orbit error of each profile
    surface.json    the surface generator's parameters + its datum radius
    dem.zarr/       the truth DEM: height (lat, lon), equirectangular, pixel-is-area

Truth DEM grid: ``ppd`` pixels per degree, north-up; pixel centres at
``lat = lat_max - (i + 0.5) / ppd`` and ``lon = lon_min + (j + 0.5) / ppd``
(``lon_min`` may be negative for an area across the 0/360 seam). Heights in metres
above the datum sphere ``datum_radius_m``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.altimetry.names import upgrade_columns
from mercury_dem.exceptions import StoreError
from mercury_dem.mission.catalog import POSITION_COLUMNS, ROTATION_COLUMNS

if TYPE_CHECKING:
    import pandas as pd  # imported where a table is read: opening a mission does not need it

#: The generator that rebuilds a truth surface from surface.json when the file names none
#: (missions written before the name was stored). Imported by name, on demand, so the
#: mission package does not depend on the synthetic generator.
DEFAULT_SURFACE_FACTORY = "mercury_dem.synth.terrain:surface_from_dict"


def _load_factory(spec: str) -> Callable[[dict[str, Any]], Any]:
    import importlib

    module, _, name = spec.partition(":")
    if not module.startswith("mercury_dem.") or not name:
        raise StoreError(f"truth surface factory {spec!r} is not a mercury_dem function")
    try:
        return getattr(importlib.import_module(module), name)  # type: ignore[no-any-return]
    except (ImportError, AttributeError) as exc:
        raise StoreError(f"truth surface factory {spec!r} cannot be loaded ({exc})") from None


def dem_axes(lat_min: float, lat_max: float, lon_min: float, lon_max: float, ppd: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel-centre latitudes (north to south) and longitudes (west to east) of a DEM grid."""
    n_lat = int(round((lat_max - lat_min) * ppd))
    n_lon = int(round((lon_max - lon_min) * ppd))
    lat = lat_max - (np.arange(n_lat) + 0.5) / ppd
    lon = lon_min + (np.arange(n_lon) + 0.5) / ppd
    return lat, lon


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


def write_truth_tables(root: str | Path, poses: pd.DataFrame, surface: dict[str, Any]) -> None:
    """Write a synthetic mission's truth: ``truth/poses.parquet`` and ``truth/surface.json`` under ``root``."""
    from mercury_dem.io.atomic import atomic_write_json

    (Path(root) / "truth").mkdir(exist_ok=True)
    poses.to_parquet(Path(root) / "truth" / "poses.parquet", index=False)
    atomic_write_json(Path(root) / "truth" / "surface.json", surface)


class SyntheticTruth:
    """The truth of a synthetic mission (validation only). Use ``mission.truth``."""

    def __init__(self, path: Path, image_ids: Sequence[str]) -> None:
        self.path = path
        self._ids = list(image_ids)
        self._row = {str(i): k for k, i in enumerate(image_ids)}

    def __repr__(self) -> str:
        return f"SyntheticTruth({str(self.path)!r})"

    def _index(self, image_id: str) -> int:
        try:
            return self._row[str(image_id)]
        except KeyError:
            raise StoreError(f"image {image_id!r} is not in the truth of {self.path}") from None

    @cached_property
    def poses(self) -> pd.DataFrame:
        """image_id, true_position_*, true_rotation_*, pointing_error_* (rad), ... in catalog order."""
        from mercury_dem.io.tables import read_table

        t = read_table(self.path / "poses.parquet", f"mission truth {self.path}")
        return t.set_index("image_id").loc[self._ids].reset_index()

    @cached_property
    def altimetry_profiles(self) -> pd.DataFrame | None:
        """The orbit error injected into each simulated altimetry profile (profile_id, along_m, cross_m,
        radial_m, and east_m/north_m/up_m at the profile's middle shot lat_mid/lon_mid), or None.
        """
        p = self.path / "altimetry_profiles.parquet"
        import pandas as pd

        return upgrade_columns(pd.read_parquet(p), str(p)) if p.is_file() else None

    @cached_property
    def _arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t = self.poses
        c = t[["true_" + c for c in POSITION_COLUMNS]].to_numpy(np.float64)
        r = t[["true_" + c for c in ROTATION_COLUMNS]].to_numpy(np.float64).reshape(-1, 3, 3)
        return c, r

    def true_pose(self, image_id: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position (3,), rotation (3, 3)) the image was rendered from."""
        k = self._index(image_id)
        c, r = self._arrays
        return c[k].copy(), r[k].copy()

    def true_poses(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """All true positions (N, 3) and rotations (N, 3, 3), catalog order."""
        c, r = self._arrays
        return c.copy(), r.copy()

    @cached_property
    def _surface(self) -> Any:
        d = json.loads((self.path / "surface.json").read_text())
        return _load_factory(str(d.get("factory", DEFAULT_SURFACE_FACTORY)))(d)

    def surface(self) -> Any:
        """The truth surface (``.height(lat, lon)``), rebuilt once, then cached."""
        return self._surface

    def dem(self, bounds: tuple[float, float, float, float] | None = None, ppd: float | None = None) -> Any:
        """Reference truth DEM as an ``xarray.DataArray`` (lat, lon), metres above the datum.

        Without arguments, the stored DEM. With ``bounds`` (lat_min, lat_max, lon_min, lon_max)
        and/or ``ppd``, a DEM computed from the truth surface on that grid (same convention).
        """
        import xarray as xr
        import zarr

        g = zarr.open_group(str(self.path / "dem.zarr"), mode="r")
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


def open_truth(mission_path: Path, image_ids: Sequence[str]) -> SyntheticTruth | None:
    """The truth under ``MISSION/truth/`` or None (real missions have none)."""
    p = Path(mission_path) / "truth"
    return SyntheticTruth(p, image_ids) if (p / "poses.parquet").is_file() else None
