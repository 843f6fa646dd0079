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
