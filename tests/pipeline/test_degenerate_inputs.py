"""Degenerate inputs through a whole run (issue 19 §2): each named in report.json and the printed report, the run
goes on, and the other images come out as in the clean run.

One modified tiny mission carries several faults at once (tests/pipeline/degenerate.py): an all-zero image, an
all-saturated image, an image whose chunk lost half its bytes, an island of two images; the tiny mission's two
one-image tiles come with it. The run is made without the DEM (the faults are in matching and adjustment; the
clean run's DEM is tested elsewhere). A second pass re-adjusts it after a tile network was given an image with no
measures and a point with one measure (a singular part of an adjustment).

Tolerance against the clean run (``sync_run``): every image adjusted in both runs within 0.3 px (image space, on
the truth surface) and 0.15 px RMS. Measured 2026-11-26: 0.088 px max, 0.040 px RMS over 33 images — the faulted
images only take away measures near them; the adjusted pointing's own error against the truth is ~0.27 px.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.io.run_store import RunStore, read_solution
from mercury_dem.pipeline.graph import run_pipeline
from mercury_dem.pipeline.report import print_report

from . import degenerate as d
from .conftest import read_report, tiny_config

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def degenerate_run(tiny_mission_path: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, Any]]:
    """(mission, run, report) of the faulted mission, run in-process without the DEM."""
    root = tmp_path_factory.mktemp("degenerate")
    mission = d.make_degenerate_mission(tiny_mission_path, root / "mission")
    report = run_pipeline(mission, root / "run", tiny_config(), scheduler="sync", stream=None, dem=False)
    return mission, root / "run", report


@pytest.fixture(scope="module")
def singular_run(degenerate_run: tuple[Path, Path, dict[str, Any]],
                 tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], tuple[int, int, str]]:
    """The faulted run resumed after :func:`degenerate.inject_singular` (tiles reused, levels re-adjusted)."""
    mission, run, _ = degenerate_run
    copy = tmp_path_factory.mktemp("singular") / "run"
    shutil.copytree(run, copy)
    injected = d.inject_singular(copy)
    report = run_pipeline(mission, copy, tiny_config(), scheduler="sync", stream=None, dem=False)
    return copy, report, injected


def printed(report: dict[str, Any]) -> str:
    out = io.StringIO()
    print_report(report, out)
    return out.getvalue()


def test_bad_pixels_are_named_with_their_fault(degenerate_run: tuple[Path, Path, dict[str, Any]]) -> None:
    mission, run, report = degenerate_run
    assert read_report(run)["tiles"] == report["tiles"]
    errors = report["tiles"]["image_errors"]
    reasons = report["images"]["uncontrolled_reasons"]
    text = printed(report)
    expect = {d.ZERO: "blank (all pixels 0 DN)", d.SATURATED: "blank (all pixels 4095 DN)",
              d.TRUNCATED: "Zstd decompression error"}
    for image_id, fault in expect.items():
        assert image_id in report["images"]["uncontrolled"]
        assert errors[image_id].startswith(f"image {image_id}: ") and fault in errors[image_id]
        assert fault in reasons[image_id]
        assert f"uncontrolled {image_id}: " in text and fault in text
    assert "re-ingest" in errors[d.TRUNCATED] and "remove it from the mission" in errors[d.ZERO]
    assert str(mission / "images.zarr" / d.TRUNCATED) in errors[d.TRUNCATED]


def test_one_image_tiles_and_the_island_are_named(degenerate_run: tuple[Path, Path, dict[str, Any]]) -> None:
    _, _, report = degenerate_run
    failed = {f["tile"]: f["error"] for f in report["tiles"]["failed"]}
    assert len(failed) == 2 and all("no overlapping image pairs (1 images)" in e for e in failed.values())
    assert [f["failure"] for f in report["tiles"]["failed"]] == ["no_pairs", "no_pairs"]
    assert report["failures"]["tile"] == {"no_pairs": 2}
    glob = report["levels"]["global"]
    assert glob["ok"] and len(glob["islands"]) == 2 and sorted(glob["islands"][1]) == sorted(d.ISLAND)
    assert set(d.ISLAND) <= set(read_solution_ids(degenerate_run[1]))  # adjusted, held by their a-priori pointing
    text = printed(report)
    assert "global: 2 islands" in text and all(i in text for i in d.ISLAND)


def read_solution_ids(run: Path) -> list[str]:
    return [str(i) for i in read_solution(RunStore(run).solution_path("global", 0))[0]]


def _apart_px(mission_path: Path, run_a: Path, run_b: Path) -> dict[str, float]:
    """Image-space distance (px, on the truth surface) between two runs' global poses of their common images."""
    from mercury_dem.mission import open_mission
    from mercury_dem.validate.run import image_space_error_px

    mission = open_mission(mission_path)
    height = mission.need_truth().surface().height
    a = read_solution(RunStore(run_a).solution_path("global", 0))
    b = read_solution(RunStore(run_b).solution_path("global", 0))
    at = {str(i): k for k, i in enumerate(a[0])}
    return {str(i): float(image_space_error_px(mission.camera(str(i)), b[2][k], b[1][k], a[2][at[str(i)]],
                                               a[1][at[str(i)]], height, datum_radius_m=DATUM_RADIUS_M))
            for k, i in enumerate(b[0]) if str(i) in at}


