"""Apollo Metric CSM ISDs (mirrored focal2pixel, -200 on samples) read as usgscsm reads them, and adjusted.

ALE's published Apollo Metric ISD (``tests/data/ale/apollometric_isd.json``) is read: its mirrored
detector is accepted, but as usgscsm reads it (focal length +76.054 mm, a +Z look) it looks 140°
away from nadir, so it cannot take part in an adjustment (see ``docs/design/isd-check.md``).
The ISDs adjusted here are built from the real crops' NaifKeywords and SPICE
(``tests/data/real/AS15-M-029*_crop.cub``) in ALE's layout, with the kernel's ``ITRANSS``/``ITRANSL``
(``[0, -200, 0]``/``[0, 0, 200]``) as focal2pixel and the focal length written negative, which is
how usgscsm states a camera looking along its frame's -Z. The Apollo Metric lens distortion has
no usgscsm model, so these ISDs carry none: their camera is the cube's without distortion.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.geometry.isd import matrix_to_quaternion, read_isd
from mercury_dem.geometry.pose import project

from .test_adjust_isis import NOISE_PX, _apollo_cubes, _run, _summary, _world

ALE_ISD = Path(__file__).resolve().parents[1] / "data" / "ale" / "apollometric_isd.json"


def _apollo_isd(cube: Path) -> dict[str, Any]:
    """An ALE-layout ISD of a cropped, reduced Apollo Metric cube (no distortion), as described above."""
    from mercury_dem.mission.ingest import read_cube_image

    im = read_cube_image(cube, pixels=False)
    cam = im.camera
    turn = np.diag([-1.0, 1.0, -1.0])  # NAIF instrument frame <-> our camera frame (naif_camera, TRANSX < 0)
    body_to_instrument = turn.T @ im.rotation
    summing = cam.focal_plane_map[0] * 200.0  # image pixel = summing detector pixels of 5 um (0.005 mm * 200 = 1)
    q = matrix_to_quaternion(body_to_instrument)
    return {
        "name_model": "USGS_ASTRO_FRAME_SENSOR_MODEL", "name_platform": "APOLLO 15", "name_sensor": "APOLLO_METRIC",
        "target_name": "Moon", "isis_serial_number": im.serial_number, "center_ephemeris_time": im.time,
        "image_samples": cam.samples, "image_lines": cam.lines,
        "detector_sample_summing": summing, "detector_line_summing": summing,
        "starting_detector_sample": 0.0, "starting_detector_line": 0.0,
        "detector_center": {"sample": (cam.boresight_sample + 0.5) * summing,
                            "line": (cam.boresight_line + 0.5) * summing},
        "focal2pixel_samples": [0.0, -200.0, 0.0], "focal2pixel_lines": [0.0, 0.0, 200.0],
        "focal_length_model": {"focal_length": -cam.focal_length_mm},
        "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        "radii": {"semimajor": 1737.4, "semiminor": 1737.4, "unit": "km"},
        "body_rotation": {"quaternions": [[1.0, 0.0, 0.0, 0.0]], "ephemeris_times": [im.time]},  # J2000 := body
        "instrument_pointing": {"quaternions": [q.tolist()], "ephemeris_times": [im.time],
                                "constant_rotation": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]},
        "instrument_position": {"positions": [(im.position / 1000.0).tolist()], "ephemeris_times": [im.time],
                                "unit": "km"},
        "sun_position": {"positions": [(im.sun / 1000.0).tolist()], "ephemeris_times": [im.time], "unit": "km"},
    }


def test_ales_apollo_metric_isd_reads_as_usgscsm_reads_it() -> None:
    g = read_isd(ALE_ISD, require_sun=False)
    isd = json.loads(ALE_ISD.read_text())
    m = np.array(g.camera.pixel_to_focal_matrix())
    assert np.allclose(m, [[-0.005, 0.0], [0.0, 0.005]])  # mirrored: samples run along -x
    assert g.sensor_to_camera is None  # a positive focal length: usgscsm's +Z look, taken as written
    # usgscsm's groundToImage of a point ahead of the sensor: x = f X / Z, sample = -200 x + 0 (+0.5 -> ours)
    ahead = g.position + g.rotation.T @ np.array([3000.0, -2000.0, 100000.0])
    px, _ = project(g.camera, g.position, g.rotation, ahead[None])
    x, y = 76.054 * 3000.0 / 100000.0, 76.054 * -2000.0 / 100000.0
    assert px[0] == pytest.approx([-200.0 * x - 0.5, 200.0 * y - 0.5], abs=1e-9)
    # ... and, as written by ALE, it looks 140° away from the Moon (see SOURCE.md / isd-check.md)
    nadir = -g.position / np.linalg.norm(g.position)
    assert np.degrees(np.arccos(nadir @ g.rotation[2])) > 120
    assert isd["detector_center"] == {"line": 0.0, "sample": 0.0}


def test_apollo_isd_of_a_crop_is_the_cubes_camera_without_distortion(tmp_path: Path) -> None:
    from dataclasses import replace

    from mercury_dem.mission.ingest import read_cube_image

    cube = _apollo_cubes()[0]
    (tmp_path / "crop.isd").write_text(json.dumps(_apollo_isd(cube)))
    g = read_isd(tmp_path / "crop.isd", require_sun=False)
    im = read_cube_image(cube, pixels=False)
    assert g.sensor_to_camera is not None and np.allclose(g.rotation, im.rotation, atol=1e-12)
    plain = replace(im.camera, apollo_distortion=None)
    rng = np.random.default_rng(3)
    v = np.c_[rng.uniform(-0.2, 0.2, (50, 2)), np.ones(50)]  # camera-frame directions across the frame
    assert np.abs(g.camera.camera_to_pixel(v) - plain.camera_to_pixel(v)).max() < 1e-9


def test_adjust_isis_adjusts_apollo_metric_isds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Three Apollo Metric ISDs named X.isd, X and X.json (content, not extension, makes them ISDs)."""
    from mercury_dem.mission.ingest import read_isd_image

    cubes = _apollo_cubes()
    files = []
    for k, cube in enumerate(cubes):
        name = cube.name.split(".")[0] + (".isd", "", ".json")[k % 3]
        (tmp_path / name).write_text(json.dumps(_apollo_isd(cube)))
        files.append(tmp_path / name)
    net, truth, _, ims = _world(files, seed=0, read=lambda p: read_isd_image(p, [], pixels=False))
    rc, _, out = _run(tmp_path, net, files)
    assert rc == 0
    s = _summary(capsys)
    assert s["images"] == len(files) and s["unmatched_serials"] == {}
    m, n = s["measures"], s["points"]
    expected = NOISE_PX * np.sqrt((2 * m - 3 * n - 3 * len(files)) / (2 * m))
    assert s["initial_rms_px"] > 4 * expected
    assert s["rms_px"] == pytest.approx(expected, rel=0.2)
    # the corrected ISDs keep the -Z look and the mirrored detector, and reproject the adjusted points
    assert sorted(s["isds"]) == sorted(im.image_id for im in ims)
    kept = ~out.measure_rejected
    res = []
    for k, im in enumerate(ims):
        g = read_isd(s["isds"][im.image_id], require_sun=False)
        assert g.sensor_to_camera is not None
        sel = kept & (out.measure_image == k)
        px, _ = project(g.camera, g.position, g.rotation, out.adjusted_xyz[out.measure_point[sel]])
        res.append(px - np.c_[out.sample[sel], out.line[sel]])
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    assert rms == pytest.approx(s["rms_px"], rel=0.05)
