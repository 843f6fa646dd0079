"""Fuzzing the CSM ISD reader as ingest uses it: a damaged ISD gives the project's error naming the file."""

from __future__ import annotations

import copy
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import MercuryDemError
from mercury_dem.geometry.body import MERCURY
from mercury_dem.mission.ingest import read_image_list, read_isd_image

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "mdis_stereo"
ISD = REAL / "EN0213023991M.json"  # knoten/usgscsm layout, with its image
ALE_ISD = REAL.parent / "EN1072174528M_ale_isd.json"  # ALE layout (geometry only: its pixels are not here)
USGSCSM = REAL.parents[1] / "usgscsm"
APOLLO_ISD = REAL.parents[1] / "ale" / "apollometric_isd.json"  # mirrored focal2pixel
#: Every distortion model the reader knows, on usgscsm's orbitalFramer (rotated focal2pixel).
MODELS = {
    "radial": {"coefficients": [1e-4, 2e-6, 0.0]},
    "cahvor": {"coefficients": [1e-4, 2e-6, 0.0, 0.01, -0.02]},
    "dawnfc": {"coefficients": [8.4e-6]},
    "radtan": {"coefficients": [0.03, -0.01, 1e-3, -2e-3, 1e-3]},
    "lrolrocnac": {"coefficients": [1.81e-5]},
    "kaguyalism": {"x": [-0.00096, 0.00098, 8.6e-06, -3.7e-06], "y": [-0.00138, 1.35e-05, 2.7e-06, -6.2e-06],
                   "boresight_x": -0.0725, "boresight_y": 0.0214},
    "transverse": {"x": [0.0, 1.0, 0.0, 1e-4], "y": [0.0, 0.0, 1.0, 0.0, 2e-4]},
}
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


def _damaged(doc: dict, raw: str, how: str, data: st.DataObject) -> str:
    """The ISD text ``raw`` (of ``doc``) truncated, or with one value replaced or deleted (``how``)."""
    if how == "truncate":
        return raw[: data.draw(st.integers(0, len(raw) - 1))]
    path = data.draw(st.sampled_from(_paths(doc)))
    node = doc
    for k in path[:-1]:
        node = node[k]
    if how == "delete" and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = data.draw(VALUES)
    return json.dumps(doc)


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
    target.write_text(_damaged(doc, raw, how, data))
    pixels = which == "usgscsm"
    try:
        im = read_isd_image(target, [work], pixels=pixels, body=None if pixels else MERCURY)
    except MercuryDemError as exc:
        assert target.stem in str(exc), str(exc)
        return
    assert im.camera.samples > 0
    assert not pixels or im.pixels.shape == (im.camera.lines, im.camera.samples)


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.sampled_from(("dawnfc_radtan", "apollo", *MODELS)), how=st.sampled_from(("value", "delete", "truncate")),
       name=st.sampled_from(("X.json", "X.isd", "X")), data=st.data())
def test_damaged_usgscsm_model_isd_gives_our_error(tmp_path_factory: pytest.TempPathFactory, which: str, how: str,
                                                   name: str, data: st.DataObject) -> None:
    """usgscsm's/ALE's ISDs with every distortion model and a mirrored or rotated detector, any file name."""
    from mercury_dem.geometry.body import MOON

    if which == "apollo":
        doc = json.loads(APOLLO_ISD.read_text())
    elif which == "dawnfc_radtan":
        doc = json.loads((USGSCSM / "dawnfc_radtan.json").read_text())
    else:
        doc = json.loads((USGSCSM / "orbitalFramer.json").read_text())
        doc["optical_distortion"] = {which: copy.deepcopy(MODELS[which])}
    target = tmp_path_factory.mktemp("isdm") / name
    raw = json.dumps(doc)
    target.write_text(_damaged(doc, raw, how, data))
    try:
        im = read_isd_image(target, [], pixels=False, body=MOON)
    except MercuryDemError as exc:
        assert str(target) in str(exc), str(exc)
        return
    assert im.camera.samples > 0
    px = np.array([[0.0, 0.0], [im.camera.samples - 1.0, im.camera.lines - 1.0]])
    v = im.camera.pixel_to_camera(px)
    back = im.camera.camera_to_pixel(v)
    cam = im.camera
    tol = 1e-9 * max(1e3, cam.samples, cam.lines, abs(cam.boresight_sample), abs(cam.boresight_line))
    assert np.all(np.isfinite(v)) and np.abs(back - px).max() < tol


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(head=st.binary(max_size=64))
def test_any_bytes_are_an_isd_or_not(tmp_path_factory: pytest.TempPathFactory, head: bytes) -> None:
    """Sniffing never raises; what it calls an ISD is read or refused with our error naming the file."""
    from mercury_dem.geometry.isd import is_isd_file, read_isd

    f = tmp_path_factory.mktemp("sniff") / "blob"
    f.write_bytes(head)
    if is_isd_file(f):
        try:
            read_isd(f)
        except MercuryDemError as exc:
            assert "blob" in str(exc)


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
