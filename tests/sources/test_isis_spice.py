"""Exterior orientation from the cubes' SPICE tables against independent values.

Independent references: the README's known ground point of EN1072174528M, its CSM ISDs (made by
ALE from the SPICE kernels), ISIS's own CameraStatistics in the cubes, and the label's altitude.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import CubeError
from mercury_dem.geometry.isd import quaternion_to_matrix, read_isd
from mercury_dem.sources import cube_spice, isis_serial_number, open_cube, read_table
from tests.sources.cubes import APOLLO_0297, APOLLO_0298, MDIS_LEV1, MDIS_SPICE, shared, write_cube
from tests.sources.test_isis_tables import camera_statistics

AU_M = 1.495978707e11


def ground_point(position: np.ndarray, look: np.ndarray, radius: float) -> tuple[float, float]:
    """Planetocentric latitude, east longitude (deg) where the ray from ``position`` along ``look`` meets the sphere."""
    b = float(position @ look)
    t = -b - np.sqrt(b * b - (position @ position - radius**2))
    x = position + t * look
    return float(np.degrees(np.arcsin(x[2] / np.linalg.norm(x)))), float(np.degrees(np.arctan2(x[1], x[0])) % 360)


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1)))


def test_mdis_boresight_hits_the_known_ground_point() -> None:
    s = cube_spice(open_cube(MDIS_SPICE))
    lat, lon = ground_point(s.position, s.body_to_instrument[2], 2439.4e3)  # MDIS looks along +Z
    assert lat == pytest.approx(46.275, abs=0.01) and lon == pytest.approx(248.068, abs=0.01)
    assert (s.ik_code, s.instrument_frame_code, s.body_frame_code) == (-236820, -236820, 10011)
    assert s.radii_m == (2439.4e3,) * 3
    for m in (s.j2000_to_body, s.body_to_instrument):
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)


def test_mdis_exposure_time_is_the_clock_rule_and_matches_the_tables() -> None:
    cube = open_cube(MDIS_SPICE)
    s = cube_spice(cube)
    assert s.et_source.startswith("MDIS")
    # spiceinit cached the tables at ISIS's exposure centre: the same time to float precision
    assert s.et == pytest.approx(read_table(cube, "InstrumentPointing").columns["ET"][0], abs=1e-6)
    assert s.et == pytest.approx(483122606.85252, abs=1e-5)


@pytest.mark.parametrize("isd", ["EN1072174528M_knoten_isd.json", "messmdis_isd.json"])
def test_mdis_agrees_with_the_csm_isds(isd: str) -> None:
    g = read_isd(shared(f"mdis/EN1072174528M/{isd}"))
    s = cube_spice(open_cube(MDIS_SPICE))
    assert np.linalg.norm(g.position - s.position) < 1.0  # metres (measured 0.017 m)
    assert rotation_angle(g.rotation, s.body_to_instrument) < 1e-6  # rad (measured 0.10 urad)
    assert g.ephemeris_time == pytest.approx(s.et, abs=1e-6)
    assert np.linalg.norm(g.sun_position - s.sun_position) < 1e3  # messmdis_isd's Sun is 781 m off (of 4.7e10 m)


def test_lev1_boresight_inside_isis_camera_statistics() -> None:
    s = cube_spice(open_cube(MDIS_LEV1))
    lat, lon = ground_point(s.position, s.body_to_instrument[2], 2440.0e3)  # ISIS used R = 2440 km
    stats = camera_statistics(MDIS_LEV1)
    assert 77.59 < lat < 77.89 and 49.93 < lon < 51.33  # README's CameraStatistics range
    assert lat == pytest.approx(stats["Latitude"][2], abs=0.005)  # near the image mean (77.738, 50.643)
    assert lon == pytest.approx(stats["Longitude"][2], abs=0.02)
    assert s.serial_number == "MeSSEnGeR/MDIS-NAC/1/0240208184:982000"


@pytest.mark.parametrize("path", [APOLLO_0297, APOLLO_0298])
def test_apollo_minus_z_hits_the_moon_inside_the_frame(path: Path) -> None:
    s = cube_spice(open_cube(path))
    look = -s.body_to_instrument[2]  # Apollo Metric looks along -Z of its NAIF frame
    lat, lon = ground_point(s.position, look, 1737.4e3)
    stats = camera_statistics(path)
    (lat_lo, lat_hi, lat_mean), (lon_lo, lon_hi, lon_mean) = stats["Latitude"], stats["Longitude"]
    assert lat_lo < lat < lat_hi and lon_lo < lon < lon_hi
    if path == APOLLO_0297:
        assert -24.52 < lat < -17.11 and 140.79 < lon < 148.78
    assert abs(lat - lat_mean) < 0.01 and abs(lon - lon_mean) < 0.015  # the frame centre ~ the mean
    assert 110e3 < np.linalg.norm(s.position) - 1737.4e3 < 120e3  # label SpacecraftAltitude 115978 m
    assert 0.98 < np.linalg.norm(s.sun_position) / AU_M < 1.03  # the Sun seen from the Moon
    assert s.ik_code == -915240 and s.body_frame_code == 310001


def test_apollo_body_constant_rotation_is_composed_as_c_times_q() -> None:
    """BodyRotation: J2000 -> 310002 (quaternion), then ConstantRotation 310002 -> 310001.

    C . q2m(q) puts the frame centre nearer ISIS's CameraStatistics mean than q2m(q) alone or
    C^T . q2m(q) (measured 0.010 / 0.025 / 0.057 deg on 0297) on both frames.
    """
    for path in (APOLLO_0297, APOLLO_0298):
        cube = open_cube(path)
        s = cube_spice(cube)
        body = read_table(cube, "BodyRotation")
        c = np.array(body.keywords["ConstantRotation"]).reshape(3, 3)
        q_body = quaternion_to_matrix([body.columns[f"J2000Q{i}"][0] for i in range(4)])
        np.testing.assert_allclose(s.j2000_to_body, c @ q_body, atol=1e-15)
        j2i = s.body_to_instrument @ s.j2000_to_body
        pos_j2000 = s.j2000_to_body.T @ s.position
        stats = camera_statistics(path)
        mean = np.array([stats["Latitude"][2], stats["Longitude"][2]])
        miss = {}
        for name, j2b in (("C q", c @ q_body), ("q", q_body), ("C^T q", c.T @ q_body)):
            look = -(j2i @ j2b.T)[2]
            miss[name] = float(np.hypot(*(np.array(ground_point(j2b @ pos_j2000, look, 1737.4e3)) - mean)))
        assert miss["C q"] < min(miss["q"], miss["C^T q"]), miss


def test_apollo_exposure_time_is_the_label_start_time() -> None:
    """ApolloMetricCamera: StartTime is the shutter centre; the CK midpoint we use is that time.

    UTC -> TDB by hand: before 1972 NAIF's leapseconds kernel uses TAI - UTC = 9 s, so
    ET = UTC seconds past J2000 (no leap seconds) - 22 leap seconds (1972-1999) + 9 + 32.184 + 22 + ...;
    numerically ET - (UTC span without leap seconds) = 41.184 s minus the 1.7 ms periodic term.
    """
    for path in (APOLLO_0297, APOLLO_0298):
        cube = open_cube(path)
        s = cube_spice(cube)
        utc = datetime.fromisoformat(f"{cube.start_time}+00:00")
        span = (utc - datetime(2000, 1, 1, 12, tzinfo=timezone.utc)).total_seconds()
        assert s.et - span == pytest.approx(41.184, abs=0.002)
        assert s.et_source.startswith("midpoint of CkTable")


def test_serial_numbers_follow_isis_rules() -> None:
    assert cube_spice(open_cube(MDIS_SPICE)).serial_number == "MeSSEnGeR/MDIS-NAC/2/0072174528:989000"
    assert isis_serial_number(open_cube(APOLLO_0297).label) == "APOLLO15/METRIC/1971-07-31T01:25:02.243"
    assert isis_serial_number(open_cube(APOLLO_0298).label) == "APOLLO15/METRIC/1971-07-31T01:25:27.457"


def test_apollo_serial_format_matches_a_real_isis_network() -> None:
    """The serial numbers inside a jigsaw network of Apollo 15 Metric frames have our form exactly."""
    data = shared("isis_cnet/apollo_out.net").read_bytes()
    start = data.index(b"APOLLO15/METRIC/")
    serial = data[start : start + 39].decode()
    label = {"IsisCube": {"Instrument": {"SpacecraftName": "APOLLO 15", "InstrumentId": "METRIC",
                                         "StartTime": serial.split("/")[2]}}}
    assert isis_serial_number(label) == serial


def test_unknown_mission_has_no_serial_rule() -> None:
    label = {"IsisCube": {"Instrument": {"SpacecraftName": "Viking", "InstrumentId": "VIS"}}}
    with pytest.raises(CubeError, match="no serial-number rule"):
        isis_serial_number(label, "v.cub")


@pytest.mark.parametrize("which", ["synthetic", "raw_dn"])
def test_cube_without_spice_says_run_spiceinit(tmp_path: Path, which: str) -> None:
    if which == "raw_dn":
        path = shared("mdis/EN1072174528M/EN1072174528M_raw_dn.cub")
    else:
        path = write_cube(tmp_path / "plain.cub", np.zeros((1, 2, 2), np.float32))
    with pytest.raises(CubeError, match="has no InstrumentPointing table: run spiceinit attach=true") as err:
        cube_spice(open_cube(path))
    assert str(path) in str(err.value)


def test_interpolation_between_records() -> None:
    """Slerp with sign continuity and Hermite positions on a uniform rotation and a circular orbit."""
    from mercury_dem.sources.isis_spice import _position_at, _rotation_at
    from mercury_dem.sources.isis_tables import CubeTable

    cube = open_cube(MDIS_SPICE)  # only named in messages
    t = np.array([0.0, 10.0, 20.0])
    w = 0.05  # rad/s about z
    q = np.stack([np.cos(w * t / 2), 0 * t, 0 * t, np.sin(w * t / 2)], axis=1)
    q[1] *= -1  # the same rotation; interpolation must not go the long way round
    rot = CubeTable("R", 3, {f"J2000Q{i}": q[:, i] for i in range(4)} | {"ET": t}, {})
    r, n = 7000.0, 1e-3  # km, rad/s: a low orbit's mean motion
    pos = {"J2000X": r * np.cos(n * t), "J2000Y": r * np.sin(n * t), "J2000Z": 0 * t,
           "J2000XV": -r * n * np.sin(n * t), "J2000YV": r * n * np.cos(n * t), "J2000ZV": 0 * t, "ET": t}
    et = 13.0
    m = _rotation_at(cube, rot, et)
    np.testing.assert_allclose(m, quaternion_to_matrix([np.cos(w * et / 2), 0, 0, np.sin(w * et / 2)]), atol=1e-12)
    truth = np.array([r * np.cos(n * et), r * np.sin(n * et), 0.0])
    hermite = _position_at(cube, CubeTable("P", 3, pos, {}), et)
    linear = _position_at(cube, CubeTable("P", 3, {k: v for k, v in pos.items() if not k.endswith("V")}, {}), et)
    assert np.linalg.norm(linear - truth) > 0.05  # km: the chord's sag
    assert np.linalg.norm(hermite - truth) < 1e-6  # km: cubic Hermite error ~ r (n h)^4 / 384
    with pytest.raises(CubeError, match="covers ET 0.000000..20.000000 s, not the exposure time 25"):
        _position_at(cube, CubeTable("P", 3, pos, {}), 25.0)
