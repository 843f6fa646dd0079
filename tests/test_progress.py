"""Progress display (mercury_dem.progress): counts, elapsed, ETA; plain lines without control characters."""

from __future__ import annotations

import io
import re

import pytest

from mercury_dem.progress import LevelTask, Reporter, counter, eta_seconds, format_seconds

CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f]")  # anything but the newline


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class FakeTty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _lines_reporter(interval: float = 10.0) -> tuple[Reporter, io.StringIO, FakeClock]:
    out, clock = io.StringIO(), FakeClock()
    return Reporter(out, "auto", interval_s=interval, clock=clock), out, clock


def test_eta_and_format() -> None:
    assert eta_seconds(5, 10, 10.0) == pytest.approx(10.0)
    assert eta_seconds(0, 10, 3.0) < 0 and format_seconds(-1.0) == "?"
    assert format_seconds(75.4) == "1:15" and format_seconds(3725) == "1:02:05"


def test_lines_mode_counts_eta_and_no_control_characters() -> None:
    rep, out, clock = _lines_reporter(interval=10.0)
    assert rep.mode == "lines"  # a StringIO is not a terminal
    with rep.task("dem grid", 40, "chunks") as task:
        for _ in range(40):
            clock.t += 1.0  # one chunk a second: 40 s in all
            task.update()
    text = out.getvalue()
    assert not CONTROL.search(text)
    lines = text.splitlines()
    # the start, one line per 10 s (throttled, not one per chunk), the end
    assert lines[0] == "dem grid: 0/40 chunks (0 %) elapsed 0:00 ETA ?"
    assert "dem grid: 10/40 chunks (25 %) elapsed 0:10 ETA 0:30" in lines
    assert lines[-1] == "dem grid: 40/40 chunks (100 %) in 0:40"
    assert 4 <= len(lines) <= 6


def test_bar_mode_redraws_one_line_and_none_prints_nothing() -> None:
    tty, clock = FakeTty(), FakeClock()
    rep = Reporter(tty, "auto", clock=clock)
    assert rep.mode == "bar"
    with rep.task("synth", 4, "images") as task:
        for _ in range(4):
            clock.t += 1.0
            task.update()
    text = tty.getvalue()
    assert text.count("\r") >= 4 and text.endswith("\n") and text.count("\n") == 1
    assert "[####################] 4/4 images" in text
    silent = io.StringIO()
    with Reporter(silent, "none").task("x", 3) as task:
        task.update(3)
    assert silent.getvalue() == "" and Reporter(None).mode == "none"


def test_level_task_failures_and_per_level_eta() -> None:
    rep, out, clock = _lines_reporter(interval=0.0)
    task = LevelTask(rep, "cascade", {"tile": 4, "region": 2})
    for _ in range(2):
        clock.t += 2.0
        task.update("tile")
    assert out.getvalue().splitlines()[-1] == "cascade: tile 2/4 ETA 0:04 | region 0/2 elapsed 0:04"
    task.update("tile", failed=True, message="tile 7 FAILED: no overlap")
    assert "tile 7 FAILED: no overlap" in out.getvalue().splitlines()
    task.close()
    assert out.getvalue().splitlines()[-1] == "cascade: tile 3/4 (1 failed) | region 0/2 in 0:04"
    assert not CONTROL.search(out.getvalue())


def test_counter_callback_closes_at_total() -> None:
    rep, out, clock = _lines_reporter()
    cb = counter(rep, "ingest: reading", "files")
    for i in range(1, 4):
        clock.t += 1.0
        cb(i, 3)
    assert out.getvalue().splitlines()[-1] == "ingest: reading: 3/3 files (100 %) in 0:03"


def test_mode_from_cli_and_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    from mercury_dem import progress

    monkeypatch.setenv("MERCURY_DEM_PROGRESS", "none")
    assert Reporter(FakeTty()).mode == "none"
    progress.set_default_mode("lines")
    try:
        assert Reporter(FakeTty()).mode == "lines"
    finally:
        progress.set_default_mode(None)
    with pytest.raises(ValueError, match="progress mode"):
        Reporter(io.StringIO(), "fancy")
