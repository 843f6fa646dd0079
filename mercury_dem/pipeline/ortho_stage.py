"""The orthoimage stage runner: a finished run's controlled images on its DEM (``mercury-dem ortho``).

Reads the run's mission (images, cameras), the adjusted poses of the global adjustment
(``global/0/solution.parquet``) and ``dem.zarr`` (or another DEM store), calls
:mod:`mercury_dem.products.ortho` and writes into ``RUN/products/ortho/``::

    <image>.tif                 each image at its native ground pixel scale (COG, float32 DN, NaN no-data)
    mosaic_<tile>.tif           best-pixel mosaic of the tile's images (COG)
    mosaic_<tile>_index.tif     source-image index per mosaic pixel (COG, int32, -1 none; tag SOURCE_IMAGES)
    mosaic_<tile>_dtm.tif       the same mosaic at the DTM's pixel (with ``dtm_pixel_m``: the dense stage's
                                orthoimages at the DTM's scale, as a released DTM's set has them)
    ortho.json                  what was written, the rules, and every skipped image with its reason

Serial (one image in memory at a time): the products stage has no Dask client pattern yet. The dense stage
calls it on the dense DEM (``RUN/products/dense/ortho/``, its pairs' images and tiles).
An image that cannot be read or has no adjusted pose is named in ``skipped`` and the rest goes on.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.exceptions import MercuryDemError, StoreError
from mercury_dem.geometry.body import latlon_to_unit, xyz_to_lat_lon
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.atomic import atomic_write_json
from mercury_dem.io.run_store import PRODUCTS_DIR, RunStore, read_solution
from mercury_dem.products import ortho
from mercury_dem.products.ortho import Orthoimage

ORTHO_DIR = "ortho"


def _overlaps(lat: Any, lon: Any, bounds: tuple[float, float, float, float]) -> bool:
    """Whether a footprint's lat/lon box meets a tile's (longitudes compared modulo 360)."""
    a0, a1, o0, o1 = bounds
    if float(np.max(lat)) < a0 or float(np.min(lat)) > a1:
        return False
    w, e = ortho._unwrapped_lon_range(np.asarray(lon))
    return any(w + k * 360.0 <= o1 and e + k * 360.0 >= o0 for k in (-1, 0, 1))


@dataclass
class _OrthoRun:
    """What the orthoimages of a run read once: its store, mission, DEM (loaded), body, adjusted poses."""

    store: RunStore
    mission: Any
    dem: Any
    dem_path: Path
    body: Any
    poses: dict[str, tuple[Any, Any]]
    out: Path
    overwrite: bool

    def target(self, name: str) -> Path:
        """An output file's path; StoreError if it exists and ``overwrite`` is not set."""
        p = self.out / name
        if p.exists() and not self.overwrite:
            raise StoreError(f"{p} already exists; pass --overwrite to replace it")
        return p


def _open_run(run_dir: str | Path, dem_path: str | Path | None, out_dir: str | Path | None, overwrite: bool
              ) -> _OrthoRun:
    from mercury_dem.mission import open_mission
    from mercury_dem.products.make import dem_body, open_dem

    store = RunStore.open(run_dir)
    if not store.unit_complete("global", 0):
        raise StoreError(f"{store.root} has no completed global adjustment: the orthoimages need its adjusted "
                         "poses; run 'mercury-dem run' to the end first")
    mission = open_mission(store.read_run()["mission"])
    path = Path(dem_path) if dem_path is not None else store.dem_path
    ds = open_dem(path)
    body = dem_body(ds)
    if body.name != mission.body.name:
        raise StoreError(f"the DEM is of {body.name}, the run's mission of {mission.body.name}")
    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(len(sid))
    poses = {str(i): (p, r) for i, p, r, n in zip(sid, pos, rot, nmeas) if n > 0}
    out = Path(out_dir) if out_dir is not None else store.root / PRODUCTS_DIR / ORTHO_DIR
    out.mkdir(parents=True, exist_ok=True)
    return _OrthoRun(store, mission, ds["elevation"].load(), path, body, poses, out, overwrite)


