"""The registration stage: a ``dem.zarr`` + altimetry shots → ``registered.zarr``, ``merged.zarr``, tables, figure.

How it runs
-----------
1. The shots are checked (columns ``lat``, ``lon``, ``radius_m``, ``track_id``; rows with
   non-finite values dropped and counted) and split by 10° tile (:class:`TileGrid`).
2. One task per tile holding shots on the DEM (:func:`mercury_dem.altimetry.register.register_tile`);
   a task reads its own DEM window from the store (the store path travels, not the map) and
   gets its tile's shots. Tasks go through the client the caller passes (the synchronous
   in-process client by default, a ``distributed.Client`` on a cluster: the same results). An
   unexpected exception in a tile becomes that tile's failure (``ok = False``, the error),
   and the stage goes on.
3. In this process, one block of rows at a time (``block_rows``; by default about 4·10⁶
   pixels): the block's DEM rows and margins are read from the store, registered
   (:func:`mercury_dem.altimetry.merge.register_dem`; pass 1, into a float64 scratch store),
   levelled on the shots' mean per tile (``level_to_mean``; offsets from the whole map's samples,
   applied per block) and merged with the shots corrected by
   their profile offsets (:func:`mercury_dem.altimetry.merge.merge_dem`), and the block's rows
   are written into the two stores. The margins (the merge's reach and the transforms'
   largest displacement) make the result equal to the whole-map computation; memory is that
   of a block, not of the map (before: ~120 B per map pixel measured, ~40 GB for a global 64 ppd DEM).
4. Written atomically beside the DEM: ``registered.zarr`` and ``merged.zarr`` (the DEM's
   coordinates, CRS and attributes; ``merged.zarr`` adds ``altimetry_weight`` and
   ``shot_count``), and ``registration/``: ``tiles.parquet`` + ``tiles.json`` (one row per
   tile), ``profiles.parquet`` (one row per profile), ``rms_per_tile.png`` (seed 004's
   Figure 1: residual RMS before/after per tile) and ``summary.json``.

:func:`register_dem_store` is the one function ``run`` calls.
"""

from __future__ import annotations

import io
import json
import math
import time
import traceback
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import xarray as xr

from mercury_dem.altimetry.merge import (
    MeanLevel,
    MergeOptions,
    blended_scalar,
    max_displacement_m,
    mean_level_offsets,
    merge_dem,
    merge_halo_px,
    register_dem,
)
from mercury_dem.altimetry.register import (
    ProfileOffsets,
    RegisterOptions,
    TileRegistration,
    TileTransform,
    enu_frame,
    register_tile,
    tile_window,
)
from mercury_dem.exceptions import ReferenceDataError, StoreError
from mercury_dem.geometry.body import Body, latlon_to_unit, xyz_to_latlon
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.atomic import atomic_write_bytes
from mercury_dem.io.atomic import strict_json as _jsonable
from mercury_dem.io.run_store import (
    MERGED_FILE,
    REGISTERED_FILE,
    REGISTRATION_DIR,
    REGISTRATION_FIGURE,
    REGISTRATION_MAPS,
    REGISTRATION_SCRATCH_FILE,
    write_registration_tables,
)
from mercury_dem.pipeline.dem_stage import atomic_store
from mercury_dem.reference.compare import compare_heights
from mercury_dem.reference.sampling import sample_grid

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient
    from mercury_dem.config import Config
    from mercury_dem.config.dem import DemConfig

__all__ = ["REGISTRATION_PRODUCTS", "SHOT_COLUMNS", "check_shots", "make_registration_products", "register_dem_store"]

#: Columns a shot table must have (``reference.lola.read_altimetry_csv`` gives them).
SHOT_COLUMNS = ("lat", "lon", "radius_m", "track_id")
#: The maps whose products :func:`make_registration_products` writes: key (of
#: :data:`~mercury_dem.io.run_store.REGISTRATION_MAPS`, their store names) → what it is.
REGISTRATION_PRODUCTS = {"registered": "DEM registered to laser altimetry",
                         "merged": "DEM merged from laser altimetry and the registered DEM"}


