"""Readers of laser-altimeter reference heights: RDR shot tables (LOLA, MLA) and LOLA's LDEM.

Shot tables
-----------
The PDS LOLA RDR query tool writes one shot per row (``lidarPoints*.csv``), with or without
a header row; MLA RDR tables exported to CSV carry the same kind of columns. The columns
this reader needs are found by name, whatever their case, spacing or punctuation
(``Pt_Longitude``, ``PT_LONGITUDE``, ``longitude``, ``Longitude (deg)`` …, see
:data:`COLUMN_ALIASES`). A file without a header row must have the 29 columns of the LOLA
query tool's point-per-row table (:data:`LOLA_RDR_COLUMNS`; identified from the real files:
radii in km, spacecraft 55–57 km above the shots, the flag column all zero, the detector
channel 1–5); any other layout needs a header row or ``columns=``. MLA RDR tables
(``MLASCIRDR*.TAB``) have a header row with ``geoc_long, geoc_lat, altitude`` (km above a
2440 km sphere, :data:`MLA_ALTITUDE_REFERENCE_M`), ``EphemerisTime``, ``chn`` (channel ≥ 5:
noise, dropped as ``flagged``), ``UTC``, ``Sat_long``, ``Sat_lat``, … (docs/design/altimetry.md).

Units and conventions: latitude planetocentric, longitude east folded into [0, 360), radius
in metres from the body's centre of mass (the table's km × 1000 unless ``radius_unit="m"``).
Rows that cannot be used are dropped and counted by reason, never silently.

LOLA LDEM
---------
``ldem_4_reduced.cub`` is LDEM_4 (LRO-L-LOLA-4-GDR-V1.0) reduced to 0.75° in an ISIS3 cube,
int16 DN. The cube label's ``Group = Pixels`` says ``Base = 1737400.0`` and
``Multiplier = 0.5``: DN × 0.5 + 1737400 is the **radius in metres**, as in the PDS LDEM
label (SCALING_FACTOR 0.5, OFFSET 1737400 m), so the height above the 1737.4 km lunar
sphere is DN × 0.5 m (−7811 … +9141 m in the reduced cube). GDAL's ISIS3 driver reports the
same numbers as band scale/offset; the reader checks that they agree with the label text.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import NDArray

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.geometry.body import MOON_RADIUS_M, wrap_longitude  # MOON_RADIUS_M: LOLA's reference sphere
from mercury_dem.reference.sampling import sample_reference_dem

__all__ = [
    "COLUMN_ALIASES",
    "LOLA_RDR_COLUMNS",
    "MLA_ALTITUDE_REFERENCE_M",
    "MLA_BAD_CHANNEL",
    "MOON_RADIUS_M",
    "AltimetryShots",
    "assign_profiles",
    "parse_altimetry_csv",
    "read_altimetry_csv",
    "read_lola_ldem",
    "sample_reference_dem",
]

#: Columns of the LOLA RDR query tool's point-per-row CSV, in file order, for files without a
#: header row. ``unknown_16``/``unknown_17`` are not used; the others are named as the query
#: tool's header names them.
LOLA_RDR_COLUMNS: tuple[str, ...] = (
    "Coordinated_Universal_Time", "Pt_Longitude", "Pt_Latitude", "Pt_Radius", "Pt_Range",
    "Pt_Pulse", "Pt_Energy", "Pt_noi", "Pt_Thr", "Pt_Gn", "Flg", "S", "Frm",
    "Mission_Elapsed_Time", "MET_Subseconds", "Ephemeris_Time", "unknown_16", "unknown_17",
    "SC_Longitude", "SC_Latitude", "SC_radius", "Geoid", "Offnadir", "Emission",
    "Sol_INC", "Sol_Phs", "Earth_Centr", "Earth_PW", "Earth_E",
)

#: Accepted header names of each needed column, compared after lower-casing and dropping
#: everything but letters and digits (so "Pt_Longitude", "PT LONGITUDE" and "pt-longitude"
#: are one name). The first match in this order wins.
COLUMN_ALIASES: Mapping[str, tuple[str, ...]] = {
    "time": ("coordinateduniversaltime", "utc", "utctime", "time", "datetime", "ephemeristime", "et"),
    "lon": ("ptlongitude", "longitude", "lon", "long", "targetlongitude", "eastlongitude", "longitudedeg",
            "ptlongitudedeg", "lone", "geoclong", "geoclon"),
    "lat": ("ptlatitude", "latitude", "lat", "targetlatitude", "latitudedeg", "ptlatitudedeg", "geoclat"),
    "radius": ("ptradius", "radius", "ptradiuskm", "radiuskm", "planetradius", "targetradius", "rad"),
    "flag": ("flg", "flag", "shotflag", "ptflag", "flags"),
    "range": ("ptrange", "range", "rangekm", "ptrangekm"),
    "sc_lon": ("sclongitude", "sclon", "spacecraftlongitude", "satlong", "satlon"),
    "sc_lat": ("sclatitude", "sclat", "spacecraftlatitude", "satlat"),
    "sc_radius": ("scradius", "scrad", "spacecraftradius"),
    # MLA RDR: height of the bounce point above MLA_ALTITUDE_REFERENCE_M (km), used only when the
    # table has no radius column; and the detector channel (>= MLA_BAD_CHANNEL: noise, not a return).
    "altitude": ("altitude",),
    "channel": ("chn",),
}
_REQUIRED = ("time", "lon", "lat", "radius")

#: MLA RDR tables (``MLASCIRDR*.TAB``) give the bounce point's ``altitude`` in km above a
#: 2440 km sphere instead of a radius; the ODE point exports carry both ``altitude`` and
#: ``radius``. Identified from the readers of the real files (see docs/design/altimetry.md).
MLA_ALTITUDE_REFERENCE_M = 2_440_000.0
#: MLA RDR channel numbers from this value up mark noise/invalid ranges (the MLA team's
#: readers keep ``chn < 5``); such rows are counted as ``flagged``.
MLA_BAD_CHANNEL = 5


@dataclass(frozen=True, eq=False)
class AltimetryShots:
    """Altimetry shots read from one table, and what was dropped.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per usable shot, sorted by time: ``time`` (datetime64[ns] UTC for ISO times,
        float seconds for numeric times such as ephemeris time), ``lat`` (planetocentric
        degrees), ``lon`` (east degrees in [0, 360)), ``radius_m`` (metres from the centre of
        mass), ``profile_id`` (int, 0-based; a new profile starts after a time gap), and when the
        file has them ``range_m``, ``sc_lat``, ``sc_lon``, ``sc_radius_m``, ``flag``.
    n_rows : int
        Data rows in the file (header excluded).
    dropped : dict of str to int
        Rows dropped per reason: ``malformed`` (wrong number of fields), ``bad_time``,
        ``non_finite`` (lat/lon/radius missing, not numbers, or |lat| > 90),
        ``radius_out_of_range`` (beyond body radius ± tolerance), ``flagged`` (flag ≠ 0).
    datum_radius_m, radius_tolerance_m, max_gap_s : float
        The settings used.
    source : str
        The file.
    """

    table: pd.DataFrame
    n_rows: int
    dropped: dict[str, int] = field(default_factory=dict)
    datum_radius_m: float = MOON_RADIUS_M
    radius_tolerance_m: float = 25_000.0
    max_gap_s: float = 10.0
    source: str = ""

    @property
    def n_profiles(self) -> int:
        """Number of profiles (distinct profile ids)."""
        return int(self.table["profile_id"].nunique()) if len(self.table) else 0


def _norm(name: str) -> str:
    return re.sub(r"[^0-9a-z]", "", name.lower())


def _fail(source: str, fault: str) -> ReferenceDataError:
    return ReferenceDataError(f"{source}: {fault}")


def _find_columns(names: Sequence[str], source: str) -> dict[str, int]:
    normed = [_norm(n) for n in names]
    found: dict[str, int] = {}
    for key, aliases in COLUMN_ALIASES.items():
        for alias in aliases:
            if alias in normed:
                found[key] = normed.index(alias)
                break
    if "radius" not in found and "altitude" in found:
        found["radius_from_altitude"] = found["altitude"]
        found["radius"] = found["altitude"]
    missing = [k for k in _REQUIRED if k not in found]
    if missing:
        raise _fail(
            source,
            f"no column for {', '.join(missing)} among {list(names)[:40]}; accepted names: "
            + "; ".join(f"{k}: {', '.join(COLUMN_ALIASES[k][:4])}" for k in missing),
        )
    return found


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _looks_like_header(fields: Sequence[str]) -> bool:
    """A header row has no field that reads as a number or an ISO date-time."""
    return not any(_is_number(f) or re.match(r"\s*\d{4}-\d{2}-\d{2}", f) for f in fields)


def assign_profiles(time_s: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Profile ids from shot times: a gap longer than ``max_gap_s`` starts a new profile.

    Parameters
    ----------
    time_s : ndarray of shape (N,)
        Shot times in seconds, sorted ascending.
    max_gap_s : float
        Largest gap (seconds) within one profile.

    Returns
    -------
    ndarray of shape (N,), int64
        0-based profile ids, non-decreasing.
    """
    t = np.asarray(time_s, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(np.diff(t) > max_gap_s)]).astype(np.int64)


