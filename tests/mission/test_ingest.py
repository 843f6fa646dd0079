"""ingest: real cubes and ISDs become a mission whose catalog agrees with ISIS's own camera statistics."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.cli import main
from mercury_dem.exceptions import StoreError
from mercury_dem.mission import open_mission
from mercury_dem.mission.ingest import ingest_mission

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
MDIS_LEV1 = REAL / "EN0240208184M.lev1.cub"
APOLLO = [REAL / f"AS15-M-{n}_crop.cub" for n in ("0297", "0298", "0299", "0300")]

#: EN0240208184M's CameraStatistics as ISIS's camstats wrote them (camera model on its sphere
#: R = 2440.000 km); from ../shared/data/README.md, "Real pixels".
CAMSTATS = {
    "latitude": (77.59082, 77.88603, 77.73779),
    "longitude": (49.93318, 51.32502, 50.64333),
    "resolution": (17.63996, 17.69832, 17.66712),
    "incidence": (None, None, 82.86269),
    "emission": (None, None, 6.98986),
    "phase": (None, None, 89.83205),
}


def test_mdis_cube_info_agrees_with_isis_camera_statistics(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = tmp_path / "mdis"
    assert main(["ingest", str(mission), str(MDIS_LEV1)]) == 0
    out = capsys.readouterr().out
    assert "EN0240208184M" in out and "MERCURY" in out
    assert main(["info", str(mission), "--json", "--radius-km", "2440"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["body"]["name"] == "MERCURY" and info["source"] == "ingest"
    st = info["image_statistics"]["images"]["EN0240208184M"]
    tol = {"latitude": 0.005, "longitude": 0.02}
    for q, (lo, hi, mean) in CAMSTATS.items():
        got = st[q]
        if q in tol:
            assert abs(got["minimum"] - lo) < tol[q] and abs(got["maximum"] - hi) < tol[q], (q, got)
            assert abs(got["average"] - mean) < tol[q], (q, got)
        elif q == "resolution":
            for k, ref in zip(("minimum", "maximum", "average"), (lo, hi, mean)):
                assert abs(got[k] / ref - 1.0) < 0.005, (q, k, got[k], ref)
        else:
            assert abs(got["average"] - mean) < 0.05, (q, got["average"], mean)


def test_mdis_cube_pixels_and_radiometry(tmp_path: Path) -> None:
    m = open_mission(ingest_mission(tmp_path / "m", [str(MDIS_LEV1)])["path"])
    img, valid = m.read_image_masked("EN0240208184M")
    assert img.shape == (512, 512) and valid.mean() > 0.99
    r = m.radiometry("EN0240208184M")
    assert r.pixel_kind == "reflectance" and np.isnan(r.saturation) and 0 < r.dn_scale < 1e-3
    cam = m.camera("EN0240208184M")
    assert cam.summing == 2 and cam.distortion_model == "transverse"
    assert m.catalog["serial_number"].iat[0].upper().startswith("MESSENGER/MDIS-NAC/")


def test_apollo_strip_ingest(tmp_path: Path) -> None:
    s = ingest_mission(tmp_path / "a", [str(p) for p in APOLLO])
    m = open_mission(s["path"])
    assert m.body.name == "MOON" and m.body.crs() == "IAU_2015:30100" and len(m) == 4
    cat = m.catalog.set_index("image_id")
    # 0297's crop lies inside ISIS's whole-frame statistics (latitude -24.52..-17.11, longitude 140.79..148.78)
    assert -24.52 < cat.loc["AS15-M-0297_crop", "center_lat"] < -17.11
    assert 140.79 < cat.loc["AS15-M-0297_crop", "center_lon"] < 148.78
    assert cat["pixel_scale_m"].between(50, 300).all()
    assert m.camera("AS15-M-0297_crop").distortion_model == "apollo_metric"
    assert all(str(x).startswith("APOLLO15/METRIC/") for x in cat["serial_number"])


def test_bad_inputs_are_rejected_by_name_and_the_rest_go_on(tmp_path: Path) -> None:
    junk = tmp_path / "junk.cub"
    junk.write_bytes(b"Object = IsisCube\nnot a cube\n")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    nospice = REAL / "EN1072174528M_raw_dn.cub"
    inputs = [str(MDIS_LEV1), str(junk), str(text)] + ([str(nospice)] if nospice.exists() else [])
    s = ingest_mission(tmp_path / "m", inputs)
    assert s["images"] == 1
    assert set(s["rejected"]) >= {str(junk), str(text)}
    assert "junk.cub" in s["rejected"][str(junk)]
    if nospice.exists():
        assert "spiceinit" in s["rejected"][str(nospice)]
    with pytest.raises(StoreError, match="no usable image"):
        ingest_mission(tmp_path / "none", [str(junk)])
    assert not (tmp_path / "none").exists()


def test_selection_by_pixel_scale(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="max-scale-m"):
        ingest_mission(tmp_path / "m", [str(MDIS_LEV1)], max_scale_m=10.0)
    s = ingest_mission(tmp_path / "m", [str(MDIS_LEV1)], min_scale_m=10.0, max_scale_m=800.0)
    assert s["images"] == 1


def test_stereo_pair_from_isds_and_8bit_images(tmp_path: Path) -> None:
    s = ingest_mission(tmp_path / "m", [str(REAL / "mdis_stereo" / "*.json")])
    m = open_mission(s["path"])
    assert len(m) == 2, s["rejected"]
    cat = m.catalog.set_index("image_id")
    assert abs(cat.loc["EN0213023991M", "center_lat"] - 31.96) < 0.2
    assert m.radiometry("EN0213023991M").pixel_kind == "uint8"
    assert set(cat["instrument"]) == {"MDIS-NAC"}


def test_image_of_the_wrong_size_is_rejected(tmp_path: Path) -> None:
    import numpy as np
    from PIL import Image

    work = tmp_path / "in"
    work.mkdir()
    shutil.copy(REAL / "mdis_stereo" / "EN0213023991M.json", work / "EN0213023991M.json")
    Image.fromarray(np.zeros((100, 120), np.uint8)).save(work / "EN0213023991M.png")
    with pytest.raises(StoreError, match="120 x 100 pixels.*512 x 512"):
        ingest_mission(tmp_path / "m", [str(work / "EN0213023991M.json")])


def test_image_list_pairs_isds_with_images_of_other_names(tmp_path: Path) -> None:
    work = tmp_path / "in"
    work.mkdir()
    src = REAL / "mdis_stereo"
    for stem in ("EN0213023991M", "EN0213110924M"):
        shutil.copy(src / f"{stem}.json", work / f"{stem}.json")
        shutil.copy(src / f"{stem}_recovered_from_notebook_8bit.png", work / f"pic_{stem[-4:]}.png")
    lst = work / "pairs.csv"
    lst.write_text("# isd,image\nEN0213023991M.json, pic_991M.png\nEN0213110924M.json,pic_924M.png\n")
    s = ingest_mission(tmp_path / "m", [str(work / "*.json")], image_list=lst)
    assert s["images"] == 2, s["rejected"]
    lst.write_text("EN0213023991M.json\n")
    with pytest.raises(StoreError, match="pairs.csv, line 1"):
        ingest_mission(tmp_path / "m2", [str(work / "*.json")], image_list=lst)


def test_raw_dn_stored_as_floats_is_dn_of_the_instrument(tmp_path: Path) -> None:
    m = open_mission(ingest_mission(tmp_path / "m", [str(REAL / "EN1072174528M_raw_dn_with_spice.cub")])["path"])
    (i,) = m.image_ids
    r = m.radiometry(i)
    assert r.pixel_kind == "dn" and r.saturation == 4095.0 and r.dn_scale == 1.0
    img = m.read_image(i)
    assert 256 <= np.nanmin(img) and np.nanmax(img) <= 395
    # the boresight ground point of this image (README known value, via the cube's own SPICE)
    assert abs(m.catalog["center_lat"].iat[0] - 46.275) < 0.01 and abs(m.catalog["center_lon"].iat[0] - 248.068) < 0.01


def test_a_run_of_a_mission_without_a_pointing_sigma_is_refused_before_anything_is_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Ingested without --pointing-sigma-urad and no apriori.pointing_sigma_urad: the run says which key to set,
    and RUN is not created (a run.json written first would refuse the corrected configuration as different)."""
    mission = tmp_path / "mdis"
    assert main(["ingest", str(mission), str(MDIS_LEV1)]) == 0
    capsys.readouterr()
    out = tmp_path / "run"
    assert main(["run", str(mission), "--out", str(out), "--scheduler", "sync"]) == 2
    err = capsys.readouterr().err
    assert f"mission {mission} declares no a-priori pointing uncertainty" in err
    assert "apriori.pointing_sigma_urad" in err and "--pointing-sigma-urad" in err
    assert not out.exists()
