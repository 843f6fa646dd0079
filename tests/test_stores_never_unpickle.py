"""Nothing in a mission or run store is unpickled: a pickle payload planted in a store is refused.

The static side (no ``pickle``/``allow_pickle=True``/``read_pickle``/... in the package) is
``tests/cluster/test_security_defaults.py::test_package_never_unpickles``. Here the readers
themselves meet live payloads: each payload, if unpickled, creates a marker file (checked
below with a direct ``pickle.loads`` — so the test can fail); each reader must raise the
project's error naming the file, and the marker must not exist afterwards.

Payload carriers: an Arrow extension-type column of a Parquet table (``arrow.py_extension_type``,
the pickle pyarrow < 14.0.1 unpickled on read); a Zarr v2 array of object dtype with the
``pickle`` object codec; a Zarr v3 array with the ``numcodecs.pickle`` codec; a ``.npy`` of an
object array.
"""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import GridError, MercuryDemError, StoreError


class _Payload:
    """Unpickling this creates ``marker`` (harmless stand-in for arbitrary code)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # type: ignore[no-untyped-def]
        return (open, (str(self.marker), "w"))


def _pickled(marker: Path) -> bytes:
    return pickle.dumps(_Payload(marker), protocol=5)


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    m = tmp_path / "UNPICKLED"
    # the payload is live: unpickling it does create the marker
    f = pickle.loads(_pickled(m))
    f.close()
    assert m.exists()
    m.unlink()
    return m


def _parquet_with_pickled_extension(path: Path, marker: Path, like: Path | None = None) -> None:
    """A Parquet table (the columns of ``like`` if given) plus a column typed ``arrow.py_extension_type``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(like) if like is not None else pa.table({"a": pa.array([1.0, 2.0])})
    field = pa.field("evil", pa.int64(), metadata={b"ARROW:extension:name": b"arrow.py_extension_type",
                                                   b"ARROW:extension:metadata": _pickled(marker)})
    table = table.append_column(field, pa.array(np.zeros(table.num_rows, np.int64)))
    pq.write_table(table, path)


def _zarr_v2_pickle_array(path: Path, marker: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True)
    (path / ".zarray").write_text(json.dumps({
        "zarr_format": 2, "shape": [1], "chunks": [1], "dtype": "|O", "compressor": None, "fill_value": None,
        "order": "C", "filters": [{"id": "pickle", "protocol": 5}], "dimension_separator": "."}))
    (path / "0").write_bytes(_pickled(marker))


def _zarr_v3_pickle_codec(path: Path, marker: Path, shape: list[int], dtype: str) -> None:
    meta = json.loads((path / "zarr.json").read_text())
    meta["codecs"] = [{"name": "bytes", "configuration": {"endian": "little"}},
                      {"name": "numcodecs.pickle", "configuration": {}}]
    meta.update(shape=shape, data_type=dtype)
    meta["chunk_grid"] = {"name": "regular", "configuration": {"chunk_shape": shape}}
    for f in path.rglob("*"):
        if f.is_file() and f.name != "zarr.json":
            f.unlink()
    (path / "zarr.json").write_text(json.dumps(meta))
    chunk = path / "c" / "/".join("0" * len(shape))  # the one chunk, default key encoding c/0/0
    chunk.parent.mkdir(parents=True, exist_ok=True)
    chunk.write_bytes(_pickled(marker))


@pytest.fixture
def mission_copy(tmp_path: Path) -> Path:
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.io.atomic import atomic_directory
    from mercury_dem.mission import MissionWriter
    from tests.mission.test_store import _tiny_catalog

    cams, cat = _tiny_catalog(MERCURY)
    out = tmp_path / "m"
    with atomic_directory(out) as tmp:
        w = MissionWriter(tmp)
        for i in range(3):
            w.write_image(tmp, f"im{i}", np.zeros((64, 64), np.uint16))
        w.finish({"source": "test"}, MERCURY, cams, cat)
    return out


