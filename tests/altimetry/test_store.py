"""The altimetry store: round trip, per-tile reads, drops and sources recorded, ingest of real LOLA
shots into a mission, and bad inputs (wrong columns, NaNs, off-body shots, a 2-shot profile)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mercury_dem.altimetry.store import (
    ShotSource,
    combine_shots,
    open_altimetry,
    read_altimetry_tile,
    shots_from_files,
    write_altimetry,
)
from mercury_dem.cli import main
from mercury_dem.exceptions import ReferenceDataError, StoreError
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.mission import open_mission
from mercury_dem.mission.ingest import ingest_mission

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
LOLA = [REAL / "lidarPoints_head.csv", REAL / "lidarPoints_tail.csv"]
APOLLO_0297 = REAL / "AS15-M-0297_crop.cub"
MERCURY_M = 2_439_400.0


def _table(n: int, seed: int) -> pd.DataFrame:
    """Shots scattered over the globe in 50-shot profiles (times in seconds)."""
    rng = np.random.default_rng(seed)
    return pd.DataFrame({
        "time": np.arange(n) * 0.125 + 1e8, "lat": rng.uniform(-90, 90, n), "lon": rng.uniform(0, 360, n),
        "radius_m": MERCURY_M + rng.normal(0, 2000, n), "profile_id": np.arange(n) // 50,
        "flag": np.zeros(n, np.int64),
    })


def test_round_trip_and_per_tile_reads(tmp_path: Path) -> None:
    a, b = _table(3000, 1), _table(500, 2)
    src = [ShotSource("a.csv", 3010, 3000, 60, {"non_finite": 10}), ShotSource("b.csv", 500, 500, 10, {})]
    table = combine_shots([a, b], src, sigma_m=2.0)
    assert table["profile_id"].nunique() == 70  # profiles of b do not reuse a's ids
    meta = write_altimetry(tmp_path / "alt", table, sources=src, datum_radius_m=MERCURY_M)
    store = open_altimetry(tmp_path / "alt")
    assert store.n_shots == 3500 and store.n_profiles == 70 and store.dropped["non_finite"] == 10
    assert [s["name"] for s in store.sources] == ["a.csv", "b.csv"] and meta["n_shots"] == 3500
    whole = store.read()
    assert len(whole) == 3500 and (whole["sigma_m"] == 2.0).all()
    back = whole.sort_values(["source_id", "time"]).reset_index(drop=True)
    ref = table.sort_values(["source_id", "time"]).reset_index(drop=True)
    for c in ("time", "lat", "lon", "radius_m", "profile_id", "source_id", "flag"):
        np.testing.assert_array_equal(back[c].to_numpy(), ref[c].to_numpy())
    grid = TileGrid(10.0)
    tiles = grid.tile_of(table["lat"], table["lon"])
    for t in (int(tiles[0]), int(tiles[-1]), int(np.bincount(tiles).argmax())):
        one = store.read_tile(t)
        assert len(one) == int(np.sum(tiles == t)) == store.tiles[t]
        assert (one["tile_id"] == t).all() and one["time"].is_monotonic_increasing
        lat0, lat1, lon0, lon1 = grid.bounds(t)
        assert one["lat"].between(lat0, lat1).all() and one["lon"].between(lon0, lon1).all()
    empty = sorted(set(range(grid.n_tiles)) - set(store.tiles))[0]
    assert len(store.read_tile(empty)) == 0 and list(store.read_tile(empty, ["lat"]).columns) == ["lat"]
    # one row group per tile: a tile read touches only its own
    import pyarrow.parquet as pq
    assert pq.ParquetFile(store.file).metadata.num_row_groups == len(store.tiles)
    assert len(read_altimetry_tile(tmp_path / "alt", int(tiles[0]), ["radius_m"])) == store.tiles[int(tiles[0])]


def test_written_atomically_and_never_half(tmp_path: Path) -> None:
    bad = _table(100, 3)
    bad.loc[7, "radius_m"] = np.nan
    with pytest.raises(StoreError, match="invalid lat/lon/radius_m"):
        write_altimetry(tmp_path / "alt", combine_shots([bad], [ShotSource("x", 100, 100, 2, {})]),
                        sources=[ShotSource("x", 100, 100, 2, {})], datum_radius_m=MERCURY_M)
    assert list(tmp_path.iterdir()) == []  # no half-written store, no temporary left
    with pytest.raises(StoreError, match="missing or incomplete"):
        open_altimetry(tmp_path / "alt")


def test_real_lola_files_with_their_drops(tmp_path: Path) -> None:
    table, sources = shots_from_files(LOLA, 1_737_400.0)
    assert [s.n_shots for s in sources] == [55, 51]
    # head: one profile, tail: two -> three distinct profiles in the store
    assert table["profile_id"].nunique() == 3
    write_altimetry(tmp_path / "alt", table, sources=sources, datum_radius_m=1_737_400.0)
    first = open_altimetry(tmp_path / "alt").read().sort_values("time").iloc[0]
    assert first["lat"] == pytest.approx(60.0187875) and first["lon"] == pytest.approx(99.0636769)
    assert first["radius_m"] == pytest.approx(1_734_913.521)


def test_ingest_apollo_with_real_lola_shots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "junk.csv"
    junk.write_text("a,b,c\n1,2,3\n")
    mission = tmp_path / "m"
    assert main(["ingest", str(mission), str(APOLLO_0297), "--altimetry", *map(str, LOLA), str(junk),
                 "--altimetry-sigma-m", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "altimetry: 106 shots in 3 profiles from 2 files" in out and "junk.csv" in out
    m = open_mission(mission)
    assert m.body.name == "MOON" and m.altimetry.n_shots == 106
    shots = m.read_altimetry()
    assert (shots["sigma_m"] == 0.5).all() and shots["radius_m"].between(1.73e6, 1.74e6).all()
    tile = TileGrid(10.0).tile_of(60.0187875, 99.0636769)
    assert len(m.read_altimetry(int(tile))) == m.altimetry.tiles[int(tile)] > 0
    assert "no column for time" in m.meta["rejected"][str(junk)]
    assert main(["info", str(mission), "--coverage-map", str(tmp_path / "c.png")]) == 0
    assert "altimetry    106 shots in 3 profiles" in capsys.readouterr().out
    # a mission without altimetry says so
    bare = open_mission(ingest_mission(tmp_path / "bare", [str(APOLLO_0297)])["path"])
    assert bare.altimetry is None
    with pytest.raises(StoreError, match="has no altimetry"):
        bare.read_altimetry()


def test_ingest_mercury_cube_with_an_mla_like_table(tmp_path: Path) -> None:
    """An MLA-RDR-like table (its header, made-up values) read against the mission's body, Mercury."""
    header = "geoc_long,geoc_lat,altitude,EphemerisTime,MET,frm,chn,UTC,TOF_ns_ET,Sat_long,Sat_lat,Sat_alt"
    rows = [f"{50 + 0.001 * i:.4f},{77 + 0.01 * i:.4f},{-2.0 + 0.001 * i:.4f},{3.9e8 + 0.125 * i},{i},{i % 8},"
            f"{7 if i == 5 else 1},2012-03-14T00:00:{0.125 * i:06.3f},2.7e6,50.0,77.0,300.0" for i in range(40)]
    tab = tmp_path / "MLASCIRDR1203140000.TAB"
    tab.write_text(header + "\n" + "\n".join(rows) + "\n")
    s = ingest_mission(tmp_path / "m", [str(REAL / "EN0240208184M.lev1.cub")], altimetry=[str(tab)])
    assert s["body"] == "MERCURY" and s["altimetry"]["n_shots"] == 39
    m = open_mission(s["path"])
    shots = m.read_altimetry()
    assert shots["radius_m"].between(2_437_900.0, 2_438_100.0).all() and (shots["sigma_m"] == 1.0).all()
    assert m.altimetry.dropped["flagged"] == 1 and m.altimetry.n_profiles == 1


