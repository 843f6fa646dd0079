"""The dense DEM of a run (``dem_dense.zarr``) and its validation against the truth (issue 31; docs/design/dense.md).

The cloud (``dense.zarr``, :mod:`mercury_dem.io.dense_store`, written by :mod:`mercury_dem.pipeline.dense_tile`) gridded by the DEM stage's own gridding at the
dense rule's resolution (:mod:`mercury_dem.dem.dense_grid`), with the sparse DEM resampled as fallback, a precision
and a source layer; written atomically.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config import Config
from mercury_dem.dem.dense_grid import (
    control_distance,
    fuse_with_prior,
    pair_level_offsets,
    pixel_precision,
    snapped_bounds,
)
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.io.dense_store import read_cloud
from mercury_dem.io.run_store import DEM_DENSE_FILE, DEM_DENSE_SCRATCH_FILE, DENSE_FILE, RunStore
from mercury_dem.pipeline.dense_inputs import open_sparse_surface

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient

#: ``source`` layer of the dense DEM.
SOURCE_NONE, SOURCE_DENSE, SOURCE_SPARSE = 0, 1, 2


def grid_dense_dem(store: RunStore, config: Config, ppd: float, client: ComputeClient | None, body: Any, rep: Any,
                   median_pixel_scale_m: float, shots: Any = None) -> dict[str, Any]:
    """Grid the cloud into ``dem_dense.zarr`` with the sparse DEM as fallback; returns the report's block."""
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.pipeline.dem_stage import atomic_store

    cloud, sparse_path, frame = registered_cloud(store, read_cloud(store.root / DENSE_FILE), body.datum_radius_m)
    cloud, pair_level = level_pairs_on_sparse(cloud, sparse_path, config)
    xyz = latlon_to_xyz(cloud["lat"], cloud["lon"], height_m=cloud["height"], datum_radius_m=body.datum_radius_m)
    cfg, bounds = dense_grid_config(config, sparse_path, ppd, body.datum_radius_m)
    summary, g = _grid_points(store, xyz, cfg, client, body, rep)
    lat, lon = g["lat"].values, g["lon"].values
    elev = g["elevation"].transpose("lat", "lon").values.astype(np.float64)
    lat2, lon2 = np.meshgrid(lat, lon, indexing="ij")
    fallback = open_sparse_surface(sparse_path).sample(lat2, lon2)
    precision = pixel_precision(cloud, lat, lon, ppd, int(config.dense.grid_neighbours))
    ds = dense_layers(g, elev, fallback, precision, config.dense.sparse_sigma_m, config.dense.fusion_correlation)
    level = level_dense_pixels(ds, shots, body.datum_radius_m, config) if shots is not None else None
    ds.attrs.update({"source": "dense stereo points; sparse DEM (dem.zarr) resampled where no dense point reaches",
                     "grid_rule": f"{config.dense.grid_pixel_factor:g} x the pairs' median pixel scale "
                                  f"{median_pixel_scale_m:.0f} m -> {ppd:g} pixel/deg",
                     "pixels_per_degree": ppd, "frame": frame})
    out_path = store.root / DEM_DENSE_FILE
    with atomic_store(out_path, overwrite=True) as tmp:
        ds.to_zarr(str(tmp), mode="w", zarr_format=3, consolidated=False)
    source = ds["source"].values
    return {"path": str(out_path), "pixels_per_degree": ppd, "median_pair_pixel_scale_m": median_pixel_scale_m,
            "pixel_m": 2 * math.pi * body.datum_radius_m / 360.0 / ppd, "shape": list(source.shape),
            "bounds": list(bounds), "points": int(xyz.shape[0]), "frame": frame, "sparse_dem": str(sparse_path),
            "altimetry_level": level, "pair_level": pair_level,
            "source_fraction": {name: float((source == v).sum() / source.size) for name, v in
                                (("dense", SOURCE_DENSE), ("sparse_fallback", SOURCE_SPARSE), ("none", SOURCE_NONE))},
            "failed_chunks": summary.get("failed_chunks", []), "gridding_seconds": round(summary["seconds"], 2),
            "precision_median_m": _nan_median(ds["precision_m"].values.astype(np.float64))}


