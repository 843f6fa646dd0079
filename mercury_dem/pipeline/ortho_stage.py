"""The orthoimage stage runner: a finished run's controlled images on its DEM (``mercury-dem ortho``).

Reads the run's mission (images, cameras), the adjusted poses of the global adjustment
(``global/0/solution.parquet``) and ``dem.zarr`` (or another DEM store), calls
:mod:`mercury_dem.products.ortho` and writes into ``RUN/products/ortho/``::

    <image>.tif                 each image at its native ground pixel scale (COG, float32 DN, NaN no-data)
    mosaic_<tile>.tif           best-pixel mosaic of the tile's images (COG)
    mosaic_<tile>_index.tif     source-image index per mosaic pixel (COG, int32, -1 none; tag SOURCE_IMAGES)
    ortho.json                  what was written, the rules, and every skipped image with its reason

Serial (one image in memory at a time): the products stage has no Dask client pattern yet.
An image that cannot be read or has no adjusted pose is named in ``skipped`` and the rest goes on.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
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
    """
    from mercury_dem.mission import open_mission
    from mercury_dem.products.make import dem_body, open_dem

    t0 = time.perf_counter()
    store = RunStore.open(run_dir)
    if not store.unit_complete("global", 0):
        raise StoreError(f"{store.root} has no completed global adjustment: the orthoimages need its adjusted "
                         "poses; run 'mercury-dem run' to the end first")
    mission = open_mission(store.read_run()["mission"])
    ds = open_dem(dem_path or store.dem_path)
    body = dem_body(ds)
    if body.name != mission.body.name:
        raise StoreError(f"the DEM is of {body.name}, the run's mission of {mission.body.name}")
    dem = ds["elevation"].load()
    hrange = ortho.dem_height_range(dem)
    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy() if "n_measures" in table else np.ones(len(sid))
    poses = {str(i): (p, r) for i, p, r, n in zip(sid, pos, rot, nmeas) if n > 0}
    out = Path(out_dir) if out_dir is not None else store.root / PRODUCTS_DIR / ORTHO_DIR
    out.mkdir(parents=True, exist_ok=True)

    def target(name: str) -> Path:
        p = out / name
        if p.exists() and not overwrite:
            raise StoreError(f"{p} already exists; pass --overwrite to replace it")
        return p

    written: dict[str, Any] = {}
    skipped: dict[str, str] = {}
    footprints: dict[str, tuple[Any, Any]] = {}
    native: dict[str, float] = {}
    for image_id in (list(images) if images else mission.image_ids):
        if image_id not in poses:
            skipped[image_id] = ("not in the mission" if image_id not in set(mission.image_ids) else
                                 "no adjusted pose (not controlled by the global adjustment)")
            continue
        c, r = poses[image_id]
        try:
            cam = mission.camera(image_id)
            o = ortho.orthorectify_native(mission.read_image(image_id), cam, c, r, dem, body=body,
                                          polar_cut_lat=polar_cut_lat)
            footprints[image_id] = ortho.image_footprint(cam, c, r, datum_radius_m=body.datum_radius_m,
                                                         height_range_m=hrange)
        except (MercuryDemError, ValueError) as exc:
            skipped[image_id] = str(exc)
            continue
        if not np.isfinite(o.values).any():
            skipped[image_id] = "no pixel on the DEM (the DEM holds no value under the image)"
            continue
        native[image_id] = o.grid.pixel_m
        path = ortho.write_orthoimage(o, target(f"{image_id}.tif"), body=body, tags={"IMAGE_ID": image_id})
        written[image_id] = {"path": str(path), "crs": o.grid.crs, "pixel_m": o.grid.pixel_m,
                             "shape": [o.grid.height, o.grid.width], "valid_fraction": round(o.valid_fraction, 4)}

    tg = TileGrid(tile_size_deg)
    if tiles is None:
        centres = [xyz_to_lat_lon(latlon_to_unit(*footprints[i]).mean(axis=0)) for i in footprints]
        tiles = sorted({int(tg.tile_of(float(la), float(lo))) for la, lo in centres})
    mosaics: dict[str, Any] = {}
    for tile in tiles:
        bounds = tuple(float(b) for b in tg.bounds(int(tile)))
        members = [i for i in footprints if _overlaps(*footprints[i], bounds)]  # type: ignore[arg-type]
        if not members:
            mosaics[str(tile)] = {"skipped": "no orthorectified image meets the tile"}
            continue
        pixel = float(np.median([native[i] for i in members]))
        try:
            grid = ortho.tile_grid(bounds, [footprints[i] for i in members], body, pixel,  # type: ignore[arg-type]
                                   polar_cut_lat=polar_cut_lat)
        except ValueError as exc:
            mosaics[str(tile)] = {"skipped": str(exc)}
            continue

        def orthos(grid: ortho.OrthoGrid = grid, members: list[str] = members) -> Iterator[Orthoimage]:
            for i in members:
                c, r = poses[i]
                yield ortho.orthorectify(mission.read_image(i), mission.camera(i), c, r, dem, grid, body=body)

        values, index = ortho.mosaic_orthos(orthos(), grid)
        mosaic = Orthoimage(values, np.full_like(values, np.nan), grid)
        p = ortho.write_orthoimage(mosaic, target(f"mosaic_{tile}.tif"), body=body,
                                   tags={"TILE_ID": str(tile), "MOSAIC_RULE": "smallest IFOV x range / cos(emission)"})
        q = ortho.write_source_index(index, grid, target(f"mosaic_{tile}_index.tif"), body=body, image_ids=members)
        used = np.bincount(index[index >= 0], minlength=len(members))
        mosaics[str(tile)] = {"path": str(p), "index": str(q), "crs": grid.crs, "pixel_m": pixel,
                              "shape": [grid.height, grid.width], "images": members,
                              "pixels_per_image": {m: int(n) for m, n in zip(members, used)},
                              "valid_fraction": round(float(np.isfinite(values).mean()), 4)}
    summary = {"dem": str(dem_path or store.dem_path), "body": body.name, "images": written, "skipped": skipped,
               "mosaics": mosaics, "rules": {"pixel": "IFOV x range at the centre pixel, 3 significant digits",
                                             "mosaic": "per pixel the smallest IFOV x range / cos(emission)",
                                             "mosaic_pixel": "median native pixel of the tile's images"},
               "seconds": round(time.perf_counter() - t0, 2)}
    atomic_write_json(out / "ortho.json", summary)
    summary["out"] = str(out)
    return summary
