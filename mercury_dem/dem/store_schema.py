"""The schema of a ``dem.zarr`` store: what its arrays and attributes say, and how its layers are compressed.

One place for the CF attributes of the map layers and coordinates, the root attributes (the body, the
datum, the CRS code, the grid, the gridding's settings), the ``spatial_ref`` grid mapping's attributes
and the layers' compressor. The writers (:func:`mercury_dem.pipeline.dem_stage.create_store`, the
template of :func:`~mercury_dem.pipeline.dem_stage.dem_template`, the registration's maps) take them
from here; the cached lookup of the CRS attributes is :func:`mercury_dem.io.crs_cache.spatial_ref_attrs`.

Nothing here imports zarr, pyproj or rioxarray at module level: a cold ``mercury-dem grid`` imports this
module in a process that must stay free of them (tests/test_cli_startup.py).
"""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np

from mercury_dem.dem.grid import GridSpec
from mercury_dem.geometry.body import Body

__all__ = ["ATTRS", "COORD_ATTRS", "NAN_FILL_ATTR", "compute_spatial_ref_attrs", "gridding_attr", "layer_compressors",
           "root_attrs", "spatial_ref_cache_key", "spatial_ref_extra"]

#: CF attributes of the map layers (:data:`mercury_dem.dem.grid.LAYERS`).
ATTRS: dict[str, dict[str, str]] = {
    "elevation": {
        "long_name": "elevation above the datum sphere (root attribute datum_radius_m), the reference "
                     "ellipsoid of the grid mapping spatial_ref",
        "standard_name": "height_above_reference_ellipsoid",
        "units": "m",
    },
    "radius": {"long_name": "planetocentric radius of the surface", "units": "m"},
    "point_count": {"long_name": "control points within the search radius of the pixel centre", "units": "1"},
    "distance_to_nearest_point": {
        "long_name": "horizontal distance from the pixel centre to the nearest control point",
        "units": "m",
    },
    "spread": {
        "long_name": "standard deviation of the radii of the points used (precision / figure of merit)",
        "units": "m",
    },
}


def root_attrs(grid: GridSpec, cfg: Any, attrs: dict[str, Any] | None, body: Body) -> dict[str, Any]:
    """The store's root attributes: title, CF convention, the body and its datum, the height reference in
    words, the CRS code, the grid, the gridding's settings (:func:`gridding_attr`), then ``attrs``.
    """
    code = body.crs("geographic")
    if body.datum_is_iau_sphere:
        reference = (f"elevation is metres above the {body.name.title()} IAU 2015 sphere of radius "
                     f"{body.datum_radius_m / 1000:g} km, the sphere of the CRS {code} (grid mapping spatial_ref)")
    else:
        reference = (
            f"elevation is metres above a sphere of radius {body.datum_radius_m / 1000:g} km (the datum), the "
            f"sphere of the grid mapping spatial_ref; latitude/longitude are those of {code} (crs_code, the IAU "
            f"2015 sphere of radius {body.radius_m:.0f} m, to which heights never refer)"
        )
    out = {
        "title": f"{body.name.title()} DEM gridded from a control point cloud",
        "Conventions": "CF-1.8",
        "body": json.dumps(body.to_dict()),
        "datum_radius_m": body.datum_radius_m,
        "height_reference": reference,
        "crs_code": code,
        "pixels_per_degree": grid.pixels_per_degree,
        "pixel_size_m": grid.pixel_size_m,
        "grid_bounds_deg": [grid.lat_min, grid.lat_max, grid.lon_min, grid.lon_max],
        "pixel_registration": "lat/lon are pixel centres; row 0 is the northernmost",
        "method": cfg.method,
        "gridding": gridding_attr(cfg),
    }
    if attrs:
        out.update(attrs)
    return out


def gridding_attr(cfg: Any) -> str:
    """The store's ``gridding`` attribute: the settings a pixel's value depends on, as JSON
    (``max_distance_m`` is the no-value distance used, once resolved from the points' spacing).
    """
    return json.dumps({k: getattr(cfg, k) for k in ("method", "neighbours", "sigma_filter", "search_radius_factor",
                                                    "shepard_fallback_neighbours", "shepard_max_points",
                                                    "max_distance_m", "smoothing_passes", "smoothing_size")})


