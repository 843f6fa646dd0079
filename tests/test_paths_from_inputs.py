"""Names from inputs cannot escape their directory (issue 19 §3).

Image ids come from file names (cubes, ISDs) and from a mission's catalog; they name
``images.zarr/<id>`` and ``<id>.json`` of corrected ISDs. Hostile ids — ``../x``, ``/abs/x``,
``..\\x``, ``.``, empty, NUL, newline — are refused with the project's error naming the file
and the fault, and nothing is written outside the mission (checked by listing the whole
temporary tree before and after). Unit ids of the run store are integers (``int()`` in
``RunStore.unit_dir``), serial numbers and point ids never become file names (they are
values inside the network store and the ``.net``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.io.names import check_name, name_fault

HOSTILE = ["../x", "/abs/x", "..\\x", "..", ".", "", "a\x00b", "a\nb", "x/../../y", ".zgroup", "zarr.json",
           "__x", "a" * 201]
REAL = Path(__file__).resolve().parent / "data" / "real"


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.mark.parametrize("name", HOSTILE)
def test_name_check_refuses(name: str) -> None:
    assert name_fault(name) is not None
    with pytest.raises(ValueError, match="image id .* it would become a file name"):
        check_name(name, "image id")


@pytest.mark.parametrize("name", ["EN1072174528M", "AS15-M-0297_crop", "T03_0012", "c", "img.v2", "ÉN 01"])
def test_name_check_accepts_real_ids(name: str) -> None:
    assert name_fault(name) is None and check_name(name, "image id") == name


def test_mission_writer_refuses_hostile_ids_and_writes_nothing(tmp_path: Path) -> None:
    from mercury_dem.mission import MissionWriter

    root = tmp_path / "deep" / "m"
    root.mkdir(parents=True)
    MissionWriter(root)
    before = _tree(tmp_path)
    for name in HOSTILE:
        with pytest.raises(StoreError, match=r"mission .*/m: image id .*; nothing was written"):
            MissionWriter.write_image(root, name, np.zeros((4, 4), np.uint8))
    assert _tree(tmp_path) == before
    assert (root / "images.zarr" / "zarr.json").is_file()  # the group is intact ('' and '.' would overwrite it)


@pytest.mark.parametrize("name", ["../../outside", "/etc/passwd", "..\\x", "a\nb", ""])
def test_mission_catalog_with_hostile_id_is_refused(tmp_path: Path, name: str) -> None:
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.io.atomic import atomic_directory
    from mercury_dem.mission import MissionWriter, open_mission
    from tests.mission.test_store import _tiny_catalog

    cams, cat = _tiny_catalog(MERCURY)
    m = tmp_path / "m"
    with atomic_directory(m) as tmp:
        w = MissionWriter(tmp)
        for i in range(3):
            w.write_image(tmp, f"im{i}", np.zeros((64, 64), np.uint16))
        w.finish({"source": "test"}, MERCURY, cams, cat)
    assert len(open_mission(m)) == 3
    table = pd.read_parquet(m / "catalog.parquet")
    table.loc[1, "image_id"] = name
    table.to_parquet(m / "catalog.parquet", index=False)
    with pytest.raises(StoreError, match=r"mission .*/m: catalog\.parquet image id .* cannot name its array"):
        open_mission(m)


def test_ingest_rejects_files_whose_names_are_not_safe_ids(tmp_path: Path) -> None:
    """ISDs named ``..json`` (id '.'), ``a\\nb.json``, ``..\\x.json`` and a cube ``.x.cub`` (id ''), beside a good
    ISD: the good one is ingested, each bad one is rejected naming its file and the fault, and nothing is
    written outside the mission (``images.zarr`` is intact: an id '' or '.' would overwrite it)."""
    from mercury_dem.mission import open_mission
    from mercury_dem.mission.ingest import ingest_mission

    src = tmp_path / "in"
    src.mkdir()
    isd = REAL / "mdis_stereo" / "EN0213023991M.json"
    png = REAL / "mdis_stereo" / "EN0213023991M_recovered_from_notebook_8bit.png"
    stems = ["EN0213023991M", ".", "a\nb", "..\\x"]
    for stem in stems:
        shutil.copy(isd, src / f"{stem}.json")
        shutil.copy(png, src / f"{stem}.png")
    shutil.copy(REAL / "EN0240208184M.lev1.cub", src / ".x.cub")
    inputs = [str(src / f"{s}.json") for s in stems] + [str(src / ".x.cub")]
    before = _tree(tmp_path)
    s = ingest_mission(tmp_path / "out" / "m", inputs)
    assert s["images"] == 1, s["rejected"]
    assert _tree(tmp_path) - before <= {"out", *(f"out/m/{p}" for p in _tree(tmp_path / "out" / "m")), "out/m"}
    rejected = s["rejected"]
    assert set(rejected) == set(inputs[1:]), rejected
    assert "its image id '.' (from the file name) is a relative directory reference; rename the file" in \
        rejected[str(src / "..json")]
    assert "control character '\\n'" in rejected[str(src / "a\nb.json")]
    assert "path separator" in rejected[str(src / "..\\x.json")]
    assert "image id '' (from the file name) is empty" in rejected[str(src / ".x.cub")]
    m = open_mission(s["path"])
    assert list(m.image_ids) == ["EN0213023991M"]
    assert m.read_image("EN0213023991M").shape == (512, 512)
    assert json.loads((Path(s["path"]) / "mission.json").read_text())["n_images"] == 1


def test_corrected_isds_are_not_written_for_hostile_ids(tmp_path: Path) -> None:
    """``adjust-isis``'s ISD writer: an image id that is not a safe name gets no file (and a reason)."""
    from types import SimpleNamespace

    from mercury_dem.pipeline.adjust_isis import _isd_outputs

    out = tmp_path / "a" / "isds"
    out.mkdir(parents=True)
    images = [SimpleNamespace(image_id=n, files=[str(tmp_path / "none.json")]) for n in ("../../escape", "/abs/x")]
    written, skipped = _isd_outputs(images, np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)), np.arange(2), out)
    assert written == {} and set(skipped) == {"../../escape", "/abs/x"}
    assert all("no ISD written" in why for why in skipped.values())
    assert _tree(tmp_path) == {"a", "a/isds"}
