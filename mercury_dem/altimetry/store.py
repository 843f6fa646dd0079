"""Altimetry shots kept columnar beside a mission (or a run), readable whole or per tile.

Layout of an altimetry store (a directory, written under a temporary name and renamed when
complete, :func:`mercury_dem.io.atomic.atomic_directory`)::

    altimetry/
      shots.parquet    one row per shot, sorted by (tile_id, time); ONE ROW GROUP PER TILE
      altimetry.json   format, version, tile size, body radius, counts, the row groups of
                       each tile, every source file with its rows and dropped counts
      .complete

Columns of ``shots.parquet`` (:data:`SHOT_COLUMNS`, the canonical shot table of
:mod:`mercury_dem.reference.lola` plus three): ``time`` (datetime64[ns] UTC or float seconds,
one kind per store), ``lat`` (planetocentric deg), ``lon`` (east deg in [0, 360)),
``radius_m`` (metres from the centre of mass), ``profile_id`` (int64, profile id unique in the
store), ``sigma_m`` (the shot's 1-sigma height uncertainty, m), ``tile_id`` (int64, the
project's tile grid, :class:`mercury_dem.geometry.tiling.TileGrid`), ``source_id`` (int32,
index into ``altimetry.json`` ``sources``); optionally ``range_m``, ``sc_lat``, ``sc_lon``,
``sc_radius_m``, ``flag``.

Why one row group per tile: :func:`read_tile` reads only that tile's row groups
(``ParquetFile.read_row_groups``), so a tile task on a Dask worker never scans the other
tiles' shots (10^7 shots are ~0.5 GB). The row groups of each tile are recorded in
``altimetry.json`` and checked against the file's own row-group statistics when opened.

Everything read from disk is checked: a store written by someone else, cut short or edited
raises :class:`~mercury_dem.exceptions.StoreError` naming the file and the fault.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mercury_dem.altimetry.names import stored_columns, upgrade_columns, upgrade_keys
from mercury_dem.exceptions import ConfigError, StoreError
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.io.atomic import atomic_directory, atomic_write_json, is_complete

if TYPE_CHECKING:
    import pandas as pd  # imported where tables are built: opening a store (mercury-dem info) does not need it

FORMAT = "mercury-dem-altimetry"
VERSION = 1
SHOTS_FILE = "shots.parquet"
META_FILE = "altimetry.json"
#: Columns every store has, in file order.
SHOT_COLUMNS: tuple[str, ...] = ("time", "lat", "lon", "radius_m", "profile_id", "sigma_m", "tile_id", "source_id")
#: Columns a store may have besides.
OPTIONAL_COLUMNS: tuple[str, ...] = ("range_m", "sc_lat", "sc_lon", "sc_radius_m", "flag")
#: Drop reasons of :mod:`mercury_dem.reference.lola`, in its order.
DROP_REASONS: tuple[str, ...] = ("malformed", "bad_time", "non_finite", "radius_out_of_range", "flagged", "same_shot")
#: Default 1-sigma height uncertainty of a real shot, metres: the range precision of LOLA/MLA
#: (orbit errors are systematic per profile and are solved by the registration, not weighted here).
DEFAULT_SIGMA_M = 1.0


@dataclass(frozen=True)
class ShotSource:
    """One input of a store: a file (or ``simulated``), its rows, shots kept and drops by reason."""

    name: str
    n_rows: int
    n_shots: int
    n_profiles: int
    dropped: dict[str, int]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "n_rows": self.n_rows, "n_shots": self.n_shots, "n_profiles": self.n_profiles,
                "dropped": dict(self.dropped)}


def combine_shots(
    tables: Sequence[pd.DataFrame],
    sources: Sequence[ShotSource],
    sigma_m: float = DEFAULT_SIGMA_M,
) -> pd.DataFrame:
    """One shot table from several (one per source file): profile ids made unique, sources numbered.

    Parameters
    ----------
    tables : sequence of DataFrame
        Canonical shot tables (:attr:`mercury_dem.reference.lola.AltimetryShots.table`); a
        ``sigma_m`` column is kept, otherwise ``sigma_m`` fills it.
    sources : sequence of ShotSource
        One per table (only its position is used here: ``source_id``).
    sigma_m : float
        Height sigma of shots without one, metres (> 0).

    Returns
    -------
    DataFrame
        The rows of all tables, ``profile_id`` offset so that profiles of different files never
        share an id, ``source_id`` the table's position; not yet sorted or tiled.

    Raises
    ------
    StoreError
        when the tables mix ISO times with numeric times (the store holds one kind).
    """
    if len(tables) != len(sources):
        raise ValueError("combine_shots: one source per table")
    if not (math.isfinite(sigma_m) and sigma_m > 0):
        raise ConfigError(f"altimetry sigma_m must be a positive number of metres, got {sigma_m!r}")
    kinds = {("datetime" if _is_datetime(t["time"]) else "numeric") for t in tables if len(t)}
    if len(kinds) > 1:
        names = ", ".join(s.name for s in sources)
        raise StoreError(f"altimetry inputs {names} mix ISO (UTC) times with numeric (ephemeris) times; "
                         "one store holds one kind: convert the files to one kind of time column")
    out = []
    offset = 0
    for k, t in enumerate(tables):
        t = upgrade_columns(t, sources[k].name).copy()
        if len(t):
            t["profile_id"] = t["profile_id"].astype(np.int64) + offset
            offset = int(t["profile_id"].max()) + 1
        if "sigma_m" not in t.columns:
            t["sigma_m"] = float(sigma_m)
        t["source_id"] = np.int32(k)
        out.append(t)
    import pandas as pd

    if not out:
        return pd.DataFrame({c: [] for c in SHOT_COLUMNS if c != "tile_id"})
    return pd.concat(out, ignore_index=True)


def _is_datetime(column: Any) -> bool:
    import pandas as pd

    return bool(pd.api.types.is_datetime64_any_dtype(column))


def _check_table(table: pd.DataFrame, where: str) -> None:
    missing = [c for c in SHOT_COLUMNS if c not in table.columns]
    if missing:
        raise StoreError(f"{where}: shot table lacks columns {missing}")
    lat = table["lat"].to_numpy(np.float64)
    lon = table["lon"].to_numpy(np.float64)
    rad = table["radius_m"].to_numpy(np.float64)
    sig = table["sigma_m"].to_numpy(np.float64)
    bad = ~(np.isfinite(lat) & np.isfinite(lon) & np.isfinite(rad) & (np.abs(lat) <= 90.0)
            & (lon >= 0.0) & (lon < 360.0) & (rad > 0.0) & np.isfinite(sig) & (sig > 0.0))
    if bad.any():
        i = int(np.argmax(bad))
        raise StoreError(f"{where}: {int(bad.sum())} shots with invalid lat/lon/radius_m/sigma_m, e.g. row {i}: "
                         f"lat {lat[i]!r}, lon {lon[i]!r}, radius_m {rad[i]!r}, sigma_m {sig[i]!r}")


def write_altimetry(
    path: str | Path,
    table: pd.DataFrame,
    *,
    sources: Sequence[ShotSource],
    datum_radius_m: float,
    tile_size_deg: float = 10.0,
    overwrite: bool = False,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write a shot table as an altimetry store at ``path`` (atomically; see the module docstring).

    Parameters
    ----------
    path : str or Path
        The store directory (``MISSION/altimetry``).
    table : DataFrame
        Shots with at least ``time, lat, lon, radius_m, profile_id, sigma_m, source_id``
        (:func:`combine_shots` makes one); ``tile_id`` is computed here.
    sources : sequence of ShotSource
        What each ``source_id`` is (recorded in ``altimetry.json`` with its drop counts).
    datum_radius_m : float
        The body's reference radius the shots were screened against, metres.
    tile_size_deg : float
        Tile size of the grid the shots are partitioned by (one of the allowed sizes).
    overwrite : bool
        Replace an existing store.
    extra : dict, optional
        More facts for ``altimetry.json`` (e.g. the simulation's settings).

    Returns
    -------
    dict
        The ``altimetry.json`` content.
    """
    path = Path(path)
    grid = TileGrid(tile_size_deg)
    t = table.copy()
    t["tile_id"] = grid.tile_of(t["lat"].to_numpy(np.float64), t["lon"].to_numpy(np.float64)) if len(t) else \
        np.zeros(0, np.int64)
    _check_table(t, f"altimetry store {path}")
    ts = (t["time"].astype("int64").to_numpy() if _is_datetime(t["time"])
          else t["time"].to_numpy(np.float64))
    order = np.lexsort((ts, t["tile_id"].to_numpy()))
    cols = list(SHOT_COLUMNS) + [c for c in OPTIONAL_COLUMNS if c in t.columns]
    t = t.iloc[order][cols].reset_index(drop=True)
    t = t.astype({"profile_id": np.int64, "tile_id": np.int64, "source_id": np.int32, "sigma_m": np.float64,
                  "lat": np.float64, "lon": np.float64, "radius_m": np.float64})
    dropped = dict.fromkeys(DROP_REASONS, 0)
    for s in sources:
        for k, v in s.dropped.items():
            dropped[k] = dropped.get(k, 0) + int(v)
    import pyarrow as pa
    import pyarrow.parquet as pq

    tiles = t["tile_id"].to_numpy()
    starts = np.flatnonzero(np.r_[True, tiles[1:] != tiles[:-1]]) if len(t) else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], len(t)] if len(t) else np.zeros(0, np.int64)
    row_groups: dict[str, list[int]] = {}
    with atomic_directory(path, overwrite=overwrite) as tmp:
        arrow = pa.Table.from_pandas(t, preserve_index=False)
        with pq.ParquetWriter(tmp / SHOTS_FILE, arrow.schema) as writer:
            for k, (a, b) in enumerate(zip(starts, ends)):
                writer.write_table(arrow.slice(int(a), int(b - a)), row_group_size=int(b - a))
                row_groups[str(int(tiles[a]))] = [k]
            if not len(t):
                writer.write_table(arrow)
        meta = {
            "format": FORMAT, "version": VERSION, "tile_size_deg": float(tile_size_deg),
            # stored key kept as it was written by earlier versions (the value is the datum radius)
            "body_radius_m": float(datum_radius_m), "n_shots": int(len(t)),
            "n_profiles": int(t["profile_id"].nunique()) if len(t) else 0,
            "time_kind": "datetime" if _is_datetime(t["time"]) else "numeric",
            "columns": cols, "dropped": dropped, "sources": [s.to_dict() for s in sources],
            "tiles": {k: int(e - s) for k, s, e in zip(row_groups, starts, ends)},
            "row_groups": row_groups, **(extra or {}),
        }
        atomic_write_json(tmp / META_FILE, meta)
    return meta