def registered_cloud(store: RunStore, cloud: dict[str, NDArray[Any]], datum_radius_m: float
                     ) -> tuple[dict[str, NDArray[Any]], Path, str]:
    """The cloud in the frame of the run's final sparse DEM, that DEM's path, and the frame's name.

    Where the run registered its DEM to altimetry and stored the transform (``registration/transform.json``
    beside ``registered.zarr``), the points are moved by that transform
    (:func:`~mercury_dem.altimetry.merge.register_points`: the tiles' blended displacement and the mean
    level, as the registered map got them) and the registered DEM is the fallback and prior; otherwise (no
    altimetry, a failed registration, a run registered before the transform was stored) the cloud stays in
    the adjusted frame with ``dem.zarr``.
    """
    from mercury_dem.altimetry.merge import register_points
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.io.run_store import REGISTERED_FILE, read_registration_transform

    t = read_registration_transform(store.registration_dir)
    registered = store.root / REGISTERED_FILE
    if t is None or not registered.exists():
        return cloud, store.dem_path, "adjusted"
    xyz = latlon_to_xyz(cloud["lat"], cloud["lon"], height_m=cloud["height"], datum_radius_m=datum_radius_m)
    la, lo, h = register_points(xyz, cloud["lat"], cloud["lon"], datum_radius_m, t["table"],
                                TileGrid(float(t["tile_size_deg"])), t.get("level_offset_m"))
    return {**cloud, "lat": la, "lon": lo, "height": h}, registered, "registered to altimetry"


def level_pairs_on_sparse(cloud: dict[str, NDArray[Any]], sparse_path: Path, config: Config
                          ) -> tuple[dict[str, NDArray[Any]], dict[str, Any] | None]:
    """The cloud with each pair's points on the sparse DEM's level (``dense.level_pairs_on_sparse``,
    :func:`~mercury_dem.dem.dense_grid.pair_level_offsets`: the clipped mean of sparse DEM − point per pair; the
    sparse DEM sampled bilinearly, NaN next to its gaps) and the report's summary of the offsets (None when off).
    """
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.reference.sampling import sample_grid

    if not config.dense.level_pairs_on_sparse or not cloud["height"].size:
        return cloud, None
    sparse = open_dem(sparse_path)
    values = sparse["elevation"].transpose("lat", "lon").values.astype(np.float64)
    prior = sample_grid(values, sparse["lat"].values, sparse["lon"].values, cloud["lat"], cloud["lon"])
    shift, offsets = pair_level_offsets(prior - cloud["height"], cloud["pair"],
                                        clip_nmad=config.dense.pair_level_clip_nmad,
                                        min_points=config.dense.pair_level_min_points)
    o = np.array(list(offsets.values()))
    pairs = int(np.unique(cloud["pair"]).size)
    summary = {"pairs": pairs, "pairs_levelled": int(o.size), "offset_median_m": float(np.median(o)) if o.size else None,
               "offset_min_m": float(o.min()) if o.size else None, "offset_max_m": float(o.max()) if o.size else None,
               "reference": str(sparse_path)}
    return {**cloud, "height": cloud["height"] + shift}, summary


def level_dense_pixels(ds: Any, shots: Any, datum_radius_m: float, config: Config) -> dict[str, Any] | None:
    """``ds``'s ``elevation`` levelled on the altimetry shots' mean per tile on its dense pixels (``source`` =
    dense; :func:`~mercury_dem.altimetry.merge.level_on_shots`), in place, when ``dense.level_to_altimetry``, and
    ``elevation_dense`` (the dense value alone) moved by the same offsets, so that the dense values alone are
    reported in the delivered DEM's frame (before, only ``elevation`` was levelled: on the demo the dense values
    alone stood +221 m above the truth where the delivered DEM was -30 m; levelling them on the shots by their
    own offsets instead gave offsets down to -1 km where a few hundred pixels far from the cloud's core met the
    shots); the report's summary of the offsets (None when off).
    """
    from mercury_dem.altimetry.merge import level_on_shots
    from mercury_dem.geometry.tiling import TileGrid

    if not config.dense.level_to_altimetry or shots is None or not len(shots):
        return None
    dense = ds["source"].transpose("lat", "lon").values == SOURCE_DENSE
    elev = ds["elevation"].transpose("lat", "lon").values.astype(np.float64)
    levelled, offset, own, n = level_on_shots(
        np.where(dense, elev, np.nan), ds["lat"].values, ds["lon"].values, shots["lat"].to_numpy(),
        shots["lon"].to_numpy(), shots["radius_m"].to_numpy() - datum_radius_m, TileGrid(config.tiling.tile_size_deg),
        min_shots=config.dense.level_min_shots)
    shift = np.where(dense, levelled - elev, 0.0)
    for layer in ("elevation", "elevation_dense"):
        if layer in ds:
            dims, attrs = ds[layer].dims, dict(ds[layer].attrs)
            values = ds[layer].transpose("lat", "lon").values.astype(np.float64) + shift
            ds[layer] = (("lat", "lon"), values.astype(np.float32))
            ds[layer] = ds[layer].transpose(*dims)
            ds[layer].attrs.update(attrs)
            ds[layer].encoding = {}
    o = offset[own]
    return {"tiles": int(own.sum()), "shots": int(n.sum()), "layers": ["elevation", "elevation_dense"],
            "offset_median_m": float(np.median(o)) if o.size else None,
            "offset_min_m": float(o.min()) if o.size else None, "offset_max_m": float(o.max()) if o.size else None}


