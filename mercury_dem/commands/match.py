"""``mercury-dem match MISSION --out RUN [--tiles ID,...]``: the tile-matching stage alone."""

from __future__ import annotations

import argparse
import json
import sys

from mercury_dem.config import Config

NAME = "match"
HELP = "match the images of tiles into per-tile control networks (the first stage of 'run')"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mission", help="mission store")
    p.add_argument("--out", required=True, help="run directory (created or reused)")
    p.add_argument("--tiles", help="comma-separated tile ids (default: every non-empty tile)")
    p.add_argument("--force", action="store_true", help="recompute the tiles even when complete")
    p.add_argument("--json", action="store_true", help="print the tile summaries as JSON")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.graph import prepare_store
    from mercury_dem.pipeline.report import unit_message
    from mercury_dem.pipeline.stages import plan_run, run_tile

    store = prepare_store(args.mission, args.out, config, None)
    if store.plan_complete():
        plan = store.read_plan_info()
    else:
        plan = plan_run(store, open_mission(args.mission), config)
    tiles = [int(t) for t in args.tiles.split(",")] if args.tiles else plan["non_empty_tiles"]
    out = []
    for t in tiles:
        if args.force:
            store.remove(f"tile/{t}")
        s = run_tile(store.location, t, config)
        out.append(s)
        if not args.json:
            state = "ok" if s["ok"] else f"FAILED: {unit_message(s['error'], f'tile {t}')}"
            redundant = f" ({s['pairs_redundant']} redundant, not tried)" if s.get("pairs_redundant") else ""
            print(f"tile {t}: {s.get('pairs', 0)} pairs{redundant}, {s.get('pairs_matched', 0)} matched, "
                  f"{s.get('points', 0)} points, {s.get('measures', 0)} measures, {s.get('seconds', 0):.1f} s  {state}",
                  file=sys.stdout)
    if args.json:
        print(json.dumps(out, indent=2))
    return 0 if any(s["ok"] for s in out) else 1
