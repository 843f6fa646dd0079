"""The forked ``dem.zarr`` writer of a cold ``mercury-dem grid`` (mercury_dem.pipeline.store_writer).

Each case runs in a fresh interpreter (the writer forks only where no thread runs and zarr is
not yet imported: never inside pytest's own process). Checked: the forked path writes the same
store, file for file and byte for byte, as the in-process path; the gridding process then never
imports zarr; a fault in the child is the project's StoreError naming the store and leaves no
store behind; a fault in the parent stops the child (reaped) and leaves no store; the writer
declines where it does not apply, and ``grid_dem`` then writes in-process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _python(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    e = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
             MERCURY_DEM_PROGRESS="none")
    e.pop("MERCURY_DEM_GRID_WRITER", None)
    e.update(env or {})
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=e, timeout=180, cwd="/tmp")


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 20 000-point cloud (seed 11) and a config of 9 chunks (several writes in flight)."""
    from tests.dem.dem_synthetic import sample_cloud

    d = tmp_path_factory.mktemp("writer")
    np.save(d / "pts.npy", sample_cloud(np.random.default_rng(11), 20_000, (-4.0, 4.0), (30.0, 40.0)))
    cfg = d / "grid.yaml"
    cfg.write_text("dem:\n  pixels_per_degree: 16\n  lat_min: -4.0\n  lat_max: 4.0\n  lon_min: 30.0\n  lon_max: 40.0\n"
                   "  chunk_size: 48\n")
    return d / "pts.npy", cfg


def _grid_code(pts: Path, cfg: Path, out: Path, prelude: str = "") -> str:
    """Run 'mercury-dem grid' in-process; print its exit status, whether zarr got imported, and stderr."""
    return ("import contextlib, io, json, os, sys\n" + prelude +
            "import mercury_dem.cli as c\nerr = io.StringIO()\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):\n"
            f"    rc = c.main(['grid', {str(pts)!r}, '--out', {str(out)!r}, '--config', {str(cfg)!r}, '--no-coverage'])\n"
            "try:\n    os.waitpid(-1, os.WNOHANG)\n    reaped = False\nexcept ChildProcessError:\n    reaped = True\n"
            "import gc\n"
            "print(json.dumps({'rc': rc, 'zarr': 'zarr' in sys.modules, 'reaped': reaped, 'err': err.getvalue(),"
            " 'frozen': gc.get_freeze_count()}))\n")


def _result(p: subprocess.CompletedProcess[str]) -> dict:
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def _files(store: Path) -> dict[str, bytes]:
    return {f.relative_to(store).as_posix(): f.read_bytes() for f in sorted(store.rglob("*")) if f.is_file()}


@pytest.mark.integration  # a whole `grid` in fresh interpreters (~1.5 s CPU, 4-9 s wall each)
def test_forked_writer_writes_the_in_process_store_byte_for_byte(cloud: tuple[Path, Path], tmp_path: Path) -> None:
    pts, cfg = cloud
    forked = _result(_python(_grid_code(pts, cfg, tmp_path / "forked")))
    inproc = _result(_python(_grid_code(pts, cfg, tmp_path / "inproc"), {"MERCURY_DEM_GRID_WRITER": "inprocess"}))
    assert forked["rc"] == 0 and inproc["rc"] == 0, (forked, inproc)
    assert forked["zarr"] is False  # the child wrote the store: the gridding process never imported zarr
    assert inproc["zarr"] is True  # the probe sees zarr when this process writes (so the check above can fail)
    assert forked["reaped"] and inproc["reaped"]
    assert forked["frozen"] == 0 and inproc["frozen"] == 0  # main(argv): a process that lives on is never frozen
    # the program itself (main() without argv: the exit-time garbage collection skipped, mercury_dem.cli)
    prog = _python("import sys, runpy\n"
                   f"sys.argv = ['mercury-dem', 'grid', {str(pts)!r}, '--out', {str(tmp_path / 'prog')!r}, '--config', "
                   f"{str(cfg)!r}, '--no-coverage']\n"
                   "import gc, mercury_dem.cli as c\nrc = c.main()\nprint('frozen', rc, gc.get_freeze_count() > 0)\n")
    assert prog.returncode == 0 and prog.stdout.strip().splitlines()[-1] == "frozen 0 True", prog.stderr[-2000:]
    a, b = _files(tmp_path / "forked" / "dem.zarr"), _files(tmp_path / "inproc" / "dem.zarr")
    c = _files(tmp_path / "prog" / "dem.zarr")
    assert sorted(a) == sorted(b) == sorted(c) and len([k for k in a if "/c/" in k]) >= 9 * 5  # every chunk, layer
    for name in b:  # attributes, coordinates, chunks: same bytes (the source path is the same file)
        assert a[name] == b[name] == c[name], name
    root = json.loads(a["zarr.json"])
    assert root["attributes"]["complete"] is True and root["attributes"]["n_points"] == 20_000
    assert not [p for p in tmp_path.rglob("*") if ".tmp" in p.name]  # no temporary left


@pytest.mark.integration  # a whole `grid` in fresh interpreters (~1.5 s CPU, 4-9 s wall each)
def test_a_fault_in_the_writer_is_a_store_error_and_leaves_no_store(cloud: tuple[Path, Path], tmp_path: Path) -> None:
    """The child inherits a create_store that fails as a full disk would: the command says where and what."""
    pts, cfg = cloud
    prelude = ("import mercury_dem.pipeline.dem_stage as ds\n"
               "def full(*a, **k):\n    raise OSError(28, 'No space left on device')\n"
               "ds.create_store = full\n")
    r = _result(_python(_grid_code(pts, cfg, tmp_path / "out", prelude)))
    assert r["rc"] == 2, r
    assert "writing " in r["err"] and "No space left on device" in r["err"] and "MERCURY_DEM_GRID_WRITER" in r["err"]
    assert r["zarr"] is False and r["reaped"]
    assert not (tmp_path / "out" / "dem.zarr").exists()
    assert [p.name for p in (tmp_path / "out").iterdir()] == []  # nothing half-written, no temporary


