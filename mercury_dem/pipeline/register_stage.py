"""The registration stage: a ``dem.zarr`` + altimetry shots → ``registered.zarr``, ``merged.zarr``, tables, figure.

How it runs
-----------
1. The shots are checked (columns ``lat``, ``lon``, ``radius_m``, ``profile_id``; rows with
   non-finite values dropped and counted) and split by tile of the run's grid (:class:`TileGrid` of
   ``tiling.tile_size_deg``).
2. One task per tile holding shots on the DEM (:func:`mercury_dem.altimetry.register.register_tile`);
   a task reads its own DEM window from the store (the store path travels, not the map) and
   gets its tile's shots. Tasks go through the client the caller passes (the synchronous
   in-process client by default, a ``distributed.Client`` on a cluster: the same results). An
   unexpected exception in a tile becomes that tile's failure (``ok = False``, the error),
   and the stage goes on.
3. In this process, one block of rows at a time (``registration.block_pixels``; by default about 4·10⁶
   pixels): :func:`mercury_dem.altimetry.register_map.register_and_merge_blockwise` registers, levels
   and merges the map (its docstring), reading the DEM's rows from the store and handing back each
   finished block, which is written into the two stores. Memory is that of a block, not of the map
   (before: ~120 B per map pixel measured, ~40 GB for a global 64 ppd DEM). Every constant of the
   stage is the ``registration`` configuration section's (``mercury-dem config --template``).
4. Written atomically beside the DEM: ``registered.zarr`` and ``merged.zarr`` (the DEM's
   coordinates, CRS and attributes; ``merged.zarr`` adds ``altimetry_weight`` and
   ``shot_count``), and ``registration/``: ``tiles.parquet`` + ``tiles.json`` (one row per
   tile), ``profiles.parquet`` (one row per profile), ``rms_per_tile.png`` (seed 004's
   Figure 1, :func:`mercury_dem.products.registration_figure.rms_per_tile_png`) and ``summary.json``.

:func:`register_dem_store` is the one function ``run`` calls.
"""

from __future__ import annotations

import io
import json
import time
import traceback
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import xarray as xr

from mercury_dem.altimetry.merge import MergedDem, MergeOptions
from mercury_dem.altimetry.names import upgrade_columns
from mercury_dem.altimetry.register import (
    ProfileOffsets,
    RegisterOptions,
    TileRegistration,
    TileTransform,
    register_tile,
    tile_window,
)
from mercury_dem.altimetry.register_map import (
    SAMPLE_NAMES,
    BlockwiseMaps,
    ShotPositions,
    corrected_shots,
    level_allowed_tiles,
    register_and_merge_blockwise,
    rows_per_block,
    sample_blockwise,
)
from mercury_dem.config.registration import RegistrationConfig
from mercury_dem.config.tiling import TilingConfig
from mercury_dem.dem.store_schema import layer_compressors
from mercury_dem.exceptions import ReferenceDataError, StoreError
from mercury_dem.geometry.body import Body
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
from mercury_dem.products.registration_figure import rms_per_tile_png
from mercury_dem.reference.compare import compare_heights

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient
    from mercury_dem.config import Config
    from mercury_dem.config.dem import DemConfig

__all__ = ["REGISTRATION_PRODUCTS", "SHOT_COLUMNS", "check_shots", "make_registration_products", "register_dem_store"]

