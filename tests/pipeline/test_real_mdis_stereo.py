"""The real MDIS NAC stereo pair (CSM ISDs + 8-bit images) end to end, compared with MLA's shape of Mercury."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mercury_dem.cli import main

REAL = Path(__file__).resolve().parents[1] / "data" / "real"

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def mdis_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("mdis")
    src = REAL / "mdis_stereo"
    # MESSENGER's reconstructed MDIS pointing: a few hundred µrad (the sigma matching used before session 11)
    assert main(["ingest", str(root / "m"), str(src / "*.json"), "--pointing-sigma-urad", "450"]) == 0
    cfg = root / "cfg.yaml"
    cfg.write_text("reference:\n  shape_harmonics: package:GTMES_150V05_SHA.TAB\n"  # the packaged table
                   "dense:\n  enabled: true\n")  # the dense stage on a real block (issue 31 section 5.5)
    assert main(["run", str(root / "m"), "--out", str(root / "run"), "--scheduler", "sync",
                 "--config", str(cfg)]) == 0
    return root / "run"


def test_stereo_pair_runs_and_is_compared_with_mla(mdis_run: Path) -> None:
    rep = json.loads((mdis_run / "report.json").read_text())
    g = rep["levels"]["global"]
    assert rep["images"]["controlled"] == 2 and g["rms_px"] <= 0.5 and g["points"] >= 100
    assert (mdis_run / "products" / "dem.tif").is_file()
    shape = next(v for k, v in rep["dem"]["reference"].items() if k.startswith("shape:"))
    # Degree 148 resolves ~52 km: the pair's 60-km overlap is one or two wavelengths, so the spread
    # holds the relief the shape model lacks; an uncontrolled pair floats by a few hundred metres.
    assert shape["n"] > 500 and abs(shape["bias_m"]) < 1000 and shape["std_m"] < 1000
    # Without altimetry the points start on GTMES (1 km sigma) instead of the datum sphere: the pair no longer
    # floats (-482 m, RMSE 651 m, with the datum prior; +23 m, RMSE 368 m with the shape, 2026-12-02).
    assert g["point_prior_centre"]["centre"] == "shape"
    check = rep["dem"]["shape_check"]
    assert check["status"] == "ok" and abs(check["bias_m"]) < 150 and check["shape"]["name"].startswith("GTMES")
    assert abs(shape["bias_m"]) < 150
    assert main(["verify", str(mdis_run)]) == 0


def test_the_pair_gives_a_dense_dem_and_orthoimages(mdis_run: Path) -> None:
    """Issue 31 section 5.5 on the MDIS pair: with the ISDs' Sun read (rows of 4 numbers in km labelled "m",
    geometry/isd._knoten_sun) the pair passes the illumination test and gives a dense DEM, its products, its
    orthoimages and its heights against GTMES beside the sparse DEM's on the same pixels.

    Measured 2026-12-02 (branch hC): incidence 70.9 / 68.2 deg, sun azimuths 2.0 deg apart; 1 pair, 151,115
    points, 118 pixel/deg (3 x 120 m). Against GTMES_150V05 (degree 148: ~52 km, about the whole overlap) on
    25,687 pixels: delivered 498 m RMSE (bias -112 m), dense values alone 706 m (-199 m), sparse 371 m (-27 m);
    the dense cloud sits on the adjusted tie points (median dense - tie -14 m, NMAD 99 m). Holes within the
    footprint (27,856 pixels seen by both images): delivered 0.7 %, sparse 1.6 %, dense values alone 7.4 %.
    """
    rep = json.loads((mdis_run / "report.json").read_text())
    dense = rep["dense"]
    (row,) = dense["pairs"]["table"]
    assert row["status"] == "selected" and row["sun_azimuth_difference_deg"] < 10
    assert dense["pairs"]["selected"] == 1 and dense["points"] > 50_000 and not dense["failures"]
    assert "error" not in dense["products"] and (mdis_run / "products/dense/dem.tif").is_file()
    assert dense["ortho"]["images"] == 2
    ref = dense["reference"]
    key = next(k for k in ref["dense"] if k.startswith("shape:"))
    d, s, f = ref["dense"][key], ref["sparse"][key], ref["delivered"][key]
    assert d["n"] == s["n"] == f["n"] == ref["pixels"] > 10_000  # the same pixels
    holes = dense["dem"]["hole_fraction"]
    assert holes["footprint_pixels"] > 10_000 and holes["delivered"] < holes["sparse"] < 0.05


@pytest.mark.xfail(strict=True, reason="issue 31 section 5.5: on the MDIS pair the delivered dense DEM is 498 m RMSE "
                   "from GTMES_150V05 against the sparse DEM's 371 m on the same 25,687 pixels (dense values alone "
                   "706 m; measured, branch hC). GTMES resolves ~52 km, the whole overlap: the figure is dominated by "
                   "the relief the sparse DEM smooths away and by the mean of the tie-free areas (bias -112 vs -27 m)")
def test_issue_31_dense_no_worse_than_sparse_on_the_mdis_pair(mdis_run: Path) -> None:
    """The issue's goal on the MDIS pair: the delivered dense DEM no farther from GTMES than the sparse one."""
    rep = json.loads((mdis_run / "report.json").read_text())
    ref = rep["dense"]["reference"]
    key = next(k for k in ref["dense"] if k.startswith("shape:"))
    assert ref["delivered"][key]["rmse_m"] <= ref["sparse"][key]["rmse_m"]
