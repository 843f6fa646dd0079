"""Products for planetary software: the ISIS shape-model cube and PDS4 labels.

* ``isis/dem_radius.cub``: the DEM as an ISIS3 cube that ``spiceinit shape=user
  model=...`` (ISIS's DemShape) can use. ISIS reads a shape model's pixels as
  planetocentric RADII in metres (not heights), finds the pixel of a latitude/longitude
  through the cube's Mapping group, and treats Null (and the other special pixels) as
  "no surface". So the values are ``datum_radius_m + elevation`` as Real (float32: the
  step at 2440 km is 0.25 m, at 1737 km 0.125 m), NaN becomes ISIS Null, and the Mapping
  group is the body's IAU equirectangular map (sphere of the IAU radius, latitude of true
  scale 0): ``ProjectionName = Equirectangular``, ``CenterLongitude`` 180 with
  ``LongitudeDomain = 360``, or 0 with ``LongitudeDomain = 180`` for a map across 0 deg
  (the longitudes the map's x = R (lon - clon) needs), ``Planetocentric``,
  ``PositiveEast``, ``TargetName`` the body's name (not the CRS's). All latitudes of the
  DEM are in the cube (no polar cut). Written by GDAL's ISIS3 driver from an in-memory
  GeoTIFF to a temporary name, its label parsed with ``pvl`` and checked, then renamed.
  Heights are in the GeoTIFFs; ISIS needs only this radius cube.
* ``pds/*.xml``: a PDS4 label beside each PDS GeoTIFF, written by GDAL's PDS4 driver with
  ``CREATE_LABEL_ONLY``: the label describes the GeoTIFF's pixel array in place (one
  copy of the data). PDS4 cannot describe compressed or tiled data, so the PDS GeoTIFFs
  are plain striped, uncompressed float32 files (``dem.tif`` stays a COG). GDAL names the
  target from the CRS ("Mercury (2015) - Sphere"); the label's Target_Identification is
  rewritten to the body's name. Each label is read back with rasterio and compared with
  its GeoTIFF (CRS, size, transform, units, values).
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import StoreError
from mercury_dem.geometry.body import Body
from mercury_dem.io.atomic import atomic_write_text, tmp_sibling
from mercury_dem.products.geotiff import crosses_zero_meridian, grid_geometry, pixel_transform, west_edge

#: ISIS's Null pixel for Real (32-bit float) cubes (bits 0xFF7FFFFB).
ISIS_NULL_REAL = float(np.array([0xFF7FFFFB], dtype="<u4").view("<f4")[0])

#: PDS4 context type of each catalogued body's target.
_TARGET_TYPE = {"MERCURY": "Planet", "MOON": "Satellite"}


def isis_target_name(body: Body) -> str:
    """The TargetName ISIS/NAIF use: ``Mercury``, ``Moon``."""
    return body.name.title()


def write_isis_radius_cube(
    elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating], path: str | Path,
    body: Body, *, pixels_per_degree: float | None = None,
    bounds: tuple[float, float, float, float] | None = None,
) -> dict[str, Any]:
    """Write the DEM as an ISIS3 shape-model cube of planetocentric radii (m); return a description.

    ``pixels_per_degree``/``bounds`` (lat_min, lat_max, lon_min, lon_max): the grid's
    (``dem.zarr`` attributes). Raises StoreError when the written label is not what ISIS needs.
    """
    import rasterio
    from rasterio.io import MemoryFile

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ppd, lat_min, lat_max, lon_min, lon_max = grid_geometry(lat, lon, pixels_per_degree, bounds)
    clon = 0.0 if crosses_zero_meridian(lon_min, lon_max) else 180.0
    crs = body.crs("equirectangular" if clon == 0.0 else "equirectangular_180")
    R = body.radius_m
    res = R * math.radians(1.0 / ppd)
    west = west_edge(lon_min, lon_max, clon)
    east = west + (lon_max - lon_min)
    transform = pixel_transform(R * math.radians(west - clon), R * math.radians(lat_max), res)
    radius = (np.asarray(elevation, dtype=np.float64) + body.datum_radius_m).astype(np.float32)
    radius[~np.isfinite(radius)] = ISIS_NULL_REAL
    H, W = radius.shape
    opts = {"DATA_LOCATION": "LABEL", "TARGET_NAME": isis_target_name(body),
            "LATITUDE_TYPE": "Planetocentric", "LONGITUDE_DIRECTION": "PositiveEast",
            "FORCE_360": "YES" if clon == 180.0 else "NO",
            "BOUNDING_DEGREES": f"{west!r},{lat_min!r},{east!r},{lat_max!r}"}
    tmp = tmp_sibling(path, ".cub")
    try:
        with MemoryFile() as mf:
            with mf.open(driver="GTiff", width=W, height=H, count=1, dtype="float32", crs=crs, transform=transform,
                         nodata=ISIS_NULL_REAL) as gt:
                gt.write(radius, 1)
            del radius  # the in-memory GeoTIFF holds it (memory: dem.memory_limit_gb allows 5 maps)
            # rasterio.open, not rasterio.shutil.copy: the latter upper-cases option values (TARGET_NAME).
            with mf.open() as src, rasterio.open(tmp, "w", driver="ISIS3", width=W, height=H, count=1,
                                                 dtype="float32", crs=src.crs, transform=src.transform,
                                                 nodata=ISIS_NULL_REAL, **opts) as dst:
                dst.write(src.read(1), 1)
        mapping = check_isis_radius_label(tmp, body, shape=(H, W), center_longitude=clon, pixels_per_degree=ppd)
        tmp.replace(path)
    finally:
        for p in (tmp, tmp.with_name(tmp.name + ".aux.xml")):
            p.unlink(missing_ok=True)
    return {"path": str(path), "shape": [H, W], "crs": crs, "center_longitude": clon,
            "longitude_domain": int(mapping["LongitudeDomain"]), "pixel_m": res, "null": ISIS_NULL_REAL,
            "target_name": str(mapping["TargetName"])}


def load_isis_label(path: str | Path) -> Any:
    """The label of an ISIS3 cube, parsed with ``pvl`` (a PVLModule)."""
    import warnings

    with warnings.catch_warnings():  # pvl 1.3 warns on import (optional multidict, its own Units class)
        warnings.simplefilter("ignore", ImportWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import pvl
    return pvl.load(str(path))


def _q(v: Any) -> float:
    """A pvl value (plain or a Quantity with units) as float."""
    return float(getattr(v, "value", v))


def check_isis_radius_label(path: str | Path, body: Body, *, shape: tuple[int, int], center_longitude: float,
                            pixels_per_degree: float) -> dict[str, Any]:
    """Parse a radius cube's label (pvl) and check what ISIS's DemShape relies on; return the Mapping group."""
    try:
        label = load_isis_label(path)
        cube = label["IsisCube"]
        mapping = dict(cube["Mapping"])
        core = cube["Core"]
    except Exception as exc:  # a malformed label is a failed write
        raise StoreError(f"the ISIS cube {path} has no readable IsisCube/Mapping label ({exc})") from None
    R = body.radius_m
    domain = 180 if center_longitude == 0.0 else 360
    want = {
        "TargetName": isis_target_name(body), "ProjectionName": "Equirectangular",
        "LatitudeType": "Planetocentric", "LongitudeDirection": "PositiveEast", "LongitudeDomain": domain,
    }
    bad = [f"{k} = {mapping.get(k)!r} (want {v!r})" for k, v in want.items() if mapping.get(k) != v]
    for key, value in (("EquatorialRadius", R), ("PolarRadius", R), ("CenterLongitude", center_longitude),
                       ("CenterLatitude", 0.0), ("Scale", pixels_per_degree),
                       ("PixelResolution", R * math.radians(1.0 / pixels_per_degree))):
        if key not in mapping or not math.isclose(_q(mapping[key]), value, rel_tol=1e-12, abs_tol=1e-9):
            bad.append(f"{key} = {mapping.get(key)!r} (want {value!r})")
    dims = core["Dimensions"]
    if (int(dims["Lines"]), int(dims["Samples"]), int(dims["Bands"])) != (shape[0], shape[1], 1):
        bad.append(f"Dimensions = {dict(dims)} (want {shape[0]} lines x {shape[1]} samples x 1 band)")
    if core["Pixels"]["Type"] != "Real":
        bad.append(f"Pixels.Type = {core['Pixels']['Type']!r} (want 'Real')")
    if bad:
        raise StoreError(f"the ISIS cube {path} is not a shape model ISIS accepts: " + "; ".join(bad))
    return mapping


def _fix_target(xml: str, body: Body, title: str) -> str:
    """Name the body (not the CRS) in a GDAL-made PDS4 label's Target_Identification, and set its title."""
    name = body.name.title()
    ttype = _TARGET_TYPE.get(body.name, "Planet")
    block = re.search(r"<Target_Identification>.*?</Target_Identification>", xml, flags=re.S)
    if block is None:
        raise StoreError("GDAL's PDS4 label has no Target_Identification")
    new = re.sub(r"<name>.*?</name>", f"<name>{name}</name>", block.group(0), count=1, flags=re.S)
    new = re.sub(r"<type>.*?</type>", f"<type>{ttype}</type>", new, count=1, flags=re.S)
    new = re.sub(r"<lid_reference>.*?</lid_reference>",
                 f"<lid_reference>urn:nasa:pds:context:target:{ttype.lower()}.{body.name.lower()}</lid_reference>",
                 new, count=1, flags=re.S)
    xml = xml[: block.start()] + new + xml[block.end():]
    return re.sub(r"<title>.*?</title>", f"<title>{title}</title>", xml, count=1, flags=re.S)


