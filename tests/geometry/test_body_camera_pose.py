"""Round trips of the body, camera and pose geometry, near the poles and across the seam."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.body import (
    DATUM_RADIUS_M,
    angular_distance_deg,
    latlon_to_xyz,
    wrap_longitude,
    xyz_to_latlon,
)
from mercury_dem.geometry.camera import FramingCamera, mdis_nac, mdis_wac
from mercury_dem.geometry.pose import (
    angles_from_rotation,
    illumination_angles,
    image_to_ground,
    look_at_rotation,
    project,
    rotation_from_angles,
    validate_pose,
)


@given(
    lat=st.floats(-90, 90),
    lon=st.floats(-720, 720),
    h=st.floats(-6000, 6000),
)
def test_latlon_xyz_round_trip(lat: float, lon: float, h: float) -> None:
    lat2, lon2, h2 = xyz_to_latlon(latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M), datum_radius_m=DATUM_RADIUS_M)
    assert abs(h2 - h) < 1e-6
    assert abs(lat2 - lat) < 1e-9
    if abs(lat) < 89.9999:
        d = abs((lon2 - wrap_longitude(lon) + 180.0) % 360.0 - 180.0)
        assert d < 1e-8
    assert 0.0 <= lon2 < 360.0


def test_angular_distance_across_seam() -> None:
    assert angular_distance_deg(0.0, 359.5, 0.0, 0.5) == pytest.approx(1.0)
    assert angular_distance_deg(89.0, 0.0, 89.0, 180.0) == pytest.approx(2.0)


def test_camera_ifov_and_presets() -> None:
    nac = mdis_nac()
    assert nac.ifov_rad == pytest.approx(0.014 / 549.1178195372703)
    assert nac.ifov_rad * 1e6 == pytest.approx(25.5, abs=0.1)  # NAIF IK: IFOV 25.44 urad
    assert mdis_wac().focal_length_mm == pytest.approx(78.0, abs=0.5)
    half = nac.with_size(512)
    assert half.summing == 2 and half.boresight_sample == pytest.approx(255.5)
    with pytest.raises(GeometryError, match="does not divide"):
        nac.with_size(300)


@pytest.mark.parametrize("camera", [mdis_nac(512), mdis_wac(256), mdis_nac(1024, distortion=False)])
def test_pixel_camera_round_trip(camera: FramingCamera) -> None:
    rng = np.random.default_rng(1)
    px = rng.uniform(-0.5, camera.samples - 0.5, size=(500, 2))
    back = camera.camera_to_pixel(camera.pixel_to_camera(px))
    assert np.abs(back - px).max() < 1e-6


def test_distortion_is_mdis_sized() -> None:
    cam = mdis_nac(1024)
    # The NAC transverse polynomial moves a corner pixel by a few pixels, not by nothing or hundreds.
    corner = np.array([[0.0, 0.0]])
    ideal = FramingCamera(**{**cam.__dict__, "distortion_x": (), "distortion_y": ()})
    v = ideal.pixel_to_camera(corner)
    shift = np.abs(cam.camera_to_pixel(v) - corner).max()
    assert 0.1 < shift < 20.0


@pytest.mark.parametrize("lat,lon", [(0.0, 0.05), (0.0, 359.95), (89.95, 10.0), (-89.99, 200.0), (45.0, 180.0)])
@pytest.mark.parametrize("camera", [mdis_nac(512), mdis_wac(512)])
def test_ground_image_ground_round_trip(lat: float, lon: float, camera: FramingCamera) -> None:
    """Ground -> image -> ground below 1e-6 px and 1 mm, at the poles and across the seam."""
    rng = np.random.default_rng(2)
    target = latlon_to_xyz(lat, lon, height_m=0.0, datum_radius_m=DATUM_RADIUS_M)
    position = latlon_to_xyz(lat + 0.3, lon + 0.2, 400e3, datum_radius_m=DATUM_RADIUS_M)
    rotation = look_at_rotation(position, target)
    px = rng.uniform(0, camera.samples - 1, size=(300, 2))

    def height(la: np.ndarray, lo: np.ndarray) -> np.ndarray:
        u = latlon_to_xyz(la, lo, 0.0, datum_radius_m=DATUM_RADIUS_M) / DATUM_RADIUS_M
        return 1500.0 * np.sin(40 * u[..., 0]) * np.cos(30 * u[..., 1]) + 800 * u[..., 2]

    for h in (None, height):
        ground, hit = image_to_ground(camera, position, rotation, px, height=h, datum_radius_m=DATUM_RADIUS_M)
        assert hit.all()
        back, depth = project(camera, position, rotation, ground)
        assert np.abs(back - px).max() < 1e-6
        assert (depth > 0).all()
        if h is not None:
            la, lo, hh = xyz_to_latlon(ground, datum_radius_m=DATUM_RADIUS_M)
            # the point lies on the surface to 1 mm
            assert np.abs(hh - height(la, lo)).max() < 1e-3


def test_small_angle_rotation_log_exp() -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(scale=1e-3, size=(50, 3))
    r = rotation_from_angles(w)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-14)
    assert np.allclose(angles_from_rotation(r), w, atol=1e-14)
    big = rng.normal(scale=0.8, size=(50, 3))
    assert np.allclose(angles_from_rotation(rotation_from_angles(big)), big, atol=1e-10)


def test_pointing_angles_move_the_image_by_ifov() -> None:
    cam = mdis_nac(512)
    position = latlon_to_xyz(10, 20, 500e3, datum_radius_m=DATUM_RADIUS_M)
    target = latlon_to_xyz(10.0, 20.0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M)
    r0 = look_at_rotation(position, target)
    p0, _ = project(cam, position, r0, target[None])
    for axis, col in ((0, 1), (1, 0)):
        w = np.zeros(3)
        w[axis] = 10 * cam.ifov_rad
        p1, _ = project(cam, position, rotation_from_angles(w) @ r0, target[None])
        assert abs(p1[0, col] - p0[0, col]) == pytest.approx(10.0, rel=0.01)


def test_illumination_angles_simple() -> None:
    g = latlon_to_xyz(0.0, 0.0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M)[None]
    sc = latlon_to_xyz(0.0, 0.0, 1e6, datum_radius_m=DATUM_RADIUS_M)[None]
    sun = latlon_to_xyz(0.0, 60.0, 5e10, datum_radius_m=DATUM_RADIUS_M)[None]
    inc, emi, pha = illumination_angles(g, sc, sun)
    assert emi[0] == pytest.approx(0.0, abs=1e-9)
    assert inc[0] == pytest.approx(60.0, abs=0.01)
    assert pha[0] == pytest.approx(60.0, abs=0.01)


def test_validate_pose_names_image_and_field() -> None:
    good = look_at_rotation(latlon_to_xyz(0, 0, 1e6, datum_radius_m=DATUM_RADIUS_M), latlon_to_xyz(0, 0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M))
    validate_pose("IMG1", latlon_to_xyz(0, 0, 1e6, datum_radius_m=DATUM_RADIUS_M), good)
    with pytest.raises(GeometryError, match="IMG2.*'position'"):
        validate_pose("IMG2", [np.nan, 0, 0], good)
    with pytest.raises(GeometryError, match="IMG3.*'rotation'.*orthonormal"):
        validate_pose("IMG3", latlon_to_xyz(0, 0, 1e6, datum_radius_m=DATUM_RADIUS_M), good * 1.01)
    with pytest.raises(GeometryError, match="IMG4.*'rotation'"):
        validate_pose("IMG4", latlon_to_xyz(0, 0, 1e6, datum_radius_m=DATUM_RADIUS_M), -good)
