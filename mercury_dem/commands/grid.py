"""``mercury-dem grid POINTS --out DIR``: grid a point cloud file into DIR/dem.zarr.

A standalone use of the DEM stage, e.g. on a point cloud exported from elsewhere.
POINTS is a ``.npy`` array (N, 3) of body-fixed XYZ metres, or a ``.csv`` with either
columns ``x,y,z`` (metres) or ``lat,lon,radius`` (degrees, degrees, metres), named in a
header line (without a header the three columns are read as x, y, z).

The map covers the points: their bounding box plus ``dem.canvas_margin_pixels``, snapped to the
pixel grid (:mod:`mercury_dem.dem.extent`), unless ``--bounds W E S N`` (or the configuration's
``dem.lat_min`` ... ``dem.lon_max``) fixes it. Pixels farther from every point than the no-value
distance have no value; by default it follows the points' spacing (:mod:`mercury_dem.dem.spacing`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mercury_dem.config import Config
from mercury_dem.exceptions import ConfigError, GridError

NAME = "grid"
if TYPE_CHECKING:
    import numpy as np

#: The process ends after this command: skip the exit-time garbage collection (mercury_dem.cli._freeze_for_exit).
FREEZE_AT_EXIT = True

HELP = "grid a point cloud (.npy/.csv of XYZ or lat,lon,radius) into DIR/dem.zarr"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("points", metavar="POINTS", help=".npy (N,3) XYZ metres, or .csv with x,y,z or lat,lon,radius")
    p.add_argument("--out", metavar="DIR", required=True, help="output directory (dem.zarr and coverage.zarr go there)")
    p.add_argument("--method", choices=("median11", "shepard"), help="override dem.method")
    p.add_argument("--ppd", type=float, metavar="N", help="override dem.pixels_per_degree")
    p.add_argument("--bounds", type=float, nargs=4, metavar=("W", "E", "S", "N"),
                   help="the map's west, east, south and north edges in degrees (east-positive; whole pixels), "
                        "overriding dem.lon_min/lon_max/lat_min/lat_max; default: the points' box plus a margin")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="Dask LocalCluster workers (0 = grid in this process; same result)")
    p.add_argument("--no-coverage", action="store_true", help="skip the point-cloud coverage analysis")
    p.add_argument("--overwrite", action="store_true", help="replace an existing DIR/dem.zarr")
    p.add_argument("--body", metavar="NAME", default="mercury",
                   help="target body: its datum (heights) and IAU 2015 CRS (mercury, moon; default mercury)")


def read_points(path: str | Path) -> np.ndarray:
    """Read a point cloud file into (N, 3) body-fixed metres (see the module docstring)."""
    import numpy as np

    from mercury_dem.geometry.body import latlon_to_unit

    path = Path(path)
    if not path.is_file():
        raise GridError(f"point cloud file {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            pts = np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise GridError(f"point cloud file {path} is not a plain numpy array: {exc}") from None
        return np.asarray(pts, dtype=np.float64)
    if suffix not in (".csv", ".txt"):
        raise GridError(f"point cloud file {path}: expected .npy or .csv, got '{suffix}'")
    with open(path) as fh:
        first = fh.readline()
    names = [c.strip().lower() for c in first.split(",")]
    has_header = any(c and not _is_number(c) for c in names)
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1 if has_header else 0, ndmin=2)
    except ValueError as exc:
        raise GridError(f"point cloud file {path} is not a numeric CSV: {exc}") from None
    if data.size == 0:
        return np.zeros((0, 3))
    if has_header and {"lat", "lon", "radius"} <= set(names):
        lat, lon, r = (data[:, names.index(k)] for k in ("lat", "lon", "radius"))
        return latlon_to_unit(lat, lon) * r[:, None]
    if has_header and {"x", "y", "z"} <= set(names):
        return data[:, [names.index(k) for k in ("x", "y", "z")]]
    if has_header:
        raise GridError(f"point cloud file {path}: the header must name x,y,z or lat,lon,radius, got {first.strip()!r}")
    if data.shape[1] != 3:
        raise GridError(f"point cloud file {path}: expected 3 columns (x,y,z), got {data.shape[1]}")
    return data


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.location import UPLOAD_HINT, refuse_remote

    dem = config.dem
    changes: dict[str, Any] = {}
    if args.method:
        changes["method"] = args.method
    if args.ppd is not None:
        changes["pixels_per_degree"] = args.ppd
    if args.bounds is not None:
        w, e, south, north = args.bounds
        if not (w < e <= w + 360.0 and -90.0 <= south < north <= 90.0):
            raise ConfigError(f"--bounds W E S N = {w:g} {e:g} {south:g} {north:g}: need W < E <= W + 360 and "
                              f"-90 <= S < N <= 90 (degrees, east-positive longitudes)")
        changes.update(lon_min=w, lon_max=e, lat_min=south, lat_max=north)
    try:
        dem = dataclasses.replace(dem, **changes)  # validated again on construction
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("config key '", "config key 'dem.", 1)) from None
    out = refuse_remote(args.out, "--out", f"{UPLOAD_HINT}, or use 'mercury-dem run --out URL'")
    writer = None
    if args.workers == 0:
        import numpy  # noqa: F401  (before the fork: both processes need it, imported once)

        from mercury_dem.pipeline.store_writer import ForkedStoreWriter

        # Forked before numba, zarr or any thread: the child imports zarr and writes dem.zarr on the other
        # core while this process starts numba and grids (mercury_dem.pipeline.store_writer).
        writer = ForkedStoreWriter.start()
    try:
        summary = _grid(args, config, dem, out, writer)
    finally:
        if writer is not None:
            writer.abort()  # a no-op once the store is complete; else the child stops unmarked
    lat0, lat1, lon0, lon1 = summary["grid_bounds_deg"]
    print(f"gridded {summary['n_points']} points into {summary['path']} "
          f"({summary['shape'][0]} x {summary['shape'][1]}, {summary['method']}, {summary['n_chunks']} chunks) "
          f"in {summary['seconds']:.1f} s; {summary['no_value_pixels']} pixels without value "
          f"({100 * summary['no_value_fraction']:.2f} %, farther than {summary['no_value_distance_m']:.0f} m "
          f"from every point); map lat {lat0:g}..{lat1:g}, lon {lon0:g}..{lon1:g}")
    if summary["coverage"]:
        print("coverage: " + json.dumps({k: summary["coverage"][k] for k in
                                         ("pixel_km", "occupied_fraction", "share_with_1", "share_with_2",
                                          "share_with_3_or_more")}))
    return 0


def _grid(args: argparse.Namespace, config: Config, dem: Any, out: Path, writer: Any) -> dict[str, Any]:
    from mercury_dem.geometry.body import body_by_name

    try:
        body = body_by_name(args.body)
    except ValueError as exc:
        raise ConfigError(f"--body: {exc}") from None
    points = read_points(args.points)
    from mercury_dem.io.run_store import DEM_FILE
    from mercury_dem.pipeline.dem_stage import grid_dem
    from mercury_dem.progress import Reporter

    if args.workers == 0:
        from mercury_dem.dem.numba_start import start_gridding_kernels

        start_gridding_kernels()  # numba's first call without scipy.linalg/cffi: ~0.1-0.15 s of a cold grid
    from mercury_dem.compute import open_client

    # --workers N: a LocalCluster on the loopback unless the configuration widens it; 0: this process
    with open_client(args.workers, host=config.execution.host) as client:
        return grid_dem(points, dem, out / DEM_FILE, client=client,
                        overwrite=args.overwrite, coverage=not args.no_coverage, attrs={"source": str(args.points)},
                        progress=Reporter(sys.stderr), body=body, writer=writer)