def test_other_images_come_out_as_in_the_clean_run(degenerate_run: tuple[Path, Path, dict[str, Any]],
                                                     sync_run: tuple[Path, dict[str, Any]],
                                                     tiny_mission_path: Path) -> None:
    _, run, report = degenerate_run
    clean_run, clean = sync_run
    apart = _apart_px(tiny_mission_path, clean_run, run)
    lost = set(d.FAULTED)
    assert set(apart) == set(read_solution_ids(clean_run)) - lost  # every other image still adjusted
    v = np.array(list(apart.values()))
    assert v.max() <= 0.3 and np.sqrt(np.mean(v**2)) <= 0.15, sorted(apart.items(), key=lambda kv: -kv[1])[:5]
    assert report["images"]["controlled"] == clean["images"]["controlled"] - len(lost) + len(d.ISLAND)
    assert report["validation"]["adjusted_rms_in_ifov"] <= 0.5


def test_a_singular_part_is_named_and_the_adjustment_goes_on(
    singular_run: tuple[Path, dict[str, Any], tuple[int, int, str]],
    degenerate_run: tuple[Path, Path, dict[str, Any]],
) -> None:
    mission, run0, _ = degenerate_run
    run, report, (tile, point_id, image) = singular_run
    assert report["levels"]["global"]["ok"]
    rows = [r for r in report["levels"]["region"] if r["ok"] and tile in r["children"]]
    assert len(rows) == 1
    row = rows[0]
    assert d.NO_MEASURES in row["images_without_measures"]
    assert point_id in row["single_measure_points"]["ids"]
    assert read_report(run)["levels"]["region"] == report["levels"]["region"]
    text = printed(report)
    assert f"{row['name']}: " in text and str(point_id) in text and d.NO_MEASURES in text
    # the one-measure point is left unadjusted and changes nothing else: the same poses to 1e-6 px
    apart = _apart_px(mission, run0, run)
    assert set(apart) == set(read_solution_ids(run0)) and max(apart.values()) < 1e-6


def test_an_image_without_measures_is_held_not_fatal(degenerate_run: tuple[Path, Path, dict[str, Any]]) -> None:
    """``adjust_unit_network`` on a network (as imported or edited) holding an image with no measure: before, the
    whole solve was an AdjustmentError ("1 images have no measures"); now the image is held at its a-priori
    pose, named, and the others come out as without it."""
    from mercury_dem.adjust.unit import adjust_unit_network
    from mercury_dem.config import load_config
    from mercury_dem.io.network_store import read_network
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.stages import pointing_sigma_urad_for

    mission_path, run, _ = degenerate_run
    mission = open_mission(mission_path)
    net = read_network(RunStore(run).network_path("region", 8))  # S-000-060: 19 images
    net = net.replace(measure_rejected=np.zeros_like(net.measure_rejected),
                      point_rejected=np.zeros_like(net.point_rejected))
    config = load_config()
    cfg, sigma_urad = config.adjust, pointing_sigma_urad_for(mission, config)

    def solve(n: Any) -> Any:
        ids = [str(i) for i in n.image_ids]
        pos = np.array([mission.a_priori_pose(i)[0] for i in ids])
        rot = np.array([mission.a_priori_pose(i)[1] for i in ids])
        return adjust_unit_network(n, [mission.camera(i) for i in ids], pos, rot, cfg, pointing_sigma_urad=sigma_urad,
                                   datum_radius_m=mission.body.datum_radius_m), pos, rot

    clean, _, _ = solve(net)
    extra = net.replace(image_ids=np.append(net.image_ids, d.NO_MEASURES))
    held, pos, rot = solve(extra)
    assert held.summary["images_without_measures"] == [d.NO_MEASURES]
    assert np.array_equal(held.rotations[-1], rot[-1]) and np.array_equal(held.positions[-1], pos[-1])
    assert held.image_measures[-1] == 0
    assert np.allclose(held.rotations[:-1], clean.rotations, atol=1e-12)
