"""Atomic writes: write to a temporary name beside the target, then rename.

A reader never sees a half-written file or directory: either the old content
(or nothing) or the complete new one. Directories get a completion marker
(``.complete``) written last, so an interrupted writer is detectable.

With ``checksums=True`` the marker also holds the SHA-256 and size of every file of the
directory (a *manifest*, :func:`file_manifest`), so a file changed after the commit (a
flipped bit on disk, a truncated copy, an edited chunk) is detectable
(:func:`verify_complete`), not only an interrupted write. The marker's first line is
``complete``; the manifest, when present, is the JSON on the second line. A marker
without one (written before checksums existed, or by ``checksums=False``) still means
"complete" but cannot be verified.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import shutil
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

COMPLETE_MARKER = ".complete"

#: The checksum of the manifests (hashlib's; ~530 MB/s on one core of this machine, see
#: docs/benchmarks/faults.md). A cryptographic hash is not needed against bit rot, but SHA-256
#: is in the standard library, fast enough (I/O bound on a disk) and unambiguous.
CHECKSUM_ALGORITHM = "sha256"


_TMP_NAME = re.compile(r"^\..+\.tmp-[0-9a-f]{12}(\.[A-Za-z0-9]{1,8})?$")


def tmp_sibling(path: Path, suffix: str | None = None) -> Path:
    """A fresh temporary sibling of ``path`` (``.NAME.tmp-<12 hex>``, what :func:`sweep_temporaries` removes).

    ``suffix`` (e.g. ``".cub"``, for writers whose driver chooses the format by the extension): the name is
    ``.STEM.tmp-<12 hex>SUFFIX``, which the sweep recognises too.
    """
    tag = uuid.uuid4().hex[:12]
    if suffix is None:
        return path.with_name(f".{path.name}.tmp-{tag}")
    return path.with_name(f".{path.stem}.tmp-{tag}{suffix}")


def sweep_temporaries(root: str | Path) -> list[Path]:
    """Remove the temporary siblings (``.NAME.tmp-<12 hex>``, optionally with an extension) a killed writer left
    under ``root``.

    A writer that is SIGKILLed (or loses its machine) cannot clean up: its temporary file or
    directory stays beside the target, which was never replaced. Call this only when no writer of
    ``root`` can be running (a run's client before it submits any task). Returns what was removed.
    """
    removed: list[Path] = []
    root = Path(root)
    if not root.is_dir():
        return removed
    for dirpath, dirnames, filenames in os.walk(root):
        for name in list(dirnames) + filenames:
            if _TMP_NAME.match(name):
                p = Path(dirpath) / name
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
                removed.append(p)
        dirnames[:] = [d for d in dirnames if not _TMP_NAME.match(d)]
    return removed


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (same-directory temp file, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_sibling(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_write_bytes`); the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON to ``path`` atomically (numpy scalars and arrays as plain values); the path."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


def strict_json(obj: Any) -> Any:
    """``obj`` with NaN and infinities turned into None and numpy scalars into Python ones, recursively
    through dicts, lists and tuples (tuples become lists): what strict JSON (``allow_nan=False``) can hold.
    """
    import numpy as np  # here, as in _json_default: this module is imported by the CLI before numpy is needed

    if isinstance(obj, dict):
        return {k: strict_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict_json(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return None if not math.isfinite(float(obj)) else float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def file_digest(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes, read in blocks (hashlib.file_digest)."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, CHECKSUM_ALGORITHM).hexdigest()


def file_manifest(directory: str | Path, exclude: tuple[str, ...] = (COMPLETE_MARKER,)) -> dict[str, Any]:
    """``{"algorithm": "sha256", "files": {relative/path: [size, hex digest]}}`` of every file under ``directory``.

    ``exclude``: relative paths left out (the marker that will hold the manifest).
    """
    root = Path(directory)
    files: dict[str, list[Any]] = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and not p.is_symlink():
            rel = p.relative_to(root).as_posix()
            if rel not in exclude:
                files[rel] = [p.stat().st_size, file_digest(p)]
    return {"algorithm": CHECKSUM_ALGORITHM, "files": files}


def verify_manifest(directory: str | Path, manifest: dict[str, Any],
                    exclude: tuple[str, ...] = (COMPLETE_MARKER,)) -> list[str]:
    """The files of ``directory`` that differ from ``manifest``: one line per fault, [] when all match.

    Each line names the file (relative to ``directory``) and the fault: ``checksum mismatch``,
    ``size differs``, ``missing``, or ``not in the manifest`` (a file added after the commit).
    """
    root = Path(directory)
    if manifest.get("algorithm") != CHECKSUM_ALGORITHM:
        return [f"{COMPLETE_MARKER}: unknown checksum algorithm {manifest.get('algorithm')!r}"]
    expected: dict[str, Any] = manifest.get("files", {})
    problems: list[str] = []
    for rel, (size, digest) in expected.items():
        p = root / rel
        if not p.is_file():
            problems.append(f"{rel}: missing")
        elif p.stat().st_size != size:
            problems.append(f"{rel}: size differs ({p.stat().st_size} bytes, committed {size})")
        elif file_digest(p) != digest:
            problems.append(f"{rel}: checksum mismatch ({CHECKSUM_ALGORITHM} differs from the committed one)")
    for p in sorted(root.rglob("*")):
        if p.is_file():
            rel = p.relative_to(root).as_posix()
            if rel not in expected and rel not in exclude:
                problems.append(f"{rel}: not in the manifest (added after the commit)")
    return problems


def marker_text(manifest: dict[str, Any] | None) -> str:
    """The completion marker's content: ``complete``, then the manifest's JSON on one line when given."""
    return "complete\n" + (json.dumps(manifest, separators=(",", ":")) + "\n" if manifest is not None else "")


def read_marker_manifest(marker: str | bytes) -> dict[str, Any] | None:
    """The manifest a marker's content holds (its second line), or None (a marker without checksums).

    Raises
    ------
    ValueError : the second line is not a manifest (a damaged marker).
    """
    text = marker.decode("utf-8", "replace") if isinstance(marker, bytes) else marker
    lines = text.split("\n", 1)
    rest = lines[1].strip() if len(lines) > 1 else ""
    if not rest:
        return None
    obj = json.loads(rest)
    if not isinstance(obj, dict) or not isinstance(obj.get("files"), dict):
        raise ValueError("the completion marker's second line is not a checksum manifest")
    return obj


def verify_complete(path: str | Path) -> list[str] | None:
    """Check a directory written by :func:`atomic_directory` with ``checksums=True`` against its marker.

    Returns
    -------
    None when the marker has no manifest (cannot be verified), else the faults
    (:func:`verify_manifest`; [] when every file matches). A missing or damaged marker is a fault.
    """
    marker = Path(path) / COMPLETE_MARKER
    try:
        manifest = read_marker_manifest(marker.read_bytes())
    except OSError as exc:
        return [f"{COMPLETE_MARKER}: unreadable ({exc.strerror or exc})"]
    except ValueError as exc:
        return [f"{COMPLETE_MARKER}: damaged ({exc})"]
    if manifest is None:
        return None
    return verify_manifest(path, manifest)


@contextlib.contextmanager
def atomic_directory(
    path: str | Path, overwrite: bool = False, *, mark_complete: Callable[[Path], None] | None = None,
    checksums: bool = False,
) -> Iterator[Path]:
    """Build a directory under a temporary name; on success rename it to ``path``.

    Yields the temporary directory to write into. The completion marker is
    written last, inside, before the rename. On an exception the temporary
    directory is removed and ``path`` is untouched. With ``overwrite`` an
    existing ``path`` is replaced (moved aside, then deleted) only after the new
    one is complete.

    ``mark_complete(tmp)``, when given, replaces the ``.complete`` marker file as the
    completion mark (e.g. a Zarr attribute: zarr warns about unknown files inside a
    store); :func:`is_complete` then does not apply, the caller checks its own mark.

    ``checksums``: the marker holds the manifest of every file written (:func:`file_manifest`),
    checked by :func:`verify_complete`. Hashing reads every byte once more (~530 MB/s).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_sibling(path)
    tmp.mkdir()
    try:
        yield tmp
        if mark_complete is None:
            (tmp / COMPLETE_MARKER).write_text(marker_text(file_manifest(tmp) if checksums else None))
        else:
            mark_complete(tmp)
        if path.exists():
            if not overwrite:
                raise FileExistsError(path)
            old = tmp_sibling(path)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def is_complete(path: str | Path) -> bool:
    """True when ``path`` is a directory written to completion by :func:`atomic_directory`."""
    return (Path(path) / COMPLETE_MARKER).is_file()


#: errno values meaning "the file system is full" (quota exceeded counts: the user must free space too).
_DISK_FULL_ERRNOS = {28, 122}  # ENOSPC, EDQUOT (Linux)
_DISK_FULL_TEXT = ("no space left on device", "disk quota exceeded")


def disk_full_cause(exc: BaseException) -> BaseException | None:
    """The ENOSPC/EDQUOT error in ``exc``'s chain (``__cause__``/``__context__``), or None.

    Libraries wrap the OSError (zarr, pyarrow, a project error raised ``from`` it) or only
    quote it (GDAL's messages): both are recognised, so a full disk is never mistaken for a
    per-unit failure.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in _DISK_FULL_ERRNOS:
            return e
        if any(t in str(e).lower() for t in _DISK_FULL_TEXT):
            return e
        e = e.__cause__ or e.__context__
    return None


def disk_full_message(what: str, cause: BaseException, where: str | Path) -> str:
    """The message of :class:`~mercury_dem.exceptions.DiskFullError`: what was being written, where, what to do."""
    name = getattr(cause, "filename", None)
    path = f" ({name})" if name else ""
    return (f"{what}: no space left on device while writing{path} under {where}. Nothing half-written was kept "
            "(units already finished are complete). Free space on that file system (or move the run directory to a "
            "larger one), then resume with the same 'mercury-dem run MISSION --out RUN': it continues where it stopped")
