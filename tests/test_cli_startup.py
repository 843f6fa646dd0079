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
