"""Framing cameras of real instruments (MDIS, Apollo 15 Metric) from ISIS NAIF keywords."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.adjust.framing import FramingModel, FramingState
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz
from mercury_dem.geometry.camera import (
    FramingCamera,
    camera_from_dict,
    camera_to_dict,
    mdis_nac,
    mdis_wac,
)
from mercury_dem.geometry.distortion import ApolloMetricDistortion
from mercury_dem.geometry.naif_camera import AlphaCube, camera_from_naif
from mercury_dem.geometry.pose import look_at_rotation
from tests.adjust.test_framing import assert_jacobians_match_differences

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
MDIS_LEV1 = SHARED / "mdis" / "EN0240208184M" / "EN0240208184M.lev1.cub"
MDIS_SPICE = SHARED / "mdis" / "EN1072174528M" / "EN1072174528M_raw_dn_with_spice.cub"
MDIS_ISD = SHARED / "mdis" / "EN1072174528M" / "messmdis_isd.json"
APOLLO_CROP = SHARED / "moon" / "apollo15_metric_strip" / "AS15-M-0297_crop.cub"

#: The Apollo 15 Metric keywords of AS15-M-0297 (ISIS focal plane: x along decreasing sample).
APOLLO_KEYS: dict[str, Any] = {
    "INS-915240_FOCAL_LENGTH": 76.054, "INS-915240_PIXEL_PITCH": 0.005,
    "INS-915240_TRANSX": [0.0, -0.005, 0.0], "INS-915240_TRANSY": [0.0, 0.0, 0.005],
    "INS-915240_ITRANSS": [0.0, -200.0, 0.0], "INS-915240_ITRANSL": [0.0, 0.0, 200.0],
    "INS-915240_PP": [-0.006, -0.002], "INS-915240_OD_K": [-1.3361854e-06, 5.2261757e-10, -5.0728336e-14],
    "INS-915240_DECENTER": [-5.4958195e-07, -4.608942e-11, 2.965907],
}
APOLLO_ALPHA = {"AlphaSamples": 22900, "AlphaLines": 22900, "AlphaStartingSample": 7996.5,
                "AlphaStartingLine": 3996.5, "AlphaEndingSample": 15984.5, "AlphaEndingLine": 11984.5,
                "BetaSamples": 500, "BetaLines": 500}


def cube_label(path: Path) -> Any:
    """The PVL label of an ISIS cube (skips when the file or pvl is absent)."""
    if not path.exists():
        pytest.skip(f"{path} not present (../shared/data is only on the development machine)")
    pvl = pytest.importorskip("pvl")
    lines = []
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("latin-1").rstrip("\r\n")
            lines.append(line)
            if line.strip() == "End":
                break
    return pvl.loads("\n".join(lines))


def mdis_from_cube(path: Path) -> FramingCamera:
    lab = cube_label(path)
    inst = lab["IsisCube"]["Instrument"]
    summing = (int(inst["PixelBinningMode"]) or 1) * (2 if int(inst["FpuBinningMode"]) == 1 else 1)
    dims = lab["IsisCube"]["Core"]["Dimensions"]
    cam, rot = camera_from_naif(dict(lab["NaifKeywords"]), -236820, int(dims["Samples"]), int(dims["Lines"]),
                                name="MDIS-NAC", summing=summing)
    assert np.array_equal(rot, np.eye(3))
    return cam


def apollo_camera() -> tuple[FramingCamera, np.ndarray]:
    return camera_from_naif(APOLLO_KEYS, -915240, 500, 500, name="Apollo15-Metric", alpha=APOLLO_ALPHA)


def image_grid(cam: FramingCamera, n: int = 41) -> np.ndarray:
    s, l = np.meshgrid(np.linspace(-0.5, cam.samples - 0.5, n), np.linspace(-0.5, cam.lines - 0.5, n))
    return np.stack([s.ravel(), l.ravel()], axis=-1)


# -- the presets did not change -------------------------------------------------------------

def _hex(a: list[str]) -> np.ndarray:
    return np.array([float.fromhex(x) for x in a])


def test_presets_give_the_numbers_of_the_camera_before_the_generalisation():
    """Bit-for-bit outputs of the MDIS presets, recorded with camera.py before the affine/models change."""
    v = np.array([[0.3, -0.2, 40.0], [-1.1, 0.9, 30.0], [0.01, 0.02, 1.0]])
    px = np.array([[0.0, 0.0], [511.0, 3.25], [100.5, 400.75]])
    xy = np.array([[3.0, -2.5], [-6.5, 6.9]])
    nac, wac = mdis_nac(512), mdis_wac(1024)
    assert np.array_equal(nac.camera_to_pixel(v).ravel(), _hex([
        "0x1.93198af62998cp+8", "0x1.3c20dc96400c8p+7", "-0x1.cfc479beae1c0p+8", "0x1.b035cac2f9bb2p+9",
        "0x1.c32d4135e55c6p+8", "0x1.456b0b67a8a17p+9"]))
    assert np.array_equal(nac.pixel_to_camera(px).ravel(), _hex([
        "-0x1.a80dcfdc44eedp-7", "-0x1.ae3b3a4f17f88p-7", "0x1.ffe9b9a0d99b2p-1", "0x1.a81478b8395bfp-7",
        "-0x1.a8c95531ecf87p-7", "0x1.ffea0209ae231p-1", "-0x1.02ee6a779a666p-7", "0x1.e274a1cafe918p-8",
        "0x1.fff85b204b74ep-1"]))
    assert np.array_equal(nac.distortion_jacobian(xy[:, 0], xy[:, 1]).ravel(), _hex([
        "0x1.00e2dde916250p+0", "-0x1.b81f558fb9d16p-10", "0x1.5a6260b403e96p-8", "0x1.ff3a3cca77c8cp-1",
        "0x1.0005e0e37f602p+0", "0x1.3bfca71a14910p-9", "-0x1.9f73e628c16bfp-7", "0x1.01bd168d9b43ep+0"]))
    assert np.array_equal(wac.camera_to_pixel(v).ravel(), _hex([
        "0x1.14b5b6db6db6ep+9", "0x1.e38db6db6db6ep+8", "0x1.328f3cf3cf3d0p+8", "0x1.5396db6db6db7p+9",
        "0x1.1bb2492492492p+9", "0x1.37a4924924924p+9"]))
    assert np.array_equal(wac.pixel_to_camera(px).ravel(), _hex([
        "-0x1.73be159fe0ea7p-4", "-0x1.73be159fe0ea7p-4", "0x1.fbc3e33f7c990p-1", "-0x1.75aae75588f93p-14",
        "-0x1.72ee46e3c8986p-4", "0x1.fde56ef9bed90p-1", "-0x1.2c52e1a103d52p-4", "-0x1.43b4e57e36956p-6",
        "0x1.fe858ca674322p-1"]))
    assert nac.distortion_model == "transverse" and wac.distortion_model == "none"
    assert nac.pixel_size_mm == 0.028 and nac.focal_plane_map == ()


def test_mdis_keywords_give_the_preset_code_path():
    """MDIS NAIF keywords build the diagonal affine (no focal_plane_map): the presets' arithmetic."""
    nac = mdis_nac(512)
    keys = {"INS-236820_FOCAL_LENGTH": nac.focal_length_mm, "INS-236820_PIXEL_PITCH": 0.014,
            "INS-236820_TRANSX": [0.0, 0.014, 0.0], "INS-236820_TRANSY": [0.0, 0.0, 0.014],
            "INS-236820_ITRANSS": [0.0, 71.42857143, 0.0], "INS-236820_ITRANSL": [0.0, 0.0, 71.42857143],
            "INS-236820_BORESIGHT_SAMPLE": 512.5, "INS-236820_BORESIGHT_LINE": 512.5,
            "INS-236820_OD_T_X": list(nac.distortion_x), "INS-236820_OD_T_Y": list(nac.distortion_y)}
    cam, rot = camera_from_naif(keys, -236820, 512, 512, name="MDIS-NAC", summing=2)
    assert cam == nac
    assert np.array_equal(rot, np.eye(3))