#: CF attributes of the coordinates.
COORD_ATTRS = {
    "lat": {"units": "degrees_north", "standard_name": "latitude",
            "long_name": "planetocentric latitude of the pixel centre"},
    "lon": {"units": "degrees_east", "standard_name": "longitude", "long_name": "east longitude of the pixel centre"},
}


def spatial_ref_extra(body: Body) -> dict[str, Any]:
    """What ``spatial_ref`` carries beside rioxarray's CF attributes: the IAU code and the WKT2."""
    import pyproj

    code = body.crs("geographic")
    out: dict[str, Any] = {
        "crs_code": code,
        "crs_wkt2": pyproj.CRS.from_user_input(body.datum_geographic_crs()).to_wkt("WKT2_2019"),
    }
    if body.datum_is_iau_sphere:
        out["crs_note"] = f"the grid mapping is {code}, whose sphere is the height datum"
    else:
        out["crs_note"] = (
            f"the grid mapping (crs_wkt, crs_wkt2, semi_major_axis) is the sphere of the height datum, "
            f"R = {body.datum_radius_m:.0f} m; crs_code {code} is the IAU 2015 CRS of the same latitude/longitude "
            f"(sphere R = {body.radius_m:.0f} m), given as the horizontal reference for interoperability"
        )
    return out


def compute_spatial_ref_attrs(body: Body) -> dict[str, Any]:
    """The ``spatial_ref`` attributes rioxarray writes for the body's datum-sphere CRS
    (:meth:`~mercury_dem.geometry.body.Body.datum_geographic_crs`), plus the IAU code, the WKT2 and a note
    (:func:`spatial_ref_extra`); JSON types only. Computed with rioxarray and pyproj, no cache
    (:func:`mercury_dem.io.crs_cache.spatial_ref_attrs` keeps it).
    """
    import rioxarray  # noqa: F401  (registers the .rio accessor)
    import xarray as xr

    ds = xr.Dataset(coords={"lat": [0.0], "lon": [0.0]}).rio.set_spatial_dims(x_dim="lon", y_dim="lat")
    out = dict(ds.rio.write_crs(body.datum_geographic_crs())["spatial_ref"].attrs)
    out.update(spatial_ref_extra(body))
    plain: dict[str, Any] = json.loads(json.dumps(out, default=_plain))  # numpy scalars -> JSON types, as cached
    return plain


def _plain(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"{type(v).__name__} is not JSON-serialisable")


def layer_compressors() -> tuple[Any, ...]:
    """The 5 map layers' compressor: Blosc LZ4 with bit shuffle (typesize from the dtype).

    Chosen by measurement on the benchmark's 1000 x 1000 map (5 layers, 4 chunks): zarr's
    default zstd took 0.12 CPU-s to write 12.7 MB; Blosc LZ4 + bit shuffle 0.05 CPU-s for
    11.2 MB (no compression at all: 0.04 s, 21 MB). Faster *and* smaller: bit shuffle
    groups the float32 exponents and high mantissa bits of a smooth map. Any Zarr v3 reader
    with Blosc (xarray, zarr-python, numcodecs) opens it.
    """
    from zarr.codecs import BloscCodec

    return (BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle"),)


#: How xarray records a NaN ``_FillValue`` in a Zarr v3 attribute (base64 of the float64 bytes).
NAN_FILL_ATTR = base64.standard_b64encode(np.array(np.nan, dtype="<f8").tobytes()).decode("ascii")


def spatial_ref_cache_key(body: Body) -> str:
    """What :func:`compute_spatial_ref_attrs` depends on: the body and the installed pyproj and rioxarray (JSON)."""
    from importlib import metadata

    return json.dumps({"body": body.to_dict(),
                       "versions": [metadata.version(m) for m in ("pyproj", "rioxarray")]}, sort_keys=True, default=str)
