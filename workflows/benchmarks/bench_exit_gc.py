"""How long a process that has started numba's gridding kernels takes to exit, with and without ``gc.freeze()``.

    python workflows/benchmarks/bench_exit_gc.py [--repeats 5]

Each repetition runs three fresh interpreters that start the kernels as a cold ``mercury-dem grid`` does
(``mercury_dem.dem.numba_start.start_gridding_kernels``) and then end: normally, after ``gc.freeze()``
(what ``mercury_dem.cli`` does when ``grid`` ends its process), and with ``os._exit(0)`` (no finalisation at
all, the floor). Measured: seconds from the script's last statement to the parent seeing the process end
(``harness.measure`` runs each child and gives its wall, CPU and peak; the end is its start plus its wall, the
start taken just before the call, so an exit time is short by the harness's few-microsecond set-up). The three
modes alternate (``harness.interleave``). Prints the record and appends it to ``records/exit_gc.jsonl``
(``harness.append_record``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable

from harness import Measurement, append_record, interleave, measure

CHILD = """
import gc, os, sys, time
from mercury_dem.dem.numba_start import start_gridding_kernels
start_gridding_kernels()
mode = sys.argv[1]
if mode == "freeze":
    gc.freeze()
sys.stdout.write(repr(time.time()) + "\\n")
sys.stdout.flush()
if mode == "os_exit":
    os._exit(0)
"""

MODES = ("normal", "freeze", "os_exit")


def child(mode: str) -> Callable[[], Measurement]:
    """One of :func:`harness.interleave`'s runs: a fresh interpreter ending by ``mode``; its exit seconds in
    ``extra["exit_s"]``."""
    def run() -> Measurement:
        t0 = time.time()
        m = measure([sys.executable, "-c", CHILD, mode], cwd="/tmp", label=mode)
        m.extra["exit_s"] = round(t0 + m.wall_s - float(m.stdout.strip().splitlines()[-1]), 3)
        return m
    return run


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    ms = interleave({mode: child(mode) for mode in MODES}, args.repeats)
    out = {k: [m.extra["exit_s"] for m in v] for k, v in ms.items()}
    values = {"median_exit_s": {k: statistics.median(v) for k, v in out.items()}, "all_s": out,
              "median_wall_s": {k: round(statistics.median(m.wall_s for m in v), 3) for k, v in ms.items()},
              "median_cpu_s": {k: round(statistics.median(m.cpu_s for m in v), 3) for k, v in ms.items()},
              "peak_rss_median_bytes": {k: int(statistics.median(m.peak_rss_bytes for m in v)) for k, v in ms.items()}}
    rec = append_record("exit_gc", {"repeats": args.repeats}, values)
    print(json.dumps(rec, indent=2))


if __name__ == "__main__":
    main()
