"""A copy of the tiny mission with degenerate inputs, for the whole-run test of issue 19 §2.

:func:`make_degenerate_mission` copies the tiny mission and injects, at once:

* ``zero``: an image whose pixels are all 0;
* ``saturated``: an image whose pixels are all at its saturation value (4095 DN);
* ``truncated``: an image whose Zarr chunk lost the second half of its bytes (zstd cannot decode it);
* ``island``: two new images, copies of a well-matched overlapping pair of the block moved 100 degrees east
  (positions, rotations and sun turned about the body's z axis; truth poses the same way), so they match
  each other and nothing else: an island of two images in the hemisphere and global networks.

The tiny mission itself already has two tiles with one image each (the isolated images at 84 N and 45 N).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.mission.catalog import POSITION_COLUMNS, ROTATION_COLUMNS, SUN_COLUMNS

ZERO = "EW0200016800G"        # (-3.4, 358.4)
SATURATED = "EW0200013200G"   # (6.4, 3.3)
TRUNCATED = "EN0200019200M"   # (6.6, 10.5)
#: The originals of the island images and their copies' ids.
ISLAND_FROM = ("EW0200000000G", "EW0200005400G")
ISLAND = ("EW0200090000G", "EW0200090600G")
ISLAND_TURN_DEG = 100.0
FAULTED = (ZERO, SATURATED, TRUNCATED)


def _rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _turn(table: pd.DataFrame, pos_cols: list[str], rot_cols: list[str], extra_vec_cols: list[str] | None) -> None:
    """Turn the rows' positions (and ``extra_vec_cols``) by Rz and their body->camera rotations by Rz^T (in place)."""
    rz = _rz(ISLAND_TURN_DEG)
    table[pos_cols] = table[pos_cols].to_numpy(np.float64) @ rz.T
    if extra_vec_cols:
        table[extra_vec_cols] = table[extra_vec_cols].to_numpy(np.float64) @ rz.T
    r = table[rot_cols].to_numpy(np.float64).reshape(-1, 3, 3) @ rz.T
    table[rot_cols] = r.reshape(-1, 9)


def make_degenerate_mission(tiny: Path, out: Path) -> Path:
    """Copy ``tiny`` to ``out`` with the faults of the module docstring; returns ``out``."""
    import zarr

    shutil.copytree(tiny, out)
    images = out / "images.zarr"
    for image_id, value in ((ZERO, 0), (SATURATED, 4095)):
        arr = zarr.open_array(str(images / image_id), mode="r+")
        arr[...] = np.full(arr.shape, value, dtype=arr.dtype)
    chunk = images / TRUNCATED / "c" / "0" / "0"
    data = chunk.read_bytes()
    chunk.write_bytes(data[: len(data) // 2])

    cat = pd.read_parquet(out / "catalog.parquet")
    new = cat.set_index("image_id").loc[list(ISLAND_FROM)].reset_index()
    new["image_id"] = list(ISLAND)
    _turn(new, POSITION_COLUMNS, ROTATION_COLUMNS, SUN_COLUMNS)
    new["center_lon"] = (new["center_lon"] + ISLAND_TURN_DEG) % 360.0
    for c in ("footprint_lon_min", "footprint_lon_max"):
        new[c] = (new[c] + ISLAND_TURN_DEG) % 360.0
    new["tile_id"] = TileGrid(10.0).tile_of(new["center_lat"].to_numpy(), new["center_lon"].to_numpy())
    pd.concat([cat, new], ignore_index=True).to_parquet(out / "catalog.parquet", index=False)
    for src, dst in zip(ISLAND_FROM, ISLAND):
        shutil.copytree(images / src, images / dst)

    poses = pd.read_parquet(out / "truth" / "poses.parquet")
    tnew = poses.set_index("image_id").loc[list(ISLAND_FROM)].reset_index()
    tnew["image_id"] = list(ISLAND)
    _turn(tnew, ["true_" + c for c in POSITION_COLUMNS], ["true_" + c for c in ROTATION_COLUMNS], SUN_COLUMNS)
    pd.concat([poses, tnew], ignore_index=True).to_parquet(out / "truth" / "poses.parquet", index=False)
    meta = json.loads((out / "mission.json").read_text())
    meta["n_images"] = int(len(cat) + len(ISLAND))
    (out / "mission.json").write_text(json.dumps(meta, indent=2))
    return out


#: The camera given no measures and the id of the point given one measure, in :func:`inject_singular`.
NO_MEASURES = "EW0200021600G"  # a real mission image (the isolated one near the north pole)


def inject_singular(run: Path) -> tuple[int, int, str]:
    """Make the network of one tile of ``run`` singular and clear the levels above it (a resume re-adjusts).

    The tile's network gets an image with no measures (:data:`NO_MEASURES`) and a point seen by one
    image only (one measure, in a corner of the first measure's image). Returns (tile id, point id, measured image).
    """
    from mercury_dem.io.network_store import read_network, write_network
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS

    store = RunStore(run)
    tiles = [t for t in store.completed_units("tile") if store.read_summary("tile", t).get("ok")]
    tile = tiles[0]
    path = store.network_path("tile", tile)
    net = read_network(path)
    pid = int(np.max(net.point_ids)) + 1
    image = int(net.measure_image[0])
    changes: dict[str, np.ndarray] = {"image_ids": np.append(net.image_ids, NO_MEASURES)}
    changes["point_ids"] = np.append(net.point_ids, pid)
    for name in POINT_COLUMNS:
        col = getattr(net, name)
        changes[name] = np.concatenate([col, col[:1]])
    for name in MEASURE_COLUMNS:
        col = getattr(net, name)
        changes[name] = np.concatenate([col, col[:1]])
    changes["measure_point"][-1] = net.n_points
    changes["measure_image"][-1] = image
    changes["sample"][-1] = changes["line"][-1] = 2.5  # a corner no other measure of the image is near
    bad = net.replace(**changes)
    shutil.rmtree(path)
    write_network(bad, path)
    # the unit's completion marker carries its files' checksums: record the injected network as the unit's
    # own (otherwise the resume finds a checksum mismatch and recomputes the tile, injection and all)
    from mercury_dem.io.atomic import COMPLETE_MARKER, file_manifest, marker_text

    unit = store.unit_dir("tile", tile)
    (unit / COMPLETE_MARKER).write_text(marker_text(file_manifest(unit)))
    for level in ("region", "hemisphere", "global"):
        store.remove_level(level)
    (run / "report.json").unlink()
    return tile, pid, str(net.image_ids[image])
