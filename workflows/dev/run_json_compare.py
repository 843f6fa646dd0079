"""Compare the JSON of two runs: ``report.json``'s key paths, and every unit's ``summary.json`` and ``plan.json``.

``python workflows/dev/run_json_compare.py RUN_A RUN_B`` prints the key paths of ``report.json`` found in only one
run, and each summary whose keys (in order) or values differ; wall-clock values (any key holding ``seconds``,
``started_at``, ``finished_at``, ``created``, ``timings``, ``run``) are left out and each run's own path is read
as ``RUN``. The companion of ``run_fingerprint.py`` (which checks the arrays and tables, not the JSON). Exits 1
when anything differs.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

#: Keys whose values are wall-clock times or paths of the run, not results (any key containing "seconds" too).
TIME_KEYS = frozenset({"started_at", "finished_at", "created", "timings", "run"})


def key_paths(x: Any, prefix: str = "") -> set[str]:
    """Every key path of a JSON value (``/levels[]/rms_px``)."""
    out: set[str] = set()
    if isinstance(x, dict):
        for k, v in x.items():
            out.add(f"{prefix}/{k}")
            out |= key_paths(v, f"{prefix}/{k}")
    elif isinstance(x, list):
        for v in x:
            out |= key_paths(v, prefix + "[]")
    return out


def without_times(x: Any) -> Any:
    """A JSON value with its wall-clock entries removed."""
    if isinstance(x, dict):
        return {k: without_times(v) for k, v in x.items() if k not in TIME_KEYS and "seconds" not in k}
    if isinstance(x, list):
        return [without_times(v) for v in x]
    return x


def main(a: Path, b: Path) -> int:
    """Print the differences between the JSON of runs ``a`` and ``b``; 1 when any."""
    def load(path: Path) -> Any:
        return json.loads(path.read_text().replace(str(a), "RUN").replace(str(b), "RUN"))

    pa, pb = key_paths(load(a / "report.json")), key_paths(load(b / "report.json"))
    print(f"report.json key paths: {len(pa)} in A, {len(pb)} in B; only in A: {sorted(pa - pb)}; "
          f"only in B: {sorted(pb - pa)}")
    n = differ = 0
    for f in [*sorted(a.rglob("summary.json")), a / "plan" / "plan.json"]:
        g = b / f.relative_to(a)
        n += 1
        if not g.exists():
            print("missing", g)
            differ += 1
            continue
        x, y = load(f), load(g)
        if list(x) != list(y):
            print("keys differ", f.relative_to(a), list(x), list(y))
            differ += 1
        elif without_times(x) != without_times(y):
            print("values differ", f.relative_to(a))
            differ += 1
    print(f"{n} summaries compared, {differ} differ")
    return 1 if differ or pa != pb else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