class AltimetryStore:
    """An altimetry store on disk. Use :func:`open_altimetry`.

    Attributes: ``path``, ``meta`` (altimetry.json), ``tile_size_deg``, ``n_shots``,
    ``n_profiles``, ``tiles`` (tile id -> shot count), ``dropped`` (totals by reason),
    ``sources`` (list of dicts).
    """

    def __init__(self, path: Path, meta: dict[str, Any], row_groups: dict[int, list[int]]) -> None:
        self.path = path
        self.meta = meta
        self._row_groups = row_groups
        self.tile_size_deg = float(meta["tile_size_deg"])
        self.n_shots = int(meta["n_shots"])
        self.n_profiles = int(meta["n_profiles"])
        self.tiles = {int(k): int(v) for k, v in meta["tiles"].items()}
        self.dropped = {str(k): int(v) for k, v in meta["dropped"].items()}
        self.sources = list(meta["sources"])

    def __repr__(self) -> str:
        return f"AltimetryStore({str(self.path)!r}, {self.n_shots} shots, {self.n_profiles} profiles, {len(self.tiles)} tiles)"

    @property
    def file(self) -> Path:
        return self.path / SHOTS_FILE

    def _read(self, row_groups: list[int] | None, columns: Sequence[str] | None) -> pd.DataFrame:
        import pyarrow.parquet as pq

        cols = None if columns is None else list(dict.fromkeys([*columns, "lat", "lon", "tile_id"]))
        try:
            pf = pq.ParquetFile(self.file)
            file_cols = None if cols is None else stored_columns(cols, pf.schema_arrow.names)
            arrow = pf.read(columns=file_cols) if row_groups is None else pf.read_row_groups(row_groups,
                                                                                              columns=file_cols)
            table = upgrade_columns(arrow.to_pandas(), f"altimetry store {self.path}")
        except Exception as exc:  # pyarrow raises many types on corrupt files
            raise StoreError(f"altimetry store {self.path}: cannot read {SHOTS_FILE} ({type(exc).__name__}: {exc}); "
                             "write the altimetry again (ingest --altimetry or synth)") from None
        need = SHOT_COLUMNS if columns is None else tuple(cols or ())
        missing = [c for c in need if c not in table.columns]
        if missing:
            raise StoreError(f"altimetry store {self.path}: {SHOTS_FILE} lacks columns {missing}")
        if columns is None:
            _check_table(table, f"altimetry store {self.path}")
        else:
            lat, lon = table["lat"].to_numpy(np.float64), table["lon"].to_numpy(np.float64)
            if not np.all(np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (lon >= 0) & (lon < 360)):
                raise StoreError(f"altimetry store {self.path}: invalid lat/lon in {SHOTS_FILE}")
        if len(table):
            expect = TileGrid(self.tile_size_deg).tile_of(table["lat"].to_numpy(np.float64),
                                                          table["lon"].to_numpy(np.float64))
            if not np.array_equal(expect, table["tile_id"].to_numpy()):
                raise StoreError(f"altimetry store {self.path}: tile_id disagrees with lat/lon in {SHOTS_FILE} "
                                 "(edited or corrupt); write the altimetry again")
        return table if columns is None else table[list(columns)]

    def read(self, columns: Sequence[str] | None = None) -> pd.DataFrame:
        """Every shot (sorted by tile, then time); ``columns`` to read only some."""
        return self._read(None, columns)

    def read_tile(self, tile_id: int, columns: Sequence[str] | None = None) -> pd.DataFrame:
        """The shots of one tile (reads that tile's row groups only); empty for a tile without shots."""
        groups = self._row_groups.get(int(tile_id))
        if groups is None:
            import pyarrow.parquet as pq

            try:
                empty = upgrade_columns(pq.ParquetFile(self.file).schema_arrow.empty_table().to_pandas(),
                                        f"altimetry store {self.path}")
            except Exception as exc:  # pyarrow raises many types on corrupt files
                raise StoreError(f"altimetry store {self.path}: cannot read {SHOTS_FILE} ({exc})") from None
            missing = [c for c in (columns or SHOT_COLUMNS) if c not in empty.columns]
            if missing:
                raise StoreError(f"altimetry store {self.path}: {SHOTS_FILE} lacks columns {missing}")
            return empty if columns is None else empty[list(columns)]
        return self._read(groups, columns)

    def read_tiles(self, tiles: Sequence[int], columns: Sequence[str] | None = None) -> pd.DataFrame:
        """The shots of some tiles, or every shot when they are more than half the store's tiles (one read
        of the whole file is then cheaper than one per tile; the caller selects shots by distance anyway).
        """
        if len(tiles) > len(self.tiles) // 2:
            return self.read(columns)
        import pandas as pd

        return pd.concat([self.read_tile(t, columns) for t in tiles], ignore_index=True)

    def summary(self) -> dict[str, Any]:
        """Counts for ``info``: shots, profiles, tiles, drops, sources."""
        return {"n_shots": self.n_shots, "n_profiles": self.n_profiles, "n_tiles": len(self.tiles),
                "dropped": self.dropped, "sources": [s.get("name") for s in self.sources],
                "tile_size_deg": self.tile_size_deg}


