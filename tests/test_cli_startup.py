"""The CLI starts without the heavy libraries: ``--help`` and small commands stay fast.

Checked on ``sys.modules`` in a fresh interpreter, not on timing (robust on a loaded machine).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("dask", "distributed", "numba", "xarray", "cv2", "zarr", "rasterio", "scipy", "pandas", "matplotlib",
         "bokeh", "pyproj", "numpy")
ROOT = Path(__file__).resolve().parents[1]


def _fresh_python(code: str) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in a fresh interpreter with this checkout first on the path; exit status 0 asserted."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out


def _loaded_after(code: str) -> list[str]:
    probe = code + f"\nimport json, sys\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    return json.loads(_fresh_python(probe).stdout.strip().splitlines()[-1])


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


@pytest.mark.integration  # a command's start-up in a fresh interpreter with numba
def test_gridding_stage_does_not_import_the_products() -> None:
    """``mercury-dem grid`` needs the gridding stage only: the products (matplotlib) load on first use."""
    code = "import sys\nimport mercury_dem.pipeline.dem_stage as d\nassert 'matplotlib' not in sys.modules\n" \
           "from mercury_dem.pipeline.dem_stage import open_dem\nassert open_dem.__module__ == 'mercury_dem.products.make'"
    assert "matplotlib" in _loaded_after(code)  # loaded by the re-export, not before it


#: What the small commands (``info``, ``report``, ``verify``) must not import: each costs 0.1-0.5 s CPU.
NOT_FOR_SMALL_COMMANDS = ("pandas", "dask", "distributed", "xarray", "zarr", "scipy", "matplotlib", "numba", "cv2",
                          "rasterio", "pyproj", "bokeh", "fsspec")


def loaded_by_command(argv: list[str], mods: tuple[str, ...] = NOT_FOR_SMALL_COMMANDS) -> list[str]:
    """Run ``mercury-dem ARGV`` in a fresh interpreter (exit status 0 asserted); the modules of ``mods`` it loaded."""
    code = ("import contextlib, io, json, sys\nimport mercury_dem.cli as c\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert c.main({argv!r}) == 0\n"
            f"print(json.dumps([m for m in {mods!r} if m in sys.modules]))")
    return json.loads(_fresh_python(code).stdout.strip().splitlines()[-1])


def test_info_imports_no_heavy_library(tiny_mission_path: Path, tmp_path: Path) -> None:
    """``info`` reads the catalog with pyarrow (not pandas) and draws its map with Pillow (not matplotlib).

    Import sets, not times (robust on a loaded machine); the times are in docs/benchmarks/dem.md
    (2026-11-26, under the lock: 0.39-0.43 s wall, 0.33-0.35 s CPU with the map; was 1.10-1.12 s wall).
    """
    png = tmp_path / "cov.png"
    assert loaded_by_command(["info", str(tiny_mission_path), "--coverage-map", str(png)]) == []
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    none = tmp_path / "none.png"
    assert loaded_by_command(["info", str(tiny_mission_path), "--coverage-map", str(none), "--no-map"],
                             (*NOT_FOR_SMALL_COMMANDS, "PIL")) == []
    assert not none.exists()
    assert loaded_by_command(["info", str(tiny_mission_path), "--no-map", "--json"]) == []


def test_the_command_probe_can_fail(tiny_mission_path: Path) -> None:
    """``info --json`` computes per-image statistics with numpy: the probe sees numpy (so it sees imports)."""
    assert loaded_by_command(["info", str(tiny_mission_path), "--no-map", "--json"], ("numpy",)) == ["numpy"]


@pytest.mark.integration  # a command's start-up in a fresh interpreter with numba
def test_cold_grid_starts_numba_without_scipy_linalg_or_cffi(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cold ``mercury-dem grid`` loads neither the products' nor numba's optional libraries
    (mercury_dem.dem.numba_start) nor zarr (its forked writer does), and grids exactly what the library gives in a process where they are loaded."""
    import numpy as np
    import zarr

    from mercury_dem.config import load_config
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.io.crs_cache import spatial_ref_attrs
    from mercury_dem.pipeline.dem_stage import grid_dem
    from tests.dem.dem_synthetic import sample_cloud

    # The CRS cache as `make setup` leaves it (python -m mercury_dem.pipeline.warm), in a cache of this test's own:
    # the suite's object-store fixture points $MERCURY_DEM_CACHE at a fresh directory for its session.
    monkeypatch.setenv("MERCURY_DEM_CACHE", str(tmp_path / "cache"))
    spatial_ref_attrs.cache_clear()
    spatial_ref_attrs(MERCURY)

    pts = sample_cloud(np.random.default_rng(7), 30_000, (-5.0, 5.0), (10.0, 20.0))
    np.save(tmp_path / "pts.npy", pts)
    cfg = tmp_path / "grid.yaml"
    cfg.write_text("dem:\n  pixels_per_degree: 16\n  lat_min: -5.0\n  lat_max: 5.0\n  lon_min: 10.0\n  lon_max: 20.0\n")
    # zarr: the store is written by a forked child (mercury_dem.pipeline.store_writer), never imported here
    mods = ("scipy.linalg", "cffi", "numpy.f2py", "pandas", "xarray", "rioxarray", "rasterio", "pyproj", "matplotlib",
            "dask", "distributed", "PIL", "zarr")
    assert loaded_by_command(["grid", str(tmp_path / "pts.npy"), "--out", str(tmp_path / "cli"), "--config", str(cfg),
                              "--no-coverage"], mods) == []
    import scipy.linalg  # noqa: F401  (this process: numba started as usual, with scipy)

    grid_dem(pts, load_config(cfg).dem, tmp_path / "lib" / "dem.zarr", coverage=False, body=MERCURY)
    cli, lib = zarr.open_group(tmp_path / "cli" / "dem.zarr", mode="r"), zarr.open_group(tmp_path / "lib" / "dem.zarr", mode="r")
    assert sorted(cli.array_keys()) == sorted(lib.array_keys())
    for name in lib.array_keys():
        a, b = np.asarray(cli[name][...]), np.asarray(lib[name][...])
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    assert np.isfinite(np.asarray(lib["elevation"][...])).mean() > 0.9


@pytest.mark.integration  # a command's start-up in a fresh interpreter with numba
def test_numba_start_guard_is_scoped() -> None:
    """The refusal lasts for the first call only, and is skipped when numba has already started."""
    code = ("import sys\nfrom mercury_dem.dem.numba_start import start_gridding_kernels\n"
            "assert start_gridding_kernels() is True\n"
            "assert 'scipy.linalg' not in sys.modules and 'cffi' not in sys.modules\n"
            "import scipy.linalg, cffi\n"
            "assert start_gridding_kernels() is False\n"
            "print('ok')\n")
    assert _fresh_python(code).stdout.strip() == "ok"


@pytest.mark.integration  # a command's start-up in a fresh interpreter with numba
def test_numba_start_falls_back_when_a_refused_import_is_needed() -> None:
    """A first call that does need a refused package (a future numba) runs again with it allowed."""
    code = ("import sys\nfrom mercury_dem.dem.numba_start import start_numba_lean\n"
            "def first():\n    import scipy.linalg\n    return scipy.linalg.norm([3.0, 4.0])\n"
            "assert start_numba_lean(first) is False\n"
            "assert 'scipy.linalg' in sys.modules\n"
            "assert not any(type(f).__name__ == '_Refuse' for f in sys.meta_path)\n"
            "print('ok')\n")
    assert _fresh_python(code).stdout.strip() == "ok"
