"""``mercury-dem cnetcheck NET``: check a control network (a .net file or a network store).

Exit code 0 when the network is sound, 1 when problems were found (dangling
ids, measures outside their image, duplicate measures, islands, ...).
"""

from __future__ import annotations

import argparse
import json

from mercury_dem.config import Config

NAME = "cnetcheck"
HELP = "check a control network (.net or network store): dangling ids, duplicates, islands, statistics"


def _json_default(o: object) -> object:
    import numpy as np

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("net", metavar="NET", help="a .net file or a network store")
    p.add_argument("--json", action="store_true", help="print the full report as JSON")
    p.add_argument("--min-image-measures", type=int, default=3, metavar="N",
                   help="list images with fewer active measures than N (default 3)")
    p.add_argument("--image-size", type=int, nargs=2, metavar=("SAMPLES", "LINES"),
                   help="size of every image, to find measures outside their image")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.network_files import read_any_network
    from mercury_dem.network.check import validate

    net = read_any_network(args.net)
    sizes = None
    if args.image_size:
        sizes = {iid: tuple(args.image_size) for iid in net.image_ids.tolist()}
    report = validate(net, image_sizes=sizes, min_image_measures=args.min_image_measures)
    if args.json:
        print(json.dumps(report.to_dict(), indent=2, default=_json_default))
    else:
        print(f"{args.net}:")
        print(report.summary())
    return 0 if report.ok else 1
