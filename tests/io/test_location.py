"""Store locations: local paths, file:// URLs, object-store URLs, and the schemes refused up front."""

from __future__ import annotations

from pathlib import Path

import pytest

from mercury_dem.cli import main
from mercury_dem.io.location import UnsupportedLocationError, is_remote, refuse_remote, resolve_location
from mercury_dem.io.run_store import RunStore


def test_local_paths_and_file_urls_are_paths(tmp_path: Path) -> None:
    assert resolve_location(tmp_path / "run") == tmp_path / "run"
    assert resolve_location("relative/run") == Path("relative/run")
    assert resolve_location(f"file://{tmp_path}/my%20run") == tmp_path / "my run"
    assert RunStore(f"file://{tmp_path}/run") == RunStore(tmp_path / "run")  # the same local run
    assert not is_remote(f"file://{tmp_path}") and not is_remote(tmp_path)


def test_object_store_urls_are_kept_as_urls() -> None:
    pytest.importorskip("s3fs", reason="s3fs is not installed: pip install s3fs (make test installs it)")
    assert resolve_location("s3://bucket/run/") == "s3://bucket/run"
    assert resolve_location("S3://bucket/run") == "s3://bucket/run"
    assert is_remote("s3://bucket/run")


@pytest.mark.parametrize("url, words", [
    ("ftp://host/run", ["unsupported URL scheme 'ftp'", "s3://"]),
    ("foo://bucket/run", ["unsupported URL scheme 'foo'"]),
    ("file://otherhost/run", ["must name a local path"]),
    ("s3://", ["names no bucket"]),
])
def test_unsupported_locations_are_refused(url: str, words: list[str]) -> None:
    with pytest.raises(UnsupportedLocationError) as err:
        resolve_location(url, "--out")
    for w in words:
        assert w in str(err.value)
    assert url.rstrip("/") in str(err.value) or url in str(err.value)


def test_a_scheme_without_its_backend_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    import fsspec

    real = fsspec.get_filesystem_class

    def missing_gcsfs(protocol: str):  # type: ignore[no-untyped-def]
        if protocol in ("gs", "gcs"):
            raise ImportError("Please install gcsfs to access Google Storage")
        return real(protocol)

    monkeypatch.setattr(fsspec, "get_filesystem_class", missing_gcsfs)
    with pytest.raises(UnsupportedLocationError, match=r"gs:// backend is not installed; pip install gcsfs"):
        resolve_location("gs://bucket/run", "--out")


def test_writers_of_local_directories_refuse_urls(tmp_path: Path) -> None:
    assert refuse_remote(tmp_path / "m", "mission", "hint") == tmp_path / "m"
    with pytest.raises(UnsupportedLocationError, match="writes local directories only; upload it"):
        refuse_remote("s3://bucket/mission", "mission", "upload it")


def test_run_to_an_unsupported_url_writes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    # before: '--out s3://bucket/run' silently became the local directory ./s3:/bucket/run
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(tmp_path / "no-mission"), "--out", "ftp://bucket/run", "--scheduler", "sync"]) == 2
    assert "unsupported URL scheme 'ftp'" in capsys.readouterr().err
    assert main(["synth", "foo://bucket/mission", "--preset", "tiny"]) == 2
    assert "unsupported URL scheme 'foo'" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
