"""``mercury-dem register DIR --altimetry FILE...``: register DIR/dem.zarr onto laser altimetry and merge.

DIR is any directory holding a ``dem.zarr`` (a run, or ``mercury-dem grid --out``). FILE is a
LOLA/MLA RDR shot table (CSV, read by :func:`mercury_dem.reference.lola.read_altimetry_csv`)
or a Parquet table with the columns ``lat``, ``lon``, ``radius_m`` (metres from the centre of
mass) and ``profile_id``. Writes ``DIR/registered.zarr``, ``DIR/merged.zarr`` and
``DIR/registration/`` (per-tile and per-profile tables, the RMS figure), and unless
``--no-products`` the products of the registered and merged DEMs in ``DIR/products/registered/``
and ``DIR/products/merged/`` (as the adjusted DEM's: GeoTIFF, PDS4-labelled PDS GeoTIFFs, ISIS
cube, browse PNGs) and the figure in ``DIR/products/registration/``; see docs/design/altimetry.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from mercury_dem.config import Config
from mercury_dem.exceptions import ConfigError, ReferenceDataError

NAME = "register"
HELP = "register DIR/dem.zarr onto altimetry shots (per-tile affine + per-profile offsets) and merge them"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", metavar="DIR", help="directory holding dem.zarr (a run directory or 'grid --out')")
    p.add_argument("--altimetry", nargs="+", required=True, metavar="FILE",
                   help="shot tables: LOLA/MLA RDR CSV, or Parquet with lat, lon, radius_m, profile_id (track_id, its old name, is read too)")
    p.add_argument("--body", metavar="NAME", help="the DEM's body (mercury, moon); checked against the DEM")
    p.add_argument("--scheduler", default="sync", metavar="ADDR",
                   help="sync (default, in-process), local (a LocalCluster) or a scheduler address")
    p.add_argument("--overwrite", action="store_true", help="replace existing registered/merged outputs")
    p.add_argument("--no-products", action="store_true",
                   help="skip the products of the registered and merged DEMs (DIR/products/registered, merged: "
                        "GeoTIFF, PDS4, ISIS cube, browse; DIR/products/registration/rms_per_tile.png)")
    p.add_argument("--json", action="store_true", help="print the per-tile results as JSON")


def read_shots(paths: list[str], radius_m: float) -> Any:
    """All shot tables as one DataFrame; profile ids made unique across files."""
    import numpy as np
    import pandas as pd

    from mercury_dem.altimetry.names import upgrade_columns
    from mercury_dem.reference.lola import read_altimetry_csv

    frames = []
    next_profile = 0
    for p in paths:
        path = Path(p)
        if path.suffix.lower() in (".parquet", ".pq"):
            import pyarrow

            try:
                df = pd.read_parquet(path)
            except (OSError, ValueError, TypeError, KeyError, pyarrow.ArrowException) as exc:
                raise ReferenceDataError(f"{path}: cannot be read as Parquet ({type(exc).__name__}: {exc}); "
                                         f"write it with pandas.DataFrame.to_parquet") from None
        else:
            df = read_altimetry_csv(path, radius_m).table
        df = upgrade_columns(df, str(path))  # a user's file may carry the old name track_id
        if "profile_id" in df.columns and len(df):
            tid = pd.to_numeric(df["profile_id"], errors="coerce")
            df = df.assign(profile_id=tid + next_profile)
            if np.isfinite(tid).any():
                next_profile = int(np.nanmax(df["profile_id"])) + 1
        frames.append(df)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.compute import connect
    from mercury_dem.geometry.body import body_by_name
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.io.atomic import strict_json
    from mercury_dem.io.run_store import DEM_FILE, PRODUCTS_DIR, REGISTRATION_DIR
    from mercury_dem.pipeline.register_stage import register_dem_store
    from mercury_dem.products.make import dem_body, open_dem

    dem_path = Path(args.dir) / DEM_FILE
    body = None
    if args.body:
        try:
            body = body_by_name(args.body)
        except ValueError as exc:
            raise ConfigError(f"--body: {exc}") from None
    ds_body = dem_body(open_dem(dem_path))
    products_dir = Path(args.dir) / PRODUCTS_DIR
    shots = read_shots(args.altimetry, ds_body.datum_radius_m)
    conn = connect(config.execution, scheduler=args.scheduler)
    try:
        from mercury_dem.pipeline.register_stage import REGISTRATION_PRODUCTS

        summary = register_dem_store(
            dem_path, shots, client=conn.client, body=body, overwrite=args.overwrite, source=", ".join(args.altimetry),
            settings=config.registration, tiles=TileGrid(config.tiling.tile_size_deg),
            other_outputs=() if args.no_products else [products_dir / k for k in (*REGISTRATION_PRODUCTS, REGISTRATION_DIR)])
    finally:
        conn.close()
    if not args.no_products:
        from mercury_dem.pipeline.register_stage import make_registration_products

        prod = make_registration_products(args.dir, products_dir, config, overwrite=args.overwrite)
        summary["products"] = {"dir": str(products_dir), "files": prod["files"]}
    if args.json:
        keys = ("tile_id", "ok", "model", "reason", "translation_e_m", "translation_n_m", "translation_u_m",
                "rotation_e_deg", "rotation_n_deg", "rotation_u_deg", "scale", "n_profiles", "n_profiles_fitted",
                "n_used", "n_rejected", "rms_before_m", "rms_registered_m", "rms_after_m")
        out = {"tiles": [{k: t.get(k) for k in keys} for t in summary["tiles"]],
               **{k: summary[k] for k in ("registered", "merged", "tables", "shots", "shots_dropped_invalid",
                                          "shots_off_dem", "tiles_registered", "profiles_fitted", "statistics")},
               "products": summary.get("products")}
        print(json.dumps(strict_json(out), indent=2))
        return 0
    print(f"registered {summary['tiles_registered']} of {summary['tiles_with_shots']} tiles with shots "
          f"({summary['shots']} shots, {summary['shots_dropped_invalid']} invalid, {summary['shots_off_dem']} off the "
          f"DEM; {summary['profiles_fitted']} of {summary['profiles']} profiles fitted) in {summary['seconds']:.1f} s")
    print(f"{'tile':>5} {'model':>11} {'E m':>8} {'N m':>8} {'U m':>8} {'rot U deg':>10} {'prof':>5} "
          f"{'RMS before':>10} {'after':>8}")
    for t in summary["tiles"]:
        if t["ok"]:
            print(f"{t['tile_id']:>5} {t['model']:>11} {t['translation_e_m']:>8.1f} {t['translation_n_m']:>8.1f} "
                  f"{t['translation_u_m']:>8.1f} {t['rotation_u_deg']:>10.4f} {t['n_profiles_fitted']:>5} "
                  f"{t['rms_before_m']:>10.2f} {t['rms_after_m']:>8.2f}")
        else:
            print(f"{t['tile_id']:>5} {'-':>11} not registered: {str(t['reason']).splitlines()[0]}")
    for name, s in summary["statistics"].items():
        print(f"DEM {name:>10} − corrected shots: bias {s['bias_m']:.2f} m, RMSE {s['rmse_m']:.2f} m (n = {s['n']})")
    print(f"wrote {summary['registered']}, {summary['merged']}, {summary['tables']}/")
    if summary.get("products"):
        print(f"products: {len(summary['products']['files'])} files in {summary['products']['dir']}/registered, "
              f"merged, registration")
    return 0
