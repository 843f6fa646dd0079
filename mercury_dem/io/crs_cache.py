"""The user's cache of the DEM store's CRS attributes (``$MERCURY_DEM_CACHE/crs/``).

The ``spatial_ref`` attributes are a constant of the body and of the installed pyproj/rioxarray
(:func:`mercury_dem.dem.store_schema.compute_spatial_ref_attrs`); importing rioxarray (which loads
rasterio's GDAL and pyproj) was ~0.5 s of a cold ``mercury-dem grid`` that needs nothing else from them,
so the value is computed once and kept here (``python -m mercury_dem.pipeline.warm`` fills it).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
from typing import Any

from mercury_dem.dem.store_schema import compute_spatial_ref_attrs, spatial_ref_cache_key
from mercury_dem.geometry.body import Body
from mercury_dem.io.atomic import atomic_write_json
from mercury_dem.io.remote import cache_root

__all__ = ["spatial_ref_attrs"]


@functools.lru_cache(maxsize=4)
def spatial_ref_attrs(body: Body) -> dict[str, Any]:
    """The body's ``spatial_ref`` attributes (:func:`~mercury_dem.dem.store_schema.compute_spatial_ref_attrs`),
    from the user's cache, keyed by the body and the pyproj/rioxarray versions
    (:func:`~mercury_dem.dem.store_schema.spatial_ref_cache_key`).

    A cache that cannot be read or written is computed again (a test checks the cached value equals a
    fresh one).
    """
    key = spatial_ref_cache_key(body)
    path = cache_root() / "crs" / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.json"
    with contextlib.suppress(OSError, ValueError):  # absent or unreadable: computed below
        cached = json.loads(path.read_text())
        if cached.get("key") == key:
            return dict(cached["attrs"])
    attrs = compute_spatial_ref_attrs(body)
    with contextlib.suppress(OSError):  # a read-only cache: the value is still right, only not kept
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(path, {"key": key, "attrs": attrs})
    return attrs
