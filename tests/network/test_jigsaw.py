"""The pure parts of adjust-isis: serial matching, the adjustable cut, results merged back, the serials CSV."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.exceptions import NetworkError
from mercury_dem.network.jigsaw import (
    camera_keys_with_serials,
    cut_adjustable,
    match_serials,
    merge_adjustment,
    parse_serials_csv,
)
from mercury_dem.network.model import ControlNetwork


def _net() -> ControlNetwork:
    # points: p0 on A,B,C; p1 on A,X (X has no camera); p2 on B,C but ignored; p3 on A,C with C's measure ignored
    return ControlNetwork.from_arrays(
        ["S/A", "S/B", "S/C", "S/X"], ["p0", "p1", "p2", "p3"],
        [0, 0, 0, 1, 1, 2, 2, 3, 3], [0, 1, 2, 0, 3, 1, 2, 0, 2],
        np.arange(9.0), np.arange(9.0) + 100,
        point_ignored=np.array([False, False, True, False]),
        measure_ignored=np.array([False] * 8 + [True]),
        measure_rejected=np.ones(9, bool),  # cleared: every measure is judged again
    )


def test_match_cut_merge() -> None:
    net = _net()
    keys = camera_keys_with_serials(["a", "b", "c"], ["S/A", None, "S/C"], {1: "S/B"})
    assert keys == [["S/A", "a"], ["S/B", "b"], ["S/C", "c"]]
    m = match_serials(net, keys)
    assert m.camera_of_image.tolist() == [0, 1, 2, -1]
    assert m.unmatched == {"S/X": 1} and m.unused_cameras == ()
    cut = cut_adjustable(net, m.camera_of_image)
    assert cut.measure_index.tolist() == [0, 1, 2]  # only p0 keeps two usable measures
    assert cut.point_index.tolist() == [0] and cut.camera_index.tolist() == [0, 1, 2]
    assert not cut.network.measure_rejected.any()
    adjusted = cut.network.with_adjustment(np.array([[1.0, 2.0, 3.0]]), np.full((3, 2), 0.1),
                                           measure_rejected=np.array([False, True, False]))
    out = merge_adjustment(net, cut, adjusted)
    assert out.measure_rejected.tolist() == [False, True, False] + [False] * 6
    assert np.isnan(out.residuals[3:]).all() and np.allclose(out.residuals[:3], 0.1)
    assert out.adjusted_xyz[0].tolist() == [1.0, 2.0, 3.0] and np.isnan(out.adjusted_xyz[1:]).all()
    assert out.point_ignored.tolist() == net.point_ignored.tolist()
    assert out.measure_ignored.tolist() == net.measure_ignored.tolist()
    # with two of its three measures rejected, p0 is not determined: flagged, coordinates kept
    worse = adjusted.replace(measure_rejected=np.array([True, True, False]))
    out = merge_adjustment(net, cut, worse)
    assert out.point_rejected.tolist() == [True, False, False, False] and np.isnan(out.adjusted_xyz[0]).all()


def test_matching_by_image_id_and_clashes() -> None:
    net = _net()
    m = match_serials(net, [["x", "S/A"], ["S/B"]])  # image ids double as keys (export-isis writes them)
    assert m.camera_of_image.tolist() == [0, 1, -1, -1]
    with pytest.raises(NetworkError, match="claimed by two cameras"):
        match_serials(net, [["S/A"], ["S/A"]])
    match_serials(net, [["S/Q", "S/A"], ["S/Q", "S/B"]])  # a shared key the network does not use is fine
    with pytest.raises(NetworkError, match="no measure is left"):
        cut_adjustable(net, np.array([0, -1, -1, -1]))


def test_serials_csv() -> None:
    rows = parse_serials_csv("file,serial\n# comment\n\na.cub, S/A\n\"b.json\",\"S/B,1\"\n", "s.csv")
    assert rows == [("a.cub", "S/A", 4), ("b.json", "S/B,1", 5)]
    for text, line in (("a.cub\n", 1), ("a.cub,S/A\nb.cub,,\n", 2), ("a.cub,\n", 1)):
        with pytest.raises(NetworkError, match=f"s.csv line {line}"):
            parse_serials_csv(text, "s.csv")
    with pytest.raises(NetworkError, match="no 'file,serial' line"):
        parse_serials_csv("file,serial\n", "s.csv")
