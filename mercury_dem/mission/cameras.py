"""The mission's camera table: every distinct camera once, referenced by id from the catalog.

Stored as ``cameras.json`` (camera id -> :func:`mercury_dem.geometry.camera.camera_to_dict`).
Floats are written with ``repr`` and read back to the same bits, so a stored camera is
*equal* to the one written (synthetic missions stay bit-identical through the store).
This module only adds the store's error type and message (which file, which camera).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mercury_dem.exceptions import GeometryError, StoreError
from mercury_dem.geometry.camera import FramingCamera, camera_to_dict
from mercury_dem.geometry.camera import camera_from_dict as _from_dict


def camera_from_dict(d: Mapping[str, Any], where: str = "camera") -> FramingCamera:
    """The camera of :func:`camera_to_dict`; StoreError naming ``where`` and the field at fault."""
    try:
        return _from_dict(d)
    except (GeometryError, TypeError, ValueError) as exc:
        raise StoreError(f"{where}: {exc}") from None


__all__ = ["camera_to_dict", "camera_from_dict"]
