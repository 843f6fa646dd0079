"""Altimetry shot tables (LOLA RDR CSV, MLA-style headers) and the LOLA LDEM cube."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.reference.lola import (
    LOLA_RDR_COLUMNS,
    MOON_RADIUS_M,
    assign_profiles,
    parse_altimetry_csv,
    read_altimetry_csv,
    read_lola_ldem,
)
from mercury_dem.reference.sampling import sample_reference_dem

from .conftest import LOLA_DIR, shared

MERCURY_M = 2_439_400.0


@pytest.fixture(scope="module")
def head():
    return read_altimetry_csv(shared(LOLA_DIR / "lidarPoints_head.csv"), MOON_RADIUS_M)


@pytest.fixture(scope="module")
def tail():
    return read_altimetry_csv(shared(LOLA_DIR / "lidarPoints_tail.csv"), MOON_RADIUS_M)


@pytest.fixture(scope="module")
def ldem():
    return read_lola_ldem(shared(LOLA_DIR / "ldem_4_reduced.cub"))


def test_real_lola_shots(head, tail):
    assert (head.n_rows, len(head.table), head.n_profiles) == (55, 55, 1)
    assert sum(head.dropped.values()) == 0
    first = head.table.iloc[0]
    assert first["lat"] == pytest.approx(60.0187875)
    assert first["lon"] == pytest.approx(99.0636769)
    assert first["radius_m"] == pytest.approx(1_734_913.521)
    assert first["range_m"] == pytest.approx(56_906.246)
    assert first["sc_radius_m"] == pytest.approx(1_791_819.609)
    assert str(first["time"]) == "2010-01-27 06:19:47.013826010"
    # Range is the spacecraft radius minus the shot radius (near nadir: 0.26 deg off).
    t = head.table
    assert np.allclose(t["sc_radius_m"] - t["radius_m"], t["range_m"], atol=50.0)
    assert t["time"].is_monotonic_increasing
    # The tail repeats the head's first shot, then resumes 19.75 s later: two profiles.
    assert (tail.n_rows, tail.n_profiles) == (51, 2)
    assert list(tail.table["profile_id"][:3]) == [0, 1, 1]
    assert tail.table.iloc[0]["time"] == first["time"]


def test_gap_setting_joins_profiles():
    s = read_altimetry_csv(shared(LOLA_DIR / "lidarPoints_tail.csv"), MOON_RADIUS_M, max_gap_s=30.0)
    assert s.n_profiles == 1


def test_assign_profiles():
    t = np.array([0.0, 0.1, 0.2, 5.0, 5.1, 100.0])
    assert list(assign_profiles(t, 1.0)) == [0, 0, 0, 1, 1, 2]
    assert assign_profiles(np.zeros(0), 1.0).size == 0


def test_shots_agree_with_ldem(head, ldem):
    """Shots (absolute radii) and LDEM (DN x 0.5 above 1737.4 km) on one datum: a unit or
    scale slip (DN not halved: ~2.5 km; km read as m) would be far outside 300 m."""
    t = head.table
    h = sample_reference_dem(ldem, t["lat"], t["lon"])
    diff = (t["radius_m"] - ldem.attrs["datum_radius_m"]) - h
    assert np.all(np.isfinite(diff))
    assert abs(np.median(diff)) < 300.0  # measured 88 m mean, 192 m std on a 22 km grid at 60 N


def test_ldem_units_and_grid(ldem):
    assert ldem.shape == (240, 480) and ldem.dims == ("lat", "lon")
    assert ldem.attrs["datum_radius_m"] == 1_737_400.0 and ldem.attrs["multiplier"] == 0.5
    assert float(ldem.min()) == -7811.0 and float(ldem.max()) == 9141.0  # DN -15622 .. 18282
    lat, lon = ldem["lat"].values, ldem["lon"].values
    assert lat[0] == pytest.approx(89.625, abs=1e-4) and lat[-1] == pytest.approx(-89.625, abs=1e-4)
    assert lon[0] == pytest.approx(0.375, abs=1e-4) and lon[-1] == pytest.approx(359.625, abs=1e-4)
    assert np.all(np.diff(lon) > 0) and np.all(np.diff(lat) < 0)
    assert not np.isnan(ldem.values).any()


def test_ldem_not_a_raster(tmp_path):
    bad = tmp_path / "not_a.cub"
    bad.write_text("Object = IsisCube\nEnd\n")
    with pytest.raises(ReferenceDataError, match="not_a.cub"):
        read_lola_ldem(bad)
    with pytest.raises(ReferenceDataError, match="absent.cub"):
        read_lola_ldem(tmp_path / "absent.cub")


MLA_STYLE = """UTC, LONGITUDE, LATITUDE, RADIUS (km), Range, FLAG
2011-04-01T00:00:00.000, -10.5, 45.0, 2438.000, 400.0, 0
2011-04-01T00:00:00.125, -10.4, 45.1, 2438.010, 400.0, 0
2011-04-01T00:00:00.250, -10.3, 45.2, nan, 400.0, 0
2011-04-01T00:00:00.375, -10.2, 45.3, 2480.000, 400.0, 0
2011-04-01T00:00:00.500, -10.1, 45.4, 2438.020, 400.0, 3
2011-04-01T00:00:00.625, -10.0, 45.5, 2438.030, 400.0
not a time, -10.0, 45.5, 2438.030, 400.0, 0
2011-04-01T00:00:00.750, -9.9, 95.0, 2438.030, 400.0, 0
2011-04-01T00:20:00.000, 350.0, 46.0, 2437.5, 400.0, 0
"""


def test_header_names_any_case_and_dropped_counts():
    s = parse_altimetry_csv(MLA_STYLE, MERCURY_M, source="mla.csv")
    assert s.n_rows == 9
    assert s.dropped == {"malformed": 1, "bad_time": 1, "non_finite": 2, "radius_out_of_range": 1, "flagged": 1,
                         "same_shot": 0}
    assert s.n_rows == len(s.table) + sum(s.dropped.values())
    t = s.table
    assert len(t) == 3 and s.n_profiles == 2
    assert t["lon"].tolist() == pytest.approx([349.5, 349.6, 350.0])  # west-negative folded to [0, 360)
    assert t["radius_m"].tolist() == pytest.approx([2_438_000.0, 2_438_010.0, 2_437_500.0])


def test_numeric_times_and_metres():
    text = "et,lat,lon,radius\n100.0,1,2,2439000\n100.1,1,2,2439001\n250.0,1,2,2439002\n"
    s = parse_altimetry_csv(text, MERCURY_M, radius_unit="m", max_gap_s=1.0)
    assert s.table["time"].dtype == np.float64 and s.n_profiles == 2
    assert s.table["radius_m"].iloc[0] == 2_439_000.0


def test_explicit_columns_for_a_headerless_table():
    text = "2011-04-01T00:00:00,1.0,2.0,2439.0\n"
    s = parse_altimetry_csv(text, MERCURY_M, columns=["time", "lat", "lon", "radius"])
    assert (s.table["lat"].iloc[0], s.table["lon"].iloc[0]) == (1.0, 2.0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("2011-04-01T00:00:00,1.0,2.0,2439.0\n", "no header row and 4 columns"),
        ("time,lat,height\n2011-04-01T00:00:00,1,2\n", "no column for lon, radius"),
    ],
)
def test_unusable_tables_name_the_file(text, message):
    with pytest.raises(ReferenceDataError, match=message) as err:
        parse_altimetry_csv(text, MERCURY_M, source="shots.csv")
    assert str(err.value).startswith("shots.csv:")


def test_unreadable_files(tmp_path):
    with pytest.raises(ReferenceDataError, match="nothing.csv"):
        read_altimetry_csv(tmp_path / "nothing.csv")
    binary = tmp_path / "rdr.dat"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(ReferenceDataError, match="rdr.dat.*UTF-8"):
        read_altimetry_csv(binary)


def test_headerless_layout_has_29_columns():
    assert len(LOLA_RDR_COLUMNS) == 29


def test_ancillary_columns_not_finite_become_nan():
    """Found by the fuzzer: an infinite spacecraft longitude warned in the longitude fold."""
    text = "utc,lat,lon,radius,sc_lon,sc_radius,range\n2011-04-01T00:00:00,1,2,2439.0,1e999,nan,inf\n"
    s = parse_altimetry_csv(text, MERCURY_M)
    row = s.table.iloc[0]
    assert np.isnan(row["sc_lon"]) and np.isnan(row["sc_radius_m"]) and np.isnan(row["range_m"])


def test_mla_rdr_header_layout(tmp_path):
    """An MLA-RDR-like table written here (the column names of the PDS MLASCIRDR*.TAB files, made-up
    values): altitude in km above the 2440 km sphere becomes a radius, channel >= 5 is dropped as
    flagged, UTC is preferred over EphemerisTime, Sat_long/Sat_lat are the spacecraft's."""
    from mercury_dem.reference.lola import MLA_ALTITUDE_REFERENCE_M

    header = ("geoc_long,geoc_lat,altitude,EphemerisTime,MET,frm,chn,Pulswd,thrsh,gain,1way_range,Emiss,TXmJ,"
              "UTC,TOF_ns_ET,Sat_long,Sat_lat,Sat_alt,Offnad,Phase,Sol_inc,SCRNGE,seqid")
    rows = []
    for i in range(12):
        chn = 6 if i == 3 else i % 4
        lon = 359.9995 + 0.0004 * i  # across the 0/360 seam
        rows.append(f"{lon:.4f},{70 + 0.01 * i:.4f},{-1.5 + 0.01 * i:.5f},{3.9e8 + 0.125 * i:.6f},{250000000 + i},"
                    f"{i % 8},{chn},10.0,0.1,1.0,400.1,0.5,18.0,2012-06-01T07:03:{47 + 0.125 * i:06.3f},"
                    f"2668000.0,{lon:.4f},{70 + 0.01 * i:.4f},400.2,0.3,80.0,60.0,400.1,{i}")
    path = tmp_path / "MLASCIRDR_like.TAB"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    shots = read_altimetry_csv(path, MERCURY_M)
    t = shots.table
    assert shots.n_rows == 12 and len(t) == 11 and shots.dropped["flagged"] == 1
    assert t["radius_m"].iloc[0] == pytest.approx(MLA_ALTITUDE_REFERENCE_M - 1500.0)
    assert t["lat"].iloc[0] == pytest.approx(70.0) and t["sc_lat"].iloc[0] == pytest.approx(70.0)
    assert t["lon"].between(0.0, 360.0, inclusive="left").all()
    assert str(t["time"].iloc[0]) == "2012-06-01 07:03:47"
    assert shots.n_profiles == 1 and (t["flag"] == 0).all()
    # The ODE point export carries a radius beside the altitude: the radius wins.
    ode = tmp_path / "ode_mla.csv"
    ode.write_text("longitude,latitude,altitude,radius,EphemerisTime,chn,UTC\n"
                   "10.0,80.0,-1.0,2439.0,3.9e8,0,2012-06-01T07:03:47\n")
    assert read_altimetry_csv(ode, MERCURY_M).table["radius_m"].iloc[0] == pytest.approx(2_439_000.0)