def test_mission_catalog_with_pickled_extension_column_is_refused(mission_copy: Path, marker: Path) -> None:
    from mercury_dem.mission import open_mission

    cat = mission_copy / "catalog.parquet"
    _parquet_with_pickled_extension(cat, marker, like=cat)
    with pytest.raises(StoreError, match=r"catalog\.parquet column 'evil' declares the Arrow extension type "
                                         r"'arrow\.py_extension_type'.*nothing in them is unpickled"):
        open_mission(mission_copy)
    assert not marker.exists()


@pytest.mark.parametrize("carrier", ["zarr-v2-object-pickle", "zarr-v3-pickle-codec"])
def test_mission_image_with_pickle_codec_is_refused(mission_copy: Path, marker: Path, carrier: str) -> None:
    from mercury_dem.mission import open_mission

    arr = mission_copy / "images.zarr" / "im1"
    if carrier == "zarr-v2-object-pickle":
        _zarr_v2_pickle_array(arr, marker)
    else:
        _zarr_v3_pickle_codec(arr, marker, [64, 64], "uint16")
    mission = open_mission(mission_copy)
    mission.read_image("im0")  # the others are untouched
    with pytest.raises(StoreError, match=r"image im1: cannot read .*images\.zarr/im1"):
        mission.read_image("im1")
    assert not marker.exists()


def test_run_solution_and_plan_tables_with_pickled_extension_are_refused(tmp_path: Path, marker: Path) -> None:
    from mercury_dem.io.run_store import read_solution, write_solution

    sol = tmp_path / "solution.parquet"
    write_solution(sol, np.array(["a", "b"]), np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)))
    assert read_solution(sol)[0].tolist() == ["a", "b"]
    _parquet_with_pickled_extension(sol, marker, like=sol)
    with pytest.raises(StoreError, match=r"solution: .*solution\.parquet column 'evil'"):
        read_solution(sol)
    assert not marker.exists()


def test_network_store_column_with_pickle_codec_is_refused(tmp_path: Path, marker: Path) -> None:
    from mercury_dem.io.network_store import read_network, write_network
    from tests.network.test_model_store import _net

    path = write_network(_net(str_ids=False), tmp_path / "net")
    arrays = sorted(p.parent for p in path.rglob("zarr.json")
                    if json.loads(p.read_text()).get("node_type") == "array")
    target = arrays[0]
    meta = json.loads((target / "zarr.json").read_text())
    _zarr_v3_pickle_codec(target, marker, meta["shape"], meta["data_type"])
    with pytest.raises(MercuryDemError, match=str(path)):
        read_network(path)
    assert not marker.exists()


def test_dem_store_with_pickle_codec_is_refused(tmp_path: Path, marker: Path) -> None:
    """``products.make.open_dem`` (what ``products``/``report`` read) on a dem.zarr whose height is a pickle."""
    import zarr

    from mercury_dem.products.make import open_dem

    dem = tmp_path / "dem.zarr"
    g = zarr.open_group(str(dem), mode="w", zarr_format=3, attributes={"complete": True})
    g.create_array("height", shape=(4, 4), dtype="float32", dimension_names=("lat", "lon"))[...] = 1.0
    _zarr_v3_pickle_codec(dem / "height", marker, [4, 4], "float32")
    with pytest.raises(StoreError, match=r"dem\.zarr"):
        open_dem(dem)["height"].values
    assert not marker.exists()


def test_grid_points_npy_with_object_array_is_refused(tmp_path: Path, marker: Path) -> None:
    from mercury_dem.commands.grid import read_points

    bad = tmp_path / "points.npy"
    np.save(bad, np.array([_Payload(marker)], dtype=object), allow_pickle=True)
    with pytest.raises(GridError, match=r"points\.npy is not a plain numpy array"):
        read_points(bad)
    assert not marker.exists()
