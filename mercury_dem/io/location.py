"""Where a store lives: a local path, or an object-store URL (``s3://``, ``gs://``) through fsspec.

``--out`` of a run and the mission path may be URLs. This module decides, before
anything is written, whether a location is local or remote and refuses what the
run cannot write to: an unknown scheme (``ftp://``, ``foo://``), or a scheme whose
fsspec backend is not installed (``gs://`` without ``gcsfs``). Without this check
``--out s3://bucket/run`` was taken as the relative path ``s3:/bucket/run``.

``file://URL`` is a local path (the run behaves exactly as with the plain path).

Storage options (endpoint, credentials) are not mercury-dem settings: fsspec's
own configuration applies to every filesystem it creates, including zarr's. Set
``FSSPEC_S3_ENDPOINT_URL=http://HOST:PORT`` (or a JSON file in
``~/.config/fsspec/``, see fsspec's "configuration" page) for an S3-compatible
service that is not AWS; credentials come from the usual ``AWS_*`` variables,
``~/.aws`` or the instance role (``gs://``: ``GOOGLE_APPLICATION_CREDENTIALS``).
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote, urlparse

from mercury_dem.exceptions import StoreError

#: Object-store schemes a run store may live on, and the package that provides each backend.
OBJECT_STORE_SCHEMES = {"s3": "s3fs", "gs": "gcsfs", "gcs": "gcsfs"}

#: What a command that writes local directories only tells a user who gave it a URL.
UPLOAD_HINT = "write it locally, then upload it (aws s3 sync DIR URL; gsutil rsync -r DIR URL)"

_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-]*)://")


class UnsupportedLocationError(StoreError, ValueError):
    """A store location names a URL scheme the run cannot use, or its backend is not installed."""


def url_scheme(location: str | Path) -> str | None:
    """The lower-case scheme of ``location`` when it is a URL (``scheme://...``), else None."""
    if isinstance(location, Path):
        return None
    m = _URL.match(str(location))
    return m.group(1).lower() if m else None


def is_remote(location: str | Path) -> bool:
    """True for an object-store URL (``s3://``, ``gs://``); False for a path or ``file://``."""
    return url_scheme(location) in OBJECT_STORE_SCHEMES


def resolve_location(location: str | Path, what: str = "store") -> str | Path:
    """A local :class:`~pathlib.Path`, or the object-store URL (a str) after checking it can be used.

    Parameters
    ----------
    location : a path, ``file://`` URL or object-store URL
    what : what the location is for, named in the error (``--out``, ``mission``)

    Raises
    ------
    UnsupportedLocationError
        the scheme is not one of ``file``, ``s3``, ``gs``, ``gcs``; or its fsspec backend is not installed;
        or the URL names no bucket.
    """
    scheme = url_scheme(location)
    if scheme is None:
        return Path(location)
    text = str(location)
    if scheme == "file":
        try:
            parsed = urlparse(text)
        except ValueError as exc:  # e.g. an unclosed '[' of an IPv6 host
            raise UnsupportedLocationError(f"{what} {text}: not a valid file:// URL ({exc})") from None
        if parsed.netloc not in ("", "localhost"):
            raise UnsupportedLocationError(
                f"{what} {text}: a file:// URL must name a local path (file:///abs/path), not host {parsed.netloc!r}")
        return Path(unquote(parsed.path))
    if scheme not in OBJECT_STORE_SCHEMES:
        raise UnsupportedLocationError(
            f"{what} {text}: unsupported URL scheme {scheme!r}; use a local path, file://, "
            + ", ".join(f"{s}://" for s in OBJECT_STORE_SCHEMES))
    bucket_and_key = text[len(scheme) + 3:].strip("/")
    if not bucket_and_key:
        raise UnsupportedLocationError(f"{what} {text}: the URL names no bucket; write {scheme}://BUCKET/PREFIX")
    import fsspec

    try:
        fsspec.get_filesystem_class(scheme)
    except ImportError:
        raise UnsupportedLocationError(
            f"{what} {text}: the {scheme}:// backend is not installed; pip install {OBJECT_STORE_SCHEMES[scheme]} "
            f"(or mercury-dem[{'s3' if scheme == 's3' else 'gcs'}])") from None
    return f"{scheme}://{bucket_and_key}"


def refuse_remote(location: str | Path, what: str, hint: str) -> Path:
    """A local path for writers that do not write to object storage; a URL is refused with ``hint``.

    ``file://`` URLs become paths; an unsupported scheme is refused as by :func:`resolve_location`.
    """
    loc = resolve_location(location, what)
    if isinstance(loc, str):
        raise UnsupportedLocationError(f"{what} {loc}: this command writes local directories only; {hint}")
    return loc
