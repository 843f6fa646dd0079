"""A failed dense pair, chip or tile carries a kind (DenseFailure / UnitFailure) beside its text, set from the
exception where it is caught; the report counts them by kind; tile summaries and reports of older runs without
one still read (``unrecorded``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from mercury_dem.config import Config
from mercury_dem.dense.failures import DenseFailure, chip_failure_of, pair_failure_of
from mercury_dem.exceptions import CubeError, GeometryError, MercuryDemError, StoreError
from mercury_dem.pipeline import dense_tile
from mercury_dem.pipeline.dense_stage import kind_counts, tiles_block
from mercury_dem.pipeline.report import dense_lines


class _CvError(Exception):
    """Stands for OpenCV's cv2.error: not one of ours, not a ValueError."""


@pytest.mark.parametrize(("exc", "kind"), [
    (GeometryError("chip at (0, 0): fewer than 8 of its grid rays reach the surface"), DenseFailure.CHIP_GEOMETRY),
    (CubeError("cube cut"), DenseFailure.CHIP_GEOMETRY),
    (MercuryDemError("something of ours"), DenseFailure.CHIP_ERROR),
    (ValueError("bad disparity range"), DenseFailure.CHIP_ERROR),
    (np.linalg.LinAlgError("singular"), DenseFailure.CHIP_ERROR),
    (_CvError("(-215:Assertion failed)"), DenseFailure.UNEXPECTED),
])
def test_a_chips_kind_comes_from_the_exception_type_not_its_text(exc: BaseException, kind: DenseFailure) -> None:
    assert chip_failure_of(exc) is kind


def test_a_pairs_kind_is_a_missing_pose_or_an_unreadable_image() -> None:
    assert pair_failure_of(KeyError("EN0001")) is DenseFailure.NO_POSE
    assert pair_failure_of(OSError("no such file")) is DenseFailure.IMAGE_UNREADABLE
    assert pair_failure_of(StoreError("image EN0001: no pose")) is DenseFailure.IMAGE_UNREADABLE  # the type, not the text


class _FakeTile:
    """What ``_run_pair`` reads of a tile task: geometry, images, settings (the chips' matcher is patched)."""

    def __init__(self) -> None:
        cam = SimpleNamespace(camera=SimpleNamespace(samples=1024, lines=1024))
        self.geometry = {"A": cam, "B": cam}
        self.d = Config().dense
        self.surface = self.settings = self.limits = None
        self.margin = 100.0

    def image(self, image_id: str) -> Any:
        if image_id == "UNREADABLE":
            raise OSError(f"{image_id}: cannot read")
        return np.zeros((4, 4), np.float32)


@pytest.mark.parametrize(("raised", "kind"), [
    (GeometryError("the right camera does not see its ground"), DenseFailure.CHIP_GEOMETRY),
    (np.linalg.LinAlgError("singular"), DenseFailure.CHIP_ERROR),
    (_CvError("cv2 says no"), DenseFailure.UNEXPECTED),
])
def test_each_failed_chip_and_pair_is_recorded_with_its_kind(monkeypatch: pytest.MonkeyPatch, raised: Exception,
                                                             kind: DenseFailure) -> None:
    import mercury_dem.dense.chip as chip_mod

    def fail(*a: Any, **kw: Any) -> Any:
        raise raised

    monkeypatch.setattr(chip_mod, "dense_chip", fail)
    cloud = dense_tile.TileCloud()
    tile = _FakeTile()
    dense_tile._run_pair(tile, cloud, 0, "A", "B")  # type: ignore[arg-type]
    dense_tile._run_pair(tile, cloud, 1, "A", "NO_POSE")  # type: ignore[arg-type]
    dense_tile._run_pair(tile, cloud, 2, "A", "UNREADABLE")  # type: ignore[arg-type]  # no pose either: checked first
    tile.geometry["UNREADABLE"] = tile.geometry["A"]
    dense_tile._run_pair(tile, cloud, 3, "A", "UNREADABLE")  # type: ignore[arg-type]
    chips = [f for f in cloud.failures if f["chip"] is not None]
    pairs = [f for f in cloud.failures if f["chip"] is None]
    assert len(chips) == cloud.counts["chips_failed"] == 4 and {f["failure"] for f in chips} == {kind.value}
    assert [(f["pair"], f["failure"]) for f in pairs] == [(1, "no_pose"), (2, "no_pose"), (3, "image_unreadable")]
    assert kind_counts(cloud.failures) == {kind.value: 4, "no_pose": 2, "image_unreadable": 1}


@pytest.mark.parametrize(("raised", "kind"), [
    (StoreError("sparse dem.zarr: not complete"), "corrupt_input"),
    (GeometryError("no adjusted geometry"), "bad_input"),
    (RuntimeError("a bug"), "unexpected"),
])
def test_a_failed_tile_task_carries_its_unit_kind(monkeypatch: pytest.MonkeyPatch, raised: Exception,
                                                  kind: str) -> None:
    def fail(*a: Any, **kw: Any) -> Any:
        raise raised

    monkeypatch.setattr(dense_tile, "run_dense_tile", fail)
    s = dense_tile.tile_task("/nowhere", 5, [], Config(), 1.0)
    assert not s["ok"] and s["failure"] == kind and s["error"].startswith("dense tile 5: ")


def _ok_tile(tile: int, failures: list[dict[str, Any]]) -> dict[str, Any]:
    return {"tile": tile, "ok": True, "chips": 3, "points": 10, "failures": failures, "seconds": 1.0}


def test_the_report_counts_dense_failures_by_kind_and_reads_older_runs() -> None:
    new = [_ok_tile(1, [{"pair": 0, "chip": [0, 0, 5, 5], "error": "pair A/B chip at (0, 0): x",
                         "failure": "chip_geometry"},
                        {"pair": 1, "chip": None, "error": "pair A/C: no adjusted pose for 'C'", "failure": "no_pose"},
                        {"pair": 2, "chip": [0, 0, 5, 5], "error": "pair A/D chip at (0, 0): y",
                         "failure": "chip_geometry"}]),
           {"tile": 2, "ok": False, "error": "dense tile 2: StoreError: cut", "failure": "corrupt_input"}]
    # a tile group written by an older run (resumed: its stored summary is reused) has no kinds
    old = [_ok_tile(3, [{"pair": 4, "chip": None, "error": "pair E/F: no adjusted pose for 'F'"}]),
           {"tile": 4, "ok": False, "error": "dense tile 4: RuntimeError: a bug"}]
    block = tiles_block(new + old, {1: 50.0}, 50.0)
    assert block["failures_by_kind"] == {"chip_geometry": 2, "no_pose": 1, "unrecorded": 1}
    assert block["tiles"]["failed_by_kind"] == {"corrupt_input": 1, "unrecorded": 1}
    text = dense_lines({**block, "pairs": {"selected": 3, "candidates": 4}})
    assert "failed pairs and chips by kind: chip_geometry 2, no_pose 1, unrecorded 1" in text
    assert "failed tiles by kind: corrupt_input 1, unrecorded 1" in text
    # an older run's report.json: no counts by kind, its errors still listed
    older = {k: v for k, v in block.items() if k != "failures_by_kind"}
    older["tiles"] = {"run": 4, "failed": block["tiles"]["failed"]}
    text = dense_lines({**older, "pairs": {"selected": 3, "candidates": 4}})
    assert "by kind" not in text and "dense tile 4: RuntimeError: a bug" in text and "pair E/F" in text
