"""The dense stereo cloud's store ``RUN/dense.zarr`` (issue 31; docs/design/dense.md, "The stage", step 4).

One Zarr group per tile (``tile_XXX``), columnar (:data:`CLOUD_COLUMNS`), written atomically by its tile task
(built under a temporary name, marked ``complete`` in its attributes with the tile's summary, renamed); the root
attribute ``pairs`` lists the selected pairs a point's ``pair`` column indexes.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Columns of a tile's cloud (name -> dtype); ``left_px``/``right_px`` are (N, 2).
CLOUD_COLUMNS: dict[str, Any] = {
    "lat": np.float64, "lon": np.float64, "height": np.float64, "sigma_h_m": np.float32, "miss_m": np.float32,
    "angle_deg": np.float32, "score": np.float32, "pair": np.int32, "left_px": np.float32, "right_px": np.float32,
    "sigma_match_px": np.float32, "m_per_px": np.float32,
}


def tile_group_name(tile_id: int) -> str:
    """The group of a tile's cloud in ``dense.zarr`` (``tile_007``)."""
    return f"tile_{int(tile_id):03d}"


def empty_column(name: str) -> NDArray[Any]:
    """A column of no point, with its dtype and shape."""
    return np.zeros((0, 2) if name.endswith("_px") else 0, CLOUD_COLUMNS[name])


def tile_complete(path: Path) -> bool:
    """A tile group committed by its task (its ``complete`` attribute)."""
    import zarr

    if not (path / "zarr.json").is_file():
        return False
    try:
        return bool(zarr.open_group(str(path), mode="r").attrs.get("complete", False))
    except Exception:  # noqa: BLE001 - an unreadable group is not complete (recomputed)
        return False


def read_tile_summary(path: Path) -> dict[str, Any]:
    """The summary a tile task stored in its group's attributes."""
    import zarr

    summary: Any = zarr.open_group(str(path), mode="r").attrs["summary"]
    return dict(summary)


def write_tile_group(path: Path, arrays: dict[str, NDArray[Any]], summary: dict[str, Any]) -> None:
    """Write one tile's cloud as a Zarr group, atomically (built under a temporary name, marked complete in its
    attributes with the summary, then renamed); an existing group is replaced only once the new one is whole.
    """
    import zarr

    from mercury_dem.io.atomic import atomic_directory

    def mark(tmp: Path) -> None:
        g = zarr.open_group(str(tmp), mode="r+")
        g.attrs["summary"] = json.loads(json.dumps(summary, default=float))
        g.attrs["complete"] = True

    with atomic_directory(path, overwrite=True, mark_complete=mark) as tmp:
        g = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        for k, a in arrays.items():
            chunks = (max(1, min(a.shape[0], 1 << 20)),) + a.shape[1:]
            g.create_array(k, data=np.ascontiguousarray(a), chunks=chunks)
        g.attrs["columns"] = {k: ("(N, 2) sample, line, 0-based" if k.endswith("_px") else "(N,)")
                              for k in arrays}


def read_cloud(dense_path: Path, tiles: list[int] | None = None) -> dict[str, NDArray[Any]]:
    """The complete tiles' clouds concatenated (column -> array), in tile order."""
    import zarr

    names = sorted(p.name for p in dense_path.iterdir() if p.name.startswith("tile_")) if dense_path.is_dir() else []
    if tiles is not None:
        want = {tile_group_name(t) for t in tiles}
        names = [n for n in names if n in want]
    out: dict[str, list[NDArray[Any]]] = {k: [] for k in CLOUD_COLUMNS}
    for n in names:
        if not tile_complete(dense_path / n):
            continue
        g = zarr.open_group(str(dense_path / n), mode="r")
        for k in CLOUD_COLUMNS:
            arr: Any = g[k]
            out[k].append(np.asarray(arr[...]))
    return {k: (np.concatenate(v) if v else empty_column(k)) for k, v in out.items()}


def set_pair_records(dense_path: Path, records: list[dict[str, Any]]) -> None:
    """Open (create) ``dense.zarr`` for this run's selection of pairs: if its ``pairs`` attribute differs (the
    configuration changed under ``--force``), the tiles are removed, since their ``pair`` indices would not match.
    """
    import zarr

    root = zarr.open_group(str(dense_path), mode="a", zarr_format=3)
    if root.attrs.get("pairs") != records:
        for p in dense_path.iterdir():
            if p.name.startswith("tile_"):
                shutil.rmtree(p, ignore_errors=True)
        root.attrs["pairs"] = records
    root.attrs["columns"] = {k: str(np.dtype(v)) for k, v in CLOUD_COLUMNS.items()}
