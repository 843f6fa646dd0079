"""Atomic writes: write to a temporary name beside the target, then rename.

A reader never sees a half-written file or directory: either the old content
(or nothing) or the complete new one. Directories get a completion marker
(``.complete``) written last, so an interrupted writer is detectable.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

COMPLETE_MARKER = ".complete"


_TMP_NAME = re.compile(r"^\..+\.tmp-[0-9a-f]{12}$")


def _tmp_sibling(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:12]}")


def sweep_temporaries(root: str | Path) -> list[Path]:
    """Remove the temporary siblings (``.NAME.tmp-<12 hex>``) a killed writer left under ``root``.

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
    tmp = _tmp_sibling(path)
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
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


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


@contextlib.contextmanager
def atomic_directory(
    path: str | Path, overwrite: bool = False, *, mark_complete: Callable[[Path], None] | None = None
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
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_sibling(path)
    tmp.mkdir()
    try:
        yield tmp
        if mark_complete is None:
            (tmp / COMPLETE_MARKER).write_text("complete\n")
        else:
            mark_complete(tmp)
        if path.exists():
            if not overwrite:
                raise FileExistsError(path)
            old = _tmp_sibling(path)
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