def check_shots(shots: pd.DataFrame, source: str = "altimetry") -> tuple[pd.DataFrame, int]:
    """The usable shots (finite lat/lon/radius, |lat| ≤ 90) and the number of rows dropped.

    Raises
    ------
    ReferenceDataError
        A column of :data:`SHOT_COLUMNS` is missing or not numeric (names the source and what to do).
    """
    missing = [c for c in SHOT_COLUMNS if c not in shots.columns]
    if missing:
        raise ReferenceDataError(
            f"{source}: no column {', '.join(missing)} among {list(shots.columns)[:20]}; a shot table needs "
            f"{', '.join(SHOT_COLUMNS)} (read RDR CSVs with mercury_dem.reference.lola.read_altimetry_csv)")
    try:
        lat, lon, rad = (shots[c].to_numpy(dtype=np.float64) for c in ("lat", "lon", "radius_m"))
        track = shots["track_id"].to_numpy()
        ok_track = np.isfinite(track.astype(np.float64))
    except (TypeError, ValueError) as exc:
        raise ReferenceDataError(f"{source}: lat, lon, radius_m and track_id must be numbers ({exc})") from None
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(rad) & (np.abs(lat) <= 90.0) & ok_track
    out = pd.DataFrame({"lat": lat[ok], "lon": lon[ok], "radius_m": rad[ok],
                        "track_id": track[ok].astype(np.int64)})
    return out, int((~ok).sum())


def _tile_task(dem_path: str, tile_id: int, tile_size_deg: float, lat: np.ndarray, lon: np.ndarray,
               radius: np.ndarray, track: np.ndarray, options: RegisterOptions, margin_deg: float) -> TileRegistration:
    """Task body: read the tile's DEM window from the store, register; a crash becomes the tile's failure."""
    tiles = TileGrid(tile_size_deg)
    lat_c, lon_c = (float(v) for v in tiles.centre(tile_id))
    try:
        ds = xr.open_zarr(dem_path, consolidated=False)
        datum = float(ds.attrs["datum_radius_m"])
        la, lo = ds["lat"].values, ds["lon"].values
        b = [float(v) for v in tiles.bounds(tile_id)]
        rows = np.flatnonzero((la >= b[0] - margin_deg) & (la <= b[1] + margin_deg))
        if rows.size < 2:
            raise ValueError("the DEM has no rows in this tile")
        band = ds["elevation"].isel(lat=slice(int(rows[0]), int(rows[-1]) + 1)).values
        win = tile_window(band, la[rows[0]:rows[-1] + 1], lo, tuple(b), datum, margin_deg)  # type: ignore[arg-type]
        if win is None:
            raise ValueError("the DEM has fewer than 2 x 2 pixels in this tile")
        return register_tile(win, lat, lon, radius, track, tile_id=tile_id, centre=(lat_c, lon_c), options=options)
    except Exception as exc:  # noqa: BLE001 - a tile's failure is a value; the stage goes on
        reason = f"tile {tile_id}: {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}"
        return TileRegistration(TileTransform(tile_id, lat_c, lon_c, float("nan"), reason=reason),
                                ProfileOffsets.empty(), {"shots": int(np.size(lat))})


