"""The notebooks execute top to bottom on the tiny mission (nbclient, a python3 kernel of this venv).

Parameters reach the notebooks through environment variables read in their first
cell (the kernel inherits the test's environment).

Time: tile matching is ~70 % of a tiny run (~40 s of ~57 s on this 2-core machine), so
01 and 03 resume a run whose plan and tile level are copied from the session's shared
tiny run (same mission, same configuration): they still start their cluster, run
regions, hemispheres, globe and DEM on it with live progress, and draw every figure.
01 (a LocalCluster) is the default suite's notebook run; 03 (a cluster reached by
address) and 01 from nothing are slow (.ci/run runs them).
02 is executed once, by papermill (test_papermill.py), with its content checks.
"""

from __future__ import annotations

import json
import re
import shutil
import socket
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tests.notebooks.conftest import NOTEBOOKS
from tests.viz.runs import write_tiny_config

nbformat = pytest.importorskip("nbformat", reason="install the test extra (nbformat, nbclient, ipykernel)")
nbclient = pytest.importorskip("nbclient", reason="install the test extra (nbformat, nbclient, ipykernel)")
pytest.importorskip("ipykernel", reason="install the test extra (nbformat, nbclient, ipykernel)")


def execute(name: str, cwd: Path, env: dict[str, str], monkeypatch: pytest.MonkeyPatch, timeout: int = 600,
            on_cell: Callable[[Any], None] | None = None) -> Any:
    """Run the notebook; ``on_cell(cell)`` is called after each code cell (in nbclient's event loop)."""
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    t0 = time.perf_counter()
    hook = (lambda cell, cell_index, execute_reply: on_cell(cell)) if on_cell else None
    nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3", on_cell_executed=hook,
                            resources={"metadata": {"path": str(cwd)}}).execute()
    nb.metadata["execution_seconds"] = time.perf_counter() - t0
    (cwd / name).write_text(nbformat.writes(nb))  # the executed notebook, for a look after a failure
    return nb


def outputs(nb: Any, kind: str | None = None) -> list[dict[str, Any]]:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
            if kind is None or o.get("output_type") == kind]


def text_of(nb: Any) -> str:
    parts = []
    for o in outputs(nb):
        if o["output_type"] == "stream":
            parts.append(o["text"])
        elif "data" in o:
            parts.append(str(o["data"].get("text/plain", "")) + str(o["data"].get("text/html", "")))
    return "\n".join(parts)


def images(nb: Any) -> int:
    return sum(1 for o in outputs(nb) if "image/png" in o.get("data", {}))


def seeded_run(shared: Path, run: Path) -> Path:
    """A run of the shared tiny run's mission and configuration with only its plan and tile level done."""
    run.mkdir(parents=True)
    shutil.copy2(shared / "run.json", run / "run.json")
    for part in ("plan", "tile"):
        shutil.copytree(shared / part, run / part)
    return run


IFRAME = re.compile(r"<iframe class='mercury-dem-dashboard' src='(http://127\.0\.0\.1:(\d+)/)'")


def dashboard_snapshot(url: str) -> dict[str, Any]:
    """What the dashboard server at ``url`` serves: the HTTP page, and the Bokeh document over its websocket.

    Run in a thread: bokeh.client drives its own event loop, and nbclient's is running here.
    """
    import urllib.request

    def pull() -> dict[str, Any]:
        from bokeh.client import pull_session

        with urllib.request.urlopen(url, timeout=30) as r:
            page = (r.status, r.read().decode())
        with pull_session(url=url) as session:
            doc = session.document
            tiles = dict(doc.get_model_by_name("tiles").data)
            return {"page": page, "title": doc.title, "tile": list(tiles["tile"]), "state": list(tiles["state"]),
                    "info": doc.get_model_by_name("info").text, "tiles_html": doc.get_model_by_name("tile_states").text}

    with ThreadPoolExecutor(1) as pool:
        return pool.submit(pull).result(timeout=60)


