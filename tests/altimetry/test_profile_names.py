"""An altimeter's ground track is a profile (``profile_id``, ``n_profiles``); files written before the
rename (``track_id``, ``n_tracks``) and users' shot files with the old column still read, with a
deprecation warning naming the new name; what is written carries only the new names."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from mercury_dem.altimetry.names import upgrade_columns, upgrade_keys
from mercury_dem.altimetry.store import ShotSource, combine_shots, open_altimetry, write_altimetry
from mercury_dem.pipeline.register_stage import check_shots

MERCURY_M = 2_439_400.0


def _table(n: int = 400) -> pd.DataFrame:
    rng = np.random.default_rng(3)
    return pd.DataFrame({"time": np.arange(n) * 0.1 + 1e8, "lat": rng.uniform(-60, 60, n),
                         "lon": rng.uniform(0, 360, n), "radius_m": MERCURY_M + rng.normal(0, 500, n),
                         "profile_id": np.arange(n) // 40})


def _store(path: Path) -> pd.DataFrame:
    table = combine_shots([_table()], [ShotSource("a.csv", 400, 400, 10, {})])
    write_altimetry(path, table, sources=[ShotSource("a.csv", 400, 400, 10, {})], datum_radius_m=MERCURY_M)
    return open_altimetry(path).read()


def test_new_store_writes_only_the_new_names(tmp_path: Path) -> None:
    _store(tmp_path / "alt")
    meta = json.loads((tmp_path / "alt" / "altimetry.json").read_text())
    assert meta["n_profiles"] == 10 and "n_tracks" not in meta and meta["sources"][0]["n_profiles"] == 10
    names = pq.ParquetFile(tmp_path / "alt" / "shots.parquet").schema_arrow.names
    assert "profile_id" in names and "track_id" not in names


def test_old_store_reads_under_the_new_names(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    new = _store(tmp_path / "alt")
    # the old layout: rewrite the file with the same row groups (one per tile) under the old column name
    f = tmp_path / "alt" / "shots.parquet"
    pf = pq.ParquetFile(f)
    groups = [pf.read_row_group(i) for i in range(pf.num_row_groups)]
    with pq.ParquetWriter(f.with_suffix(".tmp"), groups[0].rename_columns(
            ["track_id" if c == "profile_id" else c for c in groups[0].column_names]).schema) as w:
        for g in groups:
            w.write_table(g.rename_columns(["track_id" if c == "profile_id" else c for c in g.column_names]))
    f.with_suffix(".tmp").replace(f)
    meta = json.loads((tmp_path / "alt" / "altimetry.json").read_text())
    meta["n_tracks"] = meta.pop("n_profiles")
    for s in meta["sources"]:
        s["n_tracks"] = s.pop("n_profiles")
    (tmp_path / "alt" / "altimetry.json").write_text(json.dumps(meta))

    with caplog.at_level(logging.WARNING, logger="mercury_dem.altimetry"):
        store = open_altimetry(tmp_path / "alt")
        old = store.read()
        tile = int(new["tile_id"].iloc[0])
        one = store.read_tile(tile, columns=["lat", "profile_id"])
    assert store.n_profiles == 10 and store.sources[0]["n_profiles"] == 10
    pd.testing.assert_frame_equal(old, new)
    np.testing.assert_array_equal(one["profile_id"], new.loc[new["tile_id"] == tile, "profile_id"])
    assert "'track_id'" in caplog.text and "write 'profile_id'" in caplog.text and "'n_tracks'" in caplog.text


def test_user_shot_file_with_the_old_column(caplog: pytest.LogCaptureFixture) -> None:
    t = _table().rename(columns={"profile_id": "track_id"})
    with caplog.at_level(logging.WARNING, logger="mercury_dem.altimetry"):
        shots, dropped = check_shots(t, "shots.parquet")
    assert dropped == 0 and list(shots.columns) == ["lat", "lon", "radius_m", "profile_id"]
    np.testing.assert_array_equal(shots["profile_id"], np.arange(400) // 40)
    assert "shots.parquet: column 'track_id'" in caplog.text


def test_new_name_wins_and_nothing_changes_without_old_names() -> None:
    both = pd.DataFrame({"profile_id": [1], "track_id": [2]})
    assert upgrade_columns(both, "x") is both
    d = {"n_profiles": 3}
    assert upgrade_keys(d, "x") is d
    assert upgrade_keys({"n_tracks": 3, "a": 1}, "x") == {"n_profiles": 3, "a": 1}
