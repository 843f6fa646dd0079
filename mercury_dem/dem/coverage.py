"""Point-cloud coverage on a sinusoidal equal-area grid (Becker et al. 2015, "Point Cloud Analysis").

The reference binned its control points into a 1 km/pixel sinusoidal equal-area
map of Mercury and reported the fraction of map pixels holding at least one
point, the shares of those with exactly 1, 2 and >= 3 points, and the distance
from every map pixel centre to its nearest control point (min, mean, standard
deviation, max, and its map).

Grid: sinusoidal projection of the datum sphere (R = 2439.4 km), central
meridian 0, ``x = R * lon * cos(lat)`` (lon in [-180, 180)), ``y = R * lat``;
rows north to south, pixel centres at half-pixel offsets from the corner
(-pi R, pi R / 2). A map pixel belongs to the planet when its centre is inside
the projection's outline ``|x| <= pi R cos(lat)``. All pixels have the same
area, so shares of pixels are shares of surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import latlon_to_unit

#: Map rows handled per kd-tree query block (bounds memory at 1 km/pixel).
ROW_BLOCK = 256


@dataclass(frozen=True)
class CoverageResult:
    """Coverage maps and their summary.

    Attributes
    ----------
    pixel_km : pixel edge of the sinusoidal grid, km
    x_km, y_km : (W,), (H,) pixel-centre coordinates of the sinusoidal grid, km
    count : (H, W) int32, points per map pixel (-1 off the planet)
    nearest_km : (H, W) float32, distance from the pixel centre to the nearest point, km (NaN off the planet)
    radius_m : the sphere of the sinusoidal projection (the body's datum), metres
    """

    pixel_km: float
    x_km: NDArray[np.float64]
    y_km: NDArray[np.float64]
    count: NDArray[np.int32]
    nearest_km: NDArray[np.float32]
    radius_m: float

    def summary(self) -> dict[str, Any]:
        """The reference's figures, as a JSON-safe dict."""
        on = self.count >= 0
        n_map = int(on.sum())
        c = self.count[on]
        occupied = int((c >= 1).sum())
        d = self.nearest_km[on].astype(np.float64)

        def share(mask: NDArray[np.bool_]) -> float:
            return float(mask.sum() / occupied) if occupied else math.nan

        return {
            "grid": f"sinusoidal equal-area, central meridian 0, sphere R = {self.radius_m / 1000:g} km",
            "pixel_km": self.pixel_km,
            "map_pixels": n_map,
            "map_area_km2": n_map * self.pixel_km**2,
            "occupied_pixels": occupied,
            "occupied_fraction": occupied / n_map if n_map else math.nan,
            "occupied_area_km2": occupied * self.pixel_km**2,
            "share_with_1": share(c == 1),
            "share_with_2": share(c == 2),
            "share_with_3_or_more": share(c >= 3),
            "empty_pixels": n_map - occupied,
            "nearest_point_km": {
                "min": float(d.min()) if d.size else math.nan,
                "mean": float(d.mean()) if d.size else math.nan,
                "std": float(d.std()) if d.size else math.nan,
                "max": float(d.max()) if d.size else math.nan,
            },
        }

    def crs(self) -> str:
        """The grid's CRS as a PROJ string: sinusoidal of the datum sphere, central meridian 0, km."""
        return f"+proj=sinu +lon_0=0 +x_0=0 +y_0=0 +R={self.radius_m:.17g} +units=km +no_defs +type=crs"

    def to_dataset(self) -> Any:
        """An xarray Dataset of the two maps (coordinates in km on the sinusoidal grid), with its
        CRS as a CF grid mapping ``spatial_ref`` (rioxarray; written to Zarr with the maps).
        """
        import pyproj
        import rioxarray  # noqa: F401  (registers .rio)
        import xarray as xr

        ds = xr.Dataset(
            {
                "count": (("y", "x"), self.count, {"long_name": "control points per map pixel (-1 off the planet)",
                                                   "units": "1"}),
                "nearest_point_distance": (("y", "x"), self.nearest_km,
                                           {"long_name": "distance from the pixel centre to the nearest control point",
                                            "units": "km"}),
            },
            coords={"x": ("x", self.x_km, {"units": "km", "standard_name": "projection_x_coordinate",
                                           "long_name": "sinusoidal easting of the pixel centre"}),
                    "y": ("y", self.y_km, {"units": "km", "standard_name": "projection_y_coordinate",
                                           "long_name": "sinusoidal northing of the pixel centre"})},
            attrs={"projection": f"sinusoidal, central meridian 0, R = {self.radius_m / 1000:g} km (equal-area)",
                   "pixel_km": self.pixel_km},
        )
        ds = ds.rio.set_spatial_dims(x_dim="x", y_dim="y").rio.write_crs(self.crs())
        ds["spatial_ref"].attrs["crs_wkt2"] = pyproj.CRS.from_user_input(self.crs()).to_wkt("WKT2_2019")
        ds["spatial_ref"].attrs["proj4"] = self.crs()
        return ds


def sinusoidal_grid(pixel_km: float, radius_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel-centre coordinates (x_km (W,), y_km (H,), y descending) of the sinusoidal grid."""
    rk = radius_m / 1000.0
    nx = int(math.ceil(2 * math.pi * rk / pixel_km))
    ny = int(math.ceil(math.pi * rk / pixel_km))
    x: NDArray[np.float64] = -math.pi * rk + (np.arange(nx, dtype=np.float64) + 0.5) * pixel_km
    y: NDArray[np.float64] = math.pi * rk / 2 - (np.arange(ny, dtype=np.float64) + 0.5) * pixel_km
    return x, y


def point_coverage(index: Any, pixel_km: float = 1.0, threads: int = -1,
                   bounds: tuple[float, float, float, float] | None = None) -> CoverageResult:
    """Coverage of a point cloud on a sinusoidal equal-area grid.

    Parameters
    ----------
    index : PointIndex (``dem.grid.build_point_index``): kd-tree of the points'
        footprints on the datum sphere (distances are horizontal)
    pixel_km : pixel edge, km (reference: 1 km)
    threads : kd-tree query threads (-1 = all cores)
    bounds : (lat_min, lat_max, lon_min, lon_max) degrees of the DEM's map, or None for
        the whole planet (the reference's global figures). The map pixels are then those
        whose centre lies inside these bounds (rows outside are cropped): a regional DEM
        gets the coverage of its own area, and the nearest distances are computed only there.

    Returns
    -------
    CoverageResult
    """
    rk = index.datum_radius_m / 1000.0
    x, y = sinusoidal_grid(pixel_km, index.datum_radius_m)
    if bounds is not None:  # crop the rows to the map's latitudes
        lat_deg = np.degrees(y / rk)
        y = y[(lat_deg >= bounds[0]) & (lat_deg <= bounds[1])]
    nx, ny = x.size, y.size
    # Bin the points.
    fp = index.tree.data / index.datum_radius_m
    lat = np.arcsin(np.clip(fp[:, 2], -1.0, 1.0))
    lon = np.arctan2(fp[:, 1], fp[:, 0])
    px = np.clip(((rk * lon * np.cos(lat) + math.pi * rk) / pixel_km).astype(np.int64), 0, nx - 1)
    row0 = int(round((math.pi * rk / 2 - y[0]) / pixel_km - 0.5)) if ny else 0  # global row of y[0]
    py = ((math.pi * rk / 2 - rk * lat) / pixel_km).astype(np.int64) - row0
    keep = (py >= 0) & (py < ny) if bounds is not None else np.ones(py.size, bool)
    py = np.clip(py, 0, max(ny - 1, 0))
    count = np.bincount(py[keep] * nx + px[keep], minlength=nx * ny).reshape(ny, nx).astype(np.int32)
    # Map pixels on the planet (and inside the bounds).
    lat_c = y / rk  # radians
    half_width = math.pi * rk * np.cos(lat_c)
    on = (np.abs(x)[None, :] <= half_width[:, None]) | (count > 0)
    if bounds is not None and bounds[3] - bounds[2] < 360.0:
        lon_c = np.degrees(x[None, :] / (rk * np.maximum(np.cos(lat_c), 1e-12))[:, None])
        on &= np.mod(lon_c - bounds[2], 360.0) <= bounds[3] - bounds[2]
    count[~on] = -1
    nearest = np.full((ny, nx), np.nan, dtype=np.float32)
    for r0 in range(0, ny, ROW_BLOCK):
        r1 = min(r0 + ROW_BLOCK, ny)
        rows, cols = np.nonzero(on[r0:r1])
        la = lat_c[r0 + rows]
        cl = np.maximum(np.cos(la), 1e-12)
        lo = np.clip(x[cols] / (rk * cl), -math.pi, math.pi)
        q = latlon_to_unit(np.degrees(la), np.degrees(lo)) * index.datum_radius_m
        d, _ = index.tree.query(q, k=1, workers=threads)
        nearest[r0 + rows, cols] = d / 1000.0
    return CoverageResult(pixel_km=pixel_km, x_km=x, y_km=y, count=count, nearest_km=nearest,
                          radius_m=index.datum_radius_m)
