"""Progress of long stages: counts, elapsed time and an ETA, as a live bar or as plain lines.

Pure presentation: nothing here computes or changes a result. Two displays:

``bar``
    one line redrawn in place (carriage return) at most every 0.2 s, for a terminal;
``lines``
    a plain line when a task starts, then at most every ``interval_s`` seconds
    (default 10), and when it ends: no control characters, for logs, CI and notebooks.

``auto`` picks ``bar`` when the stream is a terminal, else ``lines``; ``none`` prints
nothing. The command line sets the mode for the whole process (``--progress``,
:func:`set_default_mode`); the environment variable ``MERCURY_DEM_PROGRESS`` does too.

Written here rather than taken from tqdm or rich because neither is a dependency
of the package, the bar is one formatted line, and the log form (periodic,
throttled, never a control character) would need the same code around either.
Work on Dask reports through the same tasks: the orchestration updates a task as
each future completes (``distributed.as_completed``), which is Dask's own
per-future completion signal, so the counts are the scheduler's.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Self, TextIO

MODES = ("auto", "bar", "lines", "none")
_ENV = "MERCURY_DEM_PROGRESS"
_default_mode: str | None = None


def set_default_mode(mode: str | None) -> None:
    """The mode :func:`reporter` uses when none is given (the CLI's ``--progress``); None: the environment's."""
    global _default_mode
    if mode is not None and mode not in MODES:
        raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
    _default_mode = mode


def default_mode() -> str:
    """``--progress`` if the CLI set it, else ``MERCURY_DEM_PROGRESS`` if valid, else ``auto``."""
    if _default_mode is not None:
        return _default_mode
    env = os.environ.get(_ENV, "").strip().lower()
    return env if env in MODES else "auto"


def format_seconds(s: float) -> str:
    """``H:MM:SS`` (``M:SS`` under an hour); ``?`` for an unknown (negative or non-finite) time."""
    if not (s >= 0.0) or s == float("inf"):
        return "?"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def eta_seconds(done: int, total: int, elapsed: float) -> float:
    """Remaining time at the mean rate so far; -1 (unknown) before the first unit is done."""
    if done <= 0 or total <= 0:
        return -1.0
    return max(0.0, elapsed / done * (total - done))


class Reporter:
    """Where progress goes and how it looks; hands out :class:`Task` objects.

    Parameters
    ----------
    stream : text stream, or None for no output at all
    mode : ``auto``, ``bar``, ``lines`` or ``none`` (None: :func:`default_mode`)
    interval_s : least seconds between two periodic lines (``lines`` mode)
    clock : monotonic clock (tests pass a fake one)
    """

    def __init__(self, stream: TextIO | None = sys.stderr, mode: str | None = None, interval_s: float = 10.0,
                 clock: Callable[[], float] = time.monotonic):
        mode = mode or default_mode()
        if mode not in MODES:
            raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
        if mode == "auto":
            isatty = getattr(stream, "isatty", None)
            mode = "bar" if stream is not None and callable(isatty) and isatty() else "lines"
        self.stream = stream
        self.mode = "none" if stream is None else mode
        self.interval_s = interval_s
        self.clock = clock
        self._bar_open = False

    @property
    def enabled(self) -> bool:
        return self.mode != "none"

    def task(self, label: str, total: int, unit: str = "") -> Task:
        """A counted task of ``total`` units (the start is shown at once in ``lines`` mode)."""
        return Task(self, label, total, unit)

    def message(self, text: str) -> None:
        """A one-off line (a stage starting, a failure), printed below any live bar."""
        if not self.enabled:
            return
        self._end_bar()
        print(text, file=self.stream, flush=True)

    # -- display ---------------------------------------------------------------------------------
    def _show(self, text: str, final: bool) -> None:
        assert self.stream is not None
        if self.mode == "bar":
            width = max(20, shutil.get_terminal_size((100, 24)).columns - 1)
            self.stream.write("\r" + text[:width].ljust(width if not final else len(text[:width])))
            if final:
                self.stream.write("\n")
            self._bar_open = not final
            self.stream.flush()
        else:
            print(text, file=self.stream, flush=True)

    def _end_bar(self) -> None:
        if self._bar_open and self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()
            self._bar_open = False


class _Line(ABC):
    """What :class:`Task` and :class:`LevelTask` share: one throttled progress line, a final line on close."""

    reporter: Reporter
    _last: float
    _closed: bool

    @abstractmethod
    def text(self, final: bool = False) -> str:
        """The progress line (no control characters)."""

    def _complete(self) -> bool:
        """True when the last update needs no line of its own (the final one comes from close())."""
        return False

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """The final line (counts and total time); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self.reporter.enabled:
            self.reporter._show(self.text(final=True), final=True)

    def _emit(self, force: bool) -> None:
        r = self.reporter
        if not r.enabled or self._closed:
            return
        now = r.clock()
        if force or now - self._last >= (0.2 if r.mode == "bar" else r.interval_s):
            if not force and self._complete():
                return
            self._last = now
            r._show(self.text(), final=False)


class Task(_Line):
    """Counts of one task; shows ``label: done/total unit (pct %) elapsed ... ETA ...``.

    Use as a context manager, or call :meth:`close`; :meth:`update` after each unit.
    """

    def __init__(self, reporter: Reporter, label: str, total: int, unit: str = "", t0: float | None = None):
        self.reporter = reporter
        self.label = label
        self.total = max(0, int(total))
        self.unit = unit
        self.done = 0
        self.failed = 0
        self.note = ""
        self.t0 = reporter.clock() if t0 is None else t0
        self._last = -1e300
        self._closed = False
        self._emit(force=True)

    @property
    def elapsed(self) -> float:
        return self.reporter.clock() - self.t0

    def text(self, final: bool = False) -> str:
        """The progress line (no control characters)."""
        el = self.elapsed
        unit = f" {self.unit}" if self.unit else ""
        pct = f" ({100.0 * self.done / self.total:.0f} %)" if self.total else ""
        fail = f", {self.failed} failed" if self.failed else ""
        if final:
            tail = f" in {format_seconds(el)}"
        else:
            tail = f" elapsed {format_seconds(el)} ETA {format_seconds(eta_seconds(self.done, self.total, el))}"
        bar = ""
        if self.reporter.mode == "bar" and self.total:
            n = int(20 * self.done / self.total)
            bar = " [" + "#" * n + "." * (20 - n) + "]"
        note = f" {self.note}" if self.note else ""
        return f"{self.label}:{bar} {self.done}/{self.total}{unit}{pct}{fail}{tail}{note}"

    def update(self, n: int = 1, *, failed: int = 0, note: str = "") -> None:
        """``n`` more units done (``failed`` of them failed); ``note`` is shown after the counts."""
        self.done += n
        self.failed += failed
        if note:
            self.note = note
        self._emit(force=False)

    def _complete(self) -> bool:
        return bool(self.total) and self.done >= self.total


class LevelTask(_Line):
    """Counts of several levels that run at once (the cascade: tile, region, hemisphere, global).

    Shows ``label: tile 12/40 ETA 0:30 | region 3/14 ... | ... elapsed 1:02``. A level's ETA is
    its mean rate since its first unit finished (since the start for the first level), so a
    level that waits on the one before does not count its waiting time. Failures are printed
    at once, as their own line, with the unit's message.
    """

    def __init__(self, reporter: Reporter, label: str, totals: dict[str, int]):
        self.reporter = reporter
        self.label = label
        self.totals = dict(totals)
        self.done = dict.fromkeys(totals, 0)
        self.failed = dict.fromkeys(totals, 0)
        self.first_done: dict[str, float] = {}
        self.t0 = reporter.clock()
        self._last = -1e300
        self._closed = False
        if reporter.enabled:
            self._emit(force=True)

    def _level_eta(self, k: str, now: float, first: bool) -> float:
        done, total = self.done[k], self.totals[k]
        if first:
            return eta_seconds(done, total, now - self.t0)
        if k not in self.first_done or done < 2:
            return -1.0
        return eta_seconds(done - 1, total - 1, now - self.first_done[k])

    def text(self, final: bool = False) -> str:
        now = self.reporter.clock()
        parts = []
        for i, k in enumerate(self.totals):
            s = f"{k} {self.done[k]}/{self.totals[k]}"
            if self.failed[k]:
                s += f" ({self.failed[k]} failed)"
            if not final and 0 < self.done[k] < self.totals[k]:
                s += f" ETA {format_seconds(self._level_eta(k, now, i == 0))}"
            parts.append(s)
        tail = f" in {format_seconds(now - self.t0)}" if final else f" elapsed {format_seconds(now - self.t0)}"
        return f"{self.label}: " + " | ".join(parts) + tail

    def update(self, level: str, *, failed: bool = False, message: str = "") -> None:
        """One unit of ``level`` finished; a failed one prints ``message`` as its own line."""
        if level not in self.done:
            return
        self.done[level] += 1
        if level not in self.first_done:
            self.first_done[level] = self.reporter.clock()
        if failed:
            self.failed[level] += 1
            if message:
                self.reporter.message(message)
        self._emit(force=bool(failed))



def counter(rep: Reporter, label: str, unit: str = "") -> Callable[[int, int], None]:
    """A ``progress(done, total)`` callback (the form library functions take) drawing a :class:`Task`.

    Elapsed time counts from this call (make the callback just before the work); the task
    is shown from the first call (which gives the total) and closes itself at ``done == total``.
    """
    state: dict[str, Task] = {}
    t0 = rep.clock()

    def update(done: int, total: int) -> None:
        task = state.get("task")
        if task is None:
            task = state["task"] = Task(rep, label, total, unit, t0=t0)
        task.total = total
        if done > task.done:
            task.update(done - task.done)
        if done >= total:
            task.close()

    return update


def reporter(stream: TextIO | None = sys.stderr, mode: str | None = None, interval_s: float = 10.0) -> Reporter:
    """A :class:`Reporter` on ``stream`` in ``mode`` (None: the process default, see :func:`default_mode`)."""
    return Reporter(stream, mode, interval_s)


#: A reporter that shows nothing (the default of library functions that take one).
NULL = Reporter(None, "none")
