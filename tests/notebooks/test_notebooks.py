"""The notebooks execute top to bottom on the tiny mission (nbclient, a python3 kernel of this venv).

Parameters reach the notebooks through environment variables read in their first
cell (the kernel inherits the test's environment).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

from tests.notebooks.conftest import NOTEBOOKS

nbformat = pytest.importorskip("nbformat", reason="install the test extra (nbformat, nbclient, ipykernel)")
nbclient = pytest.importorskip("nbclient", reason="install the test extra (nbformat, nbclient, ipykernel)")
pytest.importorskip("ipykernel", reason="install the test extra (nbformat, nbclient, ipykernel)")


def execute(name: str, cwd: Path, env: dict[str, str], monkeypatch: pytest.MonkeyPatch, timeout: int = 600) -> Any:
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    t0 = time.perf_counter()
    nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
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


@pytest.mark.parametrize("name", ["01_quickstart.ipynb", "02_inspect_run.ipynb", "03_cluster.ipynb"])
def test_notebooks_are_stripped_and_have_a_kernelspec(name: str) -> None:
    nb = json.loads((NOTEBOOKS / name).read_text())
    assert nb["metadata"]["kernelspec"]["name"] == "python3"
    for c in nb["cells"]:
        if c["cell_type"] == "code":
            assert c["outputs"] == [] and c["execution_count"] is None, f"{name}: outputs not stripped"


def test_02_inspect_run(tiny_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    nb = execute("02_inspect_run.ipynb", tmp_path, {"MERCURY_DEM_RUN": str(tiny_run)}, monkeypatch)
    text = text_of(nb)
    report = json.loads((tiny_run / "report.json").read_text())
    for f in report["tiles"]["failed"]:
        assert f["error"] in text or str(f["tile"]) in text
    for image_id in report["images"]["uncontrolled"]:
        assert image_id in text  # the problem images table names them
    assert "browse/hillshade.png" in text
    # histograms, residual map, hillshade, pointing, DEM validation
    assert images(nb) >= 5


def test_01_quickstart_on_a_local_cluster(tiny_mission_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run = tmp_path / "run"
    nb = execute("01_quickstart.ipynb", tmp_path, {
        "MERCURY_DEM_MISSION": str(tiny_mission_path), "MERCURY_DEM_RUN": str(run), "MERCURY_DEM_WORKERS": "2",
    }, monkeypatch)
    text = text_of(nb)
    assert "Dask dashboard: http://127.0.0.1:" in text
    assert "LocalCluster 2 workers" in text or "LocalCluster" in json.loads((run / "report.json").read_text())["execution"]["description"]
    assert "global 1/1" in text  # the progress lines
    report = json.loads((run / "report.json").read_text())
    assert report["execution"]["mode"] == "local"
    v = report["validation"]["pointing_error_urad"]
    assert v["adjusted_rms"] < v["a_priori_rms"]
    assert images(nb) >= 6  # coverage, tiles, histograms, sigma0, pointing, hillshade


@pytest.mark.slow
def test_03_cluster_by_address(tiny_mission_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from distributed import LocalCluster

    run = tmp_path / "run"
    with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                      processes=True) as cluster:
        nb = execute("03_cluster.ipynb", tmp_path, {
            "MERCURY_DEM_SCHEDULER": cluster.scheduler_address, "MERCURY_DEM_MISSION": str(tiny_mission_path),
            "MERCURY_DEM_RUN": str(run),
        }, monkeypatch)
    text = text_of(nb)
    assert "global 1/1" in text
    report = json.loads((run / "report.json").read_text())
    assert report["execution"]["mode"] == "scheduler" and report["levels"]["global"]["ok"]
    assert images(nb) >= 2
