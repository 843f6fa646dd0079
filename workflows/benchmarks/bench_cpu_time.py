"""Wall and CPU seconds of a command, each run a fresh process from /tmp (N runs, env N, default 5).

    N=5 PYTHONPATH=TREE python workflows/benchmarks/bench_cpu_time.py COMMAND [ARGS...]

CPU = user + system of the child and its children (``harness.measure``: ``wait4``'s resource usage): on a loaded machine the wall clock
stretches, the CPU time much less; on an idle one a single-threaded start-up's wall time is about its CPU
time. Used for the start-up and cold-grid figures of docs/benchmarks/dem.md (run from ``/tmp``, so the
checkout does not shadow ``PYTHONPATH``).
"""

from __future__ import annotations

import os
import sys

from harness import interleave, measure

n = int(os.environ.get("N", "5"))
runs = interleave({"command": lambda: measure(sys.argv[1:], cwd="/tmp")}, n)["command"]
walls, cpus = [m.wall_s for m in runs], [m.cpu_s for m in runs]
print(f"wall min {min(walls):.3f} median {sorted(walls)[n // 2]:.3f}  "
      f"cpu min {min(cpus):.3f} median {sorted(cpus)[n // 2]:.3f}")
