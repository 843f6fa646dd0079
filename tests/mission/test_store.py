"""The Mission layer: camera table, body, radiometry and catalog as stored and read back."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import MERCURY, MOON, Body, body_by_name
from mercury_dem.geometry.camera import mdis_nac, mdis_wac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.mission import MissionWriter, open_mission
from mercury_dem.mission.cameras import camera_from_dict, camera_to_dict
from mercury_dem.mission.catalog import build_catalog, footprint_statistics
from mercury_dem.mission.radiometry import DN12, Radiometry, float_radiometry


def test_camera_round_trip_is_exact() -> None:
    for cam in (mdis_nac(512), mdis_wac(1024), mdis_nac(1024, distortion=False)):
        back = camera_from_dict(json.loads(json.dumps(camera_to_dict(cam))))
        assert back == cam


def test_camera_from_bad_dict_names_field() -> None:
    d = camera_to_dict(mdis_nac(512))
    with pytest.raises(StoreError, match="focal_length_mm"):
        camera_from_dict({**d, "focal_length_mm": float("nan")}, "cams")
    with pytest.raises(StoreError, match="unknown field"):
        camera_from_dict({**d, "colour": 1}, "cams")


def test_bodies_and_crs_codes() -> None:
    assert MERCURY.crs() == "IAU_2015:19900" and MERCURY.crs("south_polar") == "IAU_2015:19935"
    assert MOON.crs("equirectangular_180") == "IAU_2015:30115"
    assert body_by_name("moon") is MOON
    assert Body.from_dict(MOON.to_dict()) == MOON
    with pytest.raises(ValueError, match="unknown body"):
        body_by_name("Vulcan")


def _tiny_catalog(body: Body, n: int = 3) -> tuple[dict, object]:
    cam = mdis_nac(64)
    r = body.datum_radius_m
    target = np.array([[np.cos(np.radians(a)), np.sin(np.radians(a)), 0.2] for a in (10.0, 10.05, 10.1)])[:n]
    target = target / np.linalg.norm(target, axis=1, keepdims=True) * r
    pos = target * (1.0 + 200e3 / r)
    rot = np.array([look_at_rotation(p, t) for p, t in zip(pos, target)])
    sun = np.tile([1.5e11, 0.0, 0.0], (n, 1))
    cams = {"nac": cam}
    cat = build_catalog([f"im{i}" for i in range(n)], ["MDIS-NAC"] * n, cams, ["nac"] * n, np.arange(n, dtype=float),
                        pos, rot, sun, body, 10.0, [DN12] * n)
    return cams, cat


@pytest.mark.parametrize("body", [MERCURY, MOON])
def test_written_mission_reads_back(tmp_path, body) -> None:
    cams, cat = _tiny_catalog(body)
    out = tmp_path / "m"
    with atomic_directory(out) as tmp:
        w = MissionWriter(tmp)
        for i in range(3):
            w.write_image(tmp, f"im{i}", np.full((64, 64), i, np.float32))
        w.finish({"source": "test"}, body, cams, cat)
    m = open_mission(out)
    assert m.body == body and m.truth is None and len(m) == 3
    assert m.camera("im1") == cams["nac"]
    assert m.radiometry("im0") == DN12
    img, valid = m.read_image_masked("im2")
    assert img.dtype == np.float32 and valid.all() and float(img[0, 0]) == 2.0
    # the centre of a nadir view lies under the spacecraft, on the body's datum
    lat, lon = float(m.catalog["center_lat"].iat[0]), float(m.catalog["center_lon"].iat[0])
    assert abs(lon - 10.0) < 1e-6 and m.catalog["footprint_lon_min"].iat[0] < lon < m.catalog["footprint_lon_max"].iat[0]
    assert m.catalog["footprint_lat_min"].iat[0] < lat < m.catalog["footprint_lat_max"].iat[0]


def test_image_of_wrong_shape_is_named(tmp_path) -> None:
    cams, cat = _tiny_catalog(MERCURY, 1)
    out = tmp_path / "m"
    with atomic_directory(out) as tmp:
        w = MissionWriter(tmp)
        w.write_image(tmp, "im0", np.zeros((10, 64), np.uint16))
        w.finish({"source": "test"}, MERCURY, cams, cat)
    with pytest.raises(StoreError, match="im0.*camera"):
        open_mission(out).read_image("im0")


def test_bad_camera_table_is_refused(tmp_path) -> None:
    cams, cat = _tiny_catalog(MERCURY, 1)
    out = tmp_path / "m"
    with atomic_directory(out) as tmp:
        w = MissionWriter(tmp)
        w.write_image(tmp, "im0", np.zeros((64, 64), np.uint16))
        w.finish({"source": "test"}, MERCURY, cams, cat)
    (out / "cameras.json").write_text("{\"nac\": [1, 2]}")
    with pytest.raises(StoreError, match="cameras.json camera 'nac'"):
        open_mission(out)


def test_float_radiometry_scales_thresholds() -> None:
    r = float_radiometry([0.04, 0.05, float("nan")])
    assert r.pixel_kind == "reflectance" and np.isnan(r.saturation)
    assert r.dn_scale == pytest.approx(0.045 / 4095)
    with pytest.raises(ValueError):
        Radiometry("counts", 1.0, 1.0)


def test_footprint_statistics_of_a_nadir_view() -> None:
    cam = mdis_nac(64)
    r = MERCURY.datum_radius_m
    target = np.array([r, 0.0, 0.0])
    pos = np.array([r + 100e3, 0.0, 0.0])
    rot = look_at_rotation(pos, target)
    st = footprint_statistics(cam, pos, rot, np.array([1e11, 0, 0]), r)
    half = np.degrees(32 * cam.ifov_rad * 100e3 / r)  # half the image width seen from 100 km
    assert st["latitude"]["average"] == pytest.approx(0.0, abs=1e-3)
    assert st["longitude"]["maximum"] - st["longitude"]["minimum"] == pytest.approx(2 * half, rel=0.05)
    assert st["resolution"]["minimum"] == pytest.approx(100e3 * cam.ifov_rad, rel=1e-3)
    corner = np.degrees(np.hypot(32, 32) * cam.ifov_rad) * (1 + 100e3 / r)  # off-nadir angle + curvature
    assert st["emission"]["minimum"] < 0.05 and st["emission"]["maximum"] == pytest.approx(corner, rel=0.05)
