"""Resident memory of this process, read one way for every benchmark (Linux: ``/proc/self/status``).

``VmHWM`` (the peak) can be reset to the current size by writing ``5`` to ``/proc/self/clear_refs``;
:func:`peak_window` does that, so a peak is the peak of one step and not of the imports before it.
Where ``/proc`` is missing, ``getrusage`` stands in (its ``ru_maxrss`` cannot be reset).
"""

from __future__ import annotations

import resource
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

_STATUS = Path("/proc/self/status")


def _status_kib(field: str) -> int | None:
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith(field):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _maxrss_bytes(who: int) -> int:
    r = resource.getrusage(who).ru_maxrss
    return int(r if sys.platform == "darwin" else r * 1024)  # Linux: KiB, macOS: bytes


def rss_bytes() -> int:
    """Resident memory now, bytes."""
    kib = _status_kib("VmRSS:")
    return kib * 1024 if kib is not None else _maxrss_bytes(resource.RUSAGE_SELF)


def peak_rss_bytes(children: bool = False) -> int:
    """Peak resident memory of this process (since start or the last reset), or of its largest waited-for child."""
    if children:
        return _maxrss_bytes(resource.RUSAGE_CHILDREN)
    kib = _status_kib("VmHWM:")
    return kib * 1024 if kib is not None else _maxrss_bytes(resource.RUSAGE_SELF)


def reset_peak() -> bool:
    """Reset the peak to the current resident size; False where the kernel does not allow it."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


@dataclass
class PeakWindow:
    """Resident memory at the start of a window and the peak within it (bytes); ``extra`` is their difference."""

    start_bytes: int = 0
    peak_bytes: int = 0
    reset: bool = False

    @property
    def extra_bytes(self) -> int:
        return max(self.peak_bytes - self.start_bytes, 0)


@contextmanager
def peak_window() -> Iterator[PeakWindow]:
    """``with peak_window() as w: ...``; afterwards ``w.peak_bytes``, ``w.extra_bytes`` (peak above the start)."""
    w = PeakWindow(reset=reset_peak())
    w.start_bytes = rss_bytes()
    try:
        yield w
    finally:
        w.peak_bytes = peak_rss_bytes()