def test_real_mla_rdr_excerpt_reads_with_its_values(gtmes):
    """A real MESSENGER MLA RDR file (an excerpt of MLASCIRDR1201011014.TAB, 2012-01-01, two stretches
    of one pass: 53.8° N and 77.9° N; tests/data/real/SOURCE.md): each shot read with the file's
    values, the noise detections (channel >= 5) dropped, a shot detected in two channels kept once,
    and the heights agree with GTMES_150V05 (MLA's own shape model, degree 148 ≈ 50 km) to the
    relief it cannot resolve — measured +22 m and +429 m (median per stretch); a wrong altitude
    reference or unit would be kilometres off."""
    from mercury_dem.reference.lola import MLA_ALTITUDE_REFERENCE_M
    from mercury_dem.reference.sha import evaluate

    from .conftest import REAL

    shots = read_altimetry_csv(REAL / "MLASCIRDR1201011014_excerpt.TAB", MERCURY_M)
    t = shots.table
    assert shots.n_rows == 85
    assert shots.dropped["flagged"] == 43 and shots.dropped["same_shot"] == 17
    assert len(t) == 85 - 43 - 17 == 25 and t["time"].is_unique
    first = t.iloc[0]  # the file's row "126.77168, 53.74017, -2.1890, ..., 2012-01-01T10:22:42.4167", chn 2
    assert (first["lon"], first["lat"]) == (pytest.approx(126.77168), pytest.approx(53.74017))
    assert first["radius_m"] == pytest.approx(MLA_ALTITUDE_REFERENCE_M - 2189.0)
    assert str(first["time"]) == "2012-01-01 10:22:42.416700"
    assert first["sc_lat"] == pytest.approx(58.78300)
    # the two stretches are 5 min apart: two profiles
    assert shots.n_profiles == 2
    diff = t["radius_m"].to_numpy() - evaluate(gtmes, t["lat"].to_numpy(), t["lon"].to_numpy())
    for tid in (0, 1):
        assert abs(np.median(diff[t["profile_id"].to_numpy() == tid])) < 600.0
