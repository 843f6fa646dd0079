"""The one finished run of the tiny mission shared by the pipeline, viz, notebook and dashboard tests.

Session fixtures of different test directories cannot share an instance, so every directory's fixture
(``sync_run`` in tests/pipeline, ``tiny_run`` in tests/viz, tests/notebooks, tests/dashboard) calls
:func:`shared_sync_run`: the first caller runs the mission (``--scheduler sync``, progress lines written to a
string) and keeps the result for the session, under the session's base temporary directory; the others get it.
It was two identical runs before (the pipeline's and the others'), ~1 min each on this machine.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest
import yaml

#: The configuration the pipeline tests use (a small DEM grid over the tiny mission's area), the same file the
#: tiny-mission benchmarks read.
TINY_CONFIG_FILE = Path(__file__).resolve().parents[2] / "workflows" / "tiny.yaml"
TINY_CONFIG: dict[str, Any] = yaml.safe_load(TINY_CONFIG_FILE.read_text())

#: base temporary directory -> (run, the report run_pipeline returned, its progress lines)
_RUNS: dict[Path, tuple[Path, dict[str, Any], str]] = {}


def write_tiny_config(path: Path) -> Path:
    path.write_text(yaml.safe_dump(TINY_CONFIG))
    return path


def shared_sync_run(tmp_path_factory: pytest.TempPathFactory, mission_path: Path) -> tuple[Path, dict[str, Any], str]:
    """The tiny mission run in-process: (run directory, the report ``run_pipeline`` returned, progress text).

    The progress goes to a string (not a terminal: the 'lines' display), so tests of the progress lines read
    this run's instead of running the mission again. Do not modify the run: copy it first.
    """
    from mercury_dem.config import load_config
    from mercury_dem.pipeline.graph import run_pipeline

    base = tmp_path_factory.getbasetemp()
    if base not in _RUNS:
        out = base / "shared-tiny-run"
        progress = base / "shared-tiny-run.progress.txt"
        if (out / "report.json").is_file() and progress.is_file():  # another process of this session ran it
            _RUNS[base] = (out, json.loads((out / "report.json").read_text()), progress.read_text())
        else:
            stream = io.StringIO()
            report = run_pipeline(mission_path, out, load_config(overrides=TINY_CONFIG), scheduler="sync",
                                  stream=stream)
            progress.write_text(stream.getvalue())
            _RUNS[base] = (out, report, stream.getvalue())
    return _RUNS[base]


def shared_tiny_run(tmp_path_factory: pytest.TempPathFactory, mission_path: Path) -> Path:
    """The directory of :func:`shared_sync_run`'s run."""
    return shared_sync_run(tmp_path_factory, mission_path)[0]