def block_holes(path: Path, images: Any, datum_radius_m: float) -> dict[str, Any]:
    """Holes of the dense DEM ``path`` within the block's footprint, the pixels seen by at least 2 of ``images``
    (the controlled images' adjusted geometry, :func:`mercury_dem.dense.footprint.views_per_pixel`): the shares
    without a value in the delivered ``elevation`` (dense, else the sparse fallback), in the dense values alone
    (``dense``; ``dense_coverage`` = 1 - it) and in the sparse DEM on the same grid (``sparse``).
    """
    from mercury_dem.dense.footprint import hole_fractions, views_per_pixel
    from mercury_dem.pipeline.dem_stage import open_dem

    ds = open_dem(path).load()
    lat, lon = ds["lat"].values.astype(np.float64), ds["lon"].values.astype(np.float64)
    layer = {k: ds[v].transpose("lat", "lon").values.astype(np.float64) for k, v in
             (("delivered", "elevation"), ("dense", "elevation_dense"), ("sparse", "sparse_on_grid"))}
    views = views_per_pixel(lat, lon, layer["delivered"], list(images), datum_radius_m)
    out = hole_fractions(views >= 2, layer)
    out["dense_coverage"] = None if out["dense"] is None else 1.0 - out["dense"]
    out["footprint"] = "pixels seen by at least 2 of the block's controlled images (adjusted geometry)"
    out["grid_pixels"] = int(views.size)
    return out


def _nan_median(a: NDArray[Any]) -> float | None:
    return float(np.nanmedian(a)) if np.isfinite(a).any() else None


def dense_grid_config(config: Config, sparse_dem_path: Path, ppd: float, datum_radius_m: float
                      ) -> tuple[Any, tuple[float, float, float, float]]:
    """The gridding's configuration of the dense DEM: the sparse DEM's extent snapped to ``ppd``, median of
    ``dense.grid_neighbours`` points, ``dense.grid_smoothing_passes`` (null: the DEM stage's), no value beyond
    ``dense.max_gap_pixels`` from a dense point; and the bounds.
    """
    from mercury_dem.pipeline.dem_stage import open_dem

    sparse = open_dem(sparse_dem_path)
    sl, so = sparse["lat"].values, sparse["lon"].values
    half = 0.5 / float(sparse.attrs.get("pixels_per_degree", 1.0 / abs(sl[1] - sl[0]) if sl.size > 1 else 1.0))
    bounds = snapped_bounds((float(sl.min()) - half, float(sl.max()) + half, float(so.min()) - half,
                             float(so.max()) + half), ppd)
    cfg = replace(config.dem, pixels_per_degree=ppd, lat_min=bounds[0], lat_max=bounds[1], lon_min=bounds[2],
                  lon_max=bounds[3], method="median11", neighbours=config.dense.grid_neighbours,
                  smoothing_passes=(config.dem.smoothing_passes if config.dense.grid_smoothing_passes is None
                                    else config.dense.grid_smoothing_passes),
                  max_distance_m=config.dense.max_gap_pixels * 2 * math.pi * datum_radius_m / 360.0 / ppd)
    return cfg, bounds