#: Columns a shot table must have (``reference.lola.read_altimetry_csv`` gives them).
SHOT_COLUMNS = ("lat", "lon", "radius_m", "profile_id")
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
    shots = upgrade_columns(shots, source)  # a shot file may carry the old name track_id
    missing = [c for c in SHOT_COLUMNS if c not in shots.columns]
    if missing:
        raise ReferenceDataError(
            f"{source}: no column {', '.join(missing)} among {list(shots.columns)[:20]}; a shot table needs "
            f"{', '.join(SHOT_COLUMNS)} (read RDR CSVs with mercury_dem.reference.lola.read_altimetry_csv)")
    try:
        lat, lon, rad = (shots[c].to_numpy(dtype=np.float64) for c in ("lat", "lon", "radius_m"))
        profile = shots["profile_id"].to_numpy()
        ok_profile = np.isfinite(profile.astype(np.float64))
    except (TypeError, ValueError) as exc:
        raise ReferenceDataError(f"{source}: lat, lon, radius_m and profile_id must be numbers ({exc})") from None
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(rad) & (np.abs(lat) <= 90.0) & ok_profile
    out = pd.DataFrame({"lat": lat[ok], "lon": lon[ok], "radius_m": rad[ok],
                        "profile_id": profile[ok].astype(np.int64)})
    return out, int((~ok).sum())


def _tile_task(dem_path: str, tile_id: int, tile_size_deg: float, lat: np.ndarray, lon: np.ndarray,
               radius: np.ndarray, profile: np.ndarray, options: RegisterOptions, margin_deg: float) -> TileRegistration:
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
        return register_tile(win, lat, lon, radius, profile, tile_id=tile_id, centre=(lat_c, lon_c), options=options)
    except Exception as exc:  # noqa: BLE001 - a tile's failure is a value; the stage goes on
        reason = f"tile {tile_id}: {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}"
        return TileRegistration(TileTransform(tile_id, lat_c, lon_c, float("nan"), reason=reason),
                                ProfileOffsets.empty(), {"shots": int(np.size(lat))})


def _create_map(path: Path, source: xr.Dataset, layers: dict[str, tuple[Any, dict[str, Any]]],
                attrs: dict[str, Any], block_rows: int, chunk_columns: int) -> dict[str, Any]:
    """An empty map store with the DEM's coordinates, CRS and attributes (``dem.zarr`` conventions).

    ``layers``: name → (dtype, attributes). The arrays' Zarr chunks are ``block_rows`` rows by up to
    ``chunk_columns`` columns, so each block of :func:`register_dem_store` writes whole chunks. Returns the open
    Zarr arrays, for region writes.
    """
    import zarr

    from mercury_dem.compute.lazy import lazy_full

    H, W = source.sizes["lat"], source.sizes["lon"]
    cs = (max(min(block_rows, H), 1), max(min(chunk_columns, W), 1))
    data_vars = {}
    for name, (dtype, var_attrs) in layers.items():
        fill = np.nan if np.dtype(dtype).kind == "f" else 0
        data_vars[name] = xr.Variable(("lat", "lon"), lazy_full((H, W), fill, dtype, cs), attrs=var_attrs)
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


def _parquet(df: pd.DataFrame) -> bytes:
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


@dataclass(frozen=True)
class _Outputs:
    """Where the stage writes: the two maps and the tables' directory."""

    registered: Path
    merged: Path
    tables: Path

    @classmethod
    def beside(cls, out: Path) -> _Outputs:
        return cls(out / REGISTERED_FILE, out / MERGED_FILE, out / REGISTRATION_DIR)


def _open_dem_of(dem_path: Path, body: Body | None) -> tuple[xr.Dataset, Body, float]:
    """The complete DEM, its body (refused when not ``body``) and its datum radius."""
    from mercury_dem.products.make import dem_body, open_dem

    ds = open_dem(dem_path)
    dem_b = dem_body(ds)
    if body is not None and body.name != dem_b.name:
        raise StoreError(f"{dem_path} is a DEM of {dem_b.name}, not {body.name}; give the DEM's body (--body "
                         f"{dem_b.name.lower()}) or the right DEM")
    return ds, dem_b, float(ds.attrs.get("datum_radius_m", dem_b.datum_radius_m))


def _usable_shots(shots: pd.DataFrame, source: str, outputs: Sequence[Path], overwrite: bool) -> tuple[pd.DataFrame, int]:
    """:func:`check_shots`, refusing a table without a usable shot, then outputs that exist without ``overwrite``
    (inputs first: the first fault reported is the input's).
    """
    good, n_bad = check_shots(shots, source)
    if good.empty:
        raise ReferenceDataError(f"{source}: no usable shot ({n_bad} rows with missing or non-finite values)")
    for p in outputs:
        if p.exists() and not overwrite:
            raise StoreError(f"{p} already exists; pass overwrite=True (CLI: --overwrite) to replace it")
    return good, n_bad


