"""``mercury-dem ortho RUN``: orthoimages of a finished run's controlled images on its DEM, and tile mosaics."""

from __future__ import annotations

import argparse
import sys

from mercury_dem.config import Config

NAME = "ortho"
HELP = "orthorectify a finished run's controlled images onto its DEM; mosaic them per tile"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory (global adjustment and DEM done)")
    p.add_argument("--images", nargs="+", metavar="ID", help="image ids (default: every image of the mission)")
    p.add_argument("--tile", type=int, action="append", metavar="TILE",
                   help="tile id to mosaic; repeatable (default: the tiles of the images' centres)")
    p.add_argument("--out", metavar="DIR", help="output directory (default RUN/products/ortho)")
    p.add_argument("--dem", metavar="DEM", help="DEM store (default RUN/dem.zarr)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.pipeline.ortho_stage import make_orthoimages

    s = make_orthoimages(args.run_dir, out_dir=args.out, images=args.images, tiles=args.tile, dem_path=args.dem,
                         tile_size_deg=config.tiling.tile_size_deg, polar_cut_lat=config.dem.polar_cut_lat,
                         overwrite=args.overwrite)
    for image_id, why in s["skipped"].items():
        print(f"skipped image {image_id}: {why}", file=sys.stderr)
    for image_id, d in s["images"].items():
        print(f"{image_id}: {d['shape'][1]} x {d['shape'][0]} at {d['pixel_m']:g} m/pixel, {d['crs']}, "
              f"{100 * d['valid_fraction']:.0f} % with values")
    for tile, d in s["mosaics"].items():
        if "skipped" in d:
            print(f"mosaic of tile {tile} not written: {d['skipped']}", file=sys.stderr)
        else:
            print(f"mosaic of tile {tile}: {len(d['images'])} images, {d['shape'][1]} x {d['shape'][0]} at "
                  f"{d['pixel_m']:g} m/pixel, {100 * d['valid_fraction']:.0f} % with values")
    print(f"{len(s['images'])} orthoimages, {sum('path' in d for d in s['mosaics'].values())} mosaics in "
          f"{s['out']} ({s['seconds']:.1f} s)")
    return 0 if s["images"] else 1
