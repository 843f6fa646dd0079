r"""Names from inputs that become file or directory names: one check, so none escapes its directory.

Image ids (a cube's or ISD's file name, a mission catalog's ``image_id`` column) name
``images.zarr/<id>`` in a mission and ``<id>.json`` among corrected ISDs. A name such as
``../x``, ``/abs/x``, ``..\x``, ``.`` or the empty string would write outside that directory
or over it (``images.zarr/`` itself), and control characters (NUL, newline) break the catalog,
logs and ISIS's PVL. Such names are refused rather than encoded: an id is also what users
see and what ISIS serial-number lists refer to, and a silently rewritten id would no longer
match them.

Why a hand-written check and not ``pathvalidate``/``werkzeug.secure_filename``: the rule is
four lines and the project has no such dependency; the latter also rewrites names silently.
"""

from __future__ import annotations

#: Longest name accepted (bytes of UTF-8; file systems allow 255 per component, ``.json`` is added).
MAX_NAME_BYTES = 200

#: Names with a meaning inside a Zarr store (v3 metadata; v2 metadata start with '.') that an id must not take.
RESERVED = frozenset({"zarr.json"})


def name_fault(name: object) -> str | None:
    """Why ``name`` cannot be one path component inside a store, or None when it can."""
    if not isinstance(name, str):
        return f"is a {type(name).__name__}, not a string"
    if not name:
        return "is empty"
    if name in (".", ".."):
        return "is a relative directory reference"
    if "/" in name or "\\" in name:
        return "contains a path separator ('/' or '\\')"
    bad = [c for c in name if ord(c) < 32 or ord(c) == 127]
    if bad:
        return f"contains the control character {bad[0]!r}"
    if name.startswith("."):
        return "starts with '.' (hidden files and store markers)"
    if name in RESERVED or name.startswith("__"):
        return "is a name Zarr reserves inside a store (zarr.json, __*)"
    if len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        return f"is longer than {MAX_NAME_BYTES} bytes"
    return None


def check_name(name: object, what: str) -> str:
    """``name`` if it is a safe single path component; otherwise ValueError naming ``what`` and the fault.

    Callers turn the ValueError into their own error (StoreError, IngestError, ...) with the
    file at fault; ``what`` is e.g. ``"image id"``.
    """
    fault = name_fault(name)
    if fault is not None:
        raise ValueError(f"{what} {name!r} {fault}; it would become a file name")
    return name  # type: ignore[return-value]
