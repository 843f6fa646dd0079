"""ControlNetwork columns, derived networks, and the Zarr store."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from mercury_dem.exceptions import NetworkError, StoreError
from mercury_dem.io.network_store import open_network, read_network, write_network
from mercury_dem.network import ControlNetwork
from mercury_dem.network.strings import decode_strings, encode_strings


def _net(str_ids=False):
    pid = np.array(["p0", "p1", "p2"]) if str_ids else np.array([10, 11, 12])
    return ControlNetwork.from_arrays(
        ["A", "B", "C"], pid, [0, 0, 1, 1, 2, 2, 2], [0, 1, 1, 2, 0, 1, 2],
        [1.0, 2, 3, 4, 5, 6, 7], [7.0, 6, 5, 4, 3, 2, 1],
        apriori_xyz=np.arange(9.0).reshape(3, 3) + 2.4e6, residuals=np.full((7, 2), 0.25),
    )


def test_shapes_are_checked():
    with pytest.raises(NetworkError, match="column 'sample' has shape"):
        ControlNetwork.from_arrays(["A"], [1], [0, 0], [0, 0], [1.0], [1.0, 2.0])
    with pytest.raises(NetworkError, match="apriori_xyz"):
        ControlNetwork.from_arrays(["A"], [1], [0], [0], [1.0], [1.0], apriori_xyz=np.zeros((2, 3)))
    with pytest.raises(NetworkError, match="unknown network column"):
        ControlNetwork.from_arrays(["A"], [1], [0], [0], [1.0], [1.0], colour=[1])


def test_arrays_are_read_only():
    net = _net()
    with pytest.raises(ValueError):
        net.sample[0] = 99.0


def test_lookups_and_counts():
    net = _net()
    assert (net.n_images, net.n_points, net.n_measures) == (3, 3, 7)
    assert net.measures_of_image("B").tolist() == [1, 2, 5]
    assert net.measures_of_image(2).tolist() == [3, 6]
    assert net.measures_of_point(2).tolist() == [4, 5, 6]
    assert net.measures_per_point().tolist() == [2, 2, 3]
    assert net.point_index([12, 10]).tolist() == [2, 0]
    with pytest.raises(NetworkError, match="not in the network"):
        net.image_index(["Z"])
    lat, lon, r = net.point_latlon()
    assert np.all((lon >= 0) & (lon < 360)) and np.allclose(r, np.linalg.norm(net.apriori_xyz, axis=1))


def test_subsets():
    net = _net()
    sub = net.subset_images(["C", "B"], min_measures=2)
    assert sub.image_ids.tolist() == ["C", "B"]
    assert sub.point_ids.tolist() == [11, 12]  # point 10 keeps only one measure (in B)
    assert sub.image_ids[sub.measure_image].tolist() == ["B", "C", "B", "C"]
    sel = net.select_measures(net.sample > 2.5)
    assert sel.point_ids.tolist() == [11, 12] and sel.n_measures == 5
    tp = net.take_points([2, 0])
    assert tp.point_ids.tolist() == [12, 10] and tp.measure_point.tolist() == [0, 0, 0, 1, 1]
    adj = net.with_adjustment(net.apriori_xyz + 1.0, np.zeros((7, 2)))
    assert np.all(adj.adjusted_xyz == net.apriori_xyz + 1.0)
    assert len(net.points_frame()) == 3 and len(net.measures_frame()) == 7


def test_active_measures():
    net = _net().replace(measure_ignored=[True, 0, 0, 0, 0, 0, 0], point_rejected=[False, False, True])
    assert net.active_measures().tolist() == [False, True, True, True, False, False, False]
    assert net.measures_per_point(active_only=True).tolist() == [1, 2, 0]


@pytest.mark.parametrize("str_ids", [False, True])
def test_store_round_trip(tmp_path, str_ids):
    net = _net(str_ids).replace(metadata={"network_id": "tile_17"},
                                adjusted_covariance=np.ones((3, 6)), image_ids=["A", "Bé", "C✓"])
    path = write_network(net, tmp_path / "net.zarr")
    back = read_network(path)
    assert back.equals(net, check_metadata=True)
    assert back.point_ids.dtype.kind == ("U" if str_ids else "i")
    lazy = open_network(path)
    assert (lazy.n_images, lazy.n_points, lazy.n_measures) == (3, 3, 7)
    assert lazy.image_ids.tolist() == ["A", "Bé", "C✓"] and lazy.metadata["network_id"] == "tile_17"
    assert np.array_equal(lazy.column("sample"), net.sample)


def test_store_is_atomic_and_refuses_overwrite(tmp_path):
    net = _net()
    path = write_network(net, tmp_path / "n")
    with pytest.raises(StoreError, match="already exists"):
        write_network(net, path)
    write_network(net.take_points([0]), path, overwrite=True)
    assert read_network(path).n_points == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["n"]  # no temporary siblings left


def test_incomplete_or_missing_store(tmp_path):
    path = write_network(_net(), tmp_path / "n")
    (path / ".complete").unlink()
    with pytest.raises(StoreError, match="incomplete"):
        read_network(path)
    shutil.rmtree(path)
    with pytest.raises(StoreError, match="does not exist"):
        read_network(path)


def test_empty_network_store(tmp_path):
    net = ControlNetwork.empty(["A", "B"])
    back = read_network(write_network(net, tmp_path / "e"))
    assert back.equals(net) and back.image_ids.tolist() == ["A", "B"]


def test_string_codec():
    vals = np.array(["", "a", "ünïcode", "MRO/CTX/1085197697:073"])
    data, off = encode_strings(vals)
    assert decode_strings(data, off).tolist() == vals.tolist()