def test_general_affine_equals_the_diagonal_form():
    nac = mdis_nac(512)
    gen = FramingCamera(**{**nac.__dict__, "focal_plane_map": (0.028, 0.0, 0.0, 0.028)})
    rng = np.random.default_rng(3)
    px = rng.uniform(-0.5, 511.5, (500, 2))
    np.testing.assert_allclose(gen.pixel_to_camera(px), nac.pixel_to_camera(px), rtol=0, atol=1e-15)
    np.testing.assert_allclose(gen.camera_to_pixel(nac.pixel_to_camera(px)), px, rtol=0, atol=1e-9)
    assert gen.pixel_size_mm == pytest.approx(0.028, rel=1e-15) and gen.ifov_rad == pytest.approx(nac.ifov_rad)
    np.testing.assert_allclose(gen.pixel_to_focal_affine, nac.pixel_to_focal_affine, rtol=1e-15)


# -- round trips and Jacobians ----------------------------------------------------------------

def test_mdis_nac_2x2_round_trip():
    cam = mdis_from_cube(MDIS_LEV1)
    assert (cam.summing, cam.samples, cam.boresight_sample, cam.boresight_line) == (2, 512, 255.5, 255.5)
    # the stored TempDependentFocalLength: FL_TEMP_COEFFS at the label's focal-plane temperature, 3.05 C
    assert cam.focal_length_mm == 549.564368644379 == pytest.approx(549.53425088613 + 0.0098746748357875 * 3.05)
    px = image_grid(cam)
    back = cam.camera_to_pixel(cam.pixel_to_camera(px))
    assert np.max(np.abs(back - px)) < 1e-9


