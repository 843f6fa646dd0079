"""`mercury-dem report` and `mercury-dem verify` on a run whose DEM is checked against its body's shape:
a Moon block gridded with Mercury's datum (heights ~ -702 km) is a gross error (verify exits 1), a
right one is not, and a body without a shape is said so."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from mercury_dem.cli import main
from mercury_dem.geometry.body import MERCURY, MOON
from mercury_dem.reference.body_shape import body_shape, shape_check


def _run_with_check(root: Path, datum_radius_m: float) -> Path:
    """A minimal run directory (run.json, report.json) whose report holds the shape check of a 1 x 1 deg
    Moon block at the Apollo 15 strip: the LOLA shape's radii with 200 m of relief, minus ``datum_radius_m``."""
    moon = body_shape("MOON")
    lat, lon = np.linspace(-19.5, -20.5, 21), np.linspace(144.5, 145.5, 21)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    elev = moon.radius_m(la, lo) + 200.0 * np.cos(np.radians(la) * 90) - datum_radius_m
    check = shape_check(xr.DataArray(elev, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}),
                        body_name="MOON", datum_radius_m=MOON.datum_radius_m, shape=moon)
    root.mkdir()
    (root / "run.json").write_text(json.dumps({"mission": "m"}))
    report = {"run": str(root), "mission": "m",
              "tiles": {"total": 1, "non_empty": 1, "succeeded": 1, "failed": []},
              "images": {"input": 2, "controlled": 2, "uncontrolled": []},
              "levels": {"region": [], "hemisphere": [], "global": None}, "timings": {},
              "dem": {"shape_check": json.loads(json.dumps(check))}}
    (root / "report.json").write_text(json.dumps(report))
    return root


@pytest.mark.parametrize("wrong", [False, True])
def test_report_and_verify_flag_a_wrong_datum(tmp_path: Path, capsys: pytest.CaptureFixture[str], wrong: bool) -> None:
    run = _run_with_check(tmp_path / "run", MERCURY.datum_radius_m if wrong else MOON.datum_radius_m)
    assert main(["report", str(run)]) == 0
    out = capsys.readouterr().out
    assert "DEM minus the body's shape (LOLA LDEM_4" in out
    assert main(["verify", str(run)]) == (1 if wrong else 0)
    vout = capsys.readouterr().out
    for text in (out, vout):
        if wrong:
            assert "ERROR: the DEM's bias against LOLA" in text and "gross-error bound of 3 km for Moon" in text
            assert "Mercury's datum" in text and "wrong datum radius" in text
        else:
            assert "ERROR" not in text and ("bias +" in text or "bias -" in text)
    assert main(["verify", str(run), "--json"]) == (1 if wrong else 0)
    got = json.loads(capsys.readouterr().out)["dem_shape_check"]
    assert got["status"] == ("gross_error" if wrong else "ok")
    assert (got["bias_m"] == pytest.approx(-702_000, abs=1000)) if wrong else abs(got["bias_m"]) < 300


def test_a_body_without_a_shape_is_said_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _run_with_check(tmp_path / "run", MOON.datum_radius_m)
    rep = json.loads((run / "report.json").read_text())
    rep["dem"]["shape_check"] = shape_check(xr.DataArray(np.zeros((2, 2)), dims=("lat", "lon"),
                                                         coords={"lat": [1.0, 0.0], "lon": [0.0, 1.0]}),
                                            body_name="MARS", datum_radius_m=3_396_190.0, shape=None)
    (run / "report.json").write_text(json.dumps(rep))
    assert main(["verify", str(run)]) == 0
    assert "not compared (no packaged shape model of Mars)" in capsys.readouterr().out