def test_bad_shot_tables_are_counted_or_refused(tmp_path: Path) -> None:
    """Wrong columns: an error naming the file. NaNs and off-body shots: counted drops. A profile of
    two shots: kept as a profile of two (the registration decides what is too short), never merged."""
    wrong = tmp_path / "wrong.csv"
    wrong.write_text("UTC,x,y,z\n2011-04-01T00:00:00,1,2,3\n")
    with pytest.raises(ReferenceDataError, match="wrong.csv.*no column for lon, lat, radius"):
        shots_from_files([wrong], MERCURY_M)
    rows = ["UTC,Pt_Longitude,Pt_Latitude,Pt_Radius"]
    rows += [f"2011-04-01T00:00:{0.125 * i:06.3f},{10 + 0.001 * i},45.0,2438.5" for i in range(10)]
    rows[3] = "2011-04-01T00:00:00.250,nan,45.0,2438.5"              # NaN
    rows[4] = "2011-04-01T00:00:00.375,10.003,45.0,1737.4"           # the Moon's radius: off this body
    rows += ["2011-04-01T00:05:00.000,20.0,45.0,2438.5", "2011-04-01T00:05:00.125,20.001,45.0,2438.5"]
    f = tmp_path / "shots.csv"
    f.write_text("\n".join(rows) + "\n")
    table, (src,) = shots_from_files([f], MERCURY_M)
    assert src.dropped["non_finite"] == 1 and src.dropped["radius_out_of_range"] == 1
    assert src.n_rows == 12 and src.n_shots == 10
    sizes = table.groupby("profile_id").size().to_list()
    assert sizes == [8, 2]
    write_altimetry(tmp_path / "alt", table, sources=[src], datum_radius_m=MERCURY_M)
    assert open_altimetry(tmp_path / "alt").dropped == {"malformed": 0, "bad_time": 0, "non_finite": 1,
                                                        "radius_out_of_range": 1, "flagged": 0,
                                                        "same_shot": 0}