def test_apollo_crop_round_trip_and_geometry():
    cam, rot = apollo_camera()
    assert cam.distortion_model == "apollo_metric"
    # 15.976 alpha pixels of 5 um per image pixel
    assert cam.focal_plane_map == pytest.approx((0.07988, 0.0, 0.0, 0.07988), rel=1e-14)
    assert cam.pixel_size_mm == pytest.approx(0.07988) and cam.ifov_rad == pytest.approx(0.07988 / 76.054)
    px = image_grid(cam)
    v = cam.pixel_to_camera(px)
    assert np.max(np.abs(cam.camera_to_pixel(v) - px)) < 1e-9
    # +X along increasing sample, +Y along increasing line, a proper rotation
    assert np.all(np.diff(v.reshape(41, 41, 3)[:, :, 0], axis=1) > 0)
    assert np.all(np.diff(v.reshape(41, 41, 3)[:, :, 1], axis=0) > 0)
    assert np.linalg.det(rot) == pytest.approx(1.0) and np.array_equal(rot, np.diag([-1.0, 1.0, -1.0]))


def test_apollo_crop_from_the_cube_label():
    lab = cube_label(APOLLO_CROP)
    keys = dict(lab["NaifKeywords"])
    cam, rot = camera_from_naif(keys, -915240, 500, 500, name="Apollo15-Metric",
                                alpha=dict(lab["IsisCube"]["AlphaCube"]))
    ref, ref_rot = apollo_camera()
    assert cam == ref and np.array_equal(rot, ref_rot)


@pytest.mark.parametrize("which", ["transverse", "apollo_metric"])
def test_distortion_jacobian_matches_finite_differences(which):
    if which == "transverse":
        cam = mdis_nac(512)
        xy = np.random.default_rng(1).uniform(-7.0, 7.0, (2, 200))
    else:
        cam = apollo_camera()[0]
        xy = np.random.default_rng(1).uniform(-80.0, 80.0, (2, 200))
    jac = cam.distortion_jacobian(*xy)
    h = 1e-4
    for k in range(2):
        d = np.zeros((2, 1))
        d[k] = h
        fp, fm = np.stack(cam.distort(*(xy + d))), np.stack(cam.distort(*(xy - d)))
        np.testing.assert_allclose((fp - fm).T / (2 * h), jac[:, :, k], rtol=0, atol=1e-8)
    # distort and undistort are inverses
    xd, yd = cam.distort(*xy)
    np.testing.assert_allclose(np.stack(cam.undistort(xd, yd)), xy, rtol=0, atol=1e-11)