def port_closed(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
    except OSError:
        return True
    return False


class DashboardWatch:
    """Checks the embedded dashboard while the notebook runs: after the embed cell, after the run, after stop()."""

    def __init__(self, run_cell: str) -> None:
        self.run_cell = run_cell
        self.url: str | None = None
        self.port = 0
        self.snapshots: dict[str, dict[str, Any]] = {}
        self.closed_after_stop: bool | None = None

    def __call__(self, cell: Any) -> None:
        html = "".join(o.get("data", {}).get("text/html", "") for o in cell.get("outputs", []))
        if "embed(RUN" in cell.source:
            m = IFRAME.search(html)
            assert m, f"the embed cell shows no iframe onto 127.0.0.1: {html[:300]!r}"
            self.url, self.port = m.group(1), int(m.group(2))
            self.snapshots["embedded"] = dashboard_snapshot(self.url)
        elif self.run_cell in cell.source and self.url:
            self.snapshots["after the run"] = dashboard_snapshot(self.url)
        elif "dashboard.stop()" in cell.source:
            self.closed_after_stop = port_closed(self.port)


def check_dashboard(watch: DashboardWatch, n_tiles: int) -> None:
    """The embedded page was served live with the run's tile grid and followed it to the end; then it stopped."""
    assert watch.url, "no embed cell ran"
    first, last = watch.snapshots["embedded"], watch.snapshots["after the run"]
    assert first["page"][0] == 200 and "bokeh" in first["page"][1].lower()
    assert first["title"].startswith("mercury-dem: ")
    assert len(last["tile"]) == n_tiles and last["tile"].count(last["tile"][0]) == 1
    assert all(s in ("done", "failed") for s in last["state"])
    assert last["tiles_html"].count("data-tile=") == n_tiles
    assert "data-status='finished'" in last["info"]
    assert watch.closed_after_stop is True, f"the dashboard server on port {watch.port} still answers after stop()"
    assert port_closed(watch.port)


@pytest.mark.parametrize("name", ["01_quickstart.ipynb", "02_inspect_run.ipynb", "03_cluster.ipynb"])
def test_notebooks_are_stripped_and_have_a_kernelspec(name: str) -> None:
    nb = json.loads((NOTEBOOKS / name).read_text())
    assert nb["metadata"]["kernelspec"]["name"] == "python3"
    for c in nb["cells"]:
        if c["cell_type"] == "code":
            assert c["outputs"] == [] and c["execution_count"] is None, f"{name}: outputs not stripped"


@pytest.mark.parametrize("start", ["tiles matched", pytest.param("from nothing", marks=pytest.mark.slow)])
def test_01_quickstart_on_a_local_cluster(start: str, tiny_mission_path: Path, tiny_run: Path, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    run = tmp_path / "run"
    if start == "tiles matched":
        seeded_run(tiny_run, run)
    watch = DashboardWatch("report = run_pipeline(")
    nb = execute("01_quickstart.ipynb", tmp_path, {
        "MERCURY_DEM_MISSION": str(tiny_mission_path), "MERCURY_DEM_RUN": str(run), "MERCURY_DEM_WORKERS": "2",
        "MERCURY_DEM_CONFIG": str(write_tiny_config(tmp_path / "tiny.yaml")),
    }, monkeypatch, on_cell=watch)
    text = text_of(nb)
    assert "Dask dashboard: http://127.0.0.1:" in text
    assert "global 1/1" in text  # the progress lines
    report = json.loads((run / "report.json").read_text())
    # the run went to the notebook's LocalCluster of MERCURY_DEM_WORKERS=2 single-threaded worker processes on the
    # loopback (executors.connect's description), and the notebook shows that client (its HTML repr)
    assert report["execution"]["mode"] == "local"
    assert re.fullmatch(r"LocalCluster 2 workers x 1 threads on 127\.0\.0\.1", report["execution"]["description"])
    assert "LocalCluster" in text and re.search(r"Workers:</strong>\s*2\b", text), text[:2000]
    assert report["levels"]["global"]["ok"]
    v = report["validation"]["pointing_error_urad"]
    assert v["adjusted_rms"] < v["a_priori_rms"]
    assert images(nb) >= 6  # coverage, tiles, histograms, sigma0, pointing, hillshade
    check_dashboard(watch, n_tiles=report["tiles"]["non_empty"])
    assert "stopped" in text  # the last cell shows the stopped handle


# slow: a second notebook on a second cluster (~75 s here); 01 is the default suite's notebook run on a LocalCluster,
# tests/viz/test_background_run.py covers BackgroundRun and follow; .ci/run runs it
@pytest.mark.slow
def test_03_cluster_by_address(tiny_mission_path: Path, tiny_run: Path, tmp_path: Path,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    from distributed import LocalCluster

    run = seeded_run(tiny_run, tmp_path / "run")
    watch = DashboardWatch("report = job.wait()")
    with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                      processes=True) as cluster:
        nb = execute("03_cluster.ipynb", tmp_path, {
            "MERCURY_DEM_SCHEDULER": cluster.scheduler_address, "MERCURY_DEM_MISSION": str(tiny_mission_path),
            "MERCURY_DEM_RUN": str(run), "MERCURY_DEM_CONFIG": str(write_tiny_config(tmp_path / "tiny.yaml")),
        }, monkeypatch, on_cell=watch)
    text = text_of(nb)
    assert "global 1/1" in text
    report = json.loads((run / "report.json").read_text())
    assert report["execution"]["mode"] == "scheduler" and report["levels"]["global"]["ok"]
    assert images(nb) >= 2
    check_dashboard(watch, n_tiles=report["tiles"]["non_empty"])
