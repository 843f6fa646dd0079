"""Fuzzing the mission store's readers: a damaged mission.json, cameras.json or catalog gives StoreError naming it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import MERCURY
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.mission import MissionWriter, open_mission
from tests.mission.test_store import _tiny_catalog

FILES = ("mission.json", "cameras.json", "catalog.parquet")


@pytest.fixture(scope="module")
def good_mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cams, cat = _tiny_catalog(MERCURY)
    out = tmp_path_factory.mktemp("fuzz") / "m"
    with atomic_directory(out) as tmp:
        w = MissionWriter(tmp)
        for i in range(3):
            w.write_image(tmp, f"im{i}", np.zeros((64, 64), np.uint16))
        w.finish({"source": "test"}, MERCURY, cams, cat)
    return out


def _json_values() -> st.SearchStrategy:
    return st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True),
                     st.text(max_size=8), st.lists(st.integers(), max_size=3), st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


@settings(max_examples=int(__import__("os").environ.get("MERCURY_DEM_FUZZ_EXAMPLES", 120)), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.sampled_from(FILES), how=st.sampled_from(("truncate", "flip", "value")), where=st.floats(0, 1),
       value=_json_values(), data=st.data())
def test_damaged_mission_gives_store_error(good_mission: Path, tmp_path_factory: pytest.TempPathFactory, which: str,
                                           how: str, where: float, value: object, data: st.DataObject) -> None:
    m = tmp_path_factory.mktemp("case") / "m"
    shutil.copytree(good_mission, m)
    f = m / which
    raw = f.read_bytes()
    k = int(where * max(len(raw) - 1, 0))
    if how == "truncate":
        f.write_bytes(raw[:k])
    elif how == "flip":
        f.write_bytes(raw[:k] + bytes([raw[k] ^ 0xFF]) + raw[k + 1:])
    elif which.endswith(".json"):
        doc = json.loads(raw)
        key = data.draw(st.sampled_from(sorted(doc)))
        if which == "cameras.json" and isinstance(doc[key], dict):
            field = data.draw(st.sampled_from(sorted(doc[key])))
            doc[key][field] = value
        else:
            doc[key] = value
        f.write_text(json.dumps(doc))
    else:
        f.write_bytes(raw[: len(raw) // 2])
    try:
        mission = open_mission(m)
    except StoreError as exc:
        assert str(m) in str(exc)
        return
    # accepted: it must still be a consistent mission
    for i in mission.image_ids:
        mission.camera(i)
        mission.read_image(i)
        mission.radiometry(i)
    float(mission.meta.get("pointing_sigma_urad") or 1.0)
