"""The dense DEM's products (issue 31 section 3; docs/design/dense.md, "Products"): as the sparse DEM's, and more.

Into ``RUN/products/dense/``, from ``dem_dense.zarr`` (written by :mod:`mercury_dem.pipeline.dense_dem`):

- every product the sparse DEM gets (:func:`mercury_dem.products.make.make_products`: ``dem.tif`` COG, the PDS
  GeoTIFFs with PDS4 labels, the ISIS radius cube, ``statistics.json``/``.txt``, the browse PNGs, ``accuracy.json``
  against the truth), of the product layer ``elevation`` (dense where a dense value exists, else the sparse
  fallback), each file written to a temporary name and renamed;
- ``browse/dense_vs_sparse_hillshade.png``: the sparse DEM (resampled on the dense grid) and the dense DEM's own
  values (no fallback) as shaded relief side by side, cropped to where the dense points reach;
- the heights against the run's references (``reference.*``: a shape model's harmonics, a LOLA/MLA grid or shots)
  of the dense DEM's own values and of the sparse DEM on the same pixels
  (:func:`reference_comparison`), so the report says which is closer to the reference where both exist.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.config import Config
from mercury_dem.io.run_store import DEM_DENSE_FILE, DENSE_PRODUCTS_DIR, RunStore

#: The side-by-side browse image (relative to the dense products' directory).
HILLSHADE_PAIR_PNG = "browse/dense_vs_sparse_hillshade.png"


def write_dense_products(store: RunStore, config: Config, truth_height: Callable[..., Any] | None
                         ) -> dict[str, Any]:
    """All the dense DEM's products into ``RUN/products/dense/`` (replaced on every run of the stage); returns
    the report's ``dense.products`` block (files, what was skipped and why, the statistics' global row, seconds).
    """
    from mercury_dem.products.browse import write_hillshade_pair_png
    from mercury_dem.products.make import dem_body, make_products, open_dem

    t0 = time.perf_counter()
    path = store.root / DEM_DENSE_FILE
    out = store.products_dir / DENSE_PRODUCTS_DIR
    res = make_products(path, out, config, truth_height=truth_height, overwrite=True, coverage=False,
                        name="dense DEM")
    ds = open_dem(path)
    body = dem_body(ds)
    lat, lon = ds["lat"].values.astype(np.float64), ds["lon"].values.astype(np.float64)
    pair = write_hillshade_pair_png(
        ds["sparse_on_grid"].transpose("lat", "lon").values, ds["elevation_dense"].transpose("lat", "lon").values,
        lat, lon, out / HILLSHADE_PAIR_PNG,
        ("sparse DEM (tie points), resampled on the dense grid", "dense DEM (stereo points only)"),
        f"{body.name.title()}: {float(ds.attrs.get('pixels_per_degree', 0.0)):g} pixel/deg", radius_m=body.datum_radius_m)
    stats = res.get("statistics") or {}
    return {"dir": str(out), "files": [str(f) for f in res.get("files", [])] + [pair["path"]],
            "skipped": res.get("skipped", {}), "hillshade_pair": pair, "browse_title": res.get("browse_title"),
            "statistics_global": stats.get("global"), "accuracy": res.get("accuracy"),
            "seconds": round(time.perf_counter() - t0, 2)}


def reference_comparison(dem_dense_path: Path, config: Config) -> dict[str, Any] | None:
    """The dense DEM's own values, its delivered ``elevation`` (the product: there the dense value fused with the
    sparse DEM when ``dense.sparse_sigma_m`` is set) and the sparse DEM resampled on the same pixels (``source`` =
    dense, both with a value) against each reference of ``config.reference``: ``{"dense": {ref: stats},
    "delivered": {...}, "sparse": {...}}`` (``compare_with_references``'s statistics: ``bias_m``, ``rmse_m``, ...);
    None without a reference.
    """
    from mercury_dem.pipeline.dense_dem import SOURCE_DENSE
    from mercury_dem.pipeline.reference_check import compare_with_references
    from mercury_dem.products.make import dem_body, open_dem

    ref = config.reference
    if not (ref.dem or ref.altimetry or ref.shape_harmonics):
        return None
    ds = open_dem(dem_dense_path).load()
    body = dem_body(ds)
    both = (ds["source"] == SOURCE_DENSE) & np.isfinite(ds["sparse_on_grid"])
    out: dict[str, Any] = {"pixels": int(both.sum())}
    for key, layer in (("dense", "elevation_dense"), ("delivered", "elevation"), ("sparse", "sparse_on_grid")):
        view = ds[["distance_to_nearest_point"]].copy()
        view["elevation"] = ds[layer].where(both)
        out[key] = compare_with_references(view, body, ref)
    return out
