"""How long a process that has started numba's gridding kernels takes to exit, with and without ``gc.freeze()``.

    python workflows/benchmarks/bench_exit_gc.py [--repeats 5]

Each repetition runs three fresh interpreters that start the kernels as a cold ``mercury-dem grid`` does
(``mercury_dem.dem.numba_start.start_gridding_kernels``) and then end: normally, after ``gc.freeze()``
(what ``mercury_dem.cli`` does when ``grid`` ends its process), and with ``os._exit(0)`` (no finalisation at
all, the floor). Measured: seconds from the script's last statement to the parent seeing the process end.
Prints a JSON record (medians and all values).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    out: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for mode in ("normal", "freeze", "os_exit"):
            proc = subprocess.Popen([sys.executable, "-c", CHILD, mode], stdout=subprocess.PIPE, text=True, cwd="/tmp",
                                    env=dict(os.environ))
            line = proc.stdout.readline()
            proc.wait()
            out.setdefault(mode, []).append(round(time.time() - float(line), 3))
    print(json.dumps({"date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()), "load_average": os.getloadavg(),
                      "median_exit_s": {k: statistics.median(v) for k, v in out.items()}, "all_s": out}, indent=2))


if __name__ == "__main__":
    main()
