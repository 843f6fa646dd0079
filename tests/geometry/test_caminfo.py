"""caminfo-like geometry: synthetic truth, PDS3 label parsing, the real MDIS label check, the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.cli import main
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac
from mercury_dem.geometry.caminfo import (
    TOLERANCES,
    compare_with_label,
    compute_caminfo,
    label_values,
    parse_pds3_label,
)
from mercury_dem.geometry.isd import iau_body_rotation, read_isd
from mercury_dem.geometry.pose import look_at_rotation

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "mdis"
ALE_ISD = SHARED / "EN1072174528M" / "messmdis_isd.json"
CSM_ISD = SHARED / "EN1072174528M.json"
LABEL = SHARED / "EN1072174528M" / "EN1072174528M_pds3.lbl"
PAIR = [SHARED / "EN0213023991M.json", SHARED / "EN0213110924M.json"]
needs_shared = pytest.mark.skipif(
    not LABEL.exists(), reason=f"real MDIS data not found at {SHARED} (../shared is absent in a fresh clone)"
)

NUT_PREC_ANGLES = [(174.7910857155, 149472.535875), (349.5821714311, 298945.071750),
                   (164.3732571466, 448417.607625), (339.1643428622, 597890.143500),
                   (153.9554285777, 747362.679375)]
#: pck00010.tpc (Archinal et al. 2011), the Mercury model before the MESSENGER team's v2.0
#: PCK of 2015-04-29: the label (made 2015-04-30) still used it.
PCK00010 = dict(pole_ra=(281.0097, -0.0328), pole_dec=(61.4143, -0.0049), pm=(329.5469, 6.1385025),
                nut_prec_pm=(0.00993822, -0.00104581, -0.00010280, -0.00002364, -0.00000532))


# -- synthetic truth -------------------------------------------------------------------

@pytest.mark.parametrize("lat, lon", [(0.0, 0.0), (45.0, 359.99), (-89.5, 120.0)])
def test_nadir_view_matches_closed_form(lat: float, lon: float) -> None:
    """A camera straight above (lat, lon) at altitude h: centre = sub-spacecraft point,
    slant = h, pixel scale = h * IFOV, emission 0, incidence = phase = Sun's zenith angle."""
    cam = mdis_nac(512, distortion=False)
    h, r = 200e3, 2439.4e3
    c = latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M)
    rot = look_at_rotation(c, np.zeros(3))
    # Sun 60 deg from the zenith, towards the pole-ward side when possible, 5e10 m away.
    zen = latlon_to_unit(lat, lon)
    side = np.cross(zen, [1.0, 0.0, 0.0] if abs(zen[2]) > 0.9 else [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    sun = 5e10 * (math.cos(math.radians(60)) * zen + math.sin(math.radians(60)) * side)
    info = compute_caminfo(cam, c, rot, sun, radius_m=r)
    assert info.centre_lat == pytest.approx(lat, abs=1e-9)
    assert (info.centre_lon - lon + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-7)
    assert info.slant_distance_m == pytest.approx(h, abs=1e-6)
    assert info.pixel_scale_m == pytest.approx(h * 0.028 / cam.focal_length_mm, rel=1e-12)
    assert info.emission_deg == pytest.approx(0.0, abs=1e-6)
    # The ground point is not the body centre, so the Sun's direction differs by < r/5e10 rad.
    assert info.incidence_deg == pytest.approx(60.0, abs=0.01)
    assert info.phase_deg == pytest.approx(info.incidence_deg, abs=1e-6)
    assert info.spacecraft_altitude_m == pytest.approx(h, abs=1e-6)
    assert (info.sub_spacecraft_lat, info.sub_spacecraft_lon) == pytest.approx((info.centre_lat, info.centre_lon))
    # Corners at the same distance from the centre, half-diagonal = 255.5 * sqrt(2) pixels.
    d = np.degrees(np.hypot(255.5, 255.5) * cam.ifov_rad * h / r)
    corner_dist = [math.degrees(math.acos(np.clip(np.dot(latlon_to_unit(a, b), latlon_to_unit(lat, lon)), -1, 1)))
                   for a, b in zip(info.corner_lat, info.corner_lon)]
    assert corner_dist == pytest.approx([d] * 4, rel=1e-4)


def test_off_body_and_no_sun_give_nan_not_errors() -> None:
    cam = mdis_nac(512)
    c = latlon_to_xyz(0.0, 0.0, 500e3, datum_radius_m=DATUM_RADIUS_M)
    away = look_at_rotation(c, 2 * c)  # looking at the sky
    info = compute_caminfo(cam, c, away, None, radius_m=DATUM_RADIUS_M)
    assert math.isnan(info.centre_lat) and math.isnan(info.slant_distance_m) and math.isnan(info.incidence_deg)
    assert info.as_dict()["centre_lat"] is None
    json.dumps(info.as_dict())  # JSON-ready
    nadir = compute_caminfo(cam, c, look_at_rotation(c, np.zeros(3)), None, radius_m=DATUM_RADIUS_M)
    assert nadir.emission_deg == pytest.approx(0.0, abs=1e-6) and math.isnan(nadir.phase_deg)


# -- PDS3 labels ---------------------------------------------------------------------

LABEL_TEXT = """PDS_VERSION_ID = PDS3
/* ** comment with = sign ** */
MISSION_NAME                 = MESSENGER
INSTRUMENT_NAME              = "MERCURY DUAL IMAGING SYSTEM NARROW ANGLE
                                CAMERA"
SLANT_DISTANCE               = 27.62593 <KM>
CENTER_LONGITUDE             = 248.17066 <DEG>
RETICLE_POINT_LONGITUDE      = (248.15510, 248.17933,
                                248.16185, 248.18619) <DEG>
TARGET_CENTER_DISTANCE       = 2466.63167 <KM>
SPACECRAFT_ALTITUDE          = 26.63167 <KM>
FILTER_NUMBER                = N/A
Object = IMAGE
  LINES = 512
End_Object
Group = SUBFRAME1_PARAMETERS
  RETICLE_POINT_LONGITUDE = (N/A, N/A, N/A, N/A)
End_Group
END
LATER = 1
"""


def test_parse_pds3_label() -> None:
    lab = parse_pds3_label(LABEL_TEXT)
    assert lab["MISSION_NAME"] == "MESSENGER"
    assert lab["INSTRUMENT_NAME"] == "MERCURY DUAL IMAGING SYSTEM NARROW ANGLE CAMERA"
    assert lab["SLANT_DISTANCE"] == 27.62593
    assert lab["RETICLE_POINT_LONGITUDE"] == (248.15510, 248.17933, 248.16185, 248.18619)
    assert lab["FILTER_NUMBER"] is None
    assert "LINES" not in lab and "LATER" not in lab
    vals = label_values(lab)
    assert vals["slant_distance_m"] == pytest.approx(27625.93)
    assert vals["corner_lon[3]"] == 248.18619
    assert vals["radius_m"] == pytest.approx(2440e3, abs=1e-3)
    assert "centre_lat" not in vals


# -- the real MDIS image ----------------------------------------------------------------

@pytest.fixture(scope="module")
def label() -> dict:
    return label_values(parse_pds3_label(LABEL.read_text()))


@needs_shared
@pytest.mark.parametrize("isd", [ALE_ISD, CSM_ISD], ids=["ale", "usgscsm"])
def test_real_mdis_matches_label(isd: Path, label: dict) -> None:
    """Issue #2's check: ours vs EN1072174528M_pds3.lbl within the tolerances, on the label's sphere.

    Measured (ALE ISD, 2440 km, centre pixel 255.5): lat +0.0059, lon -0.0968 deg, slant and pixel
    scale +0.15 %, incidence +0.004, emission -0.005, phase -0.001 deg (docs/design/isd-check.md).
    """
    g = read_isd(isd)
    info = compute_caminfo(g.camera, g.position, g.rotation, g.sun_position, radius_m=label["radius_m"], j2000_to_body=g.j2000_to_body)
    rows = {r.quantity: r for r in compare_with_label(info, label)}
    assert set(TOLERANCES) <= set(rows)
    for name in TOLERANCES:
        assert rows[name].ok, f"{name}: ours {rows[name].ours} label {rows[name].label}"
    # Corners: the whole footprint is shifted like the centre (same order, orientation and
    # scale): each corner's offset equals the centre's to 1e-4 deg.
    for i in range(4):
        assert rows[f"corner_lat[{i}]"].difference == pytest.approx(rows["centre_lat"].difference, abs=1e-4)
        assert rows[f"corner_lon[{i}]"].difference == pytest.approx(rows["centre_lon"].difference, abs=1e-4)
    # On the ISD's own 2439.4 km sphere the camera is 0.6 km higher above the ground: slant +2.25 %.
    own = compute_caminfo(g.camera, g.position, g.rotation, g.sun_position, radius_m=g.radius_m)
    assert own.slant_distance_m / info.slant_distance_m == pytest.approx(1.0225, abs=0.001)


@needs_shared
def test_label_residuals_vanish_with_the_labels_inputs(label: dict) -> None:
    """With the label's rotation model (pck00010), spacecraft vector, Sun vector, 2440 km sphere
    and centre pixel (RA_DEC_REF_PIXEL 256 1-based = our 255), our camera model reproduces every
    label number to its printed precision: the residuals of the check are all input differences."""
    raw = parse_pds3_label(LABEL.read_text())
    g = read_isd(ALE_ISD)
    old = iau_body_rotation(g.ephemeris_time, PCK00010["pole_ra"], PCK00010["pole_dec"], PCK00010["pm"],
                            PCK00010["nut_prec_pm"], NUT_PREC_ANGLES)
    j2000_to_cam = g.rotation @ g.j2000_to_body
    sc = np.array(raw["SC_TARGET_POSITION_VECTOR"]) * 1e3  # Mercury -> spacecraft, J2000 m
    sun = sc - np.array(raw["SC_SUN_POSITION_VECTOR"]) * 1e3  # Mercury -> Sun
    info = compute_caminfo(g.camera, old @ sc, j2000_to_cam @ old.T, old @ sun, radius_m=label["radius_m"], j2000_to_body=old,
                           centre_pixel=(255.0, 255.0))
    for r in compare_with_label(info, label):
        if r.kind == "rel":
            assert abs(r.difference) < 2e-5, r
        elif r.quantity.endswith("_m"):
            assert abs(r.difference) < 0.05, r
        else:
            assert abs(r.difference) < 2e-5, r


@needs_shared
def test_older_usgscsm_pair_is_sane() -> None:
    """EN0213023991M / EN0213110924M (no label): a stereo pair over ~32 N, 184 E, ~2000 km up."""
    infos = []
    for path in PAIR:
        g = read_isd(path, require_sun=False)
        # the knoten export's 4-number Sun row in km labelled m is read (two warnings say how), no distortion key
        assert len(g.warnings) == 3 and sum("sun_position" in w for w in g.warnings) == 2
        assert g.sun_position is not None and 0.307 < np.linalg.norm(g.sun_position) / 1.495978707e11 < 0.467
        info = compute_caminfo(g.camera, g.position, g.rotation, None, radius_m=g.radius_m)
        assert 31.0 < info.centre_lat < 33.0 and 183.5 < info.centre_lon < 185.5
        assert 1.9e6 < info.spacecraft_altitude_m < 2.1e6 and 100 < info.pixel_scale_m < 130
        assert 30 < info.emission_deg < 50
        infos.append(info)
    # Each image's centre lies inside the other's footprint (corner lat/lon box).
    for a, b in [(0, 1), (1, 0)]:
        assert min(infos[b].corner_lat) < infos[a].centre_lat < max(infos[b].corner_lat)
        assert min(infos[b].corner_lon) < infos[a].centre_lon < max(infos[b].corner_lon)


# -- the command ------------------------------------------------------------------------

@needs_shared
def test_cli_table_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["geometry", str(ALE_ISD), "--label", str(LABEL)]) == 0
    out = capsys.readouterr().out
    assert "centre latitude" in out and "all 7 checked quantities within tolerance" in out
    assert main(["geometry", str(ALE_ISD), "--label", str(LABEL), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["flavour"] == "ale" and data["label"]["all_ok"] is True
    assert data["label"]["radius_m"] == pytest.approx(2440e3, abs=1e-3)
    assert data["caminfo"]["centre_lat"] == pytest.approx(46.2748, abs=1e-3)
    assert main(["geometry", str(PAIR[0]), "--json", "--no-sun"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert 60.0 < data["caminfo"]["incidence_deg"] < 80.0 and len(data["warnings"]) == 3  # measured 71.0
    raw = json.loads(Path(PAIR[0]).read_text())
    raw["sun_position"]["positions"] = [[1.0, 2.0, 3.0]]  # a Sun 4 m away: unusable in any unit
    bad_sun = tmp_path / "bad_sun.json"
    bad_sun.write_text(json.dumps(raw))
    assert main(["geometry", str(bad_sun)]) == 2  # its sun vector is unusable: say so, suggest --no-sun
    assert "--no-sun" in capsys.readouterr().err
    not_label = tmp_path / "notes.lbl"
    not_label.write_text("FOO = 1\nEND\n")
    assert main(["geometry", str(ALE_ISD), "--label", str(not_label)]) == 2
    assert "no geometry keywords" in capsys.readouterr().err


def test_cli_bad_isd_is_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "no_pointing.json"
    bad.write_text(json.dumps({"instrument_position": {"positions": [[3000.0, 0.0, 0.0]]}}))
    assert main(["geometry", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "no_pointing.json" in err and "key '" in err and "Traceback" not in err
    assert main(["geometry", str(tmp_path / "absent.json")]) == 2
    assert "cannot be read" in capsys.readouterr().err
