"""``mercury-dem export-isis RUN OUT.net [--level tile:ID|region:ID|hemisphere:ID|global]``."""

from __future__ import annotations

import argparse

from mercury_dem.config import Config
from mercury_dem.exceptions import MercuryDemError, StoreError

NAME = "export-isis"
HELP = "write one of a run's control networks as an ISIS3 binary control network (.net)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN")
    p.add_argument("out", metavar="OUT.net")
    p.add_argument("--level", default="global", help="tile:ID, region:ID, hemisphere:ID or global (default)")
    p.add_argument("--version", type=int, choices=(2, 5), default=5, help="ISIS control network format version")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.isis_net import write_isis_network
    from mercury_dem.io.network_store import read_network
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.pipeline.results import read_summary
    from mercury_dem.plan.tree import LEVELS

    store = RunStore.open(args.run_dir)
    level, _, uid = args.level.partition(":")
    if level not in LEVELS or (level != "global" and not uid.isdigit()):
        raise StoreError(f"--level must be tile:ID, region:ID, hemisphere:ID or global, got {args.level!r}")
    unit = int(uid) if uid else 0
    if not store.unit_complete(level, unit):
        raise StoreError(f"{args.run_dir} has no complete {level} {unit} network")
    path = store.network_path(level, unit)
    if not path.exists():
        raise StoreError(f"{level} {unit} of {args.run_dir} failed and has no network: {read_summary(store, level, unit).error}")
    net = read_network(path)
    write_isis_network(net, args.out, version=args.version, network_id=f"mercury-dem {level} {unit}",
                       target_name=_target_name(store))
    print(f"wrote {args.out}: {net.n_points} points, {net.n_measures} measures, {net.n_images} images (ISIS v{args.version})")
    return 0


def _target_name(store) -> str:  # type: ignore[no-untyped-def]
    """The run's body as ISIS spells a TargetName (``Mercury``, ``Moon``); Mercury when unknown."""
    from mercury_dem.mission import open_mission

    try:
        return str(open_mission(store.read_run()["mission"]).body.name).capitalize()
    except (KeyError, OSError, MercuryDemError):
        return "Mercury"
