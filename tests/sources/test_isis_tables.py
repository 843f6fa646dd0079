"""Attached tables, NAIF keywords and AlphaCube of the real cubes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import CubeError
from mercury_dem.sources import alpha_cube, naif_keywords, open_cube, read_table, table_names
from tests.sources.cubes import APOLLO_0297, APOLLO_0298, MDIS_LEV1, MDIS_SPICE, write_cube


def camera_statistics(path: Path) -> dict[str, tuple[float, float, float]]:
    """CameraStatistics rows: name -> (minimum, maximum, average)."""
    t = read_table(open_cube(path), "CameraStatistics")
    c = t.columns
    rows = zip(c["Name"], c["Minimum"], c["Maximum"], c["Average"])
    return {str(n): (float(a), float(b), float(m)) for n, a, b, m in rows}


def test_camera_statistics_text_and_doubles() -> None:
    stats = camera_statistics(MDIS_LEV1)
    # README: ISIS's own camera model over the image (sphere R = 2440 km)
    assert stats["Latitude"] == pytest.approx((77.59082, 77.88603, 77.73779), abs=5e-6)
    assert stats["Longitude"] == pytest.approx((49.93318, 51.32502, 50.64333), abs=5e-6)
    assert stats["Resolution"] == pytest.approx((17.63996, 17.69832, 17.66712), abs=5e-6)
    apollo = camera_statistics(APOLLO_0297)
    assert apollo["Latitude"][:2] == pytest.approx((-24.5183, -17.1051), abs=1e-4)
    assert list(apollo)[:2] == ["Latitude", "Longitude"] and len(apollo) == 12


def test_spice_table_layout() -> None:
    t = read_table(open_cube(MDIS_SPICE), "InstrumentPointing")
    assert t.records == 1
    assert list(t.columns) == ["J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3", "AV1", "AV2", "AV3", "ET"]
    assert t.columns["ET"].dtype == np.float64 and t.columns["ET"].shape == (1,)
    q = np.array([t.columns[f"J2000Q{i}"][0] for i in range(4)])
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    assert t.keywords["TimeDependentFrames"] == (-236890, -236892, -236880, -236000, 1)
    assert t.keywords["ConstantFrames"] == (-236820, -236800, -236890)
    assert len(t.keywords["ConstantRotation"]) == 9
    assert t.keywords["CkTableStartTime"] == pytest.approx(t.columns["ET"][0], abs=1e-4)
    assert table_names(open_cube(MDIS_SPICE)) == ("InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition")


def test_missing_table_names_it_and_the_file() -> None:
    with pytest.raises(CubeError, match="no table named 'CameraStatistics'") as err:
        read_table(open_cube(MDIS_SPICE), "CameraStatistics")
    assert str(MDIS_SPICE) in str(err.value)


def test_table_of_integer_real_and_vector_fields_msb(tmp_path: Path) -> None:
    """A table we write ourselves: Integer, Real, Text and a Size-3 Double field, big-endian."""
    recs = np.zeros(2, dtype=[("n", ">i4"), ("r", ">f4"), ("t", "S5"), ("v", ">f8", (3,))])
    recs["n"], recs["r"], recs["t"] = [7, -2], [1.5, 2.5], [b"ab", b"cdefg"]
    recs["v"] = [[1, 2, 3], [4, 5, 6]]
    fields = "".join(f"  Group = Field\n    Name = {n}\n    Type = {t}\n    Size = {s}\n  End_Group\n"
                     for n, t, s in (("n", "Integer", 1), ("r", "Real", 1), ("t", "Text", 5), ("v", "Double", 3)))
    path = tmp_path / "t.cub"
    write_cube(path, np.zeros((1, 2, 2), np.float32))
    data = path.read_bytes()
    start = len(data) + 1
    extra = (f"Object = Table\n  Name = Mine\n  StartByte = {start}\n  Bytes = {recs.nbytes}\n  Records = 2\n"
             f"  ByteOrder = Msb\n  Note = \"x\"\n{fields}End_Object\n")
    i = data.index(b"\nEnd\n") + 1  # insert the table object before the label's End, in its zero padding
    data = data[:i] + extra.encode() + data[i : 2048 - len(extra)] + data[2048:] + recs.tobytes()
    path.write_bytes(data)
    t = read_table(open_cube(path), "Mine")
    np.testing.assert_array_equal(t.columns["n"], [7, -2])
    np.testing.assert_array_equal(t.columns["r"], [1.5, 2.5])
    assert t.columns["t"].tolist() == ["ab", "cdefg"]
    np.testing.assert_array_equal(t.columns["v"], [[1, 2, 3], [4, 5, 6]])
    assert t.keywords["Note"] == "x"


def test_naif_keywords_types() -> None:
    naif = naif_keywords(open_cube(MDIS_SPICE))
    assert naif["BODY_FRAME_CODE"] == 10011
    assert naif["BODY199_RADII"] == (2439.4, 2439.4, 2439.4)
    assert naif["INS-236820_FRAME"] == "MSGR_MDIS_NAC"
    assert naif["INS-236820_LIGHTTIME_CORRECTION"] == "LT+S"
    assert naif["INS-236820_FOCAL_LENGTH"] == pytest.approx(549.11781953727)
    assert len(naif["INS-236820_OD_T_X"]) == 10


def test_alpha_cube_corners_in_our_convention() -> None:
    ac = alpha_cube(open_cube(APOLLO_0297))
    assert ac is not None and ac.alpha_samples == 22900 and abs(ac.scale_sample - 7988.0 / 500) < 1e-12
    # ISIS: alpha = slope (beta - 0.5) + AlphaStarting with slope 15.976, 1-based. The beta image's
    # outer edges (ours -0.5 and 499.5) are the ISIS alpha edges 7996.5 / 15984.5, i.e. ours - 1.
    s, ln = ac.beta_to_alpha([-0.5, 499.5, 0.0, 249.5], [-0.5, 499.5, 0.0, 249.5])
    np.testing.assert_allclose(s, [7995.5, 15983.5, 7995.5 + 7.988, 11989.5])
    np.testing.assert_allclose(ln, [3995.5, 11983.5, 3995.5 + 7.988, 7989.5])
    # ISIS's own formula on 1-based coordinates agrees after the boundary conversion
    isis = 15.976 * (np.array([1.0, 500.0]) - 0.5) + 7996.5
    np.testing.assert_allclose(ac.beta_to_alpha([0.0, 499.0], [0.0, 0.0])[0], isis - 1)
    back = ac.alpha_to_beta(*ac.beta_to_alpha([0.0, 123.25], [499.0, 7.5]))
    np.testing.assert_allclose(np.array(back), [[0.0, 123.25], [499.0, 7.5]], atol=1e-9)
    assert alpha_cube(open_cube(APOLLO_0298)).start_sample == 11996.0  # type: ignore[union-attr]  # ISIS 11996.5
    assert alpha_cube(open_cube(MDIS_SPICE)) is None
