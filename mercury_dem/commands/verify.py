"""``mercury-dem verify RUN``: check every finished unit of a run against the checksums committed with it, and
the run's DEM against its body's shape (a bias beyond the body's gross-error bound is an ERROR).
"""

from __future__ import annotations

import argparse
import json
import time

from mercury_dem.config import Config

NAME = "verify"
HELP = ("check a run's finished units against their checksums (a resumed run recomputes the ones that fail) and its "
        "DEM against the body's shape (gross errors: wrong datum, units, body)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory (or object-store URL)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace, config: Config) -> int:
    """Exit status 0 when every checksummed unit matches and the DEM is not grossly off its body's shape; 1 when
    a unit does not match (each named with its files) or the report's ``dem.shape_check`` is a gross error.
    """
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
    shape = None
    if store.report_json.is_file():
        try:
            shape = (json.loads(store.report_json.read_text()).get("dem") or {}).get("shape_check")
        except (OSError, ValueError, AttributeError):
            shape = {"status": "unreadable", "reason": "report.json cannot be read"}
    gross = bool(shape) and shape.get("status") == "gross_error"
    result = {"run": store.location, "units": len(rows), "corrupt": corrupt,
              "without_checksums": [r["unit"] for r in unverifiable], "seconds": seconds,
              "dem_shape_check": shape}
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
        from mercury_dem.pipeline.reference_check import shape_check_lines

        if shape is None:
            print("DEM minus the body's shape: not in report.json (a run without a DEM, or made before the check)")
        elif shape.get("status") == "unreadable":
            print(f"DEM minus the body's shape: {shape['reason']}")
        else:
            for line in shape_check_lines(shape):
                print(line)
    return 1 if corrupt or gross else 0