def make_orthoimages(
    run_dir: str | Path,
    *,
    out_dir: str | Path | None = None,
    images: Sequence[str] | None = None,
    tiles: Sequence[int] | None = None,
    dem_path: str | Path | None = None,
    tile_size_deg: float,
    polar_cut_lat: float,
    overwrite: bool = False,
    dtm_pixel_m: float | None = None,
) -> dict[str, Any]:
    """Orthoimages of a finished run's controlled images and mosaics of their tiles; returns a summary.

    Parameters
    ----------
    run_dir : a run directory with a completed global adjustment and a DEM
    out_dir : output directory (default ``RUN/products/ortho``)
    images : image ids (default: every image of the mission)
    tiles : tile ids to mosaic (default: the tiles of the orthorectified images' centres)
    dem_path : the DEM store (default ``RUN/dem.zarr``); its ``body`` must be the mission's
    tile_size_deg : the tile grid of the mosaics (the run's ``tiling.tile_size_deg``)
    polar_cut_lat : polar stereographic beyond this latitude (``dem.polar_cut_lat``)
    overwrite : replace existing files (else StoreError naming the first)
    dtm_pixel_m : also each tile's mosaic at this pixel (the DTM's), ``mosaic_<tile>_dtm.tif``
    """
    t0 = time.perf_counter()
    run = _open_run(run_dir, dem_path, out_dir, overwrite)
    written, skipped, footprints, native = _orthorectify_images(run, images, polar_cut_lat)
    tg = TileGrid(tile_size_deg)
    if tiles is None:
        centres = [xyz_to_lat_lon(latlon_to_unit(*footprints[i]).mean(axis=0)) for i in footprints]
        tiles = sorted({int(tg.tile_of(float(la), float(lo))) for la, lo in centres})
    mosaics = {str(t): _mosaic_tile(run, _bounds(tg, int(t)), int(t), footprints, native, polar_cut_lat, dtm_pixel_m)
               for t in tiles}
    rules = {"pixel": "IFOV x range at the centre pixel, 3 significant digits",
             "mosaic": "per pixel the smallest IFOV x range / cos(emission)",
             "mosaic_pixel": "median native pixel of the tile's images"}
    if dtm_pixel_m is not None:
        rules["mosaic_dtm_pixel"] = f"the DTM's pixel, {dtm_pixel_m:.0f} m"
    summary = {"dem": str(run.dem_path), "body": run.body.name, "images": written, "skipped": skipped,
               "mosaics": mosaics, "rules": rules, "seconds": round(time.perf_counter() - t0, 2)}
    atomic_write_json(run.out / "ortho.json", summary)
    summary["out"] = str(run.out)
    return summary


def _bounds(tg: TileGrid, tile: int) -> tuple[float, float, float, float]:
    a0, a1, o0, o1 = (float(b) for b in tg.bounds(tile))
    return a0, a1, o0, o1


