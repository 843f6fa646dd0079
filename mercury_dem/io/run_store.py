"""The run store: one place that owns every path and key of a run.

Layout of ``RUN/``::

    run.json                  mission path, configuration, versions, creation time
    plan/                     tile of every image, overlap pairs (written once, atomically)
    tile/<id>/                one unit per tile: network.zarr, pairs.parquet, summary.json, .complete
    region/<id>/              network.zarr (adjusted), solution.parquet, summary.json, .complete
    hemisphere/<id>/          the same
    global/0/                 the same; the run's result
    dem.zarr, coverage.zarr   the gridded DEM (written by the DEM stage)
    products/                 GeoTIFF, polar products, browse PNGs, statistics
    report.json               the stable report contract (see docs/design.md)
    performance.html          Dask's performance report (distributed runs)

A *unit* (a tile, region, hemisphere or the globe) is written into a temporary
directory and renamed into place with a completion marker (see
:mod:`mercury_dem.io.atomic`), so a unit directory either is complete or does not
exist; re-running a run skips complete units.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.exceptions import StoreError
from mercury_dem.io.atomic import atomic_write_json, is_complete
from mercury_dem.io.tables import read_table

LEVELS = ("tile", "region", "hemisphere", "global")


@dataclass(frozen=True)
class RunStore:
    """Paths and small readers/writers of one run directory."""

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    @classmethod
    def open(cls, root: str | Path) -> "RunStore":
        r = Path(root)
        if not (r / "run.json").is_file():
            raise StoreError(f"{r} is not a mercury-dem run (no run.json); run 'mercury-dem run MISSION --out {r}'")
        return cls(r)

    # -- run-level files ---------------------------------------------------------
    @property
    def run_json(self) -> Path:
        return self.root / "run.json"

    @property
    def plan_dir(self) -> Path:
        return self.root / "plan"

    @property
    def report_json(self) -> Path:
        return self.root / "report.json"

    @property
    def dem_path(self) -> Path:
        return self.root / "dem.zarr"

    @property
    def products_dir(self) -> Path:
        return self.root / "products"

    @property
    def performance_html(self) -> Path:
        return self.root / "performance.html"

    def read_run(self) -> dict[str, Any]:
        return json.loads(self.run_json.read_text())

    def write_run(self, info: dict[str, Any]) -> None:
        atomic_write_json(self.run_json, info)

    # -- units ---------------------------------------------------------------------
    def unit_dir(self, level: str, unit_id: int) -> Path:
        if level not in LEVELS:
            raise StoreError(f"unknown level {level!r}; one of {LEVELS}")
        return self.root / level / str(int(unit_id))

    def unit_complete(self, level: str, unit_id: int) -> bool:
        return is_complete(self.unit_dir(level, unit_id))

    def network_path(self, level: str, unit_id: int) -> Path:
        return self.unit_dir(level, unit_id) / "network.zarr"

    def solution_path(self, level: str, unit_id: int) -> Path:
        return self.unit_dir(level, unit_id) / "solution.parquet"

    def summary_path(self, level: str, unit_id: int) -> Path:
        return self.unit_dir(level, unit_id) / "summary.json"

    def read_summary(self, level: str, unit_id: int) -> dict[str, Any]:
        return json.loads(self.summary_path(level, unit_id).read_text())

    def completed_units(self, level: str) -> list[int]:
        d = self.root / level
        if not d.is_dir():
            return []
        return sorted(int(p.name) for p in d.iterdir() if p.name.isdigit() and is_complete(p))

    def remove_level(self, level: str) -> None:
        """Delete every unit of a level (``--force``)."""
        d = self.root / level
        if d.exists():
            shutil.rmtree(d)

    # -- plan ------------------------------------------------------------------------
    def read_plan(self) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Any]]:
        """(images table, overlap pairs table, plan info)."""
        if not is_complete(self.plan_dir):
            raise StoreError(f"{self.plan_dir} is missing or incomplete; re-run 'mercury-dem run'")
        images = read_table(self.plan_dir / "images.parquet", f"run plan {self.plan_dir}")
        pairs = read_table(self.plan_dir / "overlaps.parquet", f"run plan {self.plan_dir}")
        info = json.loads((self.plan_dir / "plan.json").read_text())
        return images, pairs, info


def write_solution(path: Path, image_ids: np.ndarray, rotations: np.ndarray, positions: np.ndarray,
                   extra: dict[str, np.ndarray] | None = None) -> None:
    """Per-image adjusted pointing as Parquet: image_id, rotation_00..22, position_x/y/z, extra columns."""
    cols: dict[str, Any] = {"image_id": np.asarray(image_ids, dtype=str)}
    r = np.asarray(rotations, dtype=np.float64).reshape(-1, 9)
    for k in range(9):
        cols[f"rotation_{k // 3}{k % 3}"] = r[:, k]
    p = np.asarray(positions, dtype=np.float64)
    for k, ax in enumerate("xyz"):
        cols[f"position_{ax}"] = p[:, k]
    for name, values in (extra or {}).items():
        cols[name] = np.asarray(values)
    pd.DataFrame(cols).to_parquet(path, index=False)


def read_solution(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, pd.DataFrame]:
    """(image_ids, rotations (N,3,3), positions (N,3), the whole table)."""
    df = read_table(path, "solution")
    rot = df[[f"rotation_{i}{j}" for i in range(3) for j in range(3)]].to_numpy().reshape(-1, 3, 3)
    pos = df[["position_x", "position_y", "position_z"]].to_numpy()
    return df["image_id"].to_numpy(dtype=str), rot, pos, df
