"""Wall and CPU seconds of a command, each run a fresh process from /tmp (N runs, env N, default 5).

    N=5 PYTHONPATH=TREE python workflows/benchmarks/bench_cpu_time.py COMMAND [ARGS...]

CPU = user + system of the child (``getrusage(RUSAGE_CHILDREN)``): on a loaded machine the wall clock
stretches, the CPU time much less; on an idle one a single-threaded start-up's wall time is about its CPU
time. Used for the start-up and cold-grid figures of docs/benchmarks/dem.md (run from ``/tmp``, so the
checkout does not shadow ``PYTHONPATH``).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time

n = int(os.environ.get("N", "5"))
walls, cpus = [], []
for _ in range(n):
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, check=True, cwd="/tmp")
    walls.append(time.perf_counter() - t0)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpus.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
print(f"wall min {min(walls):.3f} median {sorted(walls)[n // 2]:.3f}  "
      f"cpu min {min(cpus):.3f} median {sorted(cpus)[n // 2]:.3f}")