def _orthorectify_images(run: _OrthoRun, images: Sequence[str] | None, polar_cut_lat: float
                         ) -> tuple[dict[str, Any], dict[str, str], dict[str, tuple[Any, Any]], dict[str, float]]:
    """Each image at its native scale (written), or its reason in ``skipped``; (written, skipped, footprints,
    native pixel) by image id.
    """
    hrange = ortho.dem_height_range(run.dem)
    written: dict[str, Any] = {}
    skipped: dict[str, str] = {}
    footprints: dict[str, tuple[Any, Any]] = {}
    native: dict[str, float] = {}
    for image_id in (list(images) if images else run.mission.image_ids):
        if image_id not in run.poses:
            skipped[image_id] = ("not in the mission" if image_id not in set(run.mission.image_ids) else
                                 "no adjusted pose (not controlled by the global adjustment)")
            continue
        c, r = run.poses[image_id]
        try:
            cam = run.mission.camera(image_id)
            o = ortho.orthorectify_native(run.mission.read_image(image_id), cam, c, r, run.dem, body=run.body,
                                          polar_cut_lat=polar_cut_lat)
            footprints[image_id] = ortho.image_footprint(cam, c, r, datum_radius_m=run.body.datum_radius_m,
                                                         height_range_m=hrange)
        except (MercuryDemError, ValueError) as exc:
            skipped[image_id] = str(exc)
            continue
        if not np.isfinite(o.values).any():
            skipped[image_id] = "no pixel on the DEM (the DEM holds no value under the image)"
            continue
        native[image_id] = o.grid.pixel_m
        path = ortho.write_orthoimage(o, run.target(f"{image_id}.tif"), body=run.body, tags={"IMAGE_ID": image_id})
        written[image_id] = {"path": str(path), "crs": o.grid.crs, "pixel_m": o.grid.pixel_m,
                             "shape": [o.grid.height, o.grid.width], "valid_fraction": round(o.valid_fraction, 4)}
    return written, skipped, footprints, native


def _mosaic_tile(run: _OrthoRun, bounds: tuple[float, float, float, float], tile: int,
                 footprints: dict[str, tuple[Any, Any]], native: dict[str, float], polar_cut_lat: float,
                 dtm_pixel_m: float | None) -> dict[str, Any]:
    """A tile's mosaic at its images' median native pixel (and at the DTM's pixel, when given)."""
    members = [i for i in footprints if _overlaps(*footprints[i], bounds)]
    if not members:
        return {"skipped": "no orthorectified image meets the tile"}
    pixel = float(np.median([native[i] for i in members]))
    out: dict[str, Any] = {}
    for suffix, p in (("", pixel),) + ((("_dtm", float(dtm_pixel_m)),) if dtm_pixel_m is not None else ()):
        try:
            grid = ortho.tile_grid(bounds, [footprints[i] for i in members], run.body, p,
                                   polar_cut_lat=polar_cut_lat)
        except ValueError as exc:
            return {"skipped": str(exc)} if not suffix else {**out, "dtm": {"skipped": str(exc)}}
        res = _write_mosaic(run, grid, members, f"mosaic_{tile}{suffix}", tile)
        if suffix:
            out["dtm"] = res
        else:
            out.update(res)
    return out


def _write_mosaic(run: _OrthoRun, grid: ortho.OrthoGrid, members: list[str], name: str, tile: int
                  ) -> dict[str, Any]:
    """Mosaic ``members`` on ``grid`` (one image in memory at a time) into ``<name>.tif`` and its index."""

    def orthos() -> Iterator[Orthoimage]:
        for i in members:
            c, r = run.poses[i]
            yield ortho.orthorectify(run.mission.read_image(i), run.mission.camera(i), c, r, run.dem, grid,
                                     body=run.body)

    values, index = ortho.mosaic_orthos(orthos(), grid)
    mosaic = Orthoimage(values, np.full_like(values, np.nan), grid)
    p = ortho.write_orthoimage(mosaic, run.target(f"{name}.tif"), body=run.body,
                               tags={"TILE_ID": str(tile), "MOSAIC_RULE": "smallest IFOV x range / cos(emission)"})
    q = ortho.write_source_index(index, grid, run.target(f"{name}_index.tif"), body=run.body, image_ids=members)
    used = np.bincount(index[index >= 0], minlength=len(members))
    return {"path": str(p), "index": str(q), "crs": grid.crs, "pixel_m": grid.pixel_m,
            "shape": [grid.height, grid.width], "images": members,
            "pixels_per_image": {m: int(n) for m, n in zip(members, used)},
            "valid_fraction": round(float(np.isfinite(values).mean()), 4)}