def _corrected_shots(shots: pd.DataFrame, profiles: ProfileOffsets, tiles: TileGrid, datum: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shots moved by their profile's offset (shots of unfitted profiles unchanged)."""
    x = latlon_to_unit(shots["lat"].to_numpy(), shots["lon"].to_numpy()) * shots["radius_m"].to_numpy()[:, None]
    pf = profiles.to_frame()
    if len(pf):
        key = pd.DataFrame({"track_id": shots["track_id"].to_numpy(), "tile_id": shots["tile_id"].to_numpy()})
        pf = pf[pf["fitted"]]
        m = key.merge(pf, on=["track_id", "tile_id"], how="left")
        d = m[["offset_e_m", "offset_n_m", "offset_u_m"]].to_numpy(dtype=np.float64)
        has = np.isfinite(d).all(axis=1)
        if has.any():
            E = enu_frame(m["centre_lat"].to_numpy()[has], m["centre_lon"].to_numpy()[has])
            x[has] += np.einsum("nij,nj->ni", E, d[has])
    lat, lon, h = xyz_to_latlon(x, datum)
    return lat, lon, h + datum


def _create_map(path: Path, source: xr.Dataset, layers: dict[str, tuple[Any, dict[str, Any]]],
                attrs: dict[str, Any], block_rows: int) -> dict[str, Any]:
    """An empty map store with the DEM's coordinates, CRS and attributes (``dem.zarr`` conventions).

    ``layers``: name → (dtype, attributes). The arrays' Zarr chunks are ``block_rows`` rows by up to
    1024 columns, so each block of :func:`register_dem_store` writes whole chunks. Returns the open
    Zarr arrays, for region writes.
    """
    import dask.array as da
    import zarr

    from mercury_dem.pipeline.dem_stage import layer_compressors

    H, W = source.sizes["lat"], source.sizes["lon"]
    cs = (max(min(block_rows, H), 1), max(min(1024, W), 1))
    data_vars = {}
    for name, (dtype, var_attrs) in layers.items():
        fill = np.nan if np.dtype(dtype).kind == "f" else 0
        data_vars[name] = xr.Variable(("lat", "lon"), da.full((H, W), fill, dtype=dtype, chunks=cs), attrs=var_attrs)
    ds = xr.Dataset(data_vars, coords={"lat": source["lat"], "lon": source["lon"],
                                       "spatial_ref": source["spatial_ref"]})
    for name in layers:
        ds[name].encoding.update({"chunks": cs, "grid_mapping": "spatial_ref", "compressors": layer_compressors()})
        ds[name].attrs.pop("grid_mapping", None)
    ds.attrs.update({k: v for k, v in source.attrs.items() if k != "complete"})
    ds.attrs.update(attrs)
    ds.to_zarr(str(path), mode="w", consolidated=False, zarr_format=3, compute=False)  # metadata + coordinates only
    group = zarr.open_group(str(path), mode="r+")
    return {name: group[name] for name in layers}


def _row_of(lat_pts: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """The nearest grid row of each latitude (clipped to the grid; the grid's latitudes evenly spaced)."""
    if lat.size < 2:
        return np.zeros(lat_pts.shape, dtype=np.int64)
    r = np.rint((lat_pts - lat[0]) / (lat[1] - lat[0]))
    return np.clip(np.nan_to_num(r, nan=0.0), 0, lat.size - 1).astype(np.int64)


def _blocks(n_rows: int, block_rows: int) -> list[tuple[int, int]]:
    return [(r0, min(r0 + block_rows, n_rows)) for r0 in range(0, n_rows, block_rows)]


def _sample_blockwise(elevation: xr.DataArray, lat: np.ndarray, lon: np.ndarray, plat: np.ndarray, plon: np.ndarray,
                      block_rows: int) -> np.ndarray:
    """``sample_grid`` of the whole map at the points, reading it one block of rows (+1 row each side) at a time."""
    out = np.full(plat.shape, np.nan)
    rows = _row_of(plat, lat)
    H = lat.size
    for r0, r1 in _blocks(H, block_rows):
        sel = np.flatnonzero((rows >= r0) & (rows < r1))
        if not sel.size:
            continue
        i0, i1 = max(r0 - 1, 0), min(r1 + 1, H)
        win = elevation[i0:i1].values.astype(np.float64)
        out[sel] = sample_grid(win, lat[i0:i1], lon, plat[sel], plon[sel])
    return out


def _register_and_merge_blockwise(
    elevation: xr.DataArray, lat: np.ndarray, lon: np.ndarray, datum: float, transforms: list[TileTransform],
    tiles: TileGrid, merge_options: MergeOptions, corrected: tuple[np.ndarray, np.ndarray, np.ndarray],
    block_rows: int, level_allowed: np.ndarray | None, reg_path: Path, merged_path: Path, source: xr.Dataset,
    elev_attrs: dict[str, Any], reg_attrs: dict[str, Any], merged_attrs: dict[str, Any], overwrite: bool,
) -> dict[str, Any]:
    """The registered and merged maps, computed and written one block of rows at a time.

    Pass 1, per block: the DEM rows it needs (the block and the largest displacement of the
    transforms, :func:`max_displacement_m`, in rows) are read and the block registered
    (:func:`register_dem` with ``rows``) into a float64 scratch store; the transformed map is
    sampled at the corrected shots. Between the passes, the mean level's per-tile offsets
    (:func:`mean_level_offsets`, when ``level_allowed`` is given: the tiles that may level
    themselves). Pass 2, per block: the transformed rows of the block and the merge's margin
    (:func:`merge_halo_px`) are read back, levelled (:func:`blended_scalar`, pointwise), merged
    (:func:`merge_dem` on the shots near the block), and the block's own rows written into
    ``registered.zarr`` and ``merged.zarr`` (both built under temporary names and renamed when
    every block is in). Every pixel depends only on neighbours within those margins, so the
    stores equal the whole-map computation (a test compares them) while memory stays a block's.

    Returns the samples at the corrected shots (``as_given``, ``transformed``, ``registered``,
    ``merged``), the merge's dense-pixel count and the :class:`MeanLevel` summary holder (its
    ``height`` is not kept: an empty array).
    """
    import tempfile

    import zarr

    clat, clon, crad = corrected
    H, W = lat.size, lon.size
    step_deg = abs(float(lat[1] - lat[0])) if H > 1 else 1.0
    hm = merge_halo_px(merge_options)
    shift_deg = math.degrees(max_displacement_m(transforms, datum + 50_000.0) / datum)
    hr = int(math.ceil(shift_deg / step_deg)) + 2
    shot_rows = _row_of(clat, lat)
    order = np.argsort(shot_rows, kind="stable")
    sorted_rows = shot_rows[order]
    samples = {name: np.full(clat.shape, np.nan) for name in ("as_given", "transformed", "registered", "merged")}
    n_dense = 0
    blocks = _blocks(H, block_rows)

    def own_shots(r0: int, r1: int) -> np.ndarray:
        return order[np.searchsorted(sorted_rows, r0):np.searchsorted(sorted_rows, r1)]

    reg_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".register-scratch-", dir=reg_path.parent) as scratch_dir:
        scratch = zarr.create_array(str(Path(scratch_dir) / REGISTRATION_SCRATCH_FILE), shape=(H, W),
                                    chunks=(block_rows, W), dtype=np.float64, fill_value=np.nan, compressors=None)
        for r0, r1 in blocks:  # pass 1: the tile transforms
            i0, i1 = max(r0 - hr, 0), min(r1 + hr, H)
            win = elevation[i0:i1].values.astype(np.float64)
            reg = register_dem(win, lat[i0:i1], lon, datum, transforms, tiles, rows=(r0 - i0, r1 - i0))
            scratch[r0:r1, :] = reg
            own = own_shots(r0, r1)
            if own.size:
                i0s, i1s = max(r0 - 1, 0), min(r1 + 1, H)
                samples["as_given"][own] = sample_grid(win[i0s - i0:i1s - i0], lat[i0s:i1s], lon, clat[own], clon[own])
        for r0, r1 in blocks:  # the transformed map at the shots, now that every row is in
            own = own_shots(r0, r1)
            if own.size:
                i0s, i1s = max(r0 - 1, 0), min(r1 + 1, H)
                samples["transformed"][own] = sample_grid(scratch[i0s:i1s, :], lat[i0s:i1s], lon, clat[own], clon[own])
        n_tiles = tiles.n_tiles
        if level_allowed is not None:
            offset, own_t, shots_t = mean_level_offsets((crad - datum) - samples["transformed"], clat, clon, tiles,
                                                        allowed=level_allowed)
        else:
            offset, own_t, shots_t = np.zeros(n_tiles), np.zeros(n_tiles, bool), np.zeros(n_tiles, np.int64)
        level_on = bool(own_t.any())

        def levelled(rows: slice) -> np.ndarray:
            h = scratch[rows, :]
            if level_on:
                LA, LO = np.meshgrid(lat[rows], lon, indexing="ij")
                h = h + blended_scalar(offset, tiles, LA.ravel(), LO.ravel()).reshape(h.shape)
            return h

        with atomic_store(reg_path, overwrite=overwrite) as reg_tmp, \
                atomic_store(merged_path, overwrite=overwrite) as merged_tmp:
            reg_out = _create_map(reg_tmp, source, {"elevation": (np.float32, elev_attrs)}, reg_attrs, block_rows)
            merged_out = _create_map(merged_tmp, source, {
                "elevation": (np.float32, elev_attrs),
                "altimetry_weight": (np.float32, {"long_name": "weight of the altimetry (0: registered image DEM, "
                                                               "1: altimetry)", "units": "1"}),
                "shot_count": (np.int32, {"long_name": "altimetry shots in the pixel", "units": "1"}),
            }, merged_attrs, block_rows)
            for r0, r1 in blocks:  # pass 2: the level, the merge
                e0, e1 = max(r0 - hm, 0), min(r1 + hm, H)  # the block and the merge's margin
                reg = levelled(slice(e0, e1))
                near = order[np.searchsorted(sorted_rows, e0 - 1):np.searchsorted(sorted_rows, e1 + 1)]
                merged = merge_dem(reg, lat[e0:e1], lon, datum, clat[near], clon[near], crad[near], merge_options)
                core = slice(r0 - e0, r1 - e0)
                reg_out["elevation"][r0:r1, :] = reg[core].astype(np.float32)
                merged_out["elevation"][r0:r1, :] = merged.height[core].astype(np.float32)
                merged_out["altimetry_weight"][r0:r1, :] = merged.altimetry_weight[core]
                merged_out["shot_count"][r0:r1, :] = merged.shot_count[core]
                n_dense += int((merged.shot_count[core] >= merge_options.min_shots_per_pixel).sum())
                own = own_shots(r0, r1)
                if own.size:
                    pla, plo = clat[own], clon[own]
                    samples["registered"][own] = sample_grid(reg, lat[e0:e1], lon, pla, plo)
                    samples["merged"][own] = sample_grid(merged.height, lat[e0:e1], lon, pla, plo)
    level = (MeanLevel(np.zeros((0, 0)), offset, own_t, shots_t) if level_allowed is not None else None)
    return {"samples": samples, "n_dense_pixels": n_dense, "level": level}


def _figure_png(table: pd.DataFrame, profiles: pd.DataFrame) -> bytes:
    """Seed 004's Figure 1: residual RMS per tile (and per profile) before (blue) and after (red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ok = table[table["ok"]].sort_values("tile_id")
    x = np.arange(len(ok))
    ax = axes[0]
    ax.semilogy(x, ok["rms_before_m"], "o", ms=3, color="tab:blue", label="image DEM as given")
    ax.semilogy(x, ok["rms_registered_m"], "s", ms=3, color="tab:orange", label="after tile transform")
    ax.semilogy(x, ok["rms_after_m"], "^", ms=3, color="tab:red", label="after profile offsets")
    ax.set_xlabel("registered tile (by tile id)")
    ax.set_ylabel("RMS shot − DEM residual (m)")
    ax.set_title("per tile")
    ax.legend(fontsize=8)
    ax = axes[1]
    fp = profiles[profiles["fitted"]] if len(profiles) else profiles
    if len(fp):
        k = np.arange(len(fp))
        ax.semilogy(k, fp["rms_before_m"], ".", ms=2, color="tab:blue", label="before profile offset")
        ax.semilogy(k, fp["rms_after_m"], ".", ms=2, color="tab:red", label="after")
        ax.legend(fontsize=8)
    ax.set_xlabel("profile")
    ax.set_title("per profile (registered DEM)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _parquet(df: pd.DataFrame) -> bytes:
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


def register_dem_store(
    dem_path: str | Path,
    shots: pd.DataFrame,
    out_dir: str | Path | None = None,
    client: ComputeClient | None = None,
    *,
    body: Body | None = None,
    options: RegisterOptions | None = None,
    merge_options: MergeOptions | None = None,
    tiles: TileGrid | None = None,
    margin_deg: float = 1.0,
    overwrite: bool = False,
    source: str = "altimetry",
    block_rows: int | None = None,
    block_pixels: float = 4e6,
    other_outputs: Sequence[Path] = (),
    level_to_mean: bool = True,
) -> dict[str, Any]:
    """Register a ``dem.zarr`` onto altimetry shots and merge them; write the results beside it.

    Parameters
    ----------
    dem_path : path of a complete ``dem.zarr``
    shots : DataFrame with :data:`SHOT_COLUMNS` (planetocentric degrees, east degrees, metres from
        the centre of mass, profile id); other columns are ignored
    out_dir : where to write (default: the DEM's directory)
    client : a ``distributed.Client`` or :class:`~mercury_dem.compute.SyncClient`
        (None: the synchronous client)
    body : the body the caller expects; a DEM of another body is refused
    options, merge_options, tiles, margin_deg : the registration's settings, tile grid, window margin
    overwrite : replace existing outputs
    source : name of the shots for messages
    other_outputs : paths the caller will write afterwards (e.g. the products): refused like the
        stage's own outputs when they exist without ``overwrite``, before anything is computed
    block_rows, block_pixels : the registered and merged maps are computed and written this many rows
        at a time (default: as many rows as make ``block_pixels`` pixels, at least 16); memory is
        bounded by the block, not the map (measured at 2880 columns: 0.17 / 0.38 / 0.50 GB traced
        peak with blocks of 10⁵ / 5·10⁵ / 4·10⁶ pixels; docs/benchmarks/altimetry.md)
    level_to_mean : after the tile transforms, level the registered DEM on the corrected shots' mean per
        tile (:func:`mercury_dem.altimetry.merge.mean_level`; the transforms align the median)

    Returns
    -------
    dict
        JSON-able: paths, counts, seconds, ``tiles`` (one summary per tile), and ``statistics``
        (bias/RMSE of the DEM as given, registered and merged against the corrected shots).

    Raises
    ------
    StoreError : no complete DEM, another body's DEM, or outputs exist without ``overwrite``
    ReferenceDataError : the shot table lacks a column or has no usable shot
    """
    from mercury_dem.compute import client_or_sync
    from mercury_dem.products.make import dem_body, open_dem

    t0 = time.perf_counter()
    dem_path = Path(dem_path)
    out = Path(out_dir) if out_dir is not None else dem_path.parent
    reg_path, merged_path, table_dir = out / REGISTERED_FILE, out / MERGED_FILE, out / REGISTRATION_DIR
    ds = open_dem(dem_path)
    dem_b = dem_body(ds)
    if body is not None and body.name != dem_b.name:
        raise StoreError(f"{dem_path} is a DEM of {dem_b.name}, not {body.name}; give the DEM's body (--body "
                         f"{dem_b.name.lower()}) or the right DEM")
    datum = float(ds.attrs.get("datum_radius_m", dem_b.datum_radius_m))
    opt = options or RegisterOptions()
    tiles = tiles or TileGrid(10.0)
    client = client_or_sync(client)
    good, n_bad = check_shots(shots, source)
    if good.empty:
        raise ReferenceDataError(f"{source}: no usable shot ({n_bad} rows with missing or non-finite values)")
    for p in (reg_path, merged_path, table_dir, *other_outputs):  # inputs first, then outputs: the first fault is the input's
        if p.exists() and not overwrite:
            raise StoreError(f"{p} already exists; pass overwrite=True (CLI: --overwrite) to replace it")
    elevation = ds["elevation"]
    lat, lon = ds["lat"].values.astype(np.float64), ds["lon"].values.astype(np.float64)
    H, W = lat.size, lon.size
    rows_per_block = block_rows or max(16, min(H, int(block_pixels // max(W, 1))))
    on_dem = np.isfinite(_sample_blockwise(elevation, lat, lon, good["lat"].to_numpy(), good["lon"].to_numpy(),
                                           rows_per_block))
    good["tile_id"] = tiles.tile_of(good["lat"].to_numpy(), good["lon"].to_numpy())
    tiles_with = np.unique(good["tile_id"].to_numpy()[on_dem])
    groups = {int(k): g for k, g in good[good["tile_id"].isin(tiles_with)].groupby("tile_id")}
    run_key = uuid.uuid4().hex[:8]
    futures = [
        client.submit(_tile_task, str(dem_path), tid, tiles.tile_size_deg, g["lat"].to_numpy(), g["lon"].to_numpy(),
                      g["radius_m"].to_numpy(), g["track_id"].to_numpy(), opt, margin_deg,
                      key=f"register-tile-{tid}-{run_key}", pure=False)
        for tid, g in groups.items()
    ]
    results: list[TileRegistration] = client.gather(futures)
    t_tiles = time.perf_counter() - t0
    transforms = [r.transform for r in results]
    profiles = ProfileOffsets.concat([r.profiles for r in results])
    clat, clon, crad = _corrected_shots(good, profiles, tiles, datum)
    allowed = np.zeros(tiles.n_tiles, bool)  # tiles that may level themselves: those with a transform
    allowed[[t.tile_id for t in transforms if t.ok]] = True

    table = pd.DataFrame([r.summary() for r in results]) if results else pd.DataFrame(
        columns=["tile_id", "ok", "rms_before_m", "rms_registered_m", "rms_after_m"])
    pf = profiles.to_frame()
    elev_attrs = dict(elevation.attrs)
    elev_attrs.pop("grid_mapping", None)
    note = {"registration": json.dumps({"source": source, "tile_size_deg": tiles.tile_size_deg,
                                        "options": opt.__dict__ | {"models": list(opt.models)}})}
    mo = merge_options or MergeOptions()
    maps = _register_and_merge_blockwise(
        elevation, lat, lon, datum, transforms, tiles, mo, (clat, clon, crad), rows_per_block,
        allowed if level_to_mean else None, reg_path, merged_path, ds, elev_attrs,
        {"title": f"{dem_b.name.title()} image DEM registered to laser altimetry (per-tile affine)", **note},
        {"title": f"{dem_b.name.title()} DEM merged from laser altimetry and the registered image DEM", **note,
         "merge": json.dumps(mo.__dict__)}, overwrite)
    names = ("as_given", "transformed", "registered", "merged") if level_to_mean else ("as_given", "registered", "merged")
    stats = {name: compare_heights(maps["samples"][name], datum_radius_m=datum, reference_radius_m=crad)
             for name in names}  # "transformed": the tile transforms alone, before the mean level
    summary: dict[str, Any] = {
        "dem": str(dem_path), "registered": str(reg_path), "merged": str(merged_path), "tables": str(table_dir),
        "body": dem_b.name, "shots": int(len(shots)), "shots_dropped_invalid": n_bad,
        "shots_off_dem": int((~on_dem).sum()), "tiles_with_shots": len(results),
        "tiles_registered": int(sum(r.transform.ok for r in results)),
        "profiles": int(len(pf)), "profiles_fitted": int(pf["fitted"].sum()) if len(pf) else 0,
        "merged_dense_pixels": maps["n_dense_pixels"], "statistics": stats, "block_rows": rows_per_block,
        "mean_level": maps["level"].summary() if maps["level"] is not None else None,
        "seconds_tiles": t_tiles, "seconds": time.perf_counter() - t0,
        "tiles": [_jsonable(r.summary()) for r in results],
    }
    write_registration_tables(table_dir, tiles_parquet=_parquet(table), tiles=summary["tiles"],
                              profiles_parquet=_parquet(pf), figure_png=_figure_png(table, pf),
                              summary=_jsonable({k: v for k, v in summary.items() if k != "tiles"}), overwrite=overwrite)
    summary["seconds"] = time.perf_counter() - t0
    return summary


def make_registration_products(out_dir: str | Path, products_dir: str | Path, config: Config | DemConfig, *,
                               overwrite: bool = False) -> dict[str, Any]:
    """The products of ``registered.zarr`` and ``merged.zarr`` (written by :func:`register_dem_store`).

    Each map gets what the adjusted DEM gets (:func:`mercury_dem.products.make.make_products`:
    ``dem.tif`` COG, ``pds/*.tif`` with their PDS4 labels, ``isis/dem_radius.cub``, browse PNGs,
    statistics) in ``products_dir/registered/`` and ``products_dir/merged/``; the before/after
    RMS figure is copied to ``products_dir/registration/rms_per_tile.png``.

    Parameters
    ----------
    out_dir : the directory holding ``registered.zarr``, ``merged.zarr`` and ``registration/``
    products_dir : e.g. ``RUN/products``
    config : Config or DemConfig (the products' settings)
    overwrite : replace existing product files

    Returns
    -------
    dict: ``files`` (every file written), and per map (``registered``, ``merged``) its
    products' ``statistics``, ``skipped``, ``pds``, ``isis``, ``files`` and ``seconds`` entries
    (as :func:`~mercury_dem.products.make.make_products` returns them).
    """
    from mercury_dem.products.make import make_products

    out, prod = Path(out_dir), Path(products_dir)
    fig = out / REGISTRATION_DIR / REGISTRATION_FIGURE
    fig_out = prod / REGISTRATION_DIR / REGISTRATION_FIGURE
    if fig_out.exists() and not overwrite:
        raise StoreError(f"product {fig_out} already exists; pass --overwrite (overwrite=True) to replace it")
    summary: dict[str, Any] = {"files": []}
    for key, what in REGISTRATION_PRODUCTS.items():
        res = make_products(out / REGISTRATION_MAPS[key], prod / key, config, overwrite=overwrite, coverage=False, name=what)
        summary[key] = {k: res.get(k) for k in ("statistics", "skipped", "seconds", "pds", "isis", "files")}
        summary["files"] += res["files"]
    fig_out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(fig_out, fig.read_bytes())
    summary["files"].append(str(fig_out))
    return summary