def _grid_points(store: RunStore, xyz: NDArray[np.float64], cfg: Any, client: ComputeClient | None, body: Any, rep: Any
                 ) -> tuple[dict[str, Any], Any]:
    """The DEM stage's gridding of the dense points into a scratch store, searching only the pixels within
    reach of a point (the others are the sparse fallback's); (its summary, the grid loaded). The scratch goes.
    """
    from mercury_dem.pipeline.dem_stage import grid_dem, open_dem

    scratch = store.root / DEM_DENSE_SCRATCH_FILE
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        summary = grid_dem(xyz, cfg, scratch, client, coverage=False, body=body, record_failures=True,
                           near_points_only=True, attrs={"source": "dense stereo points"}, progress=rep,
                           label="dem (dense points)")
        return summary, open_dem(scratch).load()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def dense_layers(g: Any, elev: NDArray[np.float64], fallback: NDArray[np.float64], precision: NDArray[np.float64],
                 sparse_sigma_m: float | None = None, fusion_correlation: float = 0.0) -> Any:
    """The dense DEM's dataset: the gridding's layers ``g`` with ``elevation`` (dense, else the fallback; where
    ``sparse_sigma_m`` is given the dense value fused with the fallback by their precisions,
    :func:`~mercury_dem.dem.dense_grid.fuse_with_prior`), ``elevation_dense`` (the dense value alone),
    ``sparse_on_grid``, ``precision_m`` (NaN without a dense value; the fused sigma when fused) and ``source``.
    """
    has_dense = np.isfinite(elev)
    source = np.where(has_dense, SOURCE_DENSE, np.where(np.isfinite(fallback), SOURCE_SPARSE, SOURCE_NONE))
    final = np.where(has_dense, elev, fallback)
    precision = np.where(has_dense, precision, np.nan)
    if sparse_sigma_m is not None:  # the dense pixels fused with the sparse DEM by their precisions
        fused, fused_sigma = fuse_with_prior(elev, precision, fallback, sparse_sigma_m, fusion_correlation)
        final = np.where(has_dense, fused, fallback)
        precision = np.where(has_dense, fused_sigma, np.nan)
    ds = g.copy()
    dims = g["elevation"].dims
    ds["elevation"] = (("lat", "lon"), final.astype(np.float32))
    ds["elevation"] = ds["elevation"].transpose(*dims)
    ds["elevation_dense"] = (("lat", "lon"), elev.astype(np.float32))
    ds["sparse_on_grid"] = (("lat", "lon"), fallback.astype(np.float32))
    ds["sparse_on_grid"].attrs["long_name"] = "the sparse DEM (dem.zarr) resampled bilinearly on this grid"
    ds["precision_m"] = (("lat", "lon"), precision.astype(np.float32))
    ds["source"] = (("lat", "lon"), source.astype(np.uint8))
    ds["source"].attrs.update({"flag_values": [SOURCE_NONE, SOURCE_DENSE, SOURCE_SPARSE],
                               "flag_meanings": "none dense sparse_fallback"})
    ds["precision_m"].attrs.update({"units": "m", "long_name": "stated 1-sigma precision of the dense elevation: "
                                    "the median stated sigma_h of the pixel's points / sqrt(min(distinct pairs, "
                                    "dense.grid_neighbours)), fused with dense.sparse_sigma_m when set "
                                    "(dem.dense_grid.fuse_with_prior); NaN where no dense value"})
    ds["distance_to_nearest_point"].attrs["note"] = (
        "+inf where no dense point is within reach (dense.max_gap_pixels or the count's radius): those pixels "
        "are not searched (point_count 0)")
    for v in ds.data_vars:
        ds[v].encoding = {}
    return ds


def validate_dense_dem(path: Path, truth: Callable[..., Any], control_xyz: NDArray[np.float64] | None = None,
                       datum_radius_m: float | None = None) -> dict[str, Any]:
    """``validation.dem`` entries: the dense DEM, the sparse DEM on the dense grid, and both over the pixels
    the dense points reach (``source`` = dense) where the sparse DEM has a value, where the issue's ratio is measured.
    """
    from mercury_dem.dem.accuracy import dem_accuracy
    from mercury_dem.pipeline.dem_stage import open_dem

    ds = open_dem(path).load()
    lat, lon = ds["lat"].values, ds["lon"].values
    elev = ds["elevation"].transpose("lat", "lon").values
    source = ds["source"].transpose("lat", "lon").values
    if "sparse_on_grid" not in ds:
        raise MercuryDemError(f"{path} has no sparse_on_grid layer")
    # the sparse DEM on the dense grid (the fallback's source, kept in the store)
    sparse_on_grid = ds["sparse_on_grid"].transpose("lat", "lon").values
    # the comparison: the pixels where the dense points reach and the sparse DEM has a value too
    dense_px = (source == SOURCE_DENSE) & np.isfinite(sparse_on_grid)
    # error against the distance to the nearest control point (issue 31 section 3), for every entry
    dist = (control_distance(control_xyz, lat, lon, datum_radius_m)
            if control_xyz is not None and control_xyz.shape[0] and datum_radius_m is not None else None)
    out = {
        "dense": dem_accuracy(elev, lat, lon, truth, dist),
        "sparse_on_dense_grid": dem_accuracy(sparse_on_grid, lat, lon, truth, dist),
        "dense_on_dense_pixels": dem_accuracy(np.where(dense_px, elev, np.nan), lat, lon, truth, dist),
        "sparse_on_dense_pixels": dem_accuracy(np.where(dense_px, sparse_on_grid, np.nan), lat, lon, truth, dist),
    }
    if "elevation_dense" in ds:  # the dense value alone, before its fusion with the sparse DEM
        alone = ds["elevation_dense"].transpose("lat", "lon").values
        out["dense_alone_on_dense_pixels"] = dem_accuracy(np.where(dense_px, alone, np.nan), lat, lon, truth, dist)
    return out


def rmse_ratio(validation: dict[str, Any]) -> float | None:
    """The issue's figure: the dense DEM's RMSE over the sparse DEM's, both on the pixels the dense points reach."""
    a = validation.get("dense_on_dense_pixels", {}).get("rmse_m")
    b = validation.get("sparse_on_dense_pixels", {}).get("rmse_m")
    return float(a / b) if a is not None and b else None
