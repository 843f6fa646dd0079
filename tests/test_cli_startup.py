"""The CLI starts without the heavy libraries: ``--help`` and small commands stay fast.

Checked on ``sys.modules`` in a fresh interpreter, not on timing (robust on a loaded machine).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

HEAVY = ("dask", "distributed", "numba", "xarray", "cv2", "zarr", "rasterio", "scipy", "pandas", "matplotlib",
         "bokeh", "pyproj", "numpy")
ROOT = Path(__file__).resolve().parents[1]


def _loaded_after(code: str) -> list[str]:
    probe = code + f"\nimport json, sys\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True, timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_cli_import_and_parser_do_not_import_heavy_libraries() -> None:
    assert _loaded_after("import mercury_dem.cli") == []
    # building the parser imports every command module (discovery): they too must stay light
    assert _loaded_after("import mercury_dem.cli as c\nc.build_parser()") == []


def test_help_and_config_template_run_without_heavy_libraries() -> None:
    code = ("import contextlib, io\nimport mercury_dem.cli as c\n"
            "buf = io.StringIO()\n"
            "with contextlib.redirect_stdout(buf):\n"
            "    assert c.main(['config', '--template']) == 0\n"
            "    try:\n        c.main(['--help'])\n    except SystemExit:\n        pass\n"
            "assert 'dem:' in buf.getvalue() and 'COMMAND' in buf.getvalue()\n")
    assert _loaded_after(code) == []


def test_the_probe_can_fail() -> None:
    """The sys.modules probe sees a heavy import when there is one (so the tests above can fail)."""
    assert _loaded_after("import mercury_dem.cli\nimport numpy") == ["numpy"]


def test_gridding_stage_does_not_import_the_products() -> None:
    """``mercury-dem grid`` needs the gridding stage only: the products (matplotlib) load on first use."""
    code = "import sys\nimport mercury_dem.pipeline.dem_stage as d\nassert 'matplotlib' not in sys.modules\n" \
           "from mercury_dem.pipeline.dem_stage import open_dem\nassert open_dem.__module__ == 'mercury_dem.products.make'"
    assert "matplotlib" in _loaded_after(code)  # loaded by the re-export, not before it


def _info_probe(mission: Path, png: Path, *extra: str) -> tuple[list[str], float]:
    """Run ``info`` in a fresh interpreter: the heavy modules it loaded, and its CPU seconds (user + system)."""
    import resource

    mods = ("scipy", "matplotlib", "matplotlib.pyplot", "xarray", "zarr", "numba", "dask", "cv2")
    code = ("import contextlib, io, json, sys\nimport mercury_dem.cli as c\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert c.main(['info', {str(mission)!r}, '--coverage-map', {str(png)!r}, *{list(extra)!r}]) == 0\n"
            f"print(json.dumps([m for m in {mods!r} if m in sys.modules]))")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True, timeout=120)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return json.loads(out.stdout.strip().splitlines()[-1]), cpu


def test_info_loads_neither_scipy_nor_pyplot(tiny_mission_path: Path, tmp_path: Path) -> None:
    """``info`` needs numpy, pandas and (for its map) matplotlib's Agg canvas; no kd-tree, no pyplot.

    CPU time, not wall time, is bounded (a loaded machine stretches the wall clock): measured
    2026-11-26 on this 2-core machine under load ~11, 1.07 s with the map (1.32 s before) and 0.56 s
    with ``--no-map``; the bounds are 3x that.
    """
    loaded, cpu = _info_probe(tiny_mission_path, tmp_path / "cov.png")
    assert loaded == ["matplotlib"] and (tmp_path / "cov.png").stat().st_size > 10_000
    assert cpu < 3.2, cpu
    loaded, cpu = _info_probe(tiny_mission_path, tmp_path / "none.png", "--no-map")
    assert loaded == [] and not (tmp_path / "none.png").exists()
    assert cpu < 1.7, cpu
