"""What a SIGKILLed writer leaves (temporary siblings) is swept before a run resumes; nothing else is."""

from __future__ import annotations

from pathlib import Path

from mercury_dem.io.atomic import atomic_write_text, sweep_temporaries


def test_sweep_removes_only_temporary_siblings(tmp_path: Path) -> None:
    atomic_write_text(tmp_path / "a" / "summary.json", "{}")
    (tmp_path / "a" / ".summary.json.tmp-0123456789ab").write_text("half")
    half = tmp_path / "tile" / ".631.tmp-d3fe18fc6ced"
    (half / ".network.zarr.tmp-16ae64d40a1f").mkdir(parents=True)
    (tmp_path / ".dem.zarr.tmp-cba28b5abf15").mkdir()
    keep = [tmp_path / ".hidden", tmp_path / "x.tmp-0123456789ab", tmp_path / ".y.tmp-xyz", tmp_path / ".z.tmp-0123"]
    for p in keep:
        p.write_text("mine")
    removed = sweep_temporaries(tmp_path)
    assert sorted(p.name for p in removed) == sorted(
        [".summary.json.tmp-0123456789ab", ".631.tmp-d3fe18fc6ced", ".dem.zarr.tmp-cba28b5abf15"])
    assert not half.exists() and (tmp_path / "a" / "summary.json").read_text() == "{}"
    assert all(p.exists() for p in keep)
    assert sweep_temporaries(tmp_path / "absent") == []


def test_writers_that_keep_an_extension_leave_names_the_sweep_removes(tmp_path: Path) -> None:
    """The ISIS cube and PDS4 label writers need their extension on the temporary file (the driver picks the
    format by it): a SIGKILLed one left ``.dem_radius.tmp-15c41856.cub`` that no sweep removed (found by
    test_sigkill_resume). Their names now come from ``tmp_sibling(path, suffix)`` and are swept.
    """
    from mercury_dem.io.atomic import tmp_sibling

    cube = tmp_sibling(tmp_path / "products" / "isis" / "dem_radius.cub", ".cub")
    label = tmp_sibling(tmp_path / "products" / "pds" / "dem.xml", ".xml")
    plain = tmp_sibling(tmp_path / "products" / "dem.tif")
    assert cube.suffix == ".cub" and cube.name.startswith(".dem_radius.tmp-")
    for p in (cube, label, plain):
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("half")
    product = tmp_path / "products" / "isis" / "dem_radius.cub"
    product.write_text("whole")
    too_long = tmp_path / "products" / ".dem.tmp-0123456789ab.notanextension"
    too_long.write_text("mine")
    assert sorted(p.name for p in sweep_temporaries(tmp_path)) == sorted(p.name for p in (cube, label, plain))
    assert product.read_text() == "whole" and too_long.exists()
