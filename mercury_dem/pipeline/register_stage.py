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
3. In this process: the registered DEM (:func:`mercury_dem.altimetry.merge.register_dem`),
   the shots corrected by their profile offsets, the merged DEM
   (:func:`mercury_dem.altimetry.merge.merge_dem`). These hold the map in memory (about
   60 B per pixel at the peak): fine for the global DEMs of a modest resolution this is for
   (8 ppd: 4·10⁶ pixels); a chunked version is future work.
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
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

from mercury_dem.altimetry.merge import MergeOptions, mean_level, merge_dem, register_dem
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
from mercury_dem.io.atomic import atomic_directory, atomic_write_bytes, atomic_write_json
from mercury_dem.reference.compare import compare_heights
from mercury_dem.reference.sampling import sample_grid

__all__ = ["SHOT_COLUMNS", "check_shots", "register_dem_store"]

#: Columns a shot table must have (``reference.lola.read_altimetry_csv`` gives them).
SHOT_COLUMNS = ("lat", "lon", "radius_m", "track_id")
REGISTRATION_DIR = "registration"


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


def _write_map(path: Path, source: xr.Dataset, layers: dict[str, tuple[np.ndarray, dict[str, Any]]],
               attrs: dict[str, Any], overwrite: bool) -> None:
    """A map store with the DEM's coordinates, CRS and attributes (``dem.zarr`` conventions)."""
    from mercury_dem.pipeline.dem_stage import atomic_store, layer_compressors

    data_vars = {}
    for name, (values, var_attrs) in layers.items():
        data_vars[name] = xr.Variable(("lat", "lon"), values, attrs=var_attrs)
    ds = xr.Dataset(data_vars, coords={"lat": source["lat"], "lon": source["lon"],
                                       "spatial_ref": source["spatial_ref"]})
    cs = min(1024, max(ds.sizes["lat"], 1)), min(1024, max(ds.sizes["lon"], 1))
    for name in layers:
        ds[name].encoding.update({"chunks": cs, "grid_mapping": "spatial_ref", "compressors": layer_compressors()})
        ds[name].attrs.pop("grid_mapping", None)
    ds.attrs.update({k: v for k, v in source.attrs.items() if k != "complete"})
    ds.attrs.update(attrs)
    with atomic_store(path, overwrite=overwrite) as tmp:
        ds.to_zarr(str(tmp), mode="w", consolidated=False, zarr_format=3)


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
    client: Any = None,
    *,
    body: Body | None = None,
    options: RegisterOptions | None = None,
    merge_options: MergeOptions | None = None,
    tiles: TileGrid | None = None,
    margin_deg: float = 1.0,
    overwrite: bool = False,
    source: str = "altimetry",
    level_to_mean: bool = True,
) -> dict[str, Any]:
    """Register a ``dem.zarr`` onto altimetry shots and merge them; write the results beside it.

    Parameters
    ----------
    dem_path : path of a complete ``dem.zarr``
    shots : DataFrame with :data:`SHOT_COLUMNS` (planetocentric degrees, east degrees, metres from
        the centre of mass, profile id); other columns are ignored
    out_dir : where to write (default: the DEM's directory)
    client : a ``distributed.Client`` or :class:`~mercury_dem.pipeline.executors.SyncClient`
        (None: the synchronous client)
    body : the body the caller expects; a DEM of another body is refused
    options, merge_options, tiles, margin_deg : the registration's settings, tile grid, window margin
    overwrite : replace existing outputs
    source : name of the shots for messages
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
    from mercury_dem.pipeline.executors import SyncClient
    from mercury_dem.products.make import dem_body, open_dem

    t0 = time.perf_counter()
    dem_path = Path(dem_path)
    out = Path(out_dir) if out_dir is not None else dem_path.parent
    reg_path, merged_path, table_dir = out / "registered.zarr", out / "merged.zarr", out / REGISTRATION_DIR
    ds = open_dem(dem_path)
    dem_b = dem_body(ds)
    if body is not None and body.name != dem_b.name:
        raise StoreError(f"{dem_path} is a DEM of {dem_b.name}, not {body.name}; give the DEM's body (--body "
                         f"{dem_b.name.lower()}) or the right DEM")
    datum = float(ds.attrs.get("datum_radius_m", dem_b.datum_radius_m))
    opt = options or RegisterOptions()
    tiles = tiles or TileGrid(10.0)
    client = client or SyncClient()
    good, n_bad = check_shots(shots, source)
    if good.empty:
        raise ReferenceDataError(f"{source}: no usable shot ({n_bad} rows with missing or non-finite values)")
    for p in (reg_path, merged_path, table_dir):  # inputs first, then outputs: the first fault is the input's
        if p.exists() and not overwrite:
            raise StoreError(f"{p} already exists; pass overwrite=True (CLI: --overwrite) to replace it")
    elev = ds["elevation"].values.astype(np.float64)
    lat, lon = ds["lat"].values, ds["lon"].values
    on_dem = np.isfinite(sample_grid(elev, lat, lon, good["lat"].to_numpy(), good["lon"].to_numpy()))
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
    registered = register_dem(elev, lat, lon, datum, transforms, tiles)
    profiles = ProfileOffsets.concat([r.profiles for r in results])
    clat, clon, crad = _corrected_shots(good, profiles, tiles, datum)
    level = None
    if level_to_mean:
        allowed = np.zeros(tiles.n_tiles, bool)
        allowed[[t.tile_id for t in transforms if t.ok]] = True
        level = mean_level(registered, lat, lon, datum, clat, clon, crad, tiles, allowed=allowed)
        transformed, registered = registered, level.height
    merged = merge_dem(registered, lat, lon, datum, clat, clon, crad, merge_options)

    table = pd.DataFrame([r.summary() for r in results]) if results else pd.DataFrame(
        columns=["tile_id", "ok", "rms_before_m", "rms_registered_m", "rms_after_m"])
    pf = profiles.to_frame()
    stats = {}
    grids = [("as_given", elev), ("registered", registered), ("merged", merged.height)]
    if level is not None:  # the tile transforms alone, before the mean level
        grids.insert(1, ("transformed", transformed))
    for name, grid in grids:
        h = sample_grid(grid, lat, lon, clat, clon)
        stats[name] = compare_heights(h, datum_radius_m=datum, reference_radius_m=crad)
    elev_attrs = dict(ds["elevation"].attrs)
    elev_attrs.pop("grid_mapping", None)
    note = {"registration": json.dumps({"source": source, "tile_size_deg": tiles.tile_size_deg,
                                        "options": opt.__dict__ | {"models": list(opt.models)}})}
    _write_map(reg_path, ds, {"elevation": (registered.astype(np.float32), elev_attrs)},
               {"title": f"{dem_b.name.title()} image DEM registered to laser altimetry (per-tile affine)", **note},
               overwrite)
    mo = merge_options or MergeOptions()
    _write_map(merged_path, ds, {
        "elevation": (merged.height.astype(np.float32), elev_attrs),
        "altimetry_weight": (merged.altimetry_weight, {"long_name": "weight of the altimetry (0: registered image "
                                                       "DEM, 1: altimetry)", "units": "1"}),
        "shot_count": (merged.shot_count, {"long_name": "altimetry shots in the pixel", "units": "1"}),
    }, {"title": f"{dem_b.name.title()} DEM merged from laser altimetry and the registered image DEM", **note,
        "merge": json.dumps(mo.__dict__)}, overwrite)
    summary: dict[str, Any] = {
        "dem": str(dem_path), "registered": str(reg_path), "merged": str(merged_path), "tables": str(table_dir),
        "body": dem_b.name, "shots": int(len(shots)), "shots_dropped_invalid": n_bad,
        "shots_off_dem": int((~on_dem).sum()), "tiles_with_shots": len(results),
        "tiles_registered": int(sum(r.transform.ok for r in results)),
        "profiles": int(len(pf)), "profiles_fitted": int(pf["fitted"].sum()) if len(pf) else 0,
        "merged_dense_pixels": merged.n_dense_pixels, "statistics": stats,
        "mean_level": level.summary() if level is not None else None,
        "seconds_tiles": t_tiles, "seconds": time.perf_counter() - t0,
        "tiles": [_jsonable(r.summary()) for r in results],
    }
    with atomic_directory(table_dir, overwrite=overwrite) as tmp:
        atomic_write_bytes(tmp / "tiles.parquet", _parquet(table))
        atomic_write_json(tmp / "tiles.json", summary["tiles"])
        atomic_write_bytes(tmp / "profiles.parquet", _parquet(pf))
        atomic_write_bytes(tmp / "rms_per_tile.png", _figure_png(table, pf))
        atomic_write_json(tmp / "summary.json", _jsonable({k: v for k, v in summary.items() if k != "tiles"}))
    summary["seconds"] = time.perf_counter() - t0
    return summary


def _jsonable(obj: Any) -> Any:
    """NaN → None and numpy scalars → Python, recursively (strict JSON)."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return None if not math.isfinite(float(obj)) else float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