def write_pds4_label(tif: str | Path, body: Body, bounding_degrees: tuple[float, float, float, float]) -> dict[str, Any]:
    """Write ``<tif stem>.xml``, a PDS4 label describing the (uncompressed, striped) GeoTIFF ``tif`` in place.

    ``bounding_degrees``: (west lon, south lat, east lon, north lat) of the product (GDAL's
    own are wrong for maps across 180 deg). The label is read back with rasterio and
    compared with the GeoTIFF; raises StoreError when they differ. Returns a description.
    """
    import pyproj
    import rasterio
    import rasterio.shutil

    tif = Path(tif)
    xml = tif.with_suffix(".xml")
    tmp = tmp_sibling(xml, ".xml")
    try:
        # rasterio upper-cases creation option values: only pass options where that is harmless. GDAL warns
        # of each template variable it leaves for the archive (${LOGICAL_IDENTIFIER}, ...): not news here.
        quiet = logging.getLogger("rasterio._env")
        level = quiet.level
        quiet.setLevel(logging.ERROR)
        try:
            rasterio.shutil.copy(str(tif), str(tmp), driver="PDS4", CREATE_LABEL_ONLY="YES",
                                 BOUNDING_DEGREES=",".join(repr(float(b)) for b in bounding_degrees))
        finally:
            quiet.setLevel(level)
        text = _fix_target(tmp.read_text(encoding="utf-8"), body, xml.name)
        if f"<file_name>{tif.name}</file_name>" not in text:
            raise StoreError(f"GDAL's PDS4 label for {tif} does not reference {tif.name}")
        atomic_write_text(xml, text)
    finally:
        tmp.unlink(missing_ok=True)
    # Read back: the label must describe the GeoTIFF's pixels and georeferencing.
    with rasterio.open(tif) as a, rasterio.open(xml) as b:
        problems = []
        if (b.driver, b.width, b.height, b.count, b.dtypes) != ("PDS4", a.width, a.height, 1, a.dtypes):
            problems.append(f"size/type {b.driver} {b.width}x{b.height}x{b.count} {b.dtypes}")
        if not b.transform.almost_equals(a.transform, precision=1e-6):
            problems.append(f"transform {tuple(b.transform)[:6]} != {tuple(a.transform)[:6]}")
        ca = pyproj.CRS.from_wkt(a.crs.to_wkt())
        cb = pyproj.CRS.from_wkt(b.crs.to_wkt()) if b.crs is not None else None
        # GDAL rebuilds the CRS from the label's projection parameters: the same sphere and the same map suffice.
        if cb is None or cb.ellipsoid.semi_major_metre != ca.ellipsoid.semi_major_metre or not _same_map(ca, cb, a):
            problems.append(f"CRS {cb.name if cb else None!r} is not the map of {ca.name!r}")
        if b.units[0].lower() != (a.units[0] or "").lower():
            problems.append(f"units {b.units} != {a.units}")
        rows = sorted({0, a.height // 2, a.height - 1})
        for r in rows:
            win = ((r, r + 1), (0, a.width))
            va, vb = a.read(1, window=win), b.read(1, window=win)
            if not np.array_equal(va, vb, equal_nan=True):
                problems.append(f"values of row {r}")
        if problems:
            raise StoreError(f"the PDS4 label {xml} does not read back as {tif}: " + ", ".join(problems))
        info = {"path": str(xml), "image": str(tif), "shape": [b.height, b.width], "units": b.units[0]}
    return info


def _same_map(ca: Any, cb: Any, src: Any) -> bool:
    """Both CRSs send a few points of the raster to the same latitude/longitude."""
    import pyproj

    t = src.transform
    xs = [t.c + t.a * src.width * f for f in (0.1, 0.5, 0.9)]
    ys = [t.f + t.e * src.height * f for f in (0.1, 0.5, 0.9)]
    ta = pyproj.Transformer.from_crs(ca, ca.geodetic_crs, always_xy=True)
    tb = pyproj.Transformer.from_crs(cb, ca.geodetic_crs, always_xy=True)
    la, lb = np.array(ta.transform(xs, ys)), np.array(tb.transform(xs, ys))
    d = (la - lb + 180.0) % 360.0 - 180.0
    return bool(np.all(np.abs(d) < 1e-9))
