"""A body's known shape: what every DEM is checked against, and where free tie points start.

Each catalogued body with a packaged global shape has one :class:`BodyShape`, a global grid of
heights above the shape's own reference radius:

* MERCURY: MLA's GTMES_150V05 spherical harmonics (package data), expanded to degree 148 on a
  0.25° grid (degree 148 resolves ~52 km wavelengths on Mercury; 0.25° is 10.6 km, so the grid
  adds no error beyond bilinear interpolation of a smooth field);
* MOON: LOLA's LDEM_4 reduced to 0.75° (480 × 240, package data ``ldem_4_reduced.cub``,
  read by :func:`read_shape_cube`).

Two uses (docs/design/reference.md, "The body's shape"):

1. **Check** (:func:`shape_check`): every run's DEM minus the shape (bias, RMSE, by latitude band),
   with a verdict: a bias beyond the body's gross-error bound (:attr:`BodyShape.gross_bias_m`,
   3 km for both) is an error with its likely cause (wrong datum radius, units, wrong body).
2. **Prior**: the a-priori radius of tie points no altimetry constrains, with the stated sigma
   :attr:`BodyShape.prior_sigma_m` (as ISIS's ``spiceinit shape=`` + jigsaw's point radius sigma),
   instead of the datum sphere, so a block without altimetry does not float.

The body is always passed explicitly (:func:`body_shape` takes its name); a body without a
packaged shape gives None, and callers say so.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import CubeError, ReferenceDataError

__all__ = ["BodyShape", "LUNAR_SHAPE_PACKAGED", "body_shape", "gross_error_cause", "read_shape_cube", "shape_check",
           "truth_shape"]

DATA_DIR = Path(__file__).resolve().parent / "data"
#: LOLA LDEM_4 reduced to 0.75° (see data/README.md): the Moon's packaged shape.
LUNAR_SHAPE_PACKAGED = DATA_DIR / "ldem_4_reduced.cub"
#: Plausible heights of a global shape above its reference radius: the Moon's range is −9.1…+10.8 km
#: (LOLA), Mercury's −5.4…+4.5 km (MLA); 30 km rejects a cube whose Base/Multiplier or units are wrong.
MAX_SHAPE_HEIGHT_M = 30_000.0
#: Latitude band edges of the check's table, degrees (10° bands; only bands the DEM reaches are listed).
CHECK_BANDS_DEG = tuple(float(x) for x in range(-90, 91, 10))


@dataclass(frozen=True)
class BodyShape:
    """A body's global shape as a grid of heights above ``reference_radius_m``.

    Attributes
    ----------
    body : upper-case body name (``MERCURY``, ``MOON``)
    name : what the shape is, for reports (``GTMES_150V05 degree 148``)
    source : the file it was read from
    citation : who made it (report and docs)
    grid : DataArray (lat descending, lon ascending in [0, 360)), metres above ``reference_radius_m``
    reference_radius_m : radius the grid's heights are above
    resolution_km : the shape's resolution on the ground (what it cannot see is relief shorter than this)
    prior_sigma_m : 1-sigma of the tie points' a-priori radius taken from it (the relief it lacks)
    gross_bias_m : a DEM whose mean difference from it exceeds this is wrong, not rough
    """

    body: str
    name: str
    source: str
    citation: str
    grid: xr.DataArray
    reference_radius_m: float
    resolution_km: float
    prior_sigma_m: float
    gross_bias_m: float

    def radius_m(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
        """Radius from the centre of mass (metres) at planetocentric lat / east lon (bilinear)."""
        from mercury_dem.reference.sampling import sample_reference_dem

        lat = np.asarray(lat_deg, np.float64)
        lon = np.mod(np.asarray(lon_deg, np.float64), 360.0)
        return self.reference_radius_m + sample_reference_dem(self.grid, lat.ravel(), lon.ravel()).reshape(lat.shape)

    def radius_at_xyz(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """Radius of the shape along the direction of each body-fixed point (n, 3) -> (n,), metres."""
        p = np.asarray(xyz, np.float64).reshape(-1, 3)
        r = np.linalg.norm(p, axis=1)
        safe = np.where(r > 0, r, 1.0)
        lat = np.degrees(np.arcsin(np.clip(p[:, 2] / safe, -1.0, 1.0)))
        lon = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
        return self.radius_m(lat, lon)

    def describe(self) -> dict[str, Any]:
        return {"body": self.body, "name": self.name, "source": self.source, "citation": self.citation,
                "resolution_km": self.resolution_km, "prior_sigma_m": self.prior_sigma_m,
                "gross_bias_m": self.gross_bias_m}


def _fail(path: Path | str, fault: str) -> ReferenceDataError:
    return ReferenceDataError(f"shape model {path}: {fault}")


def _mapping_value(path: Path, mapping: Any, key: str) -> float:
    from mercury_dem.sources.isis_cube import label_float

    try:
        v = label_float(path, mapping, key, "IsisCube/Mapping/")
    except CubeError as exc:
        raise _fail(path, str(exc)) from None
    if not math.isfinite(v):
        raise _fail(path, f"IsisCube/Mapping/{key} is {v}")
    return v


def read_shape_cube(path: str | Path) -> xr.DataArray:
    """Read a global LOLA-style LDEM ISIS3 cube (SimpleCylindrical) with the project's own cube reader.

    Unlike :func:`mercury_dem.reference.lola.read_lola_ldem` (GDAL, any reference DEM a user names),
    this reader is for the packaged shape every Moon run uses: pure Python over the fuzzed
    :func:`mercury_dem.sources.open_cube`, a check of every mapping keyword it relies on, and a
    global grid required.

    Returns
    -------
    DataArray of shape (lines, samples), dims ("lat", "lon"): heights in metres above
    ``attrs["datum_radius_m"]`` (the label's ``Pixels/Base``, 1737400 m for LOLA), i.e.
    ``Multiplier × DN``; NaN at ISIS special pixels. ``lat`` pixel centres descending, ``lon``
    ascending in [0, 360).

    Raises
    ------
    ReferenceDataError
        naming the file and the fault: not a readable cube (the cube reader's reason), not
        planetocentric / east-positive SimpleCylindrical on a sphere, a resolution or corner that
        does not make a global grid, a Base unlike the mapping's radius, heights beyond
        ±30 km (units), or no valid pixel.
    """
    from mercury_dem.sources import open_cube, read_pixels

    path = Path(path)
    try:
        cube = open_cube(path)
        values, valid = read_pixels(cube)
    except CubeError as exc:
        raise _fail(path, str(exc)) from None
    if cube.bands != 1:
        raise _fail(path, f"{cube.bands} bands; a shape model has one")
    if cube.pixel_type == "Real":
        raise _fail(path, "Real pixels: a LOLA LDEM stores SignedWord DN with Base/Multiplier (units unknown)")
    label = cube.label.get("IsisCube", {})
    mapping = label.get("Mapping") if isinstance(label, Mapping) else None
    if not isinstance(mapping, Mapping):
        raise _fail(path, "no IsisCube/Mapping group: not a map-projected cube")
    proj = str(mapping.get("ProjectionName", "")).strip()
    if proj.lower() not in ("simplecylindrical", "equirectangular"):
        raise _fail(path, f"projection {proj!r}: only SimpleCylindrical is read")
    if str(mapping.get("LatitudeType", "Planetocentric")).strip().lower() != "planetocentric":
        raise _fail(path, f"LatitudeType {mapping.get('LatitudeType')!r}: only Planetocentric is read")
    if str(mapping.get("LongitudeDirection", "PositiveEast")).strip().lower() != "positiveeast":
        raise _fail(path, f"LongitudeDirection {mapping.get('LongitudeDirection')!r}: only PositiveEast is read")
    a = _mapping_value(path, mapping, "EquatorialRadius")
    c = _mapping_value(path, mapping, "PolarRadius")
    clon = _mapping_value(path, mapping, "CenterLongitude")
    res = _mapping_value(path, mapping, "PixelResolution")
    ulx = _mapping_value(path, mapping, "UpperLeftCornerX")
    uly = _mapping_value(path, mapping, "UpperLeftCornerY")
    if not (a > 0 and abs(a - c) <= 1e-6 * a):
        raise _fail(path, f"radii {a} / {c} m: only a sphere is read")
    if proj.lower() == "equirectangular" and "CenterLatitude" in mapping \
            and _mapping_value(path, mapping, "CenterLatitude") != 0.0:
        raise _fail(path, "Equirectangular with a CenterLatitude other than 0")
    if not res > 0:
        raise _fail(path, f"PixelResolution {res} m: must be > 0")
    if not (abs(cube.base - a) <= 1e-6 * a):
        raise _fail(path, f"Pixels/Base {cube.base} m differs from the mapping radius {a} m: the DN are not "
                          "heights above the shape's sphere (units?)")
    if not (0 < abs(cube.multiplier) <= 10.0):
        raise _fail(path, f"Pixels/Multiplier {cube.multiplier}: not metres per DN of an LDEM")
    deg_per_px = math.degrees(res / a)
    span_lon, span_lat = cube.samples * deg_per_px, cube.lines * deg_per_px
    lat_top = math.degrees(uly / a)
    if abs(span_lon - 360.0) > deg_per_px or abs(span_lat - 180.0) > deg_per_px or abs(lat_top - 90.0) > deg_per_px:
        raise _fail(path, f"{cube.samples} x {cube.lines} pixels of {deg_per_px:.6g} deg from latitude "
                          f"{lat_top:.6g}: not a global grid (360 x 180 deg from 90 N)")
    lon = np.mod(clon + np.degrees((ulx + res * (np.arange(cube.samples) + 0.5)) / a), 360.0)
    lon = np.where(lon >= 360.0, 0.0, np.round(lon, 9))
    lat = np.round(np.degrees((uly - res * (np.arange(cube.lines) + 0.5)) / a), 9)
    heights = np.where(valid, values.astype(np.float64) - cube.base, np.nan)
    if not np.isfinite(heights).any():
        raise _fail(path, "no valid pixel")
    top = float(np.nanmax(np.abs(heights)))
    if top > MAX_SHAPE_HEIGHT_M:
        raise _fail(path, f"heights up to {top:.0f} m above the {a:.0f} m sphere: beyond any body's relief "
                          f"({MAX_SHAPE_HEIGHT_M:.0f} m); Base/Multiplier or units are wrong")
    order = np.argsort(lon, kind="stable")
    return xr.DataArray(heights[:, order], dims=("lat", "lon"), coords={"lat": lat, "lon": lon[order]},
                        name="height", attrs={"units": "m", "datum_radius_m": float(a),
                                              "multiplier": float(cube.multiplier), "source": str(path)})


def _gtmes_shape() -> BodyShape:
    from mercury_dem.reference.sha import GTMES_PACKAGED, evaluate_grid, read_shadr

    sha = read_shadr(GTMES_PACKAGED)
    step = 0.25
    lats = 90.0 - step * (np.arange(int(180 / step)) + 0.5)
    lons = step * (np.arange(int(360 / step)) + 0.5)
    radius = evaluate_grid(sha, lats, lons, lmax=148)
    ref = 2_439_400.0  # GTMES's own reference radius (its header), also the MESSENGER datum
    grid = xr.DataArray(np.asarray(radius, np.float64) - ref, dims=("lat", "lon"), coords={"lat": lats, "lon": lons},
                        name="height", attrs={"units": "m", "datum_radius_m": ref})
    return BodyShape(
        body="MERCURY", name="GTMES_150V05 (MLA) to degree 148", source=GTMES_PACKAGED,
        citation="MESSENGER MLA team (D. E. Smith, NASA GSFC); PDS MESS-H-RSS/MLA-5-SDP-V1.0, GTMES_150V05_SHA",
        grid=grid, reference_radius_m=ref, resolution_km=2 * math.pi * (ref / 1000.0) / 148 / 2,
        # the MDIS pair's DEM differs from it by 440 m (std) over 60 km: the relief degree 148 lacks
        prior_sigma_m=1000.0, gross_bias_m=3000.0,
    )


def _lola_shape() -> BodyShape:
    grid = read_shape_cube(LUNAR_SHAPE_PACKAGED)
    ref = float(grid.attrs["datum_radius_m"])
    return BodyShape(
        body="MOON", name="LOLA LDEM_4 reduced to 0.75 deg", source=str(LUNAR_SHAPE_PACKAGED),
        citation="LOLA team, Smith et al. 2010; PDS LRO-L-LOLA-4-GDR-V1.0 (LDEM_4), reduced in ISIS3 test data",
        grid=grid, reference_radius_m=ref, resolution_km=2 * math.pi * ref / 1000 / 480,
        # the Apollo crops' DEM differs from it by ~1.4 km (std): 23 km pixels do not hold their craters
        prior_sigma_m=1000.0, gross_bias_m=3000.0,
    )


_SHAPES = {"MERCURY": _gtmes_shape, "MOON": _lola_shape}


@functools.lru_cache(maxsize=4)
def body_shape(body_name: str) -> BodyShape | None:
    """The packaged shape of a body by name (MERCURY, MOON); None for a body without one.

    Cached per process (GTMES: 0.1 s to read and expand; LOLA: 0.02 s). Raises ReferenceDataError
    when the packaged file is damaged (a broken install).
    """
    make = _SHAPES.get(str(body_name).strip().upper())
    return None if make is None else make()


def truth_shape(truth_dem: xr.DataArray, *, body_name: str, source: str) -> BodyShape:
    """A synthetic mission's shape: its stored truth DEM (regional or global), so a synthetic run is
    checked for gross errors like a real one (a DEM on the wrong datum, in the wrong units).

    Parameters
    ----------
    truth_dem : DataArray (lat, lon) of heights above ``attrs["datum_radius_m"]`` (as
        :meth:`mercury_dem.mission.truth.SyntheticTruth.dem` returns it); any longitude range
    body_name : the mission's body (stated, never defaulted)
    source : where the grid was read (for the report)

    The truth is exact, so the same 3 km bound as a real body's shape applies with room to spare:
    a right DEM differs from it by its own error (hundreds of metres at most), a wrong datum by
    hundreds of kilometres. ``prior_sigma_m`` is not used (synthetic points keep the datum prior).
    """
    ref = float(truth_dem.attrs["datum_radius_m"])
    lat = np.asarray(truth_dem["lat"].values, np.float64)
    step_deg = float(abs(np.median(np.diff(lat)))) if lat.size > 1 else 1.0
    grid = truth_dem.transpose("lat", "lon").astype(np.float64)
    return BodyShape(
        body=str(body_name).upper(), name=f"the synthetic truth surface ({1 / step_deg:g} px/deg)", source=source,
        citation="synthetic: the mission's own truth (mercury_dem.synth)", grid=grid, reference_radius_m=ref,
        resolution_km=math.radians(step_deg) * ref / 1000.0, prior_sigma_m=1000.0, gross_bias_m=3000.0,
    )


def gross_error_cause(bias_m: float, body_name: str, datum_radius_m: float, dem_median_m: float,
                      shape_median_m: float) -> str:
    """The likely cause of a DEM far from its body's shape, from the size of the offset.

    Tried in order: heights measured from another catalogued body's datum (the offset is the
    difference of the two radii), heights that are radii (the datum not subtracted), kilometres
    taken for metres or the reverse (the DEM's heights are the shape's × 1000 or ÷ 1000); else a
    generic list.
    """
    from mercury_dem.geometry.body import BODIES

    for other in BODIES.values():
        if other.name == body_name.upper():
            continue
        offset = datum_radius_m - other.datum_radius_m
        if abs(bias_m - offset) < 0.05 * abs(offset):
            return (f"the heights look measured from {other.name.title()}'s datum ({other.datum_radius_m / 1000:.1f} km) "
                    f"instead of {body_name.title()}'s ({datum_radius_m / 1000:.1f} km): wrong datum radius or wrong body "
                    "(check the mission's body and the run's datum)")
    if abs(bias_m - datum_radius_m) < 0.05 * datum_radius_m:
        return "the heights are radii (the datum radius was not subtracted)"
    scale = abs(shape_median_m) > 100.0
    if scale and abs(dem_median_m - 1000.0 * shape_median_m) < 0.5 * abs(1000.0 * shape_median_m):
        return "the heights look like kilometres read as metres (units)"
    if scale and abs(dem_median_m - shape_median_m / 1000.0) < 0.5 * abs(shape_median_m / 1000.0) + 5.0:
        return "the heights look like metres read as kilometres (units)"
    return ("wrong datum radius, units or body (the DEM is not where the body's surface is); or the block's "
            "pointing or positions are off by far more than their declared uncertainty")


def shape_check(elevation: xr.DataArray, *, body_name: str, datum_radius_m: float,
                shape: BodyShape | None, reason_without: str | None = None) -> dict[str, Any]:
    """DEM minus the body's shape: statistics, per latitude band, and a verdict.

    Parameters
    ----------
    elevation : DataArray (lat, lon), metres above ``datum_radius_m`` (NaN: no value); the caller
        masks what it does not want compared (pixels far from any control point)
    body_name, datum_radius_m : the DEM's body and datum (stated, never defaulted)
    shape : the body's shape (:func:`body_shape`), or None
    reason_without : why there is no shape, when ``shape`` is None (the report says it)

    Returns
    -------
    dict
        ``status``: ``"ok"``, ``"gross_error"`` (|bias| > ``gross_bias_m``, with ``cause``) or
        ``"not_compared"`` (with ``reason``); ``shape`` (its description); ``n``, ``bias_m``,
        ``median_m``, ``std_m``, ``rmse_m``, ``nmad_m``, ``min_m``, ``max_m`` of DEM − shape;
        ``by_latitude`` (10° bands: ``lat_min``, ``lat_max``, ``n``, ``bias_m``, ``rmse_m``).
    """
    from mercury_dem.reference.compare import compare_heights

    if shape is None:
        return {"status": "not_compared", "body": body_name,
                "reason": reason_without or f"no packaged shape model of {body_name.title()}"}
    da = elevation.transpose("lat", "lon")
    lat = np.asarray(da["lat"].values, np.float64)
    lon = np.asarray(da["lon"].values, np.float64)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    radius = shape.radius_m(la, lo)
    dem = np.asarray(da.values, np.float64)
    stats = compare_heights(dem.ravel(), datum_radius_m=datum_radius_m, reference_radius_m=radius.ravel())
    out: dict[str, Any] = {"body": body_name, "shape": shape.describe(),
                           **{k: stats[k] for k in ("n", "bias_m", "median_m", "std_m", "rmse_m", "nmad_m",
                                                    "min_m", "max_m", "datum_radius_m")}}
    if not stats["n"]:
        out.update(status="not_compared", reason="no DEM pixel with a value near a control point")
        return out
    diff = dem - (radius - datum_radius_m)
    bands = []
    for lo_b, hi_b in zip(CHECK_BANDS_DEG[:-1], CHECK_BANDS_DEG[1:]):
        rows = (lat >= lo_b) & (lat < hi_b) if hi_b < 90 else (lat >= lo_b) & (lat <= hi_b)
        d = diff[rows].ravel()
        d = d[np.isfinite(d)]
        if d.size:
            bands.append({"lat_min": lo_b, "lat_max": hi_b, "n": int(d.size), "bias_m": float(d.mean()),
                          "rmse_m": float(np.sqrt(np.mean(d * d)))})
    out["by_latitude"] = bands
    bias = float(stats["bias_m"])
    if abs(bias) > shape.gross_bias_m:
        ref_h = radius - datum_radius_m
        ok = np.isfinite(dem) & np.isfinite(ref_h)
        cause = gross_error_cause(bias, body_name, datum_radius_m, float(np.median(dem[ok])),
                                  float(np.median(ref_h[ok])))
        out.update(status="gross_error", cause=cause)
    else:
        out["status"] = "ok"
    return out

