"""The report of a bundle adjustment as files: ``bundleout.txt``, the CSV tables and ``summary.json``.

The text and the tables are made by :mod:`mercury_dem.adjust.report` (strings and DataFrames); this
module only writes them, each atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mercury_dem.adjust.report import images_table, points_table, residuals_table, text_report
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.atomic import atomic_write_json, atomic_write_text


def write_adjustment_report(
    result: AdjustmentResult, directory: str | Path, config: AdjustConfig | None = None, *,
    pointing_sigma_urad: float | None = None,
) -> dict[str, Path]:
    """Write ``bundleout.txt``, ``images.csv``, ``points.csv``, ``residuals.csv`` and ``summary.json``
    into ``directory`` (each atomically). Returns the paths by name. ``pointing_sigma_urad``: the problem's
    a-priori pointing sigma, for the report's CONSTRAINTS.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    out["report"] = atomic_write_text(d / "bundleout.txt", text_report(result, config, pointing_sigma_urad=pointing_sigma_urad))
    for name, table in (("images", images_table), ("points", points_table), ("residuals", residuals_table)):
        out[name] = atomic_write_text(d / f"{name}.csv", table(result).to_csv(index=False))
    summary: dict[str, Any] = result.summary()
    out["summary"] = atomic_write_json(d / "summary.json", summary)
    return out
