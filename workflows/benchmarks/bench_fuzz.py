"""Fuzz figures (issue 19 §1): every reader's fuzz property run for N inputs, time-boxed, one reader at a time.

For each reader this runs its fuzz test file (the properties in the default suite, docs/design/fuzzing.md) in a
fresh ``pytest`` process with ``MERCURY_DEM_FUZZ_EXAMPLES=N`` and ``--hypothesis-show-statistics``, and prints a
table: inputs tried (hypothesis's passing + failing + invalid test cases, summed over the file's properties, the
seed corpus included), faults (failed tests, with the first lines of each failure kept in ``--log``), wall time,
time per input, and the child's peak RSS (``harness.measure``: ``os.wait4``'s ``ru_maxrss``; the interpreter and
imports included). Each reader's figures are appended to ``records/fuzz.jsonl``.

A reader that runs past ``--timeout`` seconds is stopped (its process group) and reported as such, with no input
count (hypothesis prints its statistics at the end). ``CI=true`` in the environment makes the runs derandomized
(hypothesis's CI profile): the same inputs on every run.

Usage (under the benchmark lock on a shared machine)::

    flock /tmp/mercury_bench.lock python workflows/benchmarks/bench_fuzz.py --examples 2000 --timeout 600
    python workflows/benchmarks/bench_fuzz.py --examples 5000 --only isis_net --seed 7   # one reader, longer

Hypothesis's own seed is fixed per run with ``--seed`` (``-p hypothesis --hypothesis-seed``), so a failure can be
replayed; without it each run draws other inputs.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

from harness import append_record, measure

ROOT = Path(__file__).resolve().parents[2]

#: reader -> its fuzz test file(s) (relative to the checkout).
READERS: dict[str, list[str]] = {
    "isis_net": ["tests/network/test_fuzz_isis.py"],            # ISIS .net v2 and v5
    "isis_cube": ["tests/sources/test_fuzz.py"],               # cube labels, pixels and tables
    "csm_isd": ["tests/mission/test_fuzz_isd.py"],             # CSM ISDs, both layouts
    "bal": ["tests/adjust/test_fuzz_bal.py"],
    "pds3_label": ["tests/geometry/test_fuzz_pds3.py"],
    "altimetry_csv": ["tests/reference/test_fuzz.py", "tests/altimetry/test_fuzz.py"],  # LOLA/MLA RDR, CSV
    "altimetry_store": ["tests/altimetry/test_fuzz_store.py"],
    "mission_store": ["tests/mission/test_fuzz_store.py"],     # catalog.parquet, cameras.json, mission.json
    "yaml_config": ["tests/test_fuzz_config.py"],
    "network_store": ["tests/network/test_fuzz_store.py"],
    "store_location": ["tests/io/test_location_fuzz.py"],
}

STATS = re.compile(r"(\d+) passing, (\d+) failing, and (\d+) invalid")


def run_reader(files: list[str], examples: int, timeout: float, seed: int | None) -> dict[str, object]:
    env = dict(os.environ, MERCURY_DEM_FUZZ_EXAMPLES=str(examples), PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "pytest", *files, "-q", "-p", "no:cacheprovider", "--hypothesis-show-statistics",
           "-W", "error"]
    if seed is not None:
        cmd += ["--hypothesis-seed", str(seed)]
    log = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_fuzz_{os.getpid()}_{abs(hash(tuple(files)))}.log"
    # the child in a session of its own; past the timeout its process group (ours alone) is killed
    run = measure(cmd, label=",".join(files), env=env, cwd=ROOT, check=False, timeout=timeout, log=log)
    timed_out, seconds = bool(run.extra.get("timed_out")), run.wall_s
    text = log.read_text(errors="replace")
    counts = [tuple(map(int, m)) for m in STATS.findall(text)]
    inputs = sum(sum(c) for c in counts)
    summary = re.findall(r"(\d+) (passed|failed|error|errors|skipped)", text.splitlines()[-1] if text else "")
    result = {k: int(n) for n, k in summary}
    failures = re.findall(r"^(?:FAILED|ERROR) (\S+)(?: - (.*))?$", text, flags=re.M)
    return {
        "inputs": None if timed_out else inputs,
        "tests_passed": result.get("passed", 0),
        "faults": len(failures) + (1 if timed_out else 0),
        "failures": [f"{n}: {(m or '')[:200]}" for n, m in failures],
        "timed_out": timed_out,
        "seconds": seconds,
        "per_input_ms": (1e3 * seconds / inputs) if inputs and not timed_out else None,
        "peak_rss_mb": run.peak_rss_bytes / 1024.0**2,
        "cpu_seconds": run.cpu_s,
        "log": str(log),
        "exit": run.returncode,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=2000, help="MERCURY_DEM_FUZZ_EXAMPLES of every property")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per reader before it is stopped")
    ap.add_argument("--only", default="", help=f"comma-separated readers ({', '.join(READERS)})")
    ap.add_argument("--seed", type=int, default=None, help="hypothesis seed (replayable runs)")
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or list(READERS)
    unknown = set(names) - set(READERS)
    if unknown:
        ap.error(f"unknown readers {sorted(unknown)}; known: {', '.join(READERS)}")
    print(f"# bench_fuzz: {args.examples} examples per property, time box {args.timeout:.0f} s, "
          f"seed {args.seed}, CI={os.environ.get('CI', '')!r}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"{'reader':<16}{'inputs':>8}{'faults':>7}{'tests':>6}{'s':>8}{'ms/input':>10}{'peak MB':>9}  log")
    total_faults = 0
    for name in names:
        r = run_reader(READERS[name], args.examples, args.timeout, args.seed)
        append_record("fuzz", {"reader": name, "examples": args.examples, "timeout": args.timeout, "seed": args.seed,
                               "ci": os.environ.get("CI", "")}, {k: v for k, v in r.items() if k != "log"})
        total_faults += int(r["faults"])  # type: ignore[call-overload]
        inputs = "timeout" if r["timed_out"] else str(r["inputs"])
        per = "-" if r["per_input_ms"] is None else f"{r['per_input_ms']:.1f}"
        print(f"{name:<16}{inputs:>8}{r['faults']:>7}{r['tests_passed']:>6}{r['seconds']:>8.1f}{per:>10}"
              f"{r['peak_rss_mb']:>9.0f}  {r['log']}", flush=True)
        for f in r["failures"]:  # type: ignore[attr-defined]
            print(f"    FAILED {f}", flush=True)
    return 1 if total_faults else 0


if __name__ == "__main__":
    sys.exit(main())
