"""The network subcommands, called through mercury_dem.cli.main."""

from __future__ import annotations

import json

import numpy as np
import pytest
from network_world import require_isis

from mercury_dem.cli import main
from mercury_dem.io.isis_net import read_isis_network
from mercury_dem.io.network_store import read_network


@pytest.mark.integration  # three commands end to end on a real ISIS network
def test_import_convert_check(tmp_path, capsys):
    src = require_isis() / "apollo_out.net"
    store = tmp_path / "apollo.zarr"
    assert main(["import-isis", str(src), str(store)]) == 0
    net = read_network(store)
    assert (net.n_points, net.n_measures) == (395, 969)
    # store -> .net (v2) -> store: the same network
    out = tmp_path / "back.net"
    assert main(["cnet-convert", str(store), str(out), "--isis-version", "2"]) == 0
    assert read_isis_network(out).equals(read_isis_network(src))
    assert main(["cnet-convert", str(out), str(tmp_path / "again.zarr")]) == 0
    assert read_network(tmp_path / "again.zarr").equals(net)
    capsys.readouterr()
    assert main(["cnetcheck", str(store), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["ok"] and rep["n_measures"] == 969 and rep["n_islands"] == 1
    assert main(["cnetcheck", str(src), "--image-size", "100", "100"]) == 1  # apollo pixels reach ~8000
    assert "outside their image" in capsys.readouterr().out


def test_import_with_serial_map(tmp_path, capsys):
    src = require_isis() / "ctx_hand_dense.net"
    serials = read_isis_network(src).image_ids.tolist()
    mapping = tmp_path / "map.csv"
    mapping.write_text("serial,image_id\n" + "".join(f"{s},IMG{k}\n" for k, s in enumerate(serials[:3])))
    assert main(["import-isis", str(src), str(tmp_path / "a"), "--serial-map", str(mapping)]) == 2
    assert "not in the catalog" in capsys.readouterr().err
    assert main(["import-isis", str(src), str(tmp_path / "a"), "--serial-map", str(mapping), "--drop-unknown"]) == 0
    net = read_network(tmp_path / "a")
    assert net.image_ids.tolist() == ["IMG0", "IMG1", "IMG2"] and np.all(net.measure_image < 3)


def test_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "trunc.net"
    bad.write_bytes((require_isis() / "apollo_out.net").read_bytes()[:70000])
    assert main(["cnetcheck", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "trunc.net: truncated at byte offset 70000" in err and err.count("\n") == 1
