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

from mercury_dem.geometry.body import MERCURY, Body


def height_tags(body: Body = MERCURY) -> dict[str, str]:
    """The metadata tags that state what a raster's values are heights above."""
    same = body.datum_radius_m == body.radius_m
    return {
        "UNITS": "m",
        "BODY": body.name,
        "DATUM_RADIUS_M": f"{body.datum_radius_m:.1f}",
        "HEIGHT_REFERENCE": (f"elevation above the {body.datum_radius_m / 1000:g} km IAU sphere of the CRS" if same else
                             f"elevation above a {body.datum_radius_m / 1000:g} km sphere; the CRS sphere "
                             f"({body.radius_m / 1000:g} km) georeferences lat/lon only"),
    }


HEIGHT_TAGS = height_tags(MERCURY)


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
                      path: str | Path, cog: bool = True, body: Body = MERCURY) -> Path:
    """The DEM as a (cloud-optimised) GeoTIFF in the body's IAU 2015 geographic CRS (degrees)."""
    return write_raster(elevation, lon, lat, body.crs("geographic"), path, cog=cog, tags=height_tags(body))


def write_pds_equirectangular(
    elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating], path: str | Path,
    cut_lat: float = 65.0, cog: bool = True, body: Body = MERCURY
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
    R = body.radius_m
    crs = body.crs("equirectangular_180")
    x = R * np.radians(np.asarray(lon, dtype=np.float64) - 180.0)
    y = R * np.radians(lat[rows])
    p = write_raster(np.asarray(elevation)[rows], x, y, crs, path, cog=cog,
                     tags={**height_tags(body), "LATITUDE_LIMIT_DEG": f"{cut_lat}", "CENTER_LONGITUDE": "180"})
    return {"path": str(p), "shape": [int(rows.sum()), int(len(lon))], "crs": crs,
            "lat_range_deg": [float(lat[rows].min()), float(lat[rows].max())],
            "pixel_m": float(R * math.radians(abs(lat[1] - lat[0]))) if lat.size > 1 else None}
