"""Fuzzing the blocked-network reader (``io.synthetic_network_store.BlockedNetwork``, what adjust-network reads).

Seed: a small synth-network store (network group with geometry and blocks, truth apart).
Mutations as in ``test_fuzz_store``: truncate or flip bytes of any file, delete a file or
an array, set a JSON value (array metadata, group attribute) to another. Opening the
store and reading every block and the truth gives arrays or a StoreError naming the
store. ``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number of inputs (default 40, ~10 s).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import StoreError
from mercury_dem.io.synthetic_network_store import BlockedNetwork, write_synthetic_network
from mercury_dem.network.synthetic import SyntheticSpec
from tests.network.test_fuzz_store import _json_values, _paths


@pytest.fixture(scope="module")
def good_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synfuzz") / "syn"
    write_synthetic_network(SyntheticSpec(1_500, seed=5, measures_per_image=100, block_points=100), out)
    return out


def _files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and p.name != ".complete")


def _read_all(path: Path) -> None:
    bn = BlockedNetwork(path)
    for b in range(bn.n_blocks):
        blk = bn.read_block(b)
        assert blk.measure_point.size == 0 or blk.measure_point.max() < len(blk.apriori_points)
        assert np.all(np.isfinite(blk.measures))
    bn.truth_images()


def test_the_seed_reads(good_store: Path) -> None:
    _read_all(good_store)


@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "20")), deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(how=st.sampled_from(("truncate", "flip", "delete", "rmarray", "json", "attr")), where=st.floats(0, 1),
       value=_json_values(), data=st.data())
def test_damaged_synthetic_store_gives_store_error(good_store: Path, tmp_path_factory: pytest.TempPathFactory, how: str,
                                                   where: float, value: object, data: st.DataObject) -> None:
    root = tmp_path_factory.mktemp("case") / "syn"
    shutil.copytree(good_store, root)
    files = _files(root)
    if how == "attr":
        name = data.draw(st.sampled_from(["network/zarr.json", "network/geometry/zarr.json", "truth/zarr.json"]))
    elif how == "json":
        name = data.draw(st.sampled_from([f for f in files if f.endswith("zarr.json")]))
    else:
        name = data.draw(st.sampled_from(files))
    f = root / name
    raw = f.read_bytes()
    k = int(where * max(len(raw) - 1, 0))
    if how == "truncate":
        f.write_bytes(raw[:k])
    elif how == "flip":
        f.write_bytes(raw[:k] + bytes([raw[k] ^ data.draw(st.integers(1, 255))]) + raw[k + 1:] if raw else b"\xff")
    elif how == "delete":
        f.unlink()
    elif how == "rmarray":
        shutil.rmtree(f.parent)
    else:
        doc = json.loads(raw)
        if how == "attr":
            attrs = doc.setdefault("attributes", {})
            key = data.draw(st.sampled_from(sorted(attrs) + ["extra"]))
            attrs[key] = value
        else:
            path = data.draw(st.sampled_from(_paths(doc)[1:]))
            node = doc
            for p in path[:-1]:
                node = node[p]
            node[path[-1]] = value
        f.write_text(json.dumps(doc))
    try:
        _read_all(root)
    except StoreError as exc:
        assert str(root) in str(exc), str(exc)
