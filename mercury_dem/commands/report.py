"""``mercury-dem report RUN``: print a run's report.json as a readable summary (or as JSON)."""

from __future__ import annotations

import argparse
import json
import sys

from mercury_dem.config import Config
from mercury_dem.exceptions import StoreError

NAME = "report"
HELP = "print the report of a run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory")
    p.add_argument("--json", action="store_true", help="print report.json itself")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.pipeline.report import print_report

    store = RunStore.open(args.run_dir)
    if not store.report_json.is_file():
        stopped = (store.read_run() if store.has_run() else {}).get("infrastructure_failure")
        why = f" (it stopped: {stopped['error']}: {stopped['message']})" if stopped else ""
        raise StoreError(f"{args.run_dir} has no report.json yet: the run has not finished{why}; resume it with "
                         "'mercury-dem run'")
    report = json.loads(store.report_json.read_text())
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print_report(report, sys.stdout)
    return 0
