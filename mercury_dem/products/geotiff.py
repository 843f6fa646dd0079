"""GeoTIFF / COG writers: the global DEM in its geographic CRS, and the PDS-style
equirectangular product (|lat| < 65 deg), written with rasterio.

GDAL 3.10 cannot read the Zarr v3 store, so these are the GIS user's path. Values are
float32 metres above the body's datum sphere, NaN = no value (also declared as nodata);
the band carries its units (``m``) and a description, the file tags state the datum.

* ``dem.tif``: the grid mapping of ``dem.zarr`` (:meth:`Body.datum_geographic_crs`): a
  geographic CRS whose sphere IS the height datum (for the Moon its IAU 2015 code; for
  Mercury the IAU 2015 CRS with the 2439.4 km datum radius), so the heights are above the
  ellipsoid of the file's own CRS.
* ``pds/*.tif``: the IAU 2015 projected codes (sphere of the IAU radius; for Mercury
  2440.53 km, which georeferences x/y only: the heights' datum is in the tags).

Geotransforms come from the grid's pixels per degree and bounds, never from differences
of float coordinates: x and y resolutions are the same number where the grid is square
(GDAL's ISIS3 writer refuses a 13th-digit difference). Longitudes are written where the
CRS expects them: a regional map across 0 deg gets -180..180 (geographic) or the central
meridian 0 (PDS equirectangular), never 340..380.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import Body
from mercury_dem.io.atomic import tmp_sibling


def grid_geometry(lat: NDArray[np.floating], lon: NDArray[np.floating], pixels_per_degree: float | None = None,
                  bounds: tuple[float, float, float, float] | None = None) -> tuple[float, float, float, float, float]:
    """(pixels_per_degree, lat_min, lat_max, lon_min, lon_max) of a DEM grid.

    From the store's attributes when given (exact); otherwise recovered from the pixel
    centres (rounded to 1e-9, which the grid's own definition satisfies).
    """
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    if pixels_per_degree is None:
        step = abs(float(lat[1] - lat[0])) if lat.size > 1 else abs(float(lon[1] - lon[0]))
        pixels_per_degree = round(1.0 / step, 9)
    ppd = float(pixels_per_degree)
    if bounds is None:
        half = 0.5 / ppd
        bounds = (round(float(lat[-1]) - half, 9), round(float(lat[0]) + half, 9),
                  round(float(lon[0]) - half, 9), round(float(lon[-1]) + half, 9))
    lat_min, lat_max, lon_min, lon_max = (float(b) for b in bounds)
    return ppd, lat_min, lat_max, lon_min, lon_max


def crosses_zero_meridian(lon_min: float, lon_max: float) -> bool:
    """True when the map's longitudes contain the 0/360 meridian strictly inside (a global
    map: when its columns do not start at 0, e.g. -180..180).
    """
    if lon_max - lon_min >= 360.0 - 1e-9:
        return abs(lon_min - 360.0 * round(lon_min / 360.0)) > 1e-9
    k = math.floor(lon_min / 360.0) + 1  # the first multiple of 360 east of lon_min
    return 360.0 * k < lon_max


def west_edge(lon_min: float, lon_max: float, central_meridian: float = 0.0) -> float:
    """The map's west edge as a longitude within 180 deg of ``central_meridian``, in
    ``[central_meridian - 180, central_meridian + 180)`` (a shift by whole turns: the columns keep their order).
    """
    return (lon_min - (central_meridian - 180.0)) % 360.0 + (central_meridian - 180.0)


def geographic_west_edge(lon_min: float, lon_max: float) -> float:
    """West edge for the geographic GeoTIFF: -180..180 when the map crosses 0 deg, else 0..360."""
    return west_edge(lon_min, lon_max, 0.0 if crosses_zero_meridian(lon_min, lon_max) else 180.0)


def pixel_transform(west: float, north: float, res: float) -> Any:
    """North-up affine geotransform with square pixels of size ``res`` (the same number for x and y)."""
    from affine import Affine

    return Affine(res, 0.0, west, 0.0, -res, north)


def height_tags(body: Body, crs_is_datum: bool = False) -> dict[str, str]:
    """The metadata tags that state what a raster's values are heights above.

    ``crs_is_datum``: the file's CRS is the datum sphere (:meth:`Body.datum_geographic_crs`).
    """
    same = body.datum_is_iau_sphere or crs_is_datum
    return {
        "UNITS": "m",
        "BODY": body.name,
        "DATUM_RADIUS_M": f"{body.datum_radius_m:.1f}",
        "HORIZONTAL_CRS": body.crs("geographic"),
        "HEIGHT_REFERENCE": (f"elevation above the {body.datum_radius_m / 1000:g} km sphere of the file's CRS" if same
                             else f"elevation above a {body.datum_radius_m / 1000:g} km sphere; the CRS sphere "
                             f"({body.radius_m / 1000:g} km) georeferences x/y only"),
    }




def band_description(body: Body) -> str:
    """The elevation band's description: heights above the body's datum sphere, with its radius."""
    return f"elevation above the {body.name.title()} datum sphere of radius {body.datum_radius_m:.0f} m"


def write_raster(
    values: NDArray[np.floating],
    transform: Any,
    crs: str,
    path: str | Path,
    *,
    cog: bool = True,
    tags: dict[str, str] | None = None,
    description: str = "elevation",
    units: str = "m",
    raw: bool = False,
    dtype: str = "float32",
    nodata: float = math.nan,
    creation_options: dict[str, Any] | None = None,
) -> Path:
    """Write a single-band raster with an exact affine ``transform`` (default float32, NaN nodata).

    ``cog`` selects GDAL's COG driver (tiled, overviews, DEFLATE with the float
    predictor); otherwise a tiled DEFLATE GTiff. ``raw``: an uncompressed, striped GTiff
    whose pixels are one contiguous array (what a PDS4 label can describe in place;
    overrides ``cog``). The band gets ``units`` and
    ``description``; ``tags`` go to the dataset metadata. ``dtype``/``nodata``: an integer
    band (e.g. a source-image index, ``int32`` with ``nodata=-1``) gets the integer predictor.
    ``creation_options``: further GDAL creation options (e.g. the COG driver's ``BLOCKSIZE``,
    ``OVERVIEW_COUNT``). Written to a temporary sibling and renamed: a reader never sees a
    half-written file.
    """
    import rasterio
    from rasterio.crs import CRS

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.asarray(values, dtype=dtype)
    if arr.ndim != 2:
        raise ValueError(f"a raster is 2-D, got shape {arr.shape}")
    floating = np.issubdtype(arr.dtype, np.floating)
    profile: dict[str, Any] = {"width": arr.shape[1], "height": arr.shape[0], "count": 1, "dtype": dtype,
                               "crs": CRS.from_user_input(crs), "transform": transform, "nodata": nodata,
                               "compress": "DEFLATE", "predictor": 3 if floating else 2}
    if raw:
        # GDAL defers all-nodata (or all-zero) strips of an uncompressed file to its end unless told
        # otherwise: the strips must be in order for the pixels to be one contiguous array.
        profile.update({"driver": "GTiff", "compress": "NONE", "tiled": False, "interleave": "band",
                        "@WRITE_EMPTY_TILES_SYNCHRONOUSLY": "YES"})
        del profile["predictor"]
    elif cog:
        profile["driver"] = "COG"
    else:
        profile.update(driver="GTiff", tiled=True)
        if arr.shape[0] < 256 or arr.shape[1] < 256:  # GTiff tiles are multiples of 16
            profile.update(blockxsize=16 * max(1, min(16, -(-arr.shape[1] // 16))),
                           blockysize=16 * max(1, min(16, -(-arr.shape[0] // 16))))
    profile.update(creation_options or {})
    tmp = tmp_sibling(path)  # the name io.atomic.sweep_temporaries recognises, unique per writer
    try:
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(arr, 1)
            dst.set_band_unit(1, units)
            dst.set_band_description(1, description)
            dst.update_tags(**(tags or {}))
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_dem_geotiff(elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating],
                      path: str | Path, cog: bool = True, *, body: Body,
                      pixels_per_degree: float | None = None,
                      bounds: tuple[float, float, float, float] | None = None) -> Path:
    """The DEM as a (cloud-optimised) GeoTIFF in the geographic CRS of its datum sphere (degrees).

    ``pixels_per_degree``/``bounds`` (lat_min, lat_max, lon_min, lon_max): the grid's
    (``dem.zarr`` attributes); recovered from ``lat``/``lon`` when not given.
    """
    ppd, _, lat_max, lon_min, lon_max = grid_geometry(lat, lon, pixels_per_degree, bounds)
    transform = pixel_transform(geographic_west_edge(lon_min, lon_max), lat_max, 1.0 / ppd)
    return write_raster(elevation, transform, body.datum_geographic_crs(), path, cog=cog,
                        tags=height_tags(body, crs_is_datum=True), description=band_description(body))


def write_pds_equirectangular(
    elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating], path: str | Path,
    cut_lat: float = 65.0, cog: bool = True, *, body: Body,
    pixels_per_degree: float | None = None, bounds: tuple[float, float, float, float] | None = None,
    raw: bool = False,
) -> dict[str, Any]:
    """PDS-style equirectangular product: the rows with |lat| < ``cut_lat``, projected.

    CRS: the body's IAU 2015 equirectangular (latitude of true scale 0, IAU sphere R),
    central meridian 180 (``IAU_2015:19915`` for Mercury), or 0 (``19910``) for a
    regional map across 0 deg: ``x = R (lon - clon)``, ``y = R lat`` in metres, with
    ``lon - clon`` within +-180. On this grid the projection is affine, so no resampling
    is needed: the pixels are the DEM's own. Returns a small description (path, shape,
    CRS, bounds).
    """
    lat = np.asarray(lat, dtype=np.float64)
    rows = np.flatnonzero(np.abs(lat) < cut_lat)
    if rows.size == 0:
        raise ValueError(f"the DEM has no rows within +-{cut_lat} deg of latitude")
    ppd, _, lat_max, lon_min, lon_max = grid_geometry(lat, lon, pixels_per_degree, bounds)
    clon = 0.0 if crosses_zero_meridian(lon_min, lon_max) else 180.0
    crs = body.crs("equirectangular" if clon == 0.0 else "equirectangular_180")
    R = body.radius_m
    res = R * math.radians(1.0 / ppd)
    north_deg = lat_max - int(rows[0]) / ppd
    transform = pixel_transform(R * math.radians(west_edge(lon_min, lon_max, clon) - clon),
                                R * math.radians(north_deg), res)
    sel = slice(int(rows[0]), int(rows[-1]) + 1)
    p = write_raster(np.asarray(elevation)[sel], transform, crs, path, cog=cog, raw=raw,
                     tags={**height_tags(body), "LATITUDE_LIMIT_DEG": f"{cut_lat}", "CENTER_LONGITUDE": f"{clon:g}"},
                     description=band_description(body))
    west = west_edge(lon_min, lon_max, clon)
    return {"path": str(p), "shape": [int(rows.size), int(len(lon))], "crs": crs, "center_longitude": clon,
            "lat_range_deg": [float(lat[rows].min()), float(lat[rows].max())],
            "bounding_degrees": [west, north_deg - rows.size / ppd, west + (lon_max - lon_min), north_deg],
            "pixel_m": res}
