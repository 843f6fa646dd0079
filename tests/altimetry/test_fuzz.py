"""Fuzzing the shot-table input of ``register`` (Parquet bytes, table contents) and the tile fit on
arbitrary shots: a result or a ReferenceDataError naming the file, never another exception."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.altimetry.register import DemWindow, RegisterOptions, register_tile
from mercury_dem.commands.register import read_shots
from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.pipeline.register_stage import check_shots

pytestmark = pytest.mark.timeout(120)
R = 2_439_400.0


def _parquet() -> bytes:
    buf = io.BytesIO()
    n = 40
    pd.DataFrame({"lat": np.linspace(30, 31, n), "lon": np.linspace(100, 100.1, n), "radius_m": R + np.arange(n),
                  "profile_id": np.arange(n) // 10}).to_parquet(buf, index=False)
    return buf.getvalue()


_PQ = _parquet()


@st.composite
def _mutated(draw) -> bytes:
    data = bytearray(_PQ[: draw(st.integers(0, len(_PQ)))] if draw(st.booleans()) else _PQ)
    for _ in range(draw(st.integers(0, 5))):
        if not data:
            break
        i = draw(st.integers(0, len(data) - 1))
        if draw(st.booleans()):
            data[i] = draw(st.integers(0, 255))
        else:
            del data[i: i + draw(st.integers(1, 30))]
    return bytes(data)


@settings(max_examples=int(__import__("os").environ.get("FUZZ_EXAMPLES", 60)), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(_mutated())
def test_fuzz_parquet_shots(tmp_path, data):
    path = tmp_path / "fuzz_shots.parquet"
    path.write_bytes(data)
    try:
        df = read_shots([str(path)], R)
        good, n_bad = check_shots(df, str(path))
    except ReferenceDataError as exc:
        assert "fuzz_shots.parquet" in str(exc)
        return
    assert n_bad + len(good) == len(df)
    assert np.all(np.isfinite(good[["lat", "lon", "radius_m"]].to_numpy()))


_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), st.floats(-1e3, 1e3))


@settings(max_examples=int(__import__("os").environ.get("FUZZ_EXAMPLES", 40)), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 80), st.data())
def test_fuzz_register_tile_any_shots(n, data):
    """Any shots (NaN, inf, huge, duplicated, off the DEM, one track): counted, never a crash."""
    lat = np.arange(41.0, 28.9, -0.25)
    lon = np.arange(99.0, 111.1, 0.25)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    win = DemWindow(500 * np.sin(np.radians(la) * 20) * np.cos(np.radians(lo) * 15), lat, lon, R)
    d_lat = np.array(data.draw(st.lists(_values, min_size=n, max_size=n)))
    d_lon = np.array(data.draw(st.lists(_values, min_size=n, max_size=n)))
    d_h = np.array(data.draw(st.lists(_values, min_size=n, max_size=n)))
    track = np.array(data.draw(st.lists(st.integers(0, 3), min_size=n, max_size=n)), dtype=np.int64)
    with np.errstate(all="ignore"):
        lat_s = 35 + np.clip(d_lat, -1e6, 1e6) / 200
        lon_s = 105 + np.clip(d_lon, -1e6, 1e6) / 200
        rad = R + d_h
    res = register_tile(win, lat_s, lon_s, rad, track, tile_id=0, centre=(35.0, 105.0),
                        options=RegisterOptions(min_shots=5, min_profile_shots=3))
    c = res.counts
    assert c["shots"] == n and c["invalid"] + c["off_dem"] + c["used"] + c["rejected"] + c["not_registered"] == n
    assert res.transform.ok or res.transform.reason
    if res.transform.ok:
        assert np.all(np.isfinite(res.transform.translation_enu_m))