def test_adjustment_jacobians_with_a_general_camera():
    """FramingModel's analytic Jacobians (L^-1 J_D) against finite differences for a rotated, -Z camera."""
    keys = {**APOLLO_KEYS, "INS-915240_TRANSX": [0.01, -0.004, 0.003], "INS-915240_TRANSY": [-0.02, 0.003, 0.004]}
    inv = np.linalg.inv(np.array([[-0.004, 0.003], [0.003, 0.004]]))
    t0 = np.array([0.01, -0.02])
    keys["INS-915240_ITRANSS"] = [float(-(inv @ t0)[0]), *inv[0].tolist()]
    keys["INS-915240_ITRANSL"] = [float(-(inv @ t0)[1]), *inv[1].tolist()]
    cam = camera_from_naif(keys, -915240, 500, 500, name="rotated", alpha=APOLLO_ALPHA)[0]
    assert len(cam.focal_plane_map) == 4 and cam.focal_plane_map[1] != 0
    rng = np.random.default_rng(11)
    pos = np.array([latlon_to_xyz(10.0, 20.0, 100e3, datum_radius_m=DATUM_RADIUS_M)])
    target = latlon_to_xyz(10.02, 20.01, 0.0, datum_radius_m=DATUM_RADIUS_M)
    rot = look_at_rotation(pos, target[None, :])
    pts = target + rng.normal(0.0, 20000.0, (8, 3))
    prob = AdjustmentProblem((cam,), np.array([0]), pos, rot, pts, np.zeros(8, np.int64), np.arange(8),
                             np.zeros((8, 2)), np.ones(8), pointing_sigma_urad=1000.0)
    model = FramingModel(prob, 50.0)
    st = FramingState(rng.normal(0, 1e-3, (1, 3)), rng.normal(0, 30, (1, 3)), pts + rng.normal(0, 10, (8, 3)))
    _, jc, jp = model.linearize(st)
    assert model.camera_dim == 6
    assert_jacobians_match_differences(model, st, jc, jp)


# -- agreement with independent models -----------------------------------------------------

def test_mdis_cube_keywords_agree_with_the_csm_isd():
    """EN1072174528M: NaifKeywords camera vs the ISD camera, look vectors of a grid of pixels.

    Same focal length (TempDependentFocalLength = the ISD's 549.5535053 mm) and distortion; the
    ISD's pitch is 1 / ITRANSS = 0.01399999999972 mm instead of TRANSX's 0.014, which moves the
    corners by 4e-4 pixel.
    """
    from mercury_dem.geometry.isd import read_isd

    cam = mdis_from_cube(MDIS_SPICE)
    if not MDIS_ISD.exists():
        pytest.skip(f"{MDIS_ISD} not present")
    ref = read_isd(MDIS_ISD).camera
    assert cam.focal_length_mm == ref.focal_length_mm == pytest.approx(549.5535053027719)
    px = image_grid(cam, 33)
    a, b = cam.pixel_to_camera(px), ref.pixel_to_camera(px)
    angle_px = np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)) / cam.ifov_rad
    assert np.max(angle_px) < 0.05
    assert np.max(angle_px) < 1e-3  # what it is: the pitch difference only


def test_apollo_distortion_hand_computed():
    """ISIS ApolloMetricDistortionMap::SetFocalPlane at the distorted ISIS point (40, -30) mm.

    By hand (Python decimal, 40 digits): x = 40.006, y = -29.998, r2 = 2500.36004,
    dr = 1 + k1 r2 + k2 r2^2 + k3 r2^3 = 0.99913338336256887, dt = j1 r2 + j2 r2^2 = -0.0016622945976336783,
    x_u = dr x - dt sin(t0) = 39.971620676101542, y_u = dr y + dt cos(t0) = -29.970366527330516.
    """
    cam, _ = apollo_camera()
    # our focal plane is ISIS's with x reversed (the 180° turn about Y of the -Z look)
    xu, yu = cam.undistort(np.array([-40.0]), np.array([-30.0]))
    assert -xu[0] == pytest.approx(39.971620676101542, abs=1e-12)
    assert yu[0] == pytest.approx(-29.970366527330516, abs=1e-12)
    xd, yd = cam.distort(xu, yu)
    assert (xd[0], yd[0]) == pytest.approx((-40.0, -30.0), abs=1e-12)


