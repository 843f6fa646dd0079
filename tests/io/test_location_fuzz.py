"""Fuzz: store locations typed by users and completion markers read from a bucket never raise anything but our errors."""

from __future__ import annotations

import os
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from mercury_dem.io.location import UnsupportedLocationError, resolve_location

_N = int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "200"))

_SCHEMES = st.sampled_from(["s3", "gs", "gcs", "file", "ftp", "foo", "S3", "http", "s3a", "", "c"])


@settings(max_examples=_N, deadline=None, database=None)
@given(scheme=_SCHEMES, rest=st.text(max_size=40))
def test_any_location_is_a_path_a_url_or_a_clear_refusal(scheme: str, rest: str) -> None:
    text = f"{scheme}://{rest}" if scheme else rest
    try:
        loc = resolve_location(text, "--out")
    except UnsupportedLocationError as exc:
        assert "--out" in str(exc)
        return
    if isinstance(loc, str):
        assert loc.split("://", 1)[0] in ("s3", "gs", "gcs") and loc.split("://", 1)[1]
    else:
        assert isinstance(loc, Path)


@settings(max_examples=_N, deadline=None, database=None)
@given(data=st.binary(max_size=64))
def test_any_marker_bytes_give_a_token(data: bytes) -> None:
    from mercury_dem.io.remote import RemoteDir

    class Fake(RemoteDir):
        def __init__(self) -> None:  # no filesystem: only the marker's bytes matter here
            self.fs = None

        def read_bytes(self, rel: str) -> bytes | None:
            return data

        def objects(self, rel: str) -> dict[str, dict[str, object]]:  # a Zarr store's listing: any entity tag
            return {"zarr.json": {"size": len(data), "ETag": data}, "a/c/0": {"size": 0, "mtime": data}}

    assert isinstance(Fake().commit_token("tile/1", token_marker=True), str)
    token = Fake().commit_token("dem.zarr", last="zarr.json", token_marker=False)
    assert isinstance(token, str) and token == Fake().content_token("dem.zarr")
