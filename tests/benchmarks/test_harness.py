"""The benchmark harness (``workflows/benchmarks/harness``): what ``measure`` reports, the order of interleaved
runs, the records, and the headline table of docs/benchmarks.md generated from the committed records."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.benchmarks import BENCHMARKS, load_harness

harness = load_harness()
from harness import headline, records  # noqa: E402 - registered by load_harness
from harness.memory import peak_window  # noqa: E402

MB = 1024**2


def _allocate(n_bytes: int) -> int:
    a = np.ones(n_bytes // 8)  # touched: resident
    return int(a.size)


def _spin(seconds: float) -> float:
    t0 = time.process_time()
    x = 0.0
    while time.process_time() - t0 < seconds:
        x += 1.0
    return x


def test_measure_a_callable_reports_its_own_peak_and_value() -> None:
    small = harness.measure(_allocate, 8 * MB)
    big = harness.measure(_allocate, 150 * MB)
    assert big.value == 150 * MB // 8
    # the call's own growth: ~150 MB above its start, and the small call's far less (the parent's pages do not count)
    assert 140 * MB < big.extra_rss_bytes < 230 * MB, big
    assert small.extra_rss_bytes < 60 * MB, small
    assert big.peak_rss_bytes >= big.start_rss_bytes + big.extra_rss_bytes


def test_measure_counts_cpu_of_the_child() -> None:
    m = harness.measure(_spin, 0.4)
    assert m.cpu_s >= 0.35, m  # the child's CPU, not the parent's (which waits)
    assert m.wall_s >= 0.35


def test_measure_a_command_counts_its_children() -> None:
    """CPU and peak of a command include its grandchild (wait4 covers the descendants it waited for)."""
    code = ("import subprocess, sys; subprocess.run([sys.executable, '-c', "
            "'import numpy as np, time; a = np.ones(150 * 2**20 // 8); t = time.process_time()\\n"
            "while time.process_time() - t < 0.3: pass'], check=True)")
    m = harness.measure([sys.executable, "-c", code])
    assert m.returncode == 0
    assert m.peak_rss_bytes > 150 * MB, m
    assert m.cpu_s >= 0.3, m


def test_a_commands_peak_states_its_floor() -> None:
    """A command's ru_maxrss starts at the spawning process's high-water mark (Linux keeps it across exec): the
    record carries that floor, so a peak near it is read as an upper bound."""
    import numpy as np

    held = np.ones(200 * MB // 8)  # this process now holds 200 MB more
    m = harness.measure([sys.executable, "-c", "pass"])
    assert m.extra["parent_rss_bytes"] > 200 * MB and held.sum() > 0
    assert m.peak_rss_bytes >= 0.9 * m.extra["parent_rss_bytes"], m  # the floor the docstring states


def test_measure_reports_a_failing_child() -> None:
    def boom() -> None:
        raise ValueError("the fault")

    with pytest.raises(RuntimeError, match="the fault"):
        harness.measure(boom)
    with pytest.raises(RuntimeError, match="exited 3"):
        harness.measure([sys.executable, "-c", "import sys; sys.exit(3)"])
    assert harness.measure([sys.executable, "-c", "import sys; sys.exit(3)"], check=False).returncode == 3


def test_measure_stops_a_command_past_its_timeout() -> None:
    t0 = time.perf_counter()
    m = harness.measure([sys.executable, "-c", "import time; time.sleep(30)"], check=False, timeout=0.5)
    assert m.extra.get("timed_out") is True
    assert time.perf_counter() - t0 < 10


def test_interleave_alternates_and_ratio_of_medians() -> None:
    order: list[str] = []

    def run(label: str, wall: float):
        def f():
            order.append(label)
            return harness.Measurement(label, wall, wall, 0)
        return f

    out = harness.interleave({"ref": run("ref", 2.0), "ours": run("ours", 0.5)}, repeats=3)
    assert order == ["ref", "ours"] * 3
    assert [len(v) for v in out.values()] == [3, 3]
    assert harness.ratio_of_medians(out["ref"], out["ours"]) == pytest.approx(4.0)


def test_peak_window_sees_a_step_above_the_start() -> None:
    with peak_window() as w:
        a = np.ones(200 * MB // 8)
        del a
    if w.reset:  # where /proc/self/clear_refs is writable the window's peak is its own
        assert 180 * MB < w.extra_bytes < 300 * MB, w


def test_records_append_and_read(tmp_path: Path) -> None:
    rec = harness.append_record("demo", {"n": 3}, {"wall_s": 1.5}, records_dir=tmp_path)
    assert rec["machine"]["nproc"] >= 1 and rec["machine"]["memory_bytes"] > 0
    assert rec["date"].endswith("Z")
    harness.append_record("demo", {"n": 4}, {"wall_s": 2.5}, records_dir=tmp_path)
    (tmp_path / "old.jsonl").write_text(json.dumps({"seconds": 3}) + "\n")  # an older, schema-less record
    got = harness.read_records(tmp_path)
    assert [r["parameters"]["n"] for r in got] == [3, 4]


def _rec(area: str, text: str, date: str, row: int | None = None) -> dict:
    h = {"area": area, "command": "`c`", "text": text, "goal": "g", "status": "s"}
    if row is not None:
        h["row"] = row
    return {"schema": records.SCHEMA, "date": date, "headline": h}


def test_headline_takes_the_newest_record_of_each_area_in_row_order() -> None:
    recs = [_rec("b", "old b", "2026-01-01", row=20), _rec("a", "a | x", "2026-01-01", row=10),
            _rec("b", "new b", "2026-02-01"), _rec("c", "c", "2026-01-01")]
    rows = headline.table(recs).splitlines()[2:]
    assert rows == ["| a | `c` | a \\| x | g | s |", "| b | `c` | new b | g | s |", "| c | `c` | c | g | s |"]
    page = f"intro\n{headline.BEGIN}\nstale\n{headline.END}\nrest\n"
    assert headline.render(page, recs) == f"intro\n{headline.BEGIN}\n{headline.table(recs)}\n{headline.END}\nrest\n"


def test_the_docs_headline_table_is_the_records() -> None:
    """docs/benchmarks.md's headline table is exactly what the generator makes from the committed records."""
    page = headline.DOC.read_text()
    assert headline.BEGIN in page
    assert headline.render(page, harness.read_records(BENCHMARKS / "records")) == page, \
        "run `cd workflows/benchmarks && python -m harness headline` after recording a run"


def test_what_a_measured_callable_prints_is_not_lost(tmp_path: Path) -> None:
    """The child leaves with os._exit: its buffered output must be flushed first (stdout to a file: block-buffered)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import harness, test_harness_child as c; "
            "print('value', harness.measure(c._chatty).value)")
    (tmp_path / "test_harness_child.py").write_text("def _chatty():\n    print('printed in the child')\n    return 7\n")
    out = tmp_path / "out.txt"
    m = harness.measure([sys.executable, "-c", code, str(BENCHMARKS)], log=out,
                        env={"PYTHONPATH": f"{tmp_path}:{BENCHMARKS.parents[1]}", "PATH": "/usr/bin:/bin"})
    assert m.returncode == 0, out.read_text()
    assert out.read_text().splitlines() == ["printed in the child", "value 7"]
