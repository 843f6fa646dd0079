"""Fuzzing the network store reader: a damaged Zarr group gives a ControlNetwork or StoreError/NetworkError naming it.

Seed: a small network written by :func:`write_network` (integer and string point ids);
mutations truncate or flip bytes of any file (group/array ``zarr.json``, chunks), delete a
file or an array, or set a JSON value (group attribute, array metadata) to another value.
``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number of inputs (default 120, ~5 s).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import NetworkError, StoreError
from mercury_dem.io.network_store import read_network, write_network
from mercury_dem.network import ControlNetwork
from tests.network.test_model_store import _net


@pytest.fixture(scope="module")
def good_networks(tmp_path_factory: pytest.TempPathFactory) -> dict[bool, Path]:
    d = tmp_path_factory.mktemp("netfuzz")
    return {s: write_network(_net(str_ids=s), d / f"net_{s}") for s in (False, True)}


def _files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and p.name != ".complete")


def _json_values() -> st.SearchStrategy:
    return st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64), st.floats(allow_nan=False),
                     st.text(max_size=8), st.sampled_from(["float64", "int64", "uint8", "str", "bytes", "zstd", "regular"]),
                     st.lists(st.integers(-2, 10**12), max_size=3), st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


def _paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, prefix + (i,))
    return out


@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "50")), deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(str_ids=st.booleans(), how=st.sampled_from(("truncate", "flip", "delete", "rmarray", "json", "attr")),
       where=st.floats(0, 1), value=_json_values(), data=st.data())
def test_damaged_network_store_gives_store_error(good_networks: dict[bool, Path], tmp_path_factory: pytest.TempPathFactory,
                                                 str_ids: bool, how: str, where: float, value: object,
                                                 data: st.DataObject) -> None:
    net = tmp_path_factory.mktemp("case") / "net"
    shutil.copytree(good_networks[str_ids], net)
    files = _files(net)
    if how == "attr":
        name = "zarr.json"
    elif how == "json":
        name = data.draw(st.sampled_from([f for f in files if f.endswith("zarr.json")]))
    else:
        name = data.draw(st.sampled_from(files))
    f = net / name
    raw = f.read_bytes()
    k = int(where * max(len(raw) - 1, 0))
    if how == "truncate":
        f.write_bytes(raw[:k])
    elif how == "flip":
        f.write_bytes(raw[:k] + bytes([raw[k] ^ data.draw(st.integers(1, 255))]) + raw[k + 1:] if raw else b"\xff")
    elif how == "delete":
        f.unlink()
    elif how == "rmarray":
        shutil.rmtree(f.parent if f.parent != net else net / data.draw(st.sampled_from(sorted(p.name for p in net.iterdir() if p.is_dir()))))
    else:
        doc = json.loads(raw)
        if how == "attr":
            attrs = doc["attributes"]
            key = data.draw(st.sampled_from(sorted(attrs) + ["n_points_extra"]))
            attrs[key] = value
        else:
            path = data.draw(st.sampled_from(_paths(doc)[1:]))
            node = doc
            for p in path[:-1]:
                node = node[p]
            node[path[-1]] = value
        f.write_text(json.dumps(doc))
    try:
        result = read_network(net)
    except (StoreError, NetworkError) as exc:
        assert str(net) in str(exc), str(exc)
        return
    assert isinstance(result, ControlNetwork)
    assert len(result.image_ids) == result.n_images and len(result.point_ids) == result.n_points
