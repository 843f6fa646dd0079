"""JSON records of benchmark runs: ``workflows/benchmarks/records/<benchmark>.jsonl``, one run a line, appended.

A record: ``schema`` (``harness-1``), ``benchmark``, ``parameters`` (the command line's meaning), ``commit``
(``git describe``-free: the full hash, ``+dirty`` when the tree had changes), ``machine`` (CPU model, ``nproc``,
memory, kernel, Python), ``date`` (UTC, ISO 8601), ``values`` (the figures), and optionally ``headline``: the
row this run gives the headline table of ``docs/benchmarks.md`` (see :mod:`harness.headline`).
Older files in the directory (one JSON object or lines without ``schema``) are kept and not read here.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

SCHEMA = "harness-1"
REPO = Path(__file__).resolve().parents[3]
RECORDS = REPO / "workflows" / "benchmarks" / "records"


def commit(repo: Path = REPO) -> str | None:
    """The checked-out commit, ``+dirty`` when tracked files differ from it; None outside a git checkout."""
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


def machine() -> dict[str, Any]:
    """CPU model (``/proc/cpuinfo``), cores (``nproc``: the ones this process may use), memory, kernel, Python."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem = int(line.split()[1]) * 1024
                break
    except OSError:
        pass
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {"cpu": model, "nproc": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            "memory_bytes": mem, "kernel": platform.release(), "python": platform.python_version(),
            "load_average": load}


def make_record(benchmark: str, parameters: Mapping[str, Any], values: Mapping[str, Any],
                headline: Mapping[str, str] | None = None, date: str | None = None) -> dict[str, Any]:
    rec: dict[str, Any] = {
        "schema": SCHEMA, "benchmark": benchmark, "parameters": dict(parameters), "commit": commit(),
        "machine": machine(),
        "date": date or dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        "values": dict(values)}
    if headline is not None:
        rec["headline"] = dict(headline)
    return rec


def append_record(benchmark: str, parameters: Mapping[str, Any], values: Mapping[str, Any],
                  headline: Mapping[str, str] | None = None, records_dir: Path | None = None) -> dict[str, Any]:
    """Append one run's record to ``<records_dir>/<benchmark>.jsonl`` (default: ``workflows/benchmarks/records``,
    or ``$MERCURY_BENCH_RECORDS``) and return it."""
    rec = make_record(benchmark, parameters, values, headline)
    directory = records_dir or Path(os.environ.get("MERCURY_BENCH_RECORDS", RECORDS))
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / f"{benchmark}.jsonl", "a") as fh:
        fh.write(json.dumps(rec, default=_jsonable) + "\n")
    return rec


def _jsonable(x: Any) -> Any:
    if hasattr(x, "tolist"):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON-able: {type(x).__name__}")


def read_records(records_dir: Path = RECORDS) -> list[dict[str, Any]]:
    """Every harness record under ``records_dir`` (files in name order, lines in order)."""
    out = []
    for path in sorted(records_dir.glob("*.jsonl")):
        for line in path.read_text().splitlines():
            if not line.strip():
                continue
            rec = json.loads(line)
            if isinstance(rec, dict) and rec.get("schema") == SCHEMA:
                out.append(rec)
    return out
