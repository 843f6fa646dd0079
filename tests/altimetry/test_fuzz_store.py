"""Fuzzing the altimetry store reader: a store whose Parquet file or altimetry.json was cut, had bytes
changed or values edited opens and reads to valid shots, or raises StoreError naming the store;
nothing else. ``MERCURY_DEM_FUZZ_EXAMPLES`` sets the number of inputs (default 150, ~5 s)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.altimetry.store import ShotSource, combine_shots, open_altimetry, write_altimetry
from mercury_dem.exceptions import StoreError

pytestmark = pytest.mark.timeout(120)
EXAMPLES = int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "150"))


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rng = np.random.default_rng(7)
    n = 300
    t = pd.DataFrame({"time": 1e8 + 0.125 * np.arange(n), "lat": rng.uniform(-30, 30, n),
                      "lon": rng.uniform(0, 40, n), "radius_m": 2_439_400.0 + rng.normal(0, 1e3, n),
                      "profile_id": np.arange(n) // 30, "flag": np.zeros(n, np.int64)})
    src = [ShotSource("fuzz.csv", n, n, 10, {"flagged": 2})]
    root = tmp_path_factory.mktemp("alt_fuzz_base") / "alt"
    write_altimetry(root, combine_shots([t], src), sources=src, datum_radius_m=2_439_400.0)
    return root


_META_KEYS = ["n_shots", "n_profiles", "tile_size_deg", "tiles", "row_groups", "dropped", "sources", "format",
              "version", "columns"]
_VALUES = [0, -1, 1, 7.5, 1e308, None, "x", [], {}, {"1": [0]}, {"999999": [0]}, {"20": [99]}, True, 10.0, 3.0]


@st.composite
def _mutation(draw):
    kind = draw(st.sampled_from(["bytes", "truncate", "meta"]))
    if kind == "meta":
        return kind, (draw(st.sampled_from(_META_KEYS)), draw(st.sampled_from(_VALUES)))
    if kind == "truncate":
        return kind, draw(st.floats(0.0, 1.0))
    return kind, draw(st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), min_size=1, max_size=8))


@settings(max_examples=EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(_mutation())
def test_fuzz_altimetry_store(base, tmp_path_factory, mutation):
    work = tmp_path_factory.mktemp("alt_fuzz") / "alt"
    shutil.copytree(base, work)
    kind, what = mutation
    pq_file = work / "shots.parquet"
    if kind == "meta":
        meta = json.loads((work / "altimetry.json").read_text())
        key, value = what
        meta[key] = value
        (work / "altimetry.json").write_text(json.dumps(meta))
    else:
        data = bytearray(pq_file.read_bytes())
        if kind == "truncate":
            data = data[: int(what * len(data))]
        else:
            for pos, byte in what:
                data[min(int(pos * len(data)), len(data) - 1)] = byte
        pq_file.write_bytes(bytes(data))
    try:
        store = open_altimetry(work)
        shots = store.read()
        tile = next(iter(store.tiles), 0)
        one = store.read_tile(tile)
    except StoreError as exc:
        assert str(work) in str(exc)
        return
    assert len(shots) == store.n_shots and len(one) == store.tiles.get(tile, 0)
    assert np.all(np.isfinite(shots[["lat", "lon", "radius_m", "sigma_m"]].to_numpy()))
    assert shots["lon"].between(0.0, 360.0, inclusive="left").all()
