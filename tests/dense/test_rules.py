"""The dense stage's rules on exact inputs: the per-tile cap of the pairs, the height margins, the config's checks."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.config import load_config
from mercury_dem.dense.pairs import REJECTED, SELECTED, StereoCandidate
from mercury_dem.dense.rules import cap_per_tile, height_margins
from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import MERCURY, latlon_to_xyz


def _row(left: str, right: str, rank: int) -> StereoCandidate:
    """A selected pair of that rank (score 1/rank), or with rank 0 a rejected one."""
    if not rank:
        nan = float("nan")
        return StereoCandidate(left, right, REJECTED, "overlap 0.1 < 0.2", 0, nan, nan, nan, nan, nan, nan, nan,
                               nan, nan, nan)
    return StereoCandidate(left, right, SELECTED, "", rank, 1.0 / rank, 0.5, 30.0, 1.0, 1000.0, 1000.0, 40.0,
                           40.0, 0.0, 0.5)


def test_the_per_tile_cap_keeps_the_best_ranked_and_names_the_tile() -> None:
    rows = [_row("a", "b", 2), _row("c", "d", 1), _row("a", "d", 3), _row("e", "f", 0), _row("x", "y", 4)]
    tile_of = {"a": 5, "c": 5, "e": 5, "x": 6}
    out, per_tile = cap_per_tile(rows, tile_of, max_per_tile=2)
    assert per_tile == {5: [1, 0], 6: [4]}
    assert out[2].status == REJECTED and out[2].reason == "cap: tile 5 already has 2 better-ranked pairs"
    assert out[2].rejections == ("cap",)
    assert out[3].reason == "overlap 0.1 < 0.2"  # rejected rows untouched
    out, per_tile = cap_per_tile(rows, tile_of, max_per_tile=9, tiles=(6,))
    assert per_tile == {6: [4]} and out[0].reason == "tile 5 not in dense.tiles"
    assert out[0].rejections == ("tile_subset",)


def test_height_margins_from_the_tie_points_scatter_with_a_floor() -> None:
    r = MERCURY.datum_radius_m
    rng = np.random.default_rng(3)
    lat = rng.uniform(1, 9, 400)
    lon = rng.uniform(1, 9, 400)
    h = rng.normal(0, 500, 400)
    xyz = latlon_to_xyz(lat, lon, height_m=h, datum_radius_m=r)

    def flat(la: np.ndarray, lo: np.ndarray) -> np.ndarray:
        return np.zeros(np.shape(la))

    per_tile, run = height_margins(xyz, flat, r, 10.0, 3.0, 100.0)
    assert len(per_tile) == 1 and 1200 < run < 1800  # 3 x ~500 m
    assert list(per_tile.values())[0] == pytest.approx(run)
    per_tile, run = height_margins(xyz, flat, r, 10.0, 3.0, 5000.0)
    assert run == 5000.0  # the floor
    assert height_margins(np.zeros((0, 3)), flat, r, 10.0, 3.0, 700.0) == ({}, 700.0)


def test_the_dense_section_refuses_what_the_stage_cannot_use() -> None:
    assert load_config().dense.enabled is False
    with pytest.raises(ConfigError, match="dense.best_parallax_height"):
        load_config(overrides={"dense": {"best_parallax_height": [0.05, 0.6]}})
    with pytest.raises(ConfigError, match="dense.block_size"):
        load_config(overrides={"dense": {"block_size": 4}})
    with pytest.raises(ConfigError, match="unknown config key 'dense.chips'"):
        load_config(overrides={"dense": {"chips": 3}})
    with pytest.raises(ConfigError, match="dense.matcher_mode"):
        load_config(overrides={"dense": {"matcher_mode": "bm"}})
