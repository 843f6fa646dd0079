"""Completion markers with checksums: a file changed after the commit is named; remote commits carry them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import CorruptUnitError
from mercury_dem.io.atomic import (
    COMPLETE_MARKER,
    atomic_directory,
    disk_full_cause,
    read_marker_manifest,
    verify_complete,
)
from mercury_dem.io.run_store import RunStore


def _write(path: Path, checksums: bool = True) -> Path:
    rng = np.random.default_rng(7)
    with atomic_directory(path, checksums=checksums) as tmp:
        (tmp / "a.bin").write_bytes(rng.bytes(5000))
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.bin").write_bytes(rng.bytes(300))
    return path


def test_an_untouched_directory_verifies(tmp_path: Path) -> None:
    d = _write(tmp_path / "u")
    assert verify_complete(d) == []
    manifest = read_marker_manifest((d / COMPLETE_MARKER).read_text())
    assert set(manifest["files"]) == {"a.bin", "sub/b.bin"}
    assert (d / COMPLETE_MARKER).read_text().startswith("complete\n")


@pytest.mark.parametrize("seed", [3, 11])
def test_any_flipped_byte_is_named(tmp_path: Path, seed: int) -> None:
    d = _write(tmp_path / "u")
    rng = np.random.default_rng(seed)
    name = ["a.bin", "sub/b.bin"][int(rng.integers(2))]
    data = bytearray((d / name).read_bytes())
    k = int(rng.integers(len(data)))
    data[k] ^= 1 << int(rng.integers(8))  # one bit
    (d / name).write_bytes(bytes(data))
    assert verify_complete(d) == [f"{name}: checksum mismatch (sha256 differs from the committed one)"]


def test_truncated_missing_added_files_and_a_damaged_marker(tmp_path: Path) -> None:
    d = _write(tmp_path / "u")
    (d / "a.bin").write_bytes((d / "a.bin").read_bytes()[:100])
    (d / "sub" / "b.bin").unlink()
    (d / "new.bin").write_bytes(b"x")
    problems = verify_complete(d)
    assert problems[0].startswith("a.bin: size differs (100 bytes, committed 5000)")
    assert problems[1:] == ["sub/b.bin: missing", "new.bin: not in the manifest (added after the commit)"]
    (d / COMPLETE_MARKER).write_text("complete\n{not json")
    assert verify_complete(d)[0].startswith(f"{COMPLETE_MARKER}: damaged")


def test_a_marker_without_checksums_is_not_verifiable(tmp_path: Path) -> None:
    assert verify_complete(_write(tmp_path / "old", checksums=False)) is None


def test_run_store_names_and_withdraws_a_corrupt_unit(tmp_path: Path) -> None:
    store = RunStore(tmp_path / "run")
    d = _write(store.unit_dir("tile", 17))
    assert store.unit_complete("tile", 17) and store.verify_unit("tile", 17) == []
    (d / "sub" / "b.bin").write_bytes(b"\0" * 300)
    with pytest.raises(CorruptUnitError, match=r"tile/17: .*sub/b.bin: checksum mismatch.*resume the run"):
        store.check_unit("tile", 17)
    store.invalidate_unit("tile", 17)
    assert not store.unit_complete("tile", 17) and not d.exists()


def test_disk_full_is_found_through_wrappers() -> None:
    import errno

    from mercury_dem.exceptions import NetworkError

    try:
        try:
            raise OSError(errno.ENOSPC, "No space left on device", "/run/tile/x")
        except OSError as inner:
            raise NetworkError("cannot write the network") from inner
    except NetworkError as exc:
        assert disk_full_cause(exc).errno == errno.ENOSPC
    assert disk_full_cause(RuntimeError("TIFFWriteEncodedStrip: No space left on device")) is not None
    assert disk_full_cause(OSError(errno.EACCES, "Permission denied")) is None


def test_a_region_meeting_a_corrupt_child_stops_and_withdraws_it(tmp_path: Path) -> None:
    """The downstream check: a child damaged after the resume verified it is not merged; the run stops
    (CorruptUnitError, never a failed region committed without it) and the child is withdrawn."""
    from mercury_dem.pipeline.stages import _adjust_unit, child_ids
    from tests.pipeline.conftest import tiny_config

    store = RunStore(tmp_path / "run")
    tile = child_ids("region", 0, tiny_config())[0]
    d = _write(store.unit_dir("tile", tile))
    (d / "summary.json").write_text('{"ok": true}')  # added after the commit: not in the manifest
    with pytest.raises(CorruptUnitError, match=r"summary.json: not in the manifest"):
        _adjust_unit(store, "region", 0, tiny_config())
    assert not store.unit_complete("tile", tile)
