"""Make every product of a gridded DEM (``mercury-dem products``, last step of ``run``).

Reads ``dem.zarr`` (and ``coverage.zarr`` beside it when present) and writes into
``out_dir``::

    dem.tif                      global DEM, COG, geographic CRS of the datum sphere (degrees), float32
    pds/equirectangular.tif      |lat| < 65, IAU_2015:19915 (19910 across 0 deg) (metres), float32
    pds/north_polar.tif          lat >= 65, IAU_2015:19930, reprojected, float32
    pds/south_polar.tif          lat <= -65, IAU_2015:19935, reprojected, float32
                                 (the pds/*.tif are uncompressed, striped: PDS4 describes them in place)
    pds/<name>.xml               PDS4 label of each pds/<name>.tif (GDAL's PDS4 driver, label only)
    isis/dem_radius.cub          ISIS3 shape model: planetocentric radius (m), Real, ISIS Null for no value,
                                 Equirectangular Mapping group of the IAU sphere, TargetName = the body
    browse/greyscale.png, browse/hillshade.png, browse/colour_hillshade.png,
    browse/robinson.png, browse/coverage_distance.png (with coverage.zarr)
    statistics.json              reference 000 Table 1 (+ the printed table)
    coverage.json                reference 001 point-cloud coverage (with coverage.zarr)
    accuracy.json                DEM minus truth (when a truth height is given)
    profile_<n>.png/.csv         elevation profiles (when asked)
    browse/error_vs_truth.png    DEM minus truth map (when the truth is given)

Existing files are never replaced without ``overwrite``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from mercury_dem.config import Config
from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.accuracy import dem_accuracy
from mercury_dem.exceptions import GridError, StoreError
from mercury_dem.geometry.body import Body
from mercury_dem.io.atomic import atomic_write_json, atomic_write_text
from mercury_dem.products import browse
from mercury_dem.products.geotiff import (
    band_description,
    height_tags,
    pixel_transform,
    write_dem_geotiff,
    write_pds_equirectangular,
    write_raster,
)
from mercury_dem.products.planetary import write_isis_radius_cube, write_pds4_label
from mercury_dem.products.polar import reproject_polar
from mercury_dem.products.profile import elevation_profile, write_profile
from mercury_dem.products.stats import dem_statistics, format_statistics_table

#: Files always written (relative to the products directory).
PRODUCT_FILES = (
    "dem.tif", "pds/equirectangular.tif", "pds/north_polar.tif", "pds/south_polar.tif",
    "pds/equirectangular.xml", "pds/north_polar.xml", "pds/south_polar.xml", "isis/dem_radius.cub",
    "browse/greyscale.png", "browse/hillshade.png", "browse/colour_hillshade.png", "browse/robinson.png",
    "statistics.json", "statistics.txt",
)


def open_dem(path: str | Path) -> xr.Dataset:
    """Open a ``dem.zarr`` store lazily with its CRS (``decode_coords='all'``).

    Raises StoreError when the store is missing, cannot be opened (e.g. an unknown or pickle
    codec) or was not written to completion.
    """
    path = Path(path)
    if not path.exists():
        raise StoreError(f"no DEM store at {path}; run 'mercury-dem grid' (or the pipeline's DEM stage) first")
    try:
        ds = xr.open_zarr(str(path), consolidated=False, decode_coords="all")
    except Exception as exc:  # zarr/xarray raise several types (unknown codec, bad metadata, missing array)
        raise StoreError(f"the DEM store {path} cannot be opened ({type(exc).__name__}: {exc}); "
                         "grid it again with --overwrite") from None
    if not ds.attrs.get("complete"):
        raise StoreError(f"the DEM store {path} is incomplete (interrupted run?); grid it again with --overwrite")
    return ds


def dem_body(ds: xr.Dataset) -> Body:
    """The body a DEM store was gridded for (root attribute ``body``).

    A store without one is not guessed to be Mercury's (that guess once made a Moon DEM's products
    Mercury's): it raises :class:`StoreError`, whose message says to grid it again.
    """
    raw = ds.attrs.get("body")
    if not raw:
        raise StoreError("the DEM store has no 'body' attribute (written by a version before bodies were "
                         "recorded?): its heights' datum is unknown; grid it again (mercury-dem run ... --force dem)")
    try:
        return Body.from_dict(json.loads(raw) if isinstance(raw, str) else raw)
    except (ValueError, TypeError) as exc:
        raise StoreError(f"the DEM store's body attribute is invalid ({exc})") from None


def _dem_config(config: Config | DemConfig) -> DemConfig:
    return config.dem if isinstance(config, Config) else config


def make_products(
    dem_path: str | Path,
    out_dir: str | Path,
    config: Config | DemConfig,
    truth_height: Callable[[Any, Any], Any] | None = None,
    *,
    profiles: Sequence[tuple[float, float, float, float]] = (),
    overwrite: bool = False,
    coverage: bool = True,
    name: str = "DEM",
) -> dict[str, Any]:
    """Write every product of the DEM at ``dem_path`` into ``out_dir``; return a summary.

    Parameters
    ----------
    dem_path : ``dem.zarr`` written by :func:`mercury_dem.pipeline.dem_stage.grid_dem`
    out_dir : products directory (e.g. ``RUN/products``)
    config : Config or DemConfig
    truth_height : optional callable (lat, lon) -> m above the body's datum; adds accuracy.json
    profiles : (lat1, lon1, lat2, lon2) tuples, degrees
    overwrite : replace existing product files
    coverage : also map ``coverage.zarr`` beside the store when present (False for the registered
        and merged maps, which share their DEM's coverage)
    name : what the map is, in the browse image's title (e.g. "registered DEM")

    Returns
    -------
    dict: ``files`` (paths written), ``statistics`` (dict), ``table`` (printable str),
    ``coverage`` (dict or None), ``accuracy`` (dict or None), ``pds`` (descriptions, each
    with its PDS4 label under ``pds4``), ``isis`` (the radius cube's description),
    ``skipped`` (product file -> why it was not written: a PDS product whose latitudes the
    map does not reach; its .xml label is not written either), ``profiles``, ``browse_title`` (the colour
    hillshade's title), ``seconds``.

    Raises
    ------
    StoreError : no/incomplete store, or a product exists and ``overwrite`` is False
    GridError : the full map would not fit ``dem.memory_limit_gb``
    """
    t0 = time.perf_counter()
    cfg = _dem_config(config)
    dem_path, out = Path(dem_path), Path(out_dir)
    ds = open_dem(dem_path)
    body = dem_body(ds)
    planned = list(PRODUCT_FILES) + [f"profile_{i + 1}.png" for i in range(len(profiles))]
    if truth_height is not None:
        planned += ["accuracy.json", "browse/error_vs_truth.png"]
    if not overwrite:
        for rel in planned:
            if (out / rel).exists():
                raise StoreError(f"product {out / rel} already exists; pass --overwrite (overwrite=True) to replace it")
    H, W = ds.sizes["lat"], ds.sizes["lon"]
    need = H * W * 4 * 5
    if need > cfg.memory_limit_gb * 1e9:
        raise GridError(f"making products of a {H} x {W} DEM needs about {need / 1e9:.1f} GB, over "
                        f"dem.memory_limit_gb = {cfg.memory_limit_gb}; raise the limit or grid coarser")
    (out / "pds").mkdir(parents=True, exist_ok=True)
    (out / "browse").mkdir(parents=True, exist_ok=True)
    lat = ds.lat.values.astype(np.float64)
    lon = ds.lon.values.astype(np.float64)
    elev = ds.elevation.values  # float32 (H, W): the only full-map array held
    files: list[str] = []
    summary: dict[str, Any] = {"dem": str(dem_path), "shape": [H, W]}

    # GeoTIFFs.
    gb = ds.attrs.get("grid_bounds_deg")
    geom = {"pixels_per_degree": ds.attrs.get("pixels_per_degree"),
            "bounds": tuple(float(b) for b in gb) if gb is not None and len(gb) == 4 else None}
    files.append(str(write_dem_geotiff(elev, lat, lon, out / "dem.tif", cog=cfg.cog, body=body, **geom)))
    pds: dict[str, Any] = {}
    skipped: dict[str, str] = {}
    cut = cfg.polar_cut_lat
    span = f"the map's pixel centres span latitudes {lat.min():.2f} to {lat.max():.2f} deg"

    def skip(name: str, where: str) -> None:
        """PDS product ``name`` is not made: the map has no latitudes ``where``."""
        pds[name] = None
        skipped[f"pds/{name}.tif"] = f"{span}, none {where} (dem.polar_cut_lat)"
        if overwrite:  # a product an earlier call wrote for another map must not linger beside this one's
            (out / f"pds/{name}.tif").unlink(missing_ok=True)
            (out / f"pds/{name}.xml").unlink(missing_ok=True)

    if (np.abs(lat) < cut).any():
        eq = write_pds_equirectangular(elev, lat, lon, out / "pds/equirectangular.tif", cut, body=body, raw=True,
                                       **geom)
        eq["pds4"] = write_pds4_label(eq["path"], body, tuple(eq["bounding_degrees"]))
        pds["equirectangular"] = eq
        files += [eq["path"], eq["pds4"]["path"]]
    else:
        skip("equirectangular", f"within +-{cut:g} deg")
    # (the loop's variable is not ``name``: it once replaced the map's name, and an equatorial block's colour
    # hillshade was titled "south_polar")
    for cap_name, north in (("north_polar", True), ("south_polar", False)):
        covers = lat.max() >= cut if north else lat.min() <= -cut
        if not covers:
            skip(cap_name, f"north of {cut:g} deg" if north else f"south of -{cut:g} deg")
            continue
        cap = reproject_polar(elev, lat, lon, north, cut, body=body)
        half = cap["x"].size * cap["pixel_m"] / 2.0  # square grid centred on the pole
        p = write_raster(cap["values"], pixel_transform(-half, half, cap["pixel_m"]), cap["crs"],
                         out / f"pds/{cap_name}.tif", raw=True, description=band_description(body),
                         tags={**height_tags(body), "LATITUDE_LIMIT_DEG": str(cut)})
        label = write_pds4_label(p, body, (0.0, cut, 360.0, 90.0) if north else (0.0, -90.0, 360.0, -cut))
        pds[cap_name] = {"path": str(p), "shape": list(cap["values"].shape), "crs": cap["crs"], "pixel_m": cap["pixel_m"],
                     "valid_fraction_in_cap": cap["valid_fraction"], "pds4": label}
        files += [str(p), label["path"]]
    summary["pds"] = pds
    summary["skipped"] = skipped

    # ISIS shape model (radii, all latitudes).
    summary["isis"] = write_isis_radius_cube(elev, lat, lon, out / "isis/dem_radius.cub", body, **geom)
    files.append(summary["isis"]["path"])

    # Statistics (reference Table 1).
    stats = dem_statistics(elev, lat, lon, pixel_km=cfg.stats_pixel_km, polar_cut=cfg.polar_cut_lat,
                           south_limit=cfg.south_polar_stats_limit, radius_m=body.datum_radius_m)
    table = format_statistics_table(stats)
    files.append(str(atomic_write_json(out / "statistics.json", stats)))
    files.append(str(atomic_write_text(out / "statistics.txt", table + "\n")))
    summary["statistics"] = stats
    summary["table"] = table

    # Browse images.
    h, blat, blon = browse.browse_grid(elev, lat, lon, cfg.browse_width)
    R = body.datum_radius_m
    ex = browse.auto_exaggeration(h, blat, blon, radius_m=R)
    shade = browse.hillshade(h, blat, blon, exaggeration=ex, radius_m=R)
    files.append(str(browse.write_greyscale_png(h, out / "browse/greyscale.png")))
    files.append(str(browse.write_hillshade_png(shade, out / "browse/hillshade.png")))
    ppd = float(ds.attrs.get("pixels_per_degree", 1.0 / abs(lat[1] - lat[0]) if H > 1 else 1.0))
    title = f"{body.name.title()} {name} ({ds.attrs.get('method', '?')}, {ppd:g} pixel/deg): colour-coded elevation over shaded relief"
    ch, cs, clat, clon = h, shade, blat, blon
    if np.isfinite(h).mean() < 0.5:  # mostly empty map: show where the data are
        ch, cs, clat, clon = browse.crop_to_data(h, shade, blat, blon)
        title += " (cropped to the data)"
    files.append(str(browse.write_colour_png(ch, cs, clat, clon, out / "browse/colour_hillshade.png", title, ex, radius_m=R)))
    summary["browse_title"] = title
    files.append(str(browse.write_robinson_png(
        h, shade, blat, blon, out / "browse/robinson.png", min(cfg.browse_width, 1600), body=body)))
    summary["browse_exaggeration"] = ex

    # Coverage (reference 001), when the DEM stage stored it.
    summary["coverage"] = None
    cov_path = dem_path.parent / "coverage.zarr"
    if coverage and cov_path.exists():
        cov = xr.open_zarr(str(cov_path), consolidated=False, decode_coords="all")
        cov_summary = json.loads(ds.attrs["coverage"]) if ds.attrs.get("coverage") else None
        if cov_summary:
            files.append(str(atomic_write_json(out / "coverage.json", cov_summary)))
            summary["coverage"] = cov_summary
        files.append(str(browse.write_coverage_png(
            cov.nearest_point_distance.values, cov.x.values, cov.y.values, out / "browse/coverage_distance.png",
            cfg.browse_width, f"Distance to the nearest control point ({float(cov.attrs['pixel_km']):g} km/pixel "
            "sinusoidal equal-area grid)")))

    # Accuracy against truth.
    summary["accuracy"] = None
    if truth_height is not None:
        acc = dem_accuracy(elev, lat, lon, truth_height, ds.distance_to_nearest_point.values)
        files.append(str(atomic_write_json(out / "accuracy.json", acc)))
        summary["accuracy"] = acc
        glat, glon = np.meshgrid(blat, blon, indexing="ij")
        err = h - np.asarray(truth_height(glat, glon), dtype=np.float64)
        err[~np.isfinite(h)] = np.nan
        e_shade = np.zeros_like(err)
        if np.isfinite(err).mean() < 0.5:
            err, _, elat, elon = browse.crop_to_data(err, e_shade, blat, blon)
        else:
            elat, elon = blat, blon
        files.append(str(browse.write_error_png(
            err, elat, elon, out / "browse/error_vs_truth.png",
            f"DEM minus truth at browse resolution ({abs(float(blat[1] - blat[0])) if blat.size > 1 else 0:.3g}°/pixel)")))

    # Profiles.
    summary["profiles"] = []
    for i, ends in enumerate(profiles):
        prof = elevation_profile(elev, lat, lon, ends, cfg.profile_samples, radius_m=body.datum_radius_m)
        info = write_profile(prof, out / f"profile_{i + 1}.png", out / f"profile_{i + 1}.csv", truth_height)
        files += [info["png"], info["csv"]]
        summary["profiles"].append(info)

    summary["files"] = files
    summary["seconds"] = time.perf_counter() - t0
    return summary
