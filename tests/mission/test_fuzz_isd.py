"""Fuzzing the CSM ISD reader as ingest uses it: a damaged ISD gives the project's error naming the file."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import MercuryDemError
from mercury_dem.geometry.body import MERCURY
from mercury_dem.mission.ingest import read_image_list, read_isd_image

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "mdis_stereo"
ISD = REAL / "EN0213023991M.json"  # knoten/usgscsm layout, with its image
ALE_ISD = REAL.parent / "EN1072174528M_ale_isd.json"  # ALE layout (geometry only: its pixels are not here)
EXAMPLES = int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", 150))


def _paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a JSON document (dict keys and list indices)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:4]):
            out += _paths(v, prefix + (i,))
    return out


VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**15, 10**15), st.floats(allow_nan=True),
                   st.text(max_size=6), st.lists(st.floats(allow_nan=True), max_size=5),
                   st.lists(st.lists(st.floats(), max_size=4), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.sampled_from(("usgscsm", "ale")), how=st.sampled_from(("value", "delete", "truncate")),
       data=st.data())
def test_damaged_isd_gives_our_error(tmp_path_factory: pytest.TempPathFactory, which: str, how: str,
                                     data: st.DataObject) -> None:
    work = tmp_path_factory.mktemp("isd")
    shutil.copy(REAL / "EN0213023991M_recovered_from_notebook_8bit.png", work / "EN0213023991M_img.png")
    src = ISD if which == "usgscsm" else ALE_ISD
    raw = src.read_text()
    doc = json.loads(raw)
    target = work / ("EN0213023991M.json" if which == "usgscsm" else "EN1072174528M.json")
    if how == "truncate":
        target.write_text(raw[: data.draw(st.integers(0, len(raw) - 1))])
    else:
        path = data.draw(st.sampled_from(_paths(doc)))
        node = doc
        for k in path[:-1]:
            node = node[k]
        if how == "delete" and isinstance(node, dict):
            del node[path[-1]]
        else:
            node[path[-1]] = data.draw(VALUES)
        target.write_text(json.dumps(doc))
    pixels = which == "usgscsm"
    try:
        im = read_isd_image(target, [work], pixels=pixels, body=None if pixels else MERCURY)
    except MercuryDemError as exc:
        assert target.stem in str(exc), str(exc)
        return
    assert im.camera.samples > 0
    assert not pixels or im.pixels.shape == (im.camera.lines, im.camera.samples)


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(max_size=200))
def test_image_list_csv_any_text(tmp_path_factory: pytest.TempPathFactory, text: str) -> None:
    f = tmp_path_factory.mktemp("lst") / "pairs.csv"
    f.write_text(text)
    try:
        out = read_image_list(f)
    except MercuryDemError as exc:
        assert "pairs.csv" in str(exc)
        return
    assert all(isinstance(v, Path) for v in out.values())