def _numeric(col: list[str]) -> np.ndarray:
    """Floats of a column of strings; NaN where a field is not a number."""
    try:
        return np.array(col, dtype=np.float64)  # the fast path: every field parses
    except (ValueError, OverflowError):
        out = np.empty(len(col))
        for i, s in enumerate(col):
            try:
                out[i] = float(s)
            except ValueError:
                out[i] = np.nan
        return out


def _repeated_shots(time_s: NDArray[np.float64], channel: NDArray[np.float64], keep: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Rows among ``keep`` whose shot time another kept row of a lower channel already has."""
    idx = np.flatnonzero(keep)
    out = np.zeros(keep.shape, dtype=bool)
    if idx.size < 2:
        return out
    order = idx[np.lexsort((channel[idx], time_s[idx]))]
    repeat = np.zeros(order.size, dtype=bool)
    repeat[1:] = time_s[order[1:]] == time_s[order[:-1]]
    out[order[repeat]] = True
    return out


def parse_altimetry_csv(
    text: str,
    datum_radius_m: float,
    *,
    source: str = "<text>",
    columns: Sequence[str] | None = None,
    radius_unit: Literal["km", "m"] = "km",
    radius_tolerance_m: float = 25_000.0,
    max_gap_s: float = 10.0,
) -> AltimetryShots:
    """Parse the text of an altimetry shot table (see :func:`read_altimetry_csv`)."""
    if radius_unit not in ("km", "m"):
        raise ValueError(f"radius_unit must be 'km' or 'm', not {radius_unit!r}")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise _fail(source, "no rows (the file is empty)")
    rows = [ln.split(",") for ln in lines]
    if columns is not None:
        names = list(columns)
    elif _looks_like_header(rows[0]):
        names = [f.strip().strip('"') for f in rows[0]]
        rows = rows[1:]
    elif len(rows[0]) == len(LOLA_RDR_COLUMNS):
        names = list(LOLA_RDR_COLUMNS)
    else:
        raise _fail(
            source,
            f"no header row and {len(rows[0])} columns, not the {len(LOLA_RDR_COLUMNS)} of a LOLA RDR "
            f"point-per-row table; add a header row or pass columns=",
        )
    where = _find_columns(names, source)
    n_rows = len(rows)
    dropped = dict.fromkeys(("malformed", "bad_time", "non_finite", "radius_out_of_range", "flagged", "same_shot"), 0)
    good = [r for r in rows if len(r) == len(names)]
    dropped["malformed"] = n_rows - len(good)

    def col(key: str) -> list[str]:
        i = where[key]
        return [r[i] for r in good]

    raw_time = [s.strip().strip('"') for s in col("time")]
    t_num = _numeric(raw_time)
    numeric_time = bool(good) and np.count_nonzero(np.isfinite(t_num)) * 2 > len(good)
    if numeric_time:
        time: pd.Series = pd.Series(t_num)
        time_s = t_num
    else:
        dt = pd.to_datetime(pd.Series(raw_time, dtype=object), format="ISO8601", errors="coerce", utc=True)
        time = dt.dt.tz_convert(None)
        ns = time.to_numpy(dtype="datetime64[ns]")
        time_s = np.where(pd.isna(time).to_numpy(), np.nan, ns.astype(np.int64) / 1e9)
    ok_time = np.isfinite(time_s)

    lat, lon = _numeric(col("lat")), _numeric(col("lon"))
    scale = 1000.0 if radius_unit == "km" else 1.0
    radius = _numeric(col("radius")) * scale
    if "radius_from_altitude" in where:  # MLA RDR: altitude above the 2440 km sphere
        radius = radius + MLA_ALTITUDE_REFERENCE_M
    finite = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(radius) & (np.abs(lat) <= 90.0)
    in_range = np.abs(radius - datum_radius_m) <= radius_tolerance_m
    if "flag" in where:
        flag = _numeric(col("flag"))
        unflagged = flag == 0.0
    elif "channel" in where:  # MLA: a channel >= 5 is a noise detection
        chn = _numeric(col("channel"))
        unflagged = np.isfinite(chn) & (chn < MLA_BAD_CHANNEL)
        flag = np.where(unflagged, 0.0, 1.0)
    else:
        flag = None
        unflagged = np.ones(len(good), dtype=bool)
    # Each dropped row is counted once, under its first fault in this order.
    dropped["bad_time"] = int(np.count_nonzero(~ok_time))
    dropped["non_finite"] = int(np.count_nonzero(ok_time & ~finite))
    dropped["radius_out_of_range"] = int(np.count_nonzero(ok_time & finite & ~in_range))
    dropped["flagged"] = int(np.count_nonzero(ok_time & finite & in_range & ~unflagged))
    keep = ok_time & finite & in_range & unflagged
    if "channel" in where:
        # MLA records one row per detection, and one laser shot can be detected in several
        # channels (the real RDR has shots with a channel-0 and a channel-1 row 1 mm apart):
        # one ground point per shot, the lowest channel kept, the others counted.
        same = _repeated_shots(time_s, _numeric(col("channel")), keep)
        dropped["same_shot"] = int(np.count_nonzero(same))
        keep &= ~same

    data: dict[str, object] = {
        "time": time.to_numpy()[keep],
        "lat": lat[keep],
        "lon": wrap_longitude(lon[keep]),
        "radius_m": radius[keep],
    }
    if "range" in where:
        rng_m = _numeric(col("range"))[keep] * scale
        data["range_m"] = np.where(np.isfinite(rng_m), rng_m, np.nan)
    for key, out in (("sc_lat", "sc_lat"), ("sc_lon", "sc_lon"), ("sc_radius", "sc_radius_m")):
        if key in where:
            v = _numeric(col(key))[keep]
            v[~np.isfinite(v)] = np.nan  # ancillary columns are kept, not validated: NaN, never inf
            if key == "sc_lon":
                v[np.isfinite(v)] = wrap_longitude(v[np.isfinite(v)])
            data[out] = v * (scale if key == "sc_radius" else 1.0)
    if flag is not None:
        data["flag"] = flag[keep].astype(np.int64)
    table = pd.DataFrame(data)
    order = np.argsort(time_s[keep], kind="stable")
    table = table.iloc[order].reset_index(drop=True)
    table["profile_id"] = assign_profiles(time_s[keep][order], max_gap_s)
    table.attrs.update(source=source, body_radius_m=float(datum_radius_m), radius_reference="centre of mass")
    return AltimetryShots(
        table=table,
        n_rows=n_rows,
        dropped=dropped,
        datum_radius_m=float(datum_radius_m),
        radius_tolerance_m=float(radius_tolerance_m),
        max_gap_s=float(max_gap_s),
        source=source,
    )


def read_altimetry_csv(
    path: str | Path,
    datum_radius_m: float = MOON_RADIUS_M,
    *,
    columns: Sequence[str] | None = None,
    radius_unit: Literal["km", "m"] = "km",
    radius_tolerance_m: float = 25_000.0,
    max_gap_s: float = 10.0,
) -> AltimetryShots:
    """Read a LOLA or MLA RDR shot table (CSV) into shots with profile ids.

    Parameters
    ----------
    path : str or Path
        The CSV file (comma-separated, one shot per row; a header row is optional for the
        29-column LOLA RDR point-per-row layout).
    datum_radius_m : float
        Reference radius of the body, metres (1737.4 km for the Moon, 2439.4 km for
        Mercury); shots farther than ``radius_tolerance_m`` from it are dropped.
    columns : sequence of str, optional
        Column names to use instead of the file's header (the file then has no header row).
    radius_unit : {"km", "m"}
        Unit of the radius and range columns (km in the PDS LOLA and MLA tables).
    radius_tolerance_m : float
        Half-width of the accepted radius band around ``datum_radius_m``, metres.
    max_gap_s : float
        A gap between consecutive shots longer than this (seconds) starts a new profile.

    Returns
    -------
    AltimetryShots

    Raises
    ------
    ReferenceDataError
        The file cannot be read or decoded, is empty, or lacks a time, latitude, longitude or
        radius column; the message names the file and the fault.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise _fail(str(path), f"cannot be read ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _fail(str(path), f"byte {exc.start} is not UTF-8 text; is this a binary RDR (.DAT)?") from None
    return parse_altimetry_csv(
        text,
        datum_radius_m,
        source=str(path),
        columns=columns,
        radius_unit=radius_unit,
        radius_tolerance_m=radius_tolerance_m,
        max_gap_s=max_gap_s,
    )


# --------------------------------------------------------------------------- LDEM


def _label_number(label: str, key: str) -> float | None:
    m = re.search(rf"^\s*{key}\s*=\s*([-+0-9.eE]+)", label, flags=re.MULTILINE)
    return float(m.group(1)) if m else None


def read_lola_ldem(path: str | Path) -> xr.DataArray:
    """Read a LOLA LDEM ISIS3 cube (SimpleCylindrical, int16 DN) as heights in metres.

    Parameters
    ----------
    path : str or Path
        The cube (e.g. ``ldem_4_reduced.cub``), read with GDAL's ISIS3 driver through rasterio.

    Returns
    -------
    xarray.DataArray of shape (H, W), dims ("lat", "lon")
        Heights in metres above ``attrs["datum_radius_m"]`` (the label's ``Base``, 1737400 m
        for LOLA), i.e. DN × ``Multiplier``; NaN where the cube has ISIS special pixels.
        ``lat`` are pixel-centre planetocentric latitudes (descending, north first), ``lon``
        pixel-centre east longitudes in [0, 360). Attributes: ``datum_radius_m``,
        ``multiplier``, ``units``, ``source``.

    Raises
    ------
    ReferenceDataError
        The file cannot be opened as a raster, is not a single-band equirectangular grid, or
        its label's Base/Multiplier disagree with GDAL's scale/offset.
    """
    import pyproj
    import rasterio
    from rasterio.errors import RasterioError

    path = Path(path)
    try:
        with open(path, "rb") as fh:
            label = fh.read(65536).decode("latin-1")
        with rasterio.open(path) as ds:
            if ds.count != 1:
                raise _fail(str(path), f"{ds.count} bands; an LDEM has one")
            dn = ds.read(1)
            nodata = ds.nodata
            scale, offset = ds.scales[0], ds.offsets[0]
            tr = ds.transform
            crs_wkt = ds.crs.to_wkt() if ds.crs else None
            height, width = ds.height, ds.width
    except OSError as exc:
        raise _fail(str(path), f"cannot be read ({exc})") from None
    except RasterioError as exc:
        raise _fail(str(path), f"is not a raster GDAL can read ({exc})") from None
    base, mult = _label_number(label, "Base"), _label_number(label, "Multiplier")
    if base is None or mult is None:
        raise _fail(str(path), "the cube label has no Pixels Base/Multiplier; cannot tell the units")
    if not (np.isclose(base, offset) and np.isclose(mult, scale)):
        raise _fail(str(path), f"label Base/Multiplier {base}/{mult} differ from GDAL's offset/scale {offset}/{scale}")
    if crs_wkt is None or tr.b != 0.0 or tr.d != 0.0:
        raise _fail(str(path), "not a north-up map-projected grid")
    crs = pyproj.CRS.from_wkt(crs_wkt)
    # Pixel centres -> lon/lat through the cube's own projection (SimpleCylindrical, clon 180).
    to_geo = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    x = tr.c + tr.a * (np.arange(width) + 0.5)
    y = tr.f + tr.e * (np.arange(height) + 0.5)
    lon, _ = to_geo.transform(x, np.zeros_like(x))
    _, lat = to_geo.transform(np.full_like(y, x[0]), y)  # equirectangular: lat does not depend on x
    lon = np.round(wrap_longitude(lon), 9)
    lat = np.round(np.asarray(lat, dtype=np.float64), 9)
    # ISIS special pixels of a SignedWord cube: -32768 Null, -32767..-32764 LRS/LIS/HIS/HRS.
    bad = dn <= -32764 if dn.dtype == np.int16 else ~np.isfinite(dn)
    if nodata is not None:
        bad |= dn == nodata
    heights = np.where(bad, np.nan, dn.astype(np.float64) * mult)
    order = np.argsort(lon, kind="stable")  # a cube centred on 0 would start at 180
    return xr.DataArray(
        heights[:, order],
        dims=("lat", "lon"),
        coords={"lat": lat, "lon": lon[order]},
        name="height",
        attrs={
            "units": "m",
            "datum_radius_m": float(base),
            "multiplier": float(mult),
            "long_name": "height above the datum sphere (radius = datum_radius_m + height)",
            "source": str(path),
        },
    )
