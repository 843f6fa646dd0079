"""``mercury-dem import-isis NET.net OUT``: an ISIS3 control network into our network store."""

from __future__ import annotations

import argparse

from mercury_dem.config import Config

NAME = "import-isis"
HELP = "convert an ISIS3 binary control network (.net, version 2 or 5) into a network store"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("net", metavar="NET.net", help="ISIS3 binary control network")
    p.add_argument("out", metavar="OUT", help="network store to write (a directory, Zarr v3)")
    p.add_argument("--serial-map", metavar="FILE", help="serial number -> image id (JSON object, or CSV 'serial,image_id')")
    p.add_argument("--drop-unknown", action="store_true",
                   help="with --serial-map: drop measures of serial numbers not in the map instead of failing")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.isis_net import read_isis_network
    from mercury_dem.io.network_files import load_serial_map
    from mercury_dem.io.network_store import write_network

    mapping = load_serial_map(args.serial_map)
    catalog = sorted(set(mapping.values())) if mapping is not None else None
    net = read_isis_network(args.net, serial_to_image=mapping, image_ids=catalog, drop_unknown=args.drop_unknown)
    if catalog is not None:
        net = net.drop_unused_images()
    write_network(net, args.out, overwrite=args.overwrite)
    dropped = net.metadata.get("dropped_measures")
    print(f"{args.out}: {net.n_images} images, {net.n_points} points, {net.n_measures} measures"
          + (f" ({dropped} measures of unknown images dropped)" if dropped else ""))
    return 0
