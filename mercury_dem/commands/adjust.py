"""``mercury-dem adjust RUN --level region|hemisphere|global [--id ...]``: re-run one level's adjustments."""

from __future__ import annotations

import argparse
import json
import shutil
import sys

from mercury_dem.config import Config
from mercury_dem.exceptions import StoreError
from mercury_dem.plan.tree import ADJUSTED_LEVELS, CHILD_LEVEL

NAME = "adjust"
HELP = "bundle adjust stored networks of a run at one level (region, hemisphere or global)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory (its lower level must be complete)")
    p.add_argument("--level", required=True, choices=ADJUSTED_LEVELS)
    p.add_argument("--id", help="comma-separated unit ids (default: every unit of the level with input)")
    p.add_argument("--report-dir", help="also write a jigsaw-like bundleout.txt and CSV tables here")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.pipeline.report import unit_message
    from mercury_dem.pipeline.stages import run_adjust_unit
    from mercury_dem.plan.tree import child_ids, units_of_level

    store = RunStore.open(args.run_dir)
    run_cfg = store.read_run().get("config")
    if run_cfg is not None:
        from mercury_dem.config import load_config

        config = load_config(args.config, overrides=None) if args.config else load_config(overrides=run_cfg)
    tile_size = config.tiling.tile_size_deg
    ids = [int(x) for x in args.id.split(",")] if args.id else units_of_level(args.level, tile_size)
    child = CHILD_LEVEL[args.level]
    ids = [u for u in ids if any(store.unit_complete(child, c) for c in child_ids(args.level, u, tile_size))]
    if not ids:
        raise StoreError(f"no {args.level} of {args.run_dir} has a complete {child} network; run the earlier stages first")
    out = []
    for u in ids:
        store.remove(f"{args.level}/{u}")
        s = run_adjust_unit(store.location, args.level, u, config)
        out.append(s)
        if args.report_dir and s["ok"]:
            _write_tables(store, args.level, u, args.report_dir)
        if not args.json:
            if s["ok"]:
                print(f"{s['name']}: {s['images']} images, {s['points']} points, {s['measures']} measures, "
                      f"rms {s['rms_px']:.3f} px, sigma0 {s['sigma0']:.3f}, {s['rejected']} rejected, "
                      f"{s['iterations']} iterations, {s['seconds']:.1f} s", file=sys.stdout)
            else:
                print(f"{s['name']}: FAILED: {unit_message(s['error'], s['name'])}", file=sys.stdout)
    if args.json:
        print(json.dumps(out, indent=2))
    return 0 if all(s["ok"] for s in out) else 1


def _write_tables(store, level: str, unit: int, directory: str) -> None:  # type: ignore[no-untyped-def]
    """CSV tables of the unit's adjusted network (images, points, residuals)."""
    from pathlib import Path

    from mercury_dem.io.network_store import read_network
    from mercury_dem.io.run_store import BUNDLEOUT_FILE, SUMMARY_FILE, read_solution

    d = Path(directory) / f"{level}_{unit}"
    d.mkdir(parents=True, exist_ok=True)
    net = read_network(store.network_path(level, unit))
    net.points_frame().to_csv(d / "points.csv", index=False)
    net.measures_frame().to_csv(d / "residuals.csv", index=False)
    _, _, _, table = read_solution(store.solution_path(level, unit))
    table.to_csv(d / "images.csv", index=False)
    (d / SUMMARY_FILE).write_text(json.dumps(store.read_summary(level, unit), indent=2))
    report = store.unit_dir(level, unit) / BUNDLEOUT_FILE
    if report.exists():
        shutil.copyfile(report, d / BUNDLEOUT_FILE)