def open_altimetry(path: str | Path) -> AltimetryStore:
    """Open a complete altimetry store, checking ``altimetry.json`` against the Parquet file's row groups.

    Raises
    ------
    StoreError
        when the store is missing, incomplete, of another format or version, or its file and
        its description disagree (the message names the file and the fault).
    """
    import pyarrow.parquet as pq

    p = Path(path)
    if not is_complete(p):
        raise StoreError(f"altimetry store {p} is missing or incomplete (no .complete marker); write it again")
    try:
        meta = json.loads((p / META_FILE).read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"altimetry store {p}: cannot read {META_FILE} ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise StoreError(f"{p} is not an altimetry store ({META_FILE} format "
                         f"{meta.get('format') if isinstance(meta, dict) else None!r})")
    if meta.get("version") != VERSION:
        raise StoreError(f"altimetry store {p} has version {meta.get('version')!r}; this reader reads {VERSION}")
    meta = upgrade_keys(meta, f"altimetry store {p} ({META_FILE})")  # a store written before the profile rename
    if isinstance(meta.get("sources"), list):
        meta["sources"] = [upgrade_keys(s, f"altimetry store {p} ({META_FILE} sources)") if isinstance(s, dict) else s
                           for s in meta["sources"]]
    try:
        for key, kind in (("tiles", dict), ("row_groups", dict), ("dropped", dict), ("sources", list)):
            if not isinstance(meta[key], kind):
                raise TypeError(f"{key} is not a {kind.__name__}")
        if isinstance(meta["tile_size_deg"], bool) or isinstance(meta["n_shots"], bool):
            raise TypeError("tile_size_deg and n_shots must be numbers")
        grid = TileGrid(float(meta["tile_size_deg"]))
        n_shots = int(meta["n_shots"])
        int(meta["n_profiles"])
        tiles = {int(k): int(v) for k, v in meta["tiles"].items()}
        row_groups = {int(k): [int(i) for i in v] for k, v in meta["row_groups"].items()}
        for k, v in meta["dropped"].items():
            if isinstance(v, bool) or int(v) < 0:
                raise ValueError(f"dropped {k!r} is {v!r}")
        if not all(isinstance(s, dict) for s in meta["sources"]):
            raise TypeError("sources are not objects")
        if any(not 0 <= t < grid.n_tiles for t in tiles) or any(v < 0 for v in tiles.values()):
            raise ValueError("a tile id or count is out of range")
    except (KeyError, TypeError, ValueError, ConfigError, OverflowError) as exc:
        raise StoreError(f"altimetry store {p}: {META_FILE} is invalid ({type(exc).__name__}: {exc})") from None
    try:
        md = pq.ParquetFile(p / SHOTS_FILE).metadata
        rg_rows = [md.row_group(i).num_rows for i in range(md.num_row_groups)]
        total = md.num_rows
    except Exception as exc:  # pyarrow raises many types on corrupt files
        raise StoreError(f"altimetry store {p}: cannot read {SHOTS_FILE} ({type(exc).__name__}: {exc}); "
                         "write the altimetry again") from None
    if total != n_shots or sum(tiles.values()) != n_shots or set(tiles) != set(row_groups):
        raise StoreError(f"altimetry store {p}: {SHOTS_FILE} has {total} shots, {META_FILE} says {n_shots} "
                         f"({sum(tiles.values())} in its tiles); write the altimetry again")
    for t, groups in row_groups.items():
        if any(not 0 <= g < len(rg_rows) for g in groups) or sum(rg_rows[g] for g in groups) != tiles[t]:
            raise StoreError(f"altimetry store {p}: the row groups of tile {t} in {META_FILE} do not match "
                             f"{SHOTS_FILE}; write the altimetry again")
    return AltimetryStore(p, meta, row_groups)


def shots_from_files(
    files: Sequence[str | Path], datum_radius_m: float, sigma_m: float = DEFAULT_SIGMA_M, **reader: Any,
) -> tuple[pd.DataFrame, list[ShotSource]]:
    """Read LOLA/MLA RDR CSV files (:func:`mercury_dem.reference.lola.read_altimetry_csv`) into one
    table for :func:`write_altimetry`, with each file's rows and drop counts as a :class:`ShotSource`.

    ``reader`` passes options (``radius_tolerance_m``, ``max_gap_s``, ``radius_unit``) to the reader.
    A file that cannot be read raises its ReferenceDataError (naming the file).
    """
    from mercury_dem.reference.lola import read_altimetry_csv

    tables, sources = [], []
    for f in files:
        shots = read_altimetry_csv(f, datum_radius_m, **reader)
        tables.append(shots.table)
        sources.append(ShotSource(str(f), shots.n_rows, len(shots.table), shots.n_profiles, dict(shots.dropped)))
    return combine_shots(tables, sources, sigma_m), sources


def read_altimetry_tile(path: str | Path, tile_id: int, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """The shots of one tile of the store at ``path`` (a plain function for Dask tile tasks)."""
    return open_altimetry(path).read_tile(tile_id, columns)


__all__ = [
    "DEFAULT_SIGMA_M",
    "SHOT_COLUMNS",
    "OPTIONAL_COLUMNS",
    "AltimetryStore",
    "ShotSource",
    "combine_shots",
    "open_altimetry",
    "read_altimetry_tile",
    "shots_from_files",
    "write_altimetry",
]
