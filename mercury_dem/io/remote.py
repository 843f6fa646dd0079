"""A store on object storage, mirrored through a local cache, with a commit protocol that needs no rename.

Object stores (S3, GCS) have no atomic rename of a directory, so the local
protocol of :mod:`mercury_dem.io.atomic` (build under a temporary name, rename)
does not carry over. A store on a bucket is written in this order instead:

1. the unit's old completion marker is deleted (from here on the unit is not trusted),
2. every other object under the unit's prefix is deleted (partial data of an earlier attempt),
3. the unit's data objects are uploaded (one PUT each: an object appears whole or not at all),
4. the completion marker is uploaded **last**; it holds a random token of this commit (first line)
   and the unit's checksum manifest (second line, see :mod:`mercury_dem.io.atomic`), so the
   fetched copy of a unit is verified exactly like a local one.

A reader trusts a unit only when its marker exists; a unit without one is
recomputed and its partial data overwritten. The pieces of the pipeline are the
same as on a local disk: a unit is computed into a local directory (built
atomically as before, in a cache), then committed to the bucket as above; a
reader fetches a unit's objects into the cache and keeps the commit token beside
them, so a cached copy is reused only while the bucket still holds the same
commit. Zarr stores (``dem.zarr``, ``coverage.zarr``) are committed the same way
with the root ``zarr.json`` (which carries their ``complete`` attribute) as the
last object; their token is the store's **content token** (:meth:`RemoteDir.content_token`: a hash of
every object's name, size and entity tag, or modification time where the store has no tag), taken from
the bucket's listing on every fetch. A store rewritten under the same name with other values (a regrid
under the same plan, chunks written by workers after the root ``zarr.json``) has another token whatever its
``zarr.json`` says, so a stale cached copy cannot be taken for the current one: no caller has to remember
to force a download. Its cost: one listing per fetch (S3 lists 1,000 objects a request, so a DEM of 10,000
chunks is 10 requests), where the hash of ``zarr.json`` was one GET; the download itself uses that listing.

Why not write every array straight to the bucket with zarr/fsspec: the stage
runners, the products (GDAL writes GeoTIFFs to local files only) and the readers
of the run (report, dashboard, notebooks) are all path based; mirroring keeps
them unchanged, keeps a local run bit for bit what it was, and puts the whole
object-store logic in this one module.

The cache is ``$MERCURY_DEM_CACHE`` (default ``$XDG_CACHE_HOME/mercury-dem`` or
``~/.cache/mercury-dem``), one directory per store URL; it may be deleted at
any time between runs.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

from mercury_dem.exceptions import StoreError
from mercury_dem.io.atomic import COMPLETE_MARKER, atomic_directory

#: The keys of an object's info (fsspec ``find(detail=True)``) that identify its bytes, first present wins:
#: S3's entity tag (the MD5 of a single PUT), GCS's, then a modification time (a local or other filesystem).
_OBJECT_IDENTITY = ("ETag", "etag", "md5Hash", "crc32c", "mtime", "LastModified", "last_modified", "updated",
                    "created")

#: Suffix of the file beside a cached directory (``.NAME.remote-token``) holding the commit token
#: it was fetched (or committed) at: outside the directory, so a Zarr store holds only Zarr objects.
CACHE_TOKEN = ".remote-token"


def _token_file(local: Path) -> Path:
    return local.parent / f".{local.name}{CACHE_TOKEN}"


def cache_root() -> Path:
    """The local cache of object-store runs and missions (``$MERCURY_DEM_CACHE``)."""
    env = os.environ.get("MERCURY_DEM_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mercury-dem"


def cache_dir_for(url: str, kind: str) -> Path:
    """The cache directory of one store URL (``kind``: ``runs`` or ``missions``)."""
    digest = hashlib.sha256(url.rstrip("/").encode()).hexdigest()[:16]
    name = url.rstrip("/").rsplit("/", 1)[-1] or "store"
    return cache_root() / kind / f"{name}-{digest}"


class RemoteDir:
    """A prefix (``s3://bucket/run``) on an object store, reached through fsspec.

    Listings are not cached (``use_listings_cache=False``): another process (a
    worker, a user deleting a marker) may change the bucket at any time.
    """

    def __init__(self, url: str) -> None:
        import fsspec

        self.url = url.rstrip("/")
        self.fs, self.path = fsspec.core.url_to_fs(self.url, use_listings_cache=False)
        self.path = self.path.rstrip("/")

    def key(self, rel: str = "") -> str:
        return f"{self.path}/{rel.strip('/')}" if rel.strip("/") else self.path

    def url_of(self, rel: str = "") -> str:
        return f"{self.url}/{rel.strip('/')}" if rel.strip("/") else self.url

    # -- objects -----------------------------------------------------------------
    def read_bytes(self, rel: str) -> bytes | None:
        """The object's bytes, or None when it does not exist."""
        try:
            return bytes(self.fs.cat_file(self.key(rel)))
        except FileNotFoundError:
            return None

    def write_bytes(self, rel: str, data: bytes) -> None:
        """One PUT: the object appears whole or not at all."""
        self.fs.pipe_file(self.key(rel), data)

    def exists(self, rel: str) -> bool:
        return bool(self.fs.exists(self.key(rel)))

    def list(self, rel: str = "") -> list[str]:
        """Names directly under ``rel`` (files and sub-prefixes); [] when there are none."""
        try:
            entries = self.fs.ls(self.key(rel), detail=False)
        except FileNotFoundError:
            return []
        base = self.key(rel)
        return sorted({str(e).rstrip("/").rsplit("/", 1)[-1] for e in entries if str(e).rstrip("/") != base})

    def remove(self, rel: str) -> None:
        """Delete ``rel`` and everything under it (nothing when absent)."""
        with contextlib.suppress(FileNotFoundError):  # absent already: nothing to delete
            self.fs.rm(self.key(rel), recursive=True)

    # -- directories ---------------------------------------------------------------
    def commit_dir(self, local: Path, rel: str, last: str = COMPLETE_MARKER, token_marker: bool = True) -> str:
        """Commit the local directory ``local`` to ``rel`` by the protocol above; return the commit token.

        ``last`` is the object uploaded last (the completion marker; for a Zarr store its
        root ``zarr.json``). With ``token_marker`` the marker's content is
        ``complete <token>``, else its own bytes are uploaded and the token is their hash.
        """
        local = Path(local)
        files = sorted(p for p in local.rglob("*") if p.is_file())
        rels = [p.relative_to(local).as_posix() for p in files]
        self.remove(f"{rel}/{last}")  # first: from now on the unit is not trusted
        self.remove(rel)  # partial data of an earlier attempt
        data = [(str(p), self.key(f"{rel}/{r}")) for p, r in zip(files, rels) if r != last]
        if data:  # one call: s3fs/gcsfs upload the objects concurrently
            self.fs.put([a for a, _ in data], [b for _, b in data])
        if token_marker:
            token = uuid.uuid4().hex
            # the local marker's checksum manifest (second line, mercury_dem.io.atomic) travels with it
            rest = b""
            if (local / last).is_file():
                rest = (local / last).read_bytes().partition(b"\n")[2]
            marker = f"complete {token}\n".encode() + rest
        else:
            if last not in rels:
                raise StoreError(f"{local}: no {last} to commit last; the local store is incomplete")
            marker = (local / last).read_bytes()
        self.write_bytes(f"{rel}/{last}", marker)
        if not token_marker:  # the content token, as a reader will list it
            token = self.content_token(rel, last) or ""
        _token_file(local).write_text(token)
        return token

    def commit_token(self, rel: str, last: str = COMPLETE_MARKER, token_marker: bool = True) -> str | None:
        """The token of ``rel``'s last commit, or None when it has no completion marker (not trusted).

        With ``token_marker`` the random token in the marker; without (a Zarr store), the store's
        :meth:`content_token`.
        """
        if not token_marker:
            return self.content_token(rel, last)
        data = self.read_bytes(f"{rel}/{last}")
        if data is None:
            return None
        text = data.decode("utf-8", "replace").split("\n", 1)[0].strip()  # line 2: the checksum manifest
        return text.split(" ", 1)[1] if " " in text else text

    def objects(self, rel: str) -> dict[str, dict[str, Any]]:
        """Every object under ``rel`` (path relative to it -> the store's info: size, entity tag, ...); one listing."""
        prefix = self.key(rel)
        try:
            found = self.fs.find(prefix, detail=True)
        except FileNotFoundError:
            return {}
        return {str(k)[len(prefix) + 1:]: dict(v) for k, v in found.items() if str(k).startswith(prefix + "/")}

    def content_token(self, rel: str, last: str = "zarr.json",
                      objects: dict[str, dict[str, Any]] | None = None) -> str | None:
        """A token of what ``rel`` holds now: a hash of each object's name, size and identity (the entity tag
        S3 and GCS give every object, a hash of its bytes for a single PUT; where a store has none, its
        modification time). None when ``last`` (the store's commit, written last) is absent: not trusted.

        Any object rewritten with other bytes changes the token, so a cached copy recorded under an older
        token is fetched again (a Zarr store's chunks may be rewritten while its root ``zarr.json`` stays the
        same). ``objects``: a listing already taken (:meth:`objects`).
        """
        objects = self.objects(rel) if objects is None else objects
        if last not in objects:
            return None
        h = hashlib.sha256()
        for name in sorted(objects):
            info = objects[name]
            ident = next((info[k] for k in _OBJECT_IDENTITY if info.get(k) not in (None, "")), None)
            h.update(repr((name, info.get("size"), str(ident))).encode())
        return h.hexdigest()

    def fetch_dir(self, rel: str, local: Path, last: str = COMPLETE_MARKER, token_marker: bool = True,
                  mark_complete: Any = None, token: str | None = None, force: bool = False) -> bool:
        """Make ``local`` a copy of the committed ``rel``; False when ``rel`` has no completion marker.

        A cached copy whose token is the bucket's current one is kept; otherwise the
        objects are downloaded into a temporary sibling and renamed into place (a
        concurrent fetch of the same unit by another process is harmless). ``token``, when
        given, identifies the commit instead of the marker's content (a mission uploaded by
        other tools has a plain ``.complete``). Without ``token_marker`` (a Zarr store) the token is the
        store's :meth:`content_token`, from the listing the download uses; when the store changed while it
        was downloaded, the copy is kept without a token (the next fetch downloads it again). ``force``:
        download even when the cached token is current (no caller needs it for staleness: a store's token
        changes with any of its objects).
        """
        listing = None if token_marker or token else self.objects(rel)
        token = token or (self.content_token(rel, last, listing) if listing is not None
                          else self.commit_token(rel, last, token_marker))
        if token is None:
            return False
        local = Path(local)
        if not force and _cached_token(local) == token:
            return True
        prefix = self.key(rel)
        _token_file(local).unlink(missing_ok=True)
        try:
            if token_marker and mark_complete is None:
                mark_complete = _keep_fetched_marker  # the marker is written below, with the manifest
            with atomic_directory(local, overwrite=True, mark_complete=mark_complete) as tmp:
                names = sorted(listing) if listing is not None else sorted(self.objects(rel))
                pairs = [(f"{prefix}/{n}", tmp / n) for n in names]
                for _, dest in pairs:
                    dest.parent.mkdir(parents=True, exist_ok=True)
                if pairs:  # one call: downloaded concurrently
                    self.fs.get([k for k, _ in pairs], [str(d) for _, d in pairs])
                if token_marker:
                    # the local marker, as atomic_directory writes it, with the commit's checksum manifest
                    fetched = tmp / last
                    rest = fetched.read_bytes().partition(b"\n")[2] if fetched.is_file() else b""
                    fetched.write_bytes(b"complete\n" + rest)
        except OSError:
            # a concurrent fetch of the same commit (another worker process) renamed its copy first: keep it
            if not (local.is_dir() and self.commit_token(rel, last, token_marker) == token):
                raise
        if listing is not None and self.content_token(rel, last) != token:
            return True  # rewritten while downloaded: no token, so the copy is never taken for current
        _token_file(local).write_text(token)
        return True


def fetch_mission(url: str) -> Path:
    """The local cached copy of the mission at ``url`` (fetched when missing or changed on the bucket).

    A mission is uploaded whole by the user (``aws s3 sync MISSION s3://bucket/mission``);
    its ``.complete`` marker says it was written to completion. The cached copy is
    identified by ``mission.json`` and the size and entity tag of ``catalog.parquet``:
    a mission written again is fetched again.

    Raises
    ------
    StoreError : no mission at ``url``, or its ``.complete`` marker is missing.
    """
    remote = RemoteDir(url)
    meta = remote.read_bytes("mission.json")
    if meta is None:
        raise StoreError(f"mission {url} does not exist (no mission.json); upload a mission written by "
                         "'mercury-dem synth' or 'ingest' (e.g. aws s3 sync MISSION " + url + ")")
    if not remote.exists(COMPLETE_MARKER):
        raise StoreError(f"mission {url} is incomplete (no {COMPLETE_MARKER} marker: its writing or upload was "
                         "interrupted); upload it again")
    try:
        info = remote.fs.info(remote.key("catalog.parquet"))
    except FileNotFoundError:
        info = {}
    ident = repr((meta, info.get("size"), info.get("ETag") or info.get("etag") or info.get("md5Hash")))
    token = hashlib.sha256(ident.encode()).hexdigest()
    local = cache_dir_for(url, "missions")
    remote.fetch_dir("", local, token=token)
    return local


def _keep_fetched_marker(tmp: Path) -> None:
    """``mark_complete`` of a fetched unit: its marker (with the commit's manifest) is already in place."""


def forget_cached(local: Path) -> None:
    """Remove the cached copy ``local`` and its token, so the next :meth:`fetch_dir` downloads it (a local
    directory rebuilt in place, e.g. a DEM template, must not keep the token of the commit it replaced).
    """
    shutil.rmtree(local, ignore_errors=True)
    _token_file(local).unlink(missing_ok=True)


def _cached_token(local: Path) -> str | None:
    if not local.is_dir():
        return None
    try:
        return _token_file(local).read_text().strip()
    except OSError:
        return None
