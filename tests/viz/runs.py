"""One finished run of the tiny mission shared by the viz, notebook and dashboard tests.

Session fixtures of different test directories cannot share an instance, so the
run is cached on disk under the session's base temporary directory: the first
caller computes it (``--scheduler sync``), the others find its report.json.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

#: The DEM section the pipeline tests use: a small grid over the tiny mission's area.
TINY_CONFIG: dict[str, Any] = {
    "dem": {
        "pixels_per_degree": 4.0, "lat_min": -20.0, "lat_max": 30.0, "lon_min": -25.0, "lon_max": 25.0,
        "chunk_size": 64, "browse_width": 256, "stats_pixel_km": 20.0, "coverage_pixel_km": 20.0,
    },
    "execution": {"retries": 2},
}


def write_tiny_config(path: Path) -> Path:
    path.write_text(yaml.safe_dump(TINY_CONFIG))
    return path


def shared_tiny_run(tmp_path_factory: pytest.TempPathFactory, mission_path: Path) -> Path:
    from mercury_dem.config import load_config
    from mercury_dem.pipeline.graph import run_pipeline

    out = tmp_path_factory.getbasetemp() / "shared-tiny-run"
    if not (out / "report.json").is_file():
        run_pipeline(mission_path, out, load_config(overrides=TINY_CONFIG), scheduler="sync", stream=None)
    return out