def test_apollo_alpha_centre_looks_where_isis_looks():
    """Alpha sample/line 11450.5 (ISIS 1-based: the frame centre) against ISIS's camera by hand.

    ISIS: detector origin = parent size / 2 = 11450, so the centred detector pixel is (0.5, 0.5),
    focal plane (TRANSX, TRANSY) = (-0.0025, 0.0025) mm; undistorted about PP (-0.006, -0.002):
    (0.0035, 0.0045) mm up to ~1e-11 mm of radial/decentering terms; look = (x_u, y_u, -f) in the
    instrument frame (the -Z look direction of ApolloMetricDistortionMap).
    """
    cam, rot = apollo_camera()
    alpha = AlphaCube.from_isis(APOLLO_ALPHA)
    alpha0 = 11450.5 - 1.0  # 0-based
    beta = np.array([(alpha0 + 0.5 - alpha.start_sample) / alpha.scale_sample - 0.5,
                     (alpha0 + 0.5 - alpha.start_line) / alpha.scale_line - 0.5])
    d = ApolloMetricDistortion((-0.006, -0.002), tuple(APOLLO_KEYS["INS-915240_OD_K"]),
                               tuple(APOLLO_KEYS["INS-915240_DECENTER"]))  # ISIS axes
    xu, yu = d.undistort(-0.0025, 0.0025)
    assert (float(xu), float(yu)) == pytest.approx((0.0035, 0.0045), abs=1e-10)  # the PP offset only
    look_inst = np.array([float(xu), float(yu), -76.054])
    want = rot @ (look_inst / np.linalg.norm(look_inst))
    got = cam.pixel_to_camera(beta)
    assert np.max(np.abs(got - want)) < 1e-13
    # and back: the ISIS look vector projects to that pixel
    assert np.max(np.abs(cam.camera_to_pixel(want) - beta)) < 1e-9


# -- keywords errors and serialisation ------------------------------------------------------

def test_unknown_distortion_keys_are_named():
    keys = {**APOLLO_KEYS}
    del keys["INS-915240_DECENTER"]
    with pytest.raises(GeometryError, match=r"unknown distortion model: keys INS-915240_OD_K, INS-915240_PP"):
        camera_from_naif(keys, -915240, 500, 500, name="x", alpha=APOLLO_ALPHA)
    keys = {**APOLLO_KEYS, "INS-915240_OD_T_X": [0.0] * 10}
    with pytest.raises(GeometryError, match="unknown distortion model: keys .*INS-915240_OD_T_X"):
        camera_from_naif(keys, -915240, 500, 500, name="x", alpha=APOLLO_ALPHA)


def test_keyword_errors():
    keys = {**APOLLO_KEYS, "INS-915240_ITRANSS": [0.0, -201.0, 0.0]}
    with pytest.raises(GeometryError, match="ITRANSS/INS-915240_ITRANSL .* not the inverse"):
        camera_from_naif(keys, -915240, 500, 500, name="x", alpha=APOLLO_ALPHA)
    keys = {k: v for k, v in APOLLO_KEYS.items() if not k.endswith("PIXEL_PITCH")}
    with pytest.raises(GeometryError, match="INS-915240_PIXEL_PITCH is missing"):
        camera_from_naif(keys, -915240, 500, 500, name="x")
    keys = {k.replace("-915240", "-999"): v for k, v in APOLLO_KEYS.items() if "OD_K" not in k
            and "PP" not in k and "DECENTER" not in k}
    with pytest.raises(GeometryError, match="INS-999_BORESIGHT_SAMPLE/INS-999_BORESIGHT_LINE are missing"):
        camera_from_naif(keys, -999, 500, 500, name="x")