@pytest.mark.integration  # a whole `grid` in fresh interpreters (~1.5 s CPU, 4-9 s wall each)
def test_a_fault_while_gridding_stops_the_writer_and_leaves_no_store(cloud: tuple[Path, Path], tmp_path: Path) -> None:
    pts, cfg = cloud
    prelude = ("import mercury_dem.pipeline.dem_stage as ds\nfrom mercury_dem.exceptions import GridError\n"
               "real, calls = ds.grid_chunk, []\n"
               "def flaky(*a, **k):\n    calls.append(1)\n"
               "    if len(calls) == 3:\n        raise GridError('injected fault in chunk 3')\n"
               "    return real(*a, **k)\n"
               "ds.grid_chunk = flaky\n")
    r = _result(_python(_grid_code(pts, cfg, tmp_path / "out", prelude)))
    assert r["rc"] == 2 and "injected fault in chunk 3" in r["err"], r
    assert r["reaped"]  # the child was stopped and waited for before the temporary store was removed
    assert [p.name for p in (tmp_path / "out").iterdir()] == []


@pytest.mark.integration  # a whole `grid` in fresh interpreters (~1.5 s CPU, 4-9 s wall each)
def test_the_writer_declines_where_it_does_not_apply(cloud: tuple[Path, Path], tmp_path: Path) -> None:
    """No fork with the variable set, with zarr imported, with another thread running; a request it cannot
    carry unchanged (a tuple attribute becomes a JSON list) stops the child and grid_dem writes in-process."""
    pts, cfg = cloud
    code = (
        "import os, sys, threading, json\n"
        "from mercury_dem.pipeline.store_writer import ForkedStoreWriter as W\n"
        "os.environ['MERCURY_DEM_GRID_WRITER'] = 'inprocess'\nassert W.start() is None\n"
        "del os.environ['MERCURY_DEM_GRID_WRITER']\n"
        "ev = threading.Event(); t = threading.Thread(target=ev.wait); t.start()\n"
        "assert W.start() is None\nev.set(); t.join()\n"
        "import numpy as np\nfrom mercury_dem.config import load_config\n"
        "from mercury_dem.geometry.body import MERCURY\nfrom mercury_dem.pipeline.dem_stage import grid_dem\n"
        "w = W.start()\nassert w is not None\n"
        f"summary = grid_dem(np.load({str(pts)!r}), load_config({str(cfg)!r}).dem, {str(tmp_path / 'dem.zarr')!r},"
        " coverage=False, attrs={'t': (1, 2)}, writer=w, body=MERCURY)\n"
        "try:\n    os.waitpid(w.pid, os.WNOHANG)\n    raise SystemExit('child not reaped')\nexcept ChildProcessError:\n"
        "    pass\n"
        "assert 'zarr' in sys.modules\n"  # this process wrote the store
        "import zarr\nassert W.start() is None\n"
        f"g = zarr.open_group({str(tmp_path / 'dem.zarr')!r}, mode='r')\n"
        "print(json.dumps([g.attrs['complete'], g.attrs['t'], int(np.isfinite(g['elevation'][...]).sum())]))\n"
    )
    p = _python(code)
    assert p.returncode == 0, p.stderr[-3000:]
    complete, t, finite = json.loads(p.stdout.strip().splitlines()[-1])
    assert complete is True and t == [1, 2] and finite > 0.9 * 128 * 160


def test_message_reader_survives_any_bytes() -> None:
    """The pipe's reader (parent and child) on truncated or arbitrary bytes: a message, end-of-file (None), or
    ValueError (which the parent turns into StoreError) — never a hang or another exception."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from mercury_dem.pipeline.store_writer import _recv, _send

    def read_all(data: bytes) -> list:
        r, w = os.pipe()
        try:
            os.write(w, data)  # small: fits in the pipe
        finally:
            os.close(w)
        got = []
        try:
            while (msg := _recv(r)) is not None:
                got.append(msg)
        except ValueError:
            got.append("ValueError")
        finally:
            os.close(r)
        return got

    r, w = os.pipe()
    _send(w, {"kind": "write", "name": "elevation", "region": [0, 2, 0, 2], "dtype": "<f4", "shape": [2, 2]},
          np.arange(4, dtype="<f4"))
    os.close(w)
    valid = os.read(r, 1 << 16)
    os.close(r)
    assert read_all(valid) == [({"kind": "write", "name": "elevation", "region": [0, 2, 0, 2], "dtype": "<f4",
                                 "shape": [2, 2]}, np.arange(4, dtype="<f4").tobytes())]

    @settings(max_examples=60, deadline=None)
    @given(cut=st.integers(0, len(valid)), junk=st.binary(max_size=64), flip=st.integers(0, len(valid) - 1))
    def check(cut: int, junk: bytes, flip: int) -> None:
        assert read_all(valid[:cut]) in ([], [read_all(valid)[0]] if cut == len(valid) else [])
        for data in (junk, valid[:flip] + bytes([valid[flip] ^ 0xFF]) + valid[flip + 1:], valid + junk):
            for m in read_all(data):
                assert m == "ValueError" or (isinstance(m, tuple) and isinstance(m[1], bytes)), m

    check()
