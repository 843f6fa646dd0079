"""Compare the JSON of two runs: ``report.json``'s key paths, and every unit's ``summary.json`` and ``plan.json``.

``python workflows/dev/run_json_compare.py RUN_A RUN_B`` prints the key paths of ``report.json`` found in only one
run, and each summary whose keys (in order) or values differ; wall-clock values (any key holding ``seconds``,
``started_at``, ``finished_at``, ``created``, ``timings``, ``run``) are left out and each run's own path is read
as ``RUN``. The companion of ``run_fingerprint.py`` (which checks the arrays and tables, not the JSON). Exits 1
when anything differs.
"""
import json, sys
from pathlib import Path
TIME = {"seconds", "started_at", "finished_at", "solve_seconds", "verify_seconds", "created", "timings", "run",
        "first_pass_seconds", "wall_seconds"}
def paths(x, pre=""):
    out = set()
    if isinstance(x, dict):
        for k, v in x.items():
            out.add(pre + "/" + k); out |= paths(v, pre + "/" + k)
    elif isinstance(x, list):
        for v in x: out |= paths(v, pre + "[]")
    return out
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if k not in TIME and "seconds" not in k}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x
a, b = Path(sys.argv[1]), Path(sys.argv[2])
def norm(t): return t.replace(str(a), "RUN").replace(str(b), "RUN")
ra, rb = json.loads((a / "report.json").read_text()), json.loads((b / "report.json").read_text())
pa, pb = paths(ra), paths(rb)
print("report.json key paths:", len(pa), len(pb), "only in A:", sorted(pa - pb), "only in B:", sorted(pb - pa))
nd = 0; n = 0
for f in sorted(a.rglob("summary.json")) + [a / "plan" / "plan.json"]:
    g = b / f.relative_to(a)
    n += 1
    if not g.exists(): print("missing", g); nd += 1; continue
    x, y = json.loads(norm(f.read_text())), json.loads(norm(g.read_text()))
    if list(x) != list(y): print("key order/set differs", f.relative_to(a), list(x), list(y)); nd += 1
    elif strip(x) != strip(y): print("values differ", f.relative_to(a)); nd += 1
print(f"{n} summaries compared, {nd} differ")
sys.exit(1 if nd or pa != pb else 0)
