"""The mission's camera table: every distinct camera once, referenced by id from the catalog.

A camera is a frozen dataclass of numbers and tuples
(:class:`~mercury_dem.geometry.camera.FramingCamera`), so it is stored as a JSON
object of its fields: Python writes floats with ``repr``, which reads back to the
same bits, so a stored camera is *equal* to the one written (the synthetic
missions' outputs stay bit-identical through the store).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.camera import FramingCamera


def camera_to_dict(camera: FramingCamera) -> dict[str, Any]:
    """A JSON-safe mapping of a camera's fields (tuples become lists)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(camera):
        v = getattr(camera, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def _as_tuple(v: Any) -> Any:
    if isinstance(v, list):
        return tuple(_as_tuple(x) for x in v)
    return v


def camera_from_dict(d: Mapping[str, Any], where: str = "camera") -> FramingCamera:
    """The camera of :func:`camera_to_dict`; StoreError naming ``where`` and the field at fault."""
    if not isinstance(d, Mapping):
        raise StoreError(f"{where}: expected an object of camera fields, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(FramingCamera)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise StoreError(f"{where}: unknown camera fields {unknown} (written by a newer mercury-dem?)")
    kwargs = {k: _as_tuple(v) for k, v in d.items()}
    for k, v in kwargs.items():
        flat = v if isinstance(v, tuple) else (v,)
        for x in flat:
            if isinstance(x, float) and not math.isfinite(x):
                raise StoreError(f"{where}: field {k} is not finite ({x})")
    try:
        return FramingCamera(**kwargs)
    except (TypeError, ValueError) as exc:
        raise StoreError(f"{where}: invalid camera ({exc})") from None
