"""GeoTIFF / COG writers: the global DEM in its geographic CRS, and the PDS-style
equirectangular product (|lat| < 65 deg), via rioxarray/rasterio.

GDAL 3.10 cannot read the Zarr v3 store, so these are the GIS user's path. Values are
float32 metres above the 2439.4 km datum, NaN = no value (also declared as nodata);
the CRS is an IAU 2015 Mercury code (sphere 2440.53 km), which georeferences
latitude/longitude only — the heights' datum is stated in the file's metadata tags.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from mercury_dem.geometry.body import (
    CRS_EQUIRECTANGULAR_180,
    CRS_GEOGRAPHIC,
    DATUM_RADIUS_M,
    IAU_SPHERE_RADIUS_M,
)

HEIGHT_TAGS = {
    "UNITS": "m",
    "DATUM_RADIUS_M": f"{DATUM_RADIUS_M:.1f}",
    "HEIGHT_REFERENCE": "elevation above a 2439.4 km sphere; the CRS sphere (2440.53 km) georeferences lat/lon only",
}


def write_raster(
    values: NDArray[np.floating],
    x: NDArray[np.floating],
    y: NDArray[np.floating],
    crs: str,
    path: str | Path,
    *,
    cog: bool = True,
    tags: dict[str, str] | None = None,
    name: str = "elevation",
) -> Path:
    """Write a float32 raster with regularly spaced pixel-centre coordinates x (W,), y (H,).

    ``cog`` selects GDAL's COG driver (tiled, overviews, DEFLATE with the float
    predictor); otherwise a tiled DEFLATE GTiff.
    """
    import rioxarray  # noqa: F401  (registers .rio)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    da = xr.DataArray(np.asarray(values, dtype=np.float32), dims=("y", "x"), coords={"x": x, "y": y}, name=name)
    da = da.rio.write_crs(crs).rio.write_nodata(np.nan, encoded=False)
    da.attrs.update(tags or {})
    tmp = path.with_name(f".{path.name}.tmp")
    with warnings.catch_warnings():
        # rioxarray 0.19 still multiplies Affine objects with '*' (affine >= 2.4 warns).
        warnings.filterwarnings("ignore", message="Use `@` matmul", category=PendingDeprecationWarning)
        if cog:
            da.rio.to_raster(tmp, driver="COG", compress="DEFLATE", predictor=3, tags=tags or {})
        else:
            da.rio.to_raster(tmp, driver="GTiff", tiled=True, compress="DEFLATE", predictor=3, tags=tags or {})
    tmp.replace(path)
    return path


def write_dem_geotiff(elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating],
                      path: str | Path, cog: bool = True) -> Path:
    """The DEM as a (cloud-optimised) GeoTIFF in the geographic CRS IAU_2015:19900 (degrees)."""
    return write_raster(elevation, lon, lat, CRS_GEOGRAPHIC, path, cog=cog, tags=HEIGHT_TAGS)


def write_pds_equirectangular(
    elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating], path: str | Path,
    cut_lat: float = 65.0, cog: bool = True
) -> dict[str, Any]:
    """PDS-style equirectangular product: the rows with |lat| < ``cut_lat``, projected.

    CRS IAU_2015:19915 (equirectangular, central meridian 180, latitude of true scale
    0, sphere 2440.53 km): ``x = R (lon - 180)``, ``y = R lat`` in metres. On this
    grid the projection is affine, so no resampling is needed: the pixels are the
    DEM's own. Returns a small description (path, shape, CRS, bounds).
    """
    lat = np.asarray(lat, dtype=np.float64)
    rows = np.abs(lat) < cut_lat
    if not rows.any():
        raise ValueError(f"the DEM has no rows within +-{cut_lat} deg of latitude")
    R = IAU_SPHERE_RADIUS_M
    x = R * np.radians(np.asarray(lon, dtype=np.float64) - 180.0)
    y = R * np.radians(lat[rows])
    p = write_raster(np.asarray(elevation)[rows], x, y, CRS_EQUIRECTANGULAR_180, path, cog=cog,
                     tags={**HEIGHT_TAGS, "LATITUDE_LIMIT_DEG": f"{cut_lat}", "CENTER_LONGITUDE": "180"})
    return {"path": str(p), "shape": [int(rows.sum()), int(len(lon))], "crs": CRS_EQUIRECTANGULAR_180,
            "lat_range_deg": [float(lat[rows].min()), float(lat[rows].max())],
            "pixel_m": float(R * math.radians(abs(lat[1] - lat[0]))) if lat.size > 1 else None}
