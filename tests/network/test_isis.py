"""ISIS3 binary control networks: the four real files, round trips, bad files."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from network_world import require_isis

from mercury_dem.exceptions import NetworkError
from mercury_dem.io.isis_net import read_isis_network, write_isis_network
from mercury_dem.network import ControlNetwork
from mercury_dem.network.isis import encode_isis_network

PUBLISHED = {  # file: (points, measures, images, version)
    "apollo_out.net": (395, 969, 7, 2),
    "apollo_out_v5.net": (395, 969, 7, 5),
    "ctx_syrtis_major.net": (449, 930, 3, 5),
    "ctx_hand_dense.net": (35, 130, 4, 5),
}


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_real_networks_counts(name):
    net = read_isis_network(require_isis() / name)
    n, m, k, version = PUBLISHED[name]
    assert (net.n_points, net.n_measures, net.n_images) == (n, m, k)
    assert net.metadata["isis_version"] == str(version)


@pytest.mark.parametrize("name", ["apollo_out.net", "apollo_out_v5.net"])
def test_apollo_known_values(name):
    net = read_isis_network(require_isis() / name)
    assert net.point_ids[0] == "AS15_000031172" and net.point_type[0] == 2  # Free
    np.testing.assert_allclose(net.apriori_xyz[0], [1570888.49, 213125.31, 704769.93], atol=0.006)
    np.testing.assert_allclose(net.adjusted_xyz[0], [1570106.82, 211126.45, 705336.57], atol=0.006)
    first = net.measures_of_point(0)[0]
    # ISIS 1-based sample/line = ours + 1
    assert net.sample[first] + 1 == pytest.approx(4803.1347, abs=5e-5)
    assert net.line[first] + 1 == pytest.approx(4530.8581, abs=5e-5)
    np.testing.assert_allclose(net.residuals[first], [0.00169, -0.62469], atol=5e-6)
    r = np.linalg.norm(net.adjusted_xyz, axis=1)
    assert r.min() == pytest.approx(1734022.3, abs=0.05) and r.max() == pytest.approx(1740118.0, abs=0.05)
    assert net.metadata["network_id"] == "LandingSite" and net.metadata["target_name"] == "Moon"


def test_apollo_v2_and_v5_are_the_same_network():
    d = require_isis()
    a = read_isis_network(d / "apollo_out.net")
    b = read_isis_network(d / "apollo_out_v5.net")
    # identical but for the covariances, which ISIS re-rounded in its v2 -> v5 upgrade (1e-16 relative)
    assert a.differences(b) == ["apriori_covariance", "adjusted_covariance"]
    for col in ("apriori_covariance", "adjusted_covariance"):
        np.testing.assert_allclose(getattr(a, col), getattr(b, col), rtol=1e-13, equal_nan=True)
    assert a.replace(apriori_covariance=b.apriori_covariance, adjusted_covariance=b.adjusted_covariance).equals(b)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
@pytest.mark.parametrize("version", [2, 5])
def test_real_networks_round_trip(name, version, tmp_path):
    net = read_isis_network(require_isis() / name)
    out = write_isis_network(net, tmp_path / "x.net", version=version)
    back = read_isis_network(out)
    assert back.equals(net)
    assert back.metadata["network_id"] == net.metadata["network_id"]
    assert back.metadata["isis_version"] == str(version)


def test_serial_numbers_map_to_catalog_ids(tmp_path):
    path = require_isis() / "ctx_hand_dense.net"
    raw = read_isis_network(path)
    mapping = {s: f"img{k}" for k, s in enumerate(raw.image_ids.tolist())}
    net = read_isis_network(path, serial_to_image=mapping)
    assert net.image_ids.tolist() == ["img0", "img1", "img2", "img3"]
    assert np.array_equal(net.measure_image, raw.measure_image)
    # catalog order is the images table; extra catalog images are kept
    catalog = ["x", "img3", "img2", "img1", "img0"]
    net2 = read_isis_network(path, serial_to_image=mapping, image_ids=catalog)
    assert net2.image_ids.tolist() == catalog
    assert np.array_equal(net2.image_ids[net2.measure_image], net.image_ids[net.measure_image])
    # written back with the inverse mapping: the same serial numbers
    out = write_isis_network(net, tmp_path / "m.net", image_to_serial={v: k for k, v in mapping.items()})
    assert read_isis_network(out).equals(raw)


def test_no_serial_matches_the_catalog():
    path = require_isis() / "ctx_hand_dense.net"
    with pytest.raises(NetworkError, match=r"ctx_hand_dense\.net.*none of its .*serial numbers"):
        read_isis_network(path, image_ids=["EN0001", "EN0002"])


def test_partial_catalog_errors_or_drops():
    path = require_isis() / "ctx_hand_dense.net"
    raw = read_isis_network(path)
    keep = raw.image_ids[:3].tolist()
    with pytest.raises(NetworkError, match="not in the catalog"):
        read_isis_network(path, image_ids=keep)
    net = read_isis_network(path, image_ids=keep, drop_unknown=True)
    dropped = int((raw.measure_image == 3).sum())
    assert net.n_measures == raw.n_measures - dropped and net.metadata["dropped_measures"] == str(dropped)


def test_truncated_file_names_file_and_offset(tmp_path):
    data = (require_isis() / "apollo_out_v5.net").read_bytes()
    for cut in (len(data) - 1000, 65536 + 40):
        p = tmp_path / f"cut{cut}.net"
        p.write_bytes(data[:cut])
        with pytest.raises(NetworkError, match=rf"cut{cut}\.net: truncated at byte offset {cut}"):
            read_isis_network(p)


def test_corrupt_point_message_names_offset(tmp_path):
    net = _random_network(np.random.default_rng(0), 20, 60, 4)
    data = bytearray(encode_isis_network(net, version=5))
    hs = 65536
    header_bytes = int(data[:hs].split(b"HeaderBytes     = ")[1].split(b"\n")[0])
    first = hs + header_bytes
    data[first + 4] = 0xFF  # the first point's first field key becomes a bad varint/wire type
    data[first + 5] = 0xFF
    p = tmp_path / "bad.net"
    p.write_bytes(bytes(data))
    with pytest.raises(NetworkError, match=r"bad\.net: corrupt or truncated point message 0.*byte offset"):
        read_isis_network(p)


def test_not_a_network(tmp_path):
    p = tmp_path / "x.net"
    p.write_bytes(b"PDS_VERSION_ID = PDS3\n" + b"\0" * 100)
    with pytest.raises(NetworkError, match="not an ISIS binary control network"):
        read_isis_network(p)
    with pytest.raises(NetworkError, match="cannot read"):
        read_isis_network(tmp_path / "missing.net")


def _random_network(rng, n, m, k, str_ids=False, nan_frac=0.2, cov=False):
    mp = np.sort(rng.integers(0, n, m))
    mi = rng.integers(0, k, m)
    key = np.unique(mp * k + mi)
    mp, mi = key // k, key % k
    m = mp.size

    def maybe_nan(shape, scale):
        a = rng.normal(0, scale, shape)
        a[rng.random(shape) < nan_frac] = np.nan
        return a

    ids = np.array([f"P_{i:05d}" for i in rng.permutation(n)]) if str_ids else rng.permutation(10 * n)[:n]
    kw = {}
    if cov:
        c = rng.normal(0, 100, (n, 6))
        c[rng.random(n) < 0.5] = np.nan
        kw = {"apriori_covariance": c, "adjusted_covariance": rng.normal(0, 10, (n, 6))}
    return ControlNetwork.from_arrays(
        np.array([f"MESSENGER/MDIS/{i}:{i * 7}" for i in range(k)]), ids, mp, mi,
        rng.uniform(-0.5, 1023.5, m), rng.uniform(-0.5, 1023.5, m),
        point_type=rng.choice([2, 3, 4], n), apriori_xyz=maybe_nan((n, 3), 2.4e6), adjusted_xyz=maybe_nan((n, 3), 2.4e6),
        point_ignored=rng.random(n) < 0.1, point_rejected=rng.random(n) < 0.1, sigma=maybe_nan((m, 2), 0.3),
        measure_type=rng.integers(0, 4, m), measure_ignored=rng.random(m) < 0.1, measure_rejected=rng.random(m) < 0.1,
        residuals=maybe_nan((m, 2), 0.5), apriori_pixels=maybe_nan((m, 2), 500.0), **kw,
    ).sorted()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 60), m=st.integers(0, 300), k=st.integers(1, 9),
       str_ids=st.booleans(), cov=st.booleans(), version=st.sampled_from([2, 5]))
def test_our_networks_round_trip(tmp_path, seed, n, m, k, str_ids, cov, version):
    net = _random_network(np.random.default_rng(seed), n, m, k, str_ids=str_ids, cov=cov)
    net = net.take_points(np.flatnonzero(net.measures_per_point() > 0))
    p = tmp_path / f"r{seed}_{version}.net"
    write_isis_network(net, p, version=version)
    # pixels shift by 1 at the boundary: exact up to one rounding of (x + 1), < 1e-12 px here
    if version == 5:  # the header lists every image (serial number), in order
        assert read_isis_network(p).differences(net, atol=1e-12) == []
    # version 2 has no image list: the catalog gives the images table
    assert read_isis_network(p, image_ids=net.image_ids).differences(net, atol=1e-12) == []


def test_source_date_epoch_makes_exports_byte_identical(monkeypatch):
    net = _random_network(np.random.default_rng(3), 8, 30, 3)
    net = net.take_points(np.flatnonzero(net.measures_per_point() > 0))
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    first = encode_isis_network(net, version=5)
    assert b"2023-11-14T22:13:20" in first  # 1700000000 s after 1970, UTC
    assert encode_isis_network(net, version=5) == first
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000061")
    assert encode_isis_network(net, version=5) != first
