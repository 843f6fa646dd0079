"""The notebooks' parameter cells are tagged for papermill, and papermill's parameters reach a notebook.

02_inspect_run is executed with ``papermill.execute_notebook(..., parameters={"RUN": ...})`` and no
``MERCURY_DEM_RUN`` in the environment: the notebook's own default (``tiny_run`` in the working
directory) does not exist there, so it only succeeds if the injected parameter is the one used. This is the
default suite's one execution of 02 (its content is checked here too).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.notebooks.conftest import NOTEBOOKS
from tests.notebooks.test_notebooks import images, text_of


@pytest.mark.parametrize("name", ["01_quickstart.ipynb", "02_inspect_run.ipynb", "03_cluster.ipynb"])
def test_parameter_cell_is_tagged_and_first(name: str) -> None:
    nb = json.loads((NOTEBOOKS / name).read_text())
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    tagged = [i for i, c in enumerate(code) if "parameters" in c["metadata"].get("tags", [])]
    assert tagged == [0], f"{name}: exactly the first code cell carries the 'parameters' tag"
    assert "".join(code[0]["source"]).startswith("# Parameters")


def test_02_inspect_run_with_papermill_parameters(tiny_run: Path, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    papermill = pytest.importorskip("papermill", reason="install the test extra (papermill)")
    monkeypatch.delenv("MERCURY_DEM_RUN", raising=False)
    monkeypatch.delenv("MERCURY_DEM_MISSION", raising=False)
    assert not (tmp_path / "tiny_run").exists()
    out = tmp_path / "02_executed.ipynb"
    nb = papermill.execute_notebook(str(NOTEBOOKS / "02_inspect_run.ipynb"), str(out),
                                    parameters={"RUN": str(tiny_run)}, kernel_name="python3", cwd=str(tmp_path),
                                    progress_bar=False, execution_timeout=600)
    injected = [c for c in nb.cells if "injected-parameters" in c.metadata.get("tags", [])]
    assert len(injected) == 1 and str(tiny_run) in injected[0].source
    text = text_of(nb)
    assert "browse/hillshade.png" in text  # read from the injected RUN's products
    assert out.exists()
    # what 02 shows of the run: its failed tiles, the problem images, and its figures
    report = json.loads((tiny_run / "report.json").read_text())
    for f in report["tiles"]["failed"]:
        assert f["error"] in text or str(f["tile"]) in text
    for image_id in report["images"]["uncontrolled"]:
        assert image_id in text  # the problem images table names them
    # histograms, residual map, hillshade, pointing, DEM validation
    assert images(nb) >= 5
