"""Lazy constant arrays: the templates from which xarray writes a Zarr store's layout (``to_zarr(compute=False)``).

Nothing is computed from them: they give each variable its shape, dtype, chunks and fill value, so that the store's
metadata and coordinates are written before any chunk task runs. Dask is the array type xarray takes for that;
keeping the import here keeps Dask inside the execution layer (docs/architecture.md, "Where Dask lives").
"""

from __future__ import annotations

from typing import Any


def lazy_full(shape: tuple[int, int], fill_value: float, dtype: Any, chunks: tuple[int, int]) -> Any:
    """A never-computed array of ``shape`` holding ``fill_value`` (``dtype``), cut in ``chunks``
    (a ``dask.array.Array``: what xarray writes as a template).
    """
    import dask.array as da

    return da.full(shape, fill_value, dtype=dtype, chunks=chunks)
