"""The tiny mission as designed, the store round trip, and the a-priori error statistics."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.pose import angles_from_rotation, project
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.atomic import COMPLETE_MARKER
from mercury_dem.mission import open_mission
from mercury_dem.mission.catalog import CATALOG_COLUMNS
from mercury_dem.mission.coverage import mission_coverage
from mercury_dem.synth.mission import perturb_poses, plan_mission, true_poses
from mercury_dem.synth.presets import get_preset


def test_catalog_has_the_contract_columns_and_types(tiny_mission):
    cat = tiny_mission.catalog
    assert list(cat.columns[: len(CATALOG_COLUMNS)]) == CATALOG_COLUMNS
    assert 20 <= len(cat) <= 40
    assert set(cat["instrument"]) == {"MDIS-NAC", "MDIS-WAC"}
    assert cat["image_id"].is_unique
    assert (cat["samples"] == 256).all() and (cat["lines"] == 256).all()
    for image_id in tiny_mission.image_ids[:3]:
        c, r = tiny_mission.a_priori_pose(image_id)
        assert c.shape == (3,) and np.allclose(r @ r.T, np.eye(3), atol=1e-9)
        img = tiny_mission.read_image(image_id)
        assert img.dtype == np.uint16 and img.shape == (256, 256) and img.max() <= 4095
        assert tiny_mission.camera(image_id).samples == 256
    # Tile ids are those of the lead's tile grid at the label centre.
    grid = TileGrid(tiny_mission.meta["tile_size_deg"])
    assert np.array_equal(cat["tile_id"], grid.tile_of(cat["center_lat"], cat["center_lon"]))


def test_catalog_round_trips(tiny_mission, tmp_path):
    again = open_mission(tiny_mission.path)
    pd.testing.assert_frame_equal(again.catalog, tiny_mission.catalog)
    # Label values are derived from the a-priori pose: the centre pixel lands on the centre lat/lon.
    image_id = tiny_mission.image_ids[5]
    row = tiny_mission.catalog.set_index("image_id").loc[image_id]
    from mercury_dem.geometry.body import latlon_to_xyz

    c, r = tiny_mission.a_priori_pose(image_id)
    cam = tiny_mission.camera(image_id)
    px, _ = project(cam, c, r, latlon_to_xyz(row["center_lat"], row["center_lon"], height_m=0.0, datum_radius_m=DATUM_RADIUS_M)[None])
    assert np.allclose(px[0], [(cam.samples - 1) / 2, (cam.lines - 1) / 2], atol=1e-6)


def test_tiny_straddles_tiles_regions_and_the_seam(tiny_mission):
    cat = tiny_mission.catalog
    core = cat[cat["center_lat"].between(-12, 22)]
    lon = core["center_lon"].to_numpy()
    assert (lon > 340).any() and (lon < 20).any()  # both sides of the 0/360 seam
    assert (core["center_lat"] < 0).any() and (core["center_lat"] > 0).any()  # both hemispheres
    grid = TileGrid(10.0)
    regions = set(grid.region_of_tile(core["tile_id"].to_numpy()).tolist())
    assert len(regions) >= 4
    assert core["tile_id"].nunique() >= 8


def test_tiny_coverage_as_designed(tiny_mission):
    cov = mission_coverage(tiny_mission, 1.0, (-5.0, 15.0, -10.0, 10.0))
    count, conv = cov["count"], cov["convergence_deg"]
    assert np.mean(count >= 3) > 0.9
    assert np.mean((count >= 3) & (conv >= 5.0)) > 0.85
    # Isolated images: polar and mid-latitude, overlapping nothing else.
    cat = tiny_mission.catalog
    assert (cat["center_lat"] > 75).sum() >= 1
    far = cat[cat["center_lat"] > 30]
    assert len(far) >= 2
    # Scale differences and illumination as the design says.
    s = cat["pixel_scale_m"]
    assert s.max() / s.min() > 2.5
    assert cat["incidence_deg"].min() < 35 and cat["incidence_deg"].max() > 75
    assert cat["emission_deg"].max() > 30


def test_truth_is_kept_apart_and_consistent(tiny_mission):
    assert tiny_mission.has_truth
    assert not any(c.startswith("true_") for c in tiny_mission.catalog.columns)
    surf = tiny_mission.truth.surface()
    dem = tiny_mission.truth.dem()
    assert dem.dims == ("lat", "lon") and dem.shape == (240, 240)
    i, j = 37, 201
    lat, lon = float(dem.lat[i]), float(dem.lon[j])
    assert float(dem[i, j]) == pytest.approx(float(surf.height(lat, lon)), abs=0.01)
    # The image was rendered from the true pose: a-priori differs from it by the injected error.
    image_id = tiny_mission.image_ids[0]
    c_t, r_t = tiny_mission.truth.true_pose(image_id)
    c_a, r_a = tiny_mission.a_priori_pose(image_id)
    t = tiny_mission.truth.poses.iloc[0]
    omega = angles_from_rotation(r_a @ r_t.T)
    assert np.allclose(omega, [t[f"pointing_error_{a}_rad"] for a in "xyz"], atol=1e-12)
    assert np.allclose(c_a - c_t, [t[f"position_error_{a}_m"] for a in "xyz"], atol=1e-6)


def test_a_priori_errors_have_the_configured_statistics():
    design = get_preset("demo")
    plan = plan_mission(design, seed=5)
    c, r = true_poses(plan)
    c = np.repeat(c, 4, axis=0)
    r = np.repeat(r, 4, axis=0)  # ~1000 poses
    sigma = 450e-6
    c_a, r_a, omega = perturb_poses(c, r, 450.0, 100.0, np.random.default_rng(1))
    recovered = angles_from_rotation(r_a @ np.swapaxes(r, 1, 2))
    assert np.allclose(recovered, omega, atol=1e-12)
    n = omega.size
    # The sample standard deviation is within 4 standard errors of sigma.
    assert abs(np.std(omega) - sigma) < 4 * sigma / np.sqrt(2 * n)
    assert abs(np.mean(omega)) < 4 * sigma / np.sqrt(n)
    assert abs(np.std(c_a - c) - 100.0) < 4 * 100.0 / np.sqrt(2 * n)
    # The pointing error moves the image by about sigma / IFOV pixels, the position error far less.
    assert np.all(np.linalg.norm(c, axis=1) > DATUM_RADIUS_M)


def test_tiny_mission_a_priori_errors_match_its_config(tiny_mission):
    t = tiny_mission.truth.poses
    om = t[[f"pointing_error_{a}_rad" for a in "xyz"]].to_numpy()
    n = om.size
    sigma = tiny_mission.meta["pointing_sigma_urad"] * 1e-6
    assert abs(np.std(om) - sigma) < 4 * sigma / np.sqrt(2 * n)


def test_incomplete_or_missing_missions_are_refused(tiny_mission_path, tmp_path):
    with pytest.raises(StoreError, match="does not exist"):
        open_mission(tmp_path / "nothing")
    half = tmp_path / "half"
    shutil.copytree(tiny_mission_path, half)
    (half / COMPLETE_MARKER).unlink()
    with pytest.raises(StoreError, match="incomplete"):
        open_mission(half)
    broken = tmp_path / "broken"
    shutil.copytree(tiny_mission_path, broken)
    m = open_mission(broken)
    victim = m.image_ids[3]
    shutil.rmtree(broken / "images.zarr" / victim)
    with pytest.raises(StoreError, match=victim):
        m.read_image(victim)
    with pytest.raises(StoreError, match="not in the catalog"):
        m.read_image("EN0000000000X")


def test_demo_and_large_designs():
    from mercury_dem.geometry.body import angular_distance_deg

    demo = plan_mission(get_preset("demo"), seed=42)
    assert 200 <= len(demo) <= 300 and set(demo["samples"]) == {512}
    assert set(demo["instrument"]) == {"MDIS-NAC", "MDIS-WAC"}
    assert demo["target_lat"].max() > 80 and demo["target_lat"].min() < -80  # poles covered
    lat, lon, rad = get_preset("demo").gaps[0]
    in_gap = angular_distance_deg(demo["target_lat"], demo["target_lon"], lat, lon) < rad
    assert in_gap.sum() == 1 and (demo.loc[in_gap, "pass_id"] == -1).all()  # only the isolated image
    large = plan_mission(get_preset("large"), seed=42)
    assert len(large) >= 10_000 and set(large["samples"]) == {1024}
    s = large["design_pixel_scale_m"]
    assert s.min() >= 70 and s.max() <= 300 and s.max() / s.min() > 4.0 * 0.99
    from mercury_dem.geometry.camera import mdis_nac

    nac = large[large["instrument"] == "MDIS-NAC"]
    assert len(nac) > 1000
    assert (nac["design_pixel_scale_m"] / mdis_nac(1024).ifov_rad <= get_preset("large").nac_max_slant_m + 1).all()
