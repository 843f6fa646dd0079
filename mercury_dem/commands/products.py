"""``mercury-dem products DIR``: GeoTIFF/PDS products, browse PNGs and statistics of DIR/dem.zarr."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from mercury_dem.config import Config
from mercury_dem.exceptions import MercuryDemError

NAME = "products"
HELP = "make the GeoTIFF, PDS-style, browse and statistics products of DIR/dem.zarr"


class ProfileError(MercuryDemError, ValueError):
    """A --profile argument is malformed."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="directory holding dem.zarr (a run directory or 'grid --out')")
    p.add_argument("--out", metavar="OUT", help="products directory (default DIR/products)")
    p.add_argument("--profile", action="append", default=[], metavar="LAT1,LON1,LAT2,LON2",
                   help="elevation profile along the great circle between two points (degrees); repeatable")
    p.add_argument("--overwrite", action="store_true", help="replace existing product files")


def _run_truth(d: Path) -> Any:
    """The truth height of DIR's mission when DIR is a run of a mission with truth (as ``mercury-dem run``
    gives its products), else None. A run whose mission has moved gets its products without truth.
    """
    import json
    import sys

    from mercury_dem.io.run_store import RUN_FILE

    run_json = d / RUN_FILE
    if not run_json.is_file():
        return None
    try:
        from mercury_dem.mission import open_mission

        mission = open_mission(json.loads(run_json.read_text())["mission"])
    except (MercuryDemError, OSError, KeyError, ValueError) as exc:
        print(f"note: no truth for the products (the run's mission cannot be opened: {exc})", file=sys.stderr)
        return None
    return mission.truth.surface().height if mission.truth is not None else None


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.run_store import COVERAGE_FILE, DEM_FILE, PRODUCTS_DIR
    from mercury_dem.products.make import make_products
    from mercury_dem.products.profile import parse_profile

    try:
        profiles = [parse_profile(t) for t in args.profile]
    except ValueError as exc:
        raise ProfileError(f"--profile: {exc}") from None
    from mercury_dem.io.location import refuse_remote, resolve_location

    loc = resolve_location(args.dir, "DIR")
    store = None
    if isinstance(loc, str):  # a bucket run: products from its cached DEM, committed back unless --out
        from mercury_dem.io.run_store import RunStore

        store = RunStore.open(loc)
        store.fetch_zarr(COVERAGE_FILE)
        if not store.fetch_zarr(DEM_FILE):
            raise MercuryDemError(f"{loc} has no complete {DEM_FILE}; run 'mercury-dem run' to the end first")
        loc = store.root
    d = loc
    out = refuse_remote(args.out, "--out", "omit --out to write DIR/products") if args.out else d / PRODUCTS_DIR
    truth = _run_truth(d)
    summary = make_products(d / DEM_FILE, out, config, truth_height=truth, profiles=profiles,
                            overwrite=args.overwrite or store is not None)
    if store is not None and not args.out:
        store.commit_tree(PRODUCTS_DIR)
    print(summary["table"])
    if summary.get("accuracy"):
        a = summary["accuracy"]
        print(f"DEM minus truth (m): RMSE {a['rmse_m']:.0f}, bias {a['bias_m']:.0f}, std {a['std_m']:.0f}, "
              f"p5/p50/p95 {a['p5_m']:.0f} / {a['p50_m']:.0f} / {a['p95_m']:.0f} (accuracy.json; profiles show the truth)")
    if summary["coverage"]:
        c = summary["coverage"]
        n = c["nearest_point_km"]
        print(f"coverage ({c['pixel_km']:g} km/pixel sinusoidal): {100 * c['occupied_fraction']:.2f} % of map pixels "
              f"hold >= 1 point; of those {100 * c['share_with_1']:.2f} % one, {100 * c['share_with_2']:.2f} % two, "
              f"{100 * c['share_with_3_or_more']:.2f} % three or more; nearest point {n['min']:.3f} / {n['mean']:.2f} "
              f"+- {n['std']:.2f} / {n['max']:.1f} km (min / mean +- std / max)")
    for rel, why in summary["skipped"].items():
        print(f"not written: {out / rel} ({why})")
    print(f"{len(summary['files'])} files in {out} ({summary['seconds']:.1f} s)")
    return 0