def _register_tiles(client: ComputeClient | None, dem_path: Path, good: pd.DataFrame, on_dem: np.ndarray, tiles: TileGrid,
                    opt: RegisterOptions, margin_deg: float) -> list[TileRegistration]:
    """One task per tile holding shots on the DEM (:func:`_tile_task`), through ``client``."""
    tiles_with = np.unique(good["tile_id"].to_numpy()[on_dem])
    groups = {int(k): g for k, g in good[good["tile_id"].isin(tiles_with)].groupby("tile_id")}
    run_key = uuid.uuid4().hex[:8]
    futures = [
        client.submit(_tile_task, str(dem_path), tid, tiles.tile_size_deg, g["lat"].to_numpy(), g["lon"].to_numpy(),
                      g["radius_m"].to_numpy(), g["profile_id"].to_numpy(), opt, margin_deg,
                      key=f"register-tile-{tid}-{run_key}", pure=False)
        for tid, g in groups.items()
    ]
    results: list[TileRegistration] = client.gather(futures)
    return results


def _merged_layers(elev_attrs: dict[str, Any]) -> dict[str, tuple[Any, dict[str, Any]]]:
    return {"elevation": (np.float32, elev_attrs),
            "altimetry_weight": (np.float32, {"long_name": "weight of the altimetry (0: registered image DEM, "
                                                           "1: altimetry)", "units": "1"}),
            "shot_count": (np.int32, {"long_name": "altimetry shots in the pixel", "units": "1"})}


