"""``mercury-dem cnet-convert IN OUT``: convert between ISIS ``.net`` files and network stores.

The kind of each side follows its extension: ``.net`` is an ISIS3 binary
control network, anything else a network store (Zarr v3 directory).
"""

from __future__ import annotations

import argparse

from mercury_dem.config import Config

NAME = "cnet-convert"
HELP = "convert a control network: .net (ISIS3) <-> network store, by extension"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", help="a .net file or a network store")
    p.add_argument("output", metavar="OUT", help="a .net file or a network store")
    p.add_argument("--isis-version", type=int, choices=(2, 5), default=5, help="version of a .net output (default 5)")
    p.add_argument("--serial-map", metavar="FILE",
                   help="serial number -> image id (JSON object or CSV); applied when reading .net, inverted when writing .net")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.network_files import load_serial_map, read_any_network, write_any_network

    mapping = load_serial_map(args.serial_map)
    net = read_any_network(args.input, serial_to_image=mapping)
    inverse = {v: k for k, v in mapping.items()} if mapping else None
    write_any_network(net, args.output, version=args.isis_version, image_to_serial=inverse, overwrite=args.overwrite)
    print(f"{args.output}: {net.n_images} images, {net.n_points} points, {net.n_measures} measures")
    return 0