def test_mdis_temperature_dependent_focal_length():
    keys = {"INS-236820_FOCAL_LENGTH": 549.1, "INS-236820_FL_TEMP_COEFFS": [549.5, 0.01, 0.0, 0.0, 0.0, 0.0],
            "INS-236820_PIXEL_PITCH": 0.014, "INS-236820_TRANSX": [0.0, 0.014, 0.0],
            "INS-236820_TRANSY": [0.0, 0.0, 0.014], "INS-236820_BORESIGHT_SAMPLE": 512.5,
            "INS-236820_BORESIGHT_LINE": 512.5}
    assert camera_from_naif(keys, -236820, 1024, 1024, name="n")[0].focal_length_mm == 549.1
    cam = camera_from_naif(keys, -236820, 1024, 1024, name="n", focal_plane_temperature_c=4.0)[0]
    assert cam.focal_length_mm == pytest.approx(549.54)
    cam = camera_from_naif({**keys, "TempDependentFocalLength": 549.6}, -236820, 1024, 1024, name="n")[0]
    assert cam.focal_length_mm == 549.6
    cam = camera_from_naif(keys, -236820, 1024, 1024, name="n", focal_length_mm=550.0)[0]
    assert cam.focal_length_mm == 550.0 and cam.distortion_model == "none"


def test_alpha_cube_from_isis():
    a = AlphaCube.from_isis(APOLLO_ALPHA)
    assert (a.start_sample, a.start_line, a.scale_sample, a.alpha_samples) == (7996.0, 3996.0, 15.976, 22900)
    # ISIS 1-based: alpha = slope (beta - 0.5) + AlphaStartingSample at beta = 1 (our 0)
    assert a.start_sample + a.scale_sample * 0.5 - 0.5 == pytest.approx(15.976 * 0.5 + 7996.5 - 1.0)
    with pytest.raises(GeometryError, match="AlphaEndingLine"):
        AlphaCube.from_isis({k: v for k, v in APOLLO_ALPHA.items() if k != "AlphaEndingLine"})


@pytest.mark.parametrize("which", ["nac", "wac", "apollo", "mdis_general"])
def test_camera_dict_round_trip_is_exact(which):
    cam = {"nac": mdis_nac(512), "wac": mdis_wac(), "apollo": apollo_camera()[0],
           "mdis_general": FramingCamera(**{**mdis_nac().__dict__, "focal_plane_map": (0.1 / 7, 1e-5, 0.0, 0.1 / 7)})
           }[which]
    d = json.loads(json.dumps(camera_to_dict(cam)))
    back = camera_from_dict(d)
    assert back == cam
    assert camera_to_dict(back) == d


def test_camera_dict_errors_name_the_field():
    d = camera_to_dict(apollo_camera()[0])
    for field, value, pattern in [
        ("samples", 500.5, "'samples' must be an integer"),
        ("focal_length_mm", "76", "'focal_length_mm' must be a finite number"),
        ("focal_plane_map", [1.0, 2.0], "'focal_plane_map' must be a list of 4"),
        ("distortion", {"model": "fisheye"}, "'distortion.model' must be one of"),
        ("distortion", {"model": "radial"}, "'distortion.coefficients' must be a list of 3"),
        ("distortion", {"model": "apollo_metric", "radial": [1.0], "principal_point_mm": [0.0, 0.0],
                        "decentering": [0.0, 0.0, 0.0]}, "'distortion.radial' must be a list of 3"),
    ]:
        with pytest.raises(GeometryError, match=pattern):
            camera_from_dict({**d, field: value})
    with pytest.raises(GeometryError, match="field 'boresight_line' is missing"):
        camera_from_dict({k: v for k, v in d.items() if k != "boresight_line"})
    with pytest.raises(GeometryError, match=r"unknown field\(s\) \['colour'\]"):
        camera_from_dict({**d, "colour": 1})
    with pytest.raises(GeometryError, match="focal_length_mm must be > 0"):
        camera_from_dict({**d, "focal_length_mm": -1.0})


def test_render_refuses_a_general_camera():
    from mercury_dem.synth.render import RenderSettings, render_reflectance

    cam, _ = apollo_camera()
    with pytest.raises(GeometryError, match="rendering supports"):
        render_reflectance(None, cam, np.zeros(3), np.eye(3), np.ones(3) * 1e10,  # type: ignore[arg-type]
                           RenderSettings())


def test_decentering_angle_reflection_is_exact():
    """math.sin is odd: the -Z turn's t0 -> -t0 is an exact reflection of the decentering direction."""
    t0 = 2.965907
    assert math.sin(-t0) == -math.sin(t0) and math.cos(-t0) == math.cos(t0)