def _maps_attrs(dem_b: Body, source: str, tiles: TileGrid, opt: RegisterOptions, mo: MergeOptions
                ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The root attributes of ``registered.zarr`` and ``merged.zarr`` (beside the DEM's own)."""
    note = {"registration": json.dumps({"source": source, "tile_size_deg": tiles.tile_size_deg,
                                        "options": opt.__dict__ | {"models": list(opt.models)}})}
    return ({"title": f"{dem_b.name.title()} image DEM registered to laser altimetry (per-tile affine)", **note},
            {"title": f"{dem_b.name.title()} DEM merged from laser altimetry and the registered image DEM", **note,
             "merge": json.dumps(mo.__dict__)})


def _register_and_write_maps(ds: xr.Dataset, dem_b: Body, datum: float, transforms: list[TileTransform],
                             tiles: TileGrid, shots: ShotPositions, level_allowed: np.ndarray | None,
                             block_rows: int, st: RegistrationConfig, opt: RegisterOptions, out: _Outputs,
                             source: str, overwrite: bool) -> BlockwiseMaps:
    """Load → :func:`~mercury_dem.altimetry.register_map.register_and_merge_blockwise` → save: the DEM read by
    rows, the transformed map kept in a float64 scratch store, each block written into ``registered.zarr`` and
    ``merged.zarr`` (both built under temporary names, renamed when every block is in).
    """
    import tempfile

    import zarr

    mo = MergeOptions(min_shots_per_pixel=st.min_shots_per_pixel, gap_px=st.gap_px, feather_px=st.feather_px)
    elevation = ds["elevation"]
    lat, lon = ds["lat"].values.astype(np.float64), ds["lon"].values.astype(np.float64)
    elev_attrs = dict(elevation.attrs)
    elev_attrs.pop("grid_mapping", None)
    reg_attrs, merged_attrs = _maps_attrs(dem_b, source, tiles, opt, mo)
    out.registered.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".register-scratch-", dir=out.registered.parent) as scratch_dir, \
            atomic_store(out.registered, overwrite=overwrite) as reg_tmp, \
            atomic_store(out.merged, overwrite=overwrite) as merged_tmp:
        scratch = zarr.create_array(str(Path(scratch_dir) / REGISTRATION_SCRATCH_FILE), shape=(lat.size, lon.size),
                                    chunks=(block_rows, lon.size), dtype=np.float64, fill_value=np.nan,
                                    compressors=None)
        reg_out = _create_map(reg_tmp, ds, {"elevation": (np.float32, elev_attrs)}, reg_attrs, block_rows,
                              st.chunk_columns)
        merged_out = _create_map(merged_tmp, ds, _merged_layers(elev_attrs), merged_attrs, block_rows, st.chunk_columns)

        def write(r0: int, r1: int, registered: np.ndarray, merged: MergedDem) -> None:
            reg_out["elevation"][r0:r1, :] = registered.astype(np.float32)
            merged_out["elevation"][r0:r1, :] = merged.height.astype(np.float32)
            merged_out["altimetry_weight"][r0:r1, :] = merged.altimetry_weight
            merged_out["shot_count"][r0:r1, :] = merged.shot_count

        return register_and_merge_blockwise(
            lambda i0, i1: elevation[i0:i1].values.astype(np.float64), lat, lon, datum, transforms, tiles, shots,
            scratch=scratch, write=write, block_rows=block_rows, merge_options=mo, level_allowed=level_allowed,
            surface_height_m=st.max_surface_height_m, level_min_shots=st.level_min_shots,
            level_clip_nmad=st.level_clip_nmad)


def _stage_summary(results: list[TileRegistration], profiles: pd.DataFrame, maps: BlockwiseMaps,
                   shots: ShotPositions, datum: float, level_to_mean: bool, block_rows: int) -> dict[str, Any]:
    """The counts and statistics of the summary that come from the tiles and the maps."""
    names = SAMPLE_NAMES if level_to_mean else tuple(n for n in SAMPLE_NAMES if n != "transformed")
    stats = {name: compare_heights(maps.samples[name], datum_radius_m=datum, reference_radius_m=shots.radius_m)
             for name in names}  # "transformed": the tile transforms alone, before the mean level
    return {"tiles_with_shots": len(results), "tiles_registered": int(sum(r.transform.ok for r in results)),
            "profiles": int(len(profiles)), "profiles_fitted": int(profiles["fitted"].sum()) if len(profiles) else 0,
            "merged_dense_pixels": maps.n_dense_pixels, "statistics": stats, "block_rows": block_rows,
            "mean_level": maps.level.summary() if maps.level is not None else None}


def transform_record(transforms: list[TileTransform], tiles: TileGrid, maps: BlockwiseMaps) -> dict[str, Any]:
    """The transform the maps got, JSON-able (``registration/transform.json``): the tiles' blended table
    (:func:`~mercury_dem.altimetry.merge.transform_table`) and the mean level's per-tile offsets (or None), so
    the dense stage moves its points as the registered map was moved
    (:func:`~mercury_dem.altimetry.merge.register_points`).
    """
    from mercury_dem.altimetry.merge import transform_table

    table, own = transform_table(transforms, tiles)
    level = maps.level
    return {"tile_size_deg": tiles.tile_size_deg, "table": table.tolist(), "own": own.tolist(),
            "level_offset_m": level.offset_m.tolist() if level is not None else None}


def _write_tables(out: _Outputs, results: list[TileRegistration], profiles: pd.DataFrame, summary: dict[str, Any],
                  overwrite: bool, transform: dict[str, Any] | None = None) -> None:
    """``registration/``: the tiles' and profiles' tables, the figure, ``summary.json`` and ``transform.json``."""
    table = pd.DataFrame([r.summary() for r in results]) if results else pd.DataFrame(
        columns=["tile_id", "ok", "rms_before_m", "rms_registered_m", "rms_after_m"])
    write_registration_tables(out.tables, tiles_parquet=_parquet(table), tiles=summary["tiles"],
                              profiles_parquet=_parquet(profiles), figure_png=rms_per_tile_png(table, profiles),
                              summary=_jsonable({k: v for k, v in summary.items() if k != "tiles"}), overwrite=overwrite,
                              transform=transform)


def register_dem_store(
    dem_path: str | Path, shots: pd.DataFrame, out_dir: str | Path | None = None, client: ComputeClient | None = None, *,
    body: Body | None = None, options: RegisterOptions | None = None, settings: RegistrationConfig | None = None,
    tiles: TileGrid | None = None, overwrite: bool = False, source: str = "altimetry", block_rows: int | None = None,
    other_outputs: Sequence[Path] = (), level_to_mean: bool = True,
) -> dict[str, Any]:
    """Register a ``dem.zarr`` onto altimetry shots (:data:`SHOT_COLUMNS`) and merge them; write the results in
    ``out_dir`` (default: beside the DEM). Steps: the module docstring.

    ``client``: a ``distributed.Client`` or the synchronous client (None); ``body``: a DEM of another body is
    refused; ``options``: the tiles' fit; ``settings``: the ``registration`` configuration section (margins,
    blocks, chunks, the merge); ``tiles``: the tile grid (default: the configuration's ``tiling.tile_size_deg``);
    ``block_rows``: overrides ``settings.block_pixels``; ``other_outputs``: paths the caller writes afterwards,
    refused like the stage's own when they exist without ``overwrite``; ``level_to_mean``: level the
    registered DEM on the corrected shots' mean per tile. Returns a JSON-able summary (paths, counts, seconds,
    one entry per tile, bias/RMSE against the corrected shots). Raises :class:`StoreError` (no complete DEM,
    another body's, outputs exist) or :class:`ReferenceDataError` (a missing column, no usable shot).
    """
    from mercury_dem.compute import client_or_sync

    t0 = time.perf_counter()
    st = settings or RegistrationConfig()
    opt = options or RegisterOptions.from_config(st)
    tiles = tiles or TileGrid(TilingConfig().tile_size_deg)
    out = _Outputs.beside(Path(out_dir) if out_dir is not None else Path(dem_path).parent)
    ds, dem_b, datum = _open_dem_of(Path(dem_path), body)
    good, n_bad = _usable_shots(shots, source, (out.registered, out.merged, out.tables, *other_outputs), overwrite)
    lat, lon = ds["lat"].values.astype(np.float64), ds["lon"].values.astype(np.float64)
    rows = block_rows or rows_per_block(lat.size, lon.size, st.block_pixels, st.min_block_rows)
    on_dem = np.isfinite(sample_blockwise(lambda i0, i1: ds["elevation"][i0:i1].values.astype(np.float64), lat, lon,
                                          good["lat"].to_numpy(), good["lon"].to_numpy(), rows))
    good["tile_id"] = tiles.tile_of(good["lat"].to_numpy(), good["lon"].to_numpy())
    results = _register_tiles(client_or_sync(client), Path(dem_path), good, on_dem, tiles, opt, st.window_margin_deg)
    t_tiles = time.perf_counter() - t0
    transforms = [r.transform for r in results]
    profiles = ProfileOffsets.concat([r.profiles for r in results])
    corrected = corrected_shots(good, profiles, datum)
    allowed = level_allowed_tiles(transforms, tiles.n_tiles) if level_to_mean else None
    maps = _register_and_write_maps(ds, dem_b, datum, transforms, tiles, corrected, allowed, rows, st, opt, out,
                                    source, overwrite)
    pf = profiles.to_frame()
    summary: dict[str, Any] = {
        "dem": str(dem_path), "registered": str(out.registered), "merged": str(out.merged), "tables": str(out.tables),
        "body": dem_b.name, "shots": int(len(shots)), "shots_dropped_invalid": n_bad,
        "shots_off_dem": int((~on_dem).sum()), **_stage_summary(results, pf, maps, corrected, datum, level_to_mean, rows),
        "seconds_tiles": t_tiles, "seconds": time.perf_counter() - t0,
        "tiles": [_jsonable(r.summary()) for r in results],
    }
    _write_tables(out, results, pf, summary, overwrite, transform_record(transforms, tiles, maps))
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
