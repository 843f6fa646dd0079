"""``mercury-dem verify RUN``: check every finished unit of a run against the checksums committed with it."""

from __future__ import annotations

import argparse
import json
import time

from mercury_dem.config import Config

NAME = "verify"
HELP = "check a run's finished units against their checksums (a resumed run recomputes the ones that fail)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory (or object-store URL)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace, config: Config) -> int:
    """Exit status 0 when every checksummed unit matches, 1 when any does not (each named with its files)."""
    from mercury_dem.io.atomic import verify_complete
    from mercury_dem.io.run_store import RunStore, unit_name
    from mercury_dem.plan.tree import LEVELS

    store = RunStore.open(args.run_dir)
    t0 = time.perf_counter()
    rows = []
    if store.plan_complete():
        rows.append({"unit": "plan", "problems": verify_complete(store.plan_dir)})
    for level in LEVELS:
        for uid in store.completed_units(level):
            rows.append({"unit": unit_name(level, uid), "path": f"{level}/{uid}",
                         "problems": store.verify_unit(level, uid)})
    seconds = time.perf_counter() - t0
    corrupt = [r for r in rows if r["problems"]]
    unverifiable = [r for r in rows if r["problems"] is None]
    result = {"run": store.location, "units": len(rows), "corrupt": corrupt,
              "without_checksums": [r["unit"] for r in unverifiable], "seconds": seconds}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for r in corrupt:
            print(f"CORRUPT {r['unit']} ({r.get('path', 'plan')}):")
            for line in r["problems"]:
                print(f"  {line}")
        if unverifiable:
            print(f"{len(unverifiable)} units have no checksums (written before they existed): not verifiable")
        print(f"{len(rows)} units checked in {seconds:.2f} s: {len(corrupt)} corrupt"
              + (" — resume the run ('mercury-dem run MISSION --out RUN') to recompute them" if corrupt else ""))
    return 1 if corrupt else 0