def test_corrupt_store_is_refused_by_name(tmp_path: Path) -> None:
    table = combine_shots([_table(400, 4)], [ShotSource("x", 400, 400, 8, {})])
    write_altimetry(tmp_path / "alt", table, sources=[ShotSource("x", 400, 400, 8, {})], datum_radius_m=MERCURY_M)
    meta = json.loads((tmp_path / "alt" / "altimetry.json").read_text())
    meta["n_shots"] = 399
    (tmp_path / "alt" / "altimetry.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match="shots.parquet has 400 shots, altimetry.json says 399"):
        open_altimetry(tmp_path / "alt")
    (tmp_path / "alt" / "shots.parquet").write_bytes(b"PAR1 not really")
    with pytest.raises(StoreError, match="cannot read shots.parquet"):
        open_altimetry(tmp_path / "alt")


def test_shot_tiles_for_points_and_read_tiles(tmp_path: Path) -> None:
    from mercury_dem.altimetry.constraints import shot_tiles_for_points

    table = combine_shots([_table(2000, 5)], [ShotSource("a.csv", 2000, 2000, 40, {})], sigma_m=2.0)
    write_altimetry(tmp_path / "alt", table, sources=[ShotSource("a.csv", 2000, 2000, 40, {})], datum_radius_m=MERCURY_M)
    store = open_altimetry(tmp_path / "alt")
    grid = TileGrid(store.tile_size_deg)
    # three points inside three known shot tiles (at their centres), one NaN row, one point in a tile without shots
    shot = sorted(store.tiles)[:3]
    empty = sorted(set(range(grid.n_tiles)) - set(store.tiles))[0]
    lat, lon = [], []
    for t in [*shot, empty]:
        lat0, lat1, lon0, lon1 = grid.bounds(t)
        lat.append((lat0 + lat1) / 2)
        lon.append((lon0 + lon1) / 2)
    la, lo = np.radians(lat), np.radians(lon)
    xyz = MERCURY_M * np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=1)
    xyz = np.vstack([xyz, [np.nan, 0, 0]])
    assert shot_tiles_for_points(xyz, store.tile_size_deg, list(store.tiles)) == shot
    assert shot_tiles_for_points(xyz[3:], store.tile_size_deg, list(store.tiles)) == []
    few = store.read_tiles(shot, ["lat", "radius_m"])
    assert len(few) == sum(store.tiles[t] for t in shot) and list(few.columns) == ["lat", "radius_m"]
    assert len(store.read_tiles(sorted(store.tiles), ["lat"])) == store.n_shots  # most tiles: one whole read
