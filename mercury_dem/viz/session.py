"""Helpers for interactive sessions: a configuration sized to a mission's area, a run in the
background, and following a run's progress from its store.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.config import Config
    from mercury_dem.mission import Mission

import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from mercury_dem.viz.status import STATES, level_progress, unit_status


def area_config(mission: Mission, pixels_per_degree: float = 4.0, margin_deg: float = 10.0,
                overrides: dict[str, Any] | None = None) -> Any:
    """A configuration whose DEM covers the mission's area (``mission.json`` ``area_deg``) plus a margin.

    Small chunks, browse images and statistics cells suit the small presets (tiny,
    small); a global mission keeps the global DEM bounds. ``overrides`` are nested
    sections applied last (as :func:`mercury_dem.config.load_config` takes them).
    """
    from mercury_dem.config import load_config

    dem: dict[str, Any] = {"pixels_per_degree": float(pixels_per_degree), "chunk_size": 64, "browse_width": 256,
                           "stats_pixel_km": 20.0, "coverage_pixel_km": 20.0}
    area = getattr(mission, "meta", {}).get("area_deg")
    if area:
        la0, la1, lo0, lo1 = (float(v) for v in area)
        dem.update(lat_min=max(la0 - margin_deg, -90.0), lat_max=min(la1 + margin_deg, 90.0),
                   lon_min=lo0 - margin_deg, lon_max=lo1 + margin_deg)
    base: dict[str, Any] = {"dem": dem}
    for k, v in (overrides or {}).items():
        base.setdefault(k, {}).update(v)
    return load_config(overrides=base)


class BackgroundRun:
    """``run_pipeline`` in a daemon thread (for notebooks and tests that watch a run).

    Attributes ``report`` (the report once finished) and ``error`` (the exception if it failed).
    """

    def __init__(self, mission: str | Path, out: str | Path, config: Config, **kwargs: Any) -> None:
        from mercury_dem.pipeline.graph import run_pipeline

        self.out = Path(out)
        self.report: dict[str, Any] | None = None
        self.error: BaseException | None = None
        kwargs.setdefault("stream", None)

        def target() -> None:
            try:
                self.report = run_pipeline(mission, out, config, **kwargs)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller by wait()
                self.error = exc

        self.thread = threading.Thread(target=target, name=f"mercury-dem run {self.out.name}", daemon=True)
        self.thread.start()

    def running(self) -> bool:
        return self.thread.is_alive()

    def wait(self, timeout: float | None = None) -> dict[str, Any]:
        """Block until the run ends; its report (re-raises its exception)."""
        self.thread.join(timeout)
        if self.thread.is_alive():
            raise TimeoutError(f"the run into {self.out} did not finish within {timeout} s")
        if self.error is not None:
            raise self.error
        assert self.report is not None
        return self.report


def progress_line(progress: pd.DataFrame) -> str:
    """``tile 5/14 (1 failed) | region 0/6 (1 running) | ...`` from :func:`level_progress`."""
    parts = []
    for r in progress.itertuples():
        extra = ", ".join(f"{getattr(r, s)} {s}" for s in STATES if s in ("running", "failed") and getattr(r, s))
        parts.append(f"{r.level} {r.done + r.failed}/{r.total}" + (f" ({extra})" if extra else ""))
    return " | ".join(parts)


def follow(run: str | Path, running: Callable[[], bool], interval_s: float = 2.0,
           stream: TextIO | None = sys.stdout, timeout_s: float | None = None) -> pd.DataFrame:
    """Print the run's progress (from its store) whenever it changes, until ``running()`` is False.

    Works for a run driven anywhere (a thread here, a batch job, a cluster) as long
    as its store is readable; returns the last :func:`level_progress` table.
    """
    from mercury_dem.io.run_store import RunStore

    store = RunStore(run)
    t0 = time.monotonic()
    last = ""
    while True:
        alive = running()
        progress = level_progress(unit_status(store))
        line = progress_line(progress)
        if line != last and stream is not None:
            print(f"[{time.monotonic() - t0:6.1f} s] {line}", file=stream, flush=True)
            last = line
        if not alive:
            return progress
        if timeout_s is not None and time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"still running after {timeout_s} s: {line}")
        time.sleep(interval_s)
