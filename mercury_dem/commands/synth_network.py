"""``mercury-dem synth-network OUT --measures N``: a synthetic control network of any size, with its truth.

Generated point block by point block and streamed to ``OUT/network`` (a network store
with the images' a-priori geometry and the block table) and ``OUT/truth`` (true poses,
points, outlier flags); see :mod:`mercury_dem.network.synthetic` and
:mod:`mercury_dem.io.synthetic_network_store`.
"""

from __future__ import annotations

import argparse
import json
import sys

from mercury_dem.config import Config

NAME = "synth-network"
HELP = "generate a synthetic control network (MDIS-like NAC/WAC, any size) with its truth, streamed to disk"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="OUT", help="output directory (OUT/network, OUT/truth)")
    p.add_argument("--measures", type=float, required=True, metavar="N", help="about this many measures (1e6, 94.7e6, ...)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--outlier-fraction", type=float, default=0.01, metavar="F", help="share of gross outliers (default 0.01)")
    p.add_argument("--measures-per-image", type=float, default=940.0, metavar="K",
                   help="measures per image, sets the image count (default 940, the reference's)")
    p.add_argument("--block-points", type=int, default=25_000, metavar="P", help="points per block (default 25000: ~1.75e5 measures; a Dask worker holds a contiguous run of blocks)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    p.add_argument("--json", action="store_true", help="print a JSON record")


def run(args: argparse.Namespace, config: Config) -> int:
    import resource

    from mercury_dem.io.synthetic_network_store import write_synthetic_network
    from mercury_dem.network.synthetic import SyntheticSpec
    from mercury_dem.progress import Reporter

    spec = SyntheticSpec(int(args.measures), seed=args.seed, outlier_fraction=args.outlier_fraction,
                         measures_per_image=args.measures_per_image, block_points=args.block_points)
    with Reporter(sys.stderr).task("synth-network", spec.n_blocks, "blocks") as task:
        s = write_synthetic_network(spec, args.out, overwrite=args.overwrite, on_block=lambda d, t: task.update())
    record = {"out": str(s.path), "images": s.images, "points": s.points, "measures": s.measures, "blocks": s.blocks,
              "outliers": s.outliers, "seconds": round(s.seconds, 3),
              "peak_memory_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(f"{s.path}: {s.images} images, {s.points} points, {s.measures} measures ({s.outliers} outliers) "
              f"in {s.blocks} blocks, {s.seconds:.1f} s")
    return 0
