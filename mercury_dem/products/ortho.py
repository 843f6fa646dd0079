"""Orthoimages: a controlled image resampled onto a DEM, in a projected CRS of its body, and tile mosaics.

For every output pixel its centre's latitude/longitude (the map's CRS, inverted with pyproj) and the
DEM's height there (bilinear, :func:`mercury_dem.reference.sampling.sample_reference_dem`) give a
ground point, which the adjusted camera projects into the image (:func:`mercury_dem.geometry.pose.project`);
the image is resampled there with ``cv2.remap`` (:func:`mercury_dem.match.ortho.warp_with_maps`, which
low-pass filters the image first when the map's pixels are coarser than the image's). This is the
ground-to-image direction of ASP's ``mapproject`` and ISIS's ``cam2map``: no ray-surface iteration.

No value (NaN) is ever invented: a pixel is no-data where the DEM has no value (any of the four
cells of its bilinear sample), the ground point is behind the camera or beyond the limb (emission on
the body's sphere >= 90 deg), or it projects outside the image (one pixel inside its border: the
bilinear sample needs its neighbours). Terrain self-occlusion (a hill hiding the slope behind it in
an oblique view) is *not* detected: such pixels show the occluding slope, as in ``mapproject``.

Rules (docs/design/ortho.md):

* **Pixel scale** of an image's orthoimage: its native ground pixel scale, IFOV x slant range from
  the camera to the datum point of the image's centre pixel (the PDS label convention,
  :func:`mercury_dem.geometry.pose.pixel_scale_m`), rounded to 3 significant digits.
* **CRS** (the body's IAU 2015 codes, as :mod:`mercury_dem.products.geotiff` and
  :mod:`mercury_dem.products.polar`): polar stereographic (``north_polar``/``south_polar``) when the
  footprint's centre is at or beyond the polar cut latitude (``dem.polar_cut_lat``, 65 deg), else
  equirectangular with central meridian 180, or 0 when the footprint crosses the 0 deg meridian
  (:func:`mercury_dem.products.geotiff.crosses_zero_meridian`). Grid edges are whole multiples of
  the pixel size (orthoimages of one scale share pixel edges).
* **Mosaic**: per pixel, the image with the smallest *effective* ground pixel scale
  ``IFOV x range / cos(emission)`` (range and emission at that ground point, emission on the sphere),
  i.e. the finest and least foreshortened view, whole pixels from one image, no blending; ties go to
  the first image. A source-index layer records the choice.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyproj
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from mercury_dem.geometry.body import Body, latlon_to_unit, latlon_to_xyz, wrap_longitude, xyz_to_lat_lon
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays, project
from mercury_dem.match.ortho import warp_with_maps
from mercury_dem.products.geotiff import crosses_zero_meridian, pixel_transform, write_raster
from mercury_dem.reference.sampling import sample_reference_dem

#: Largest map (pixels) one orthorectification builds; above it :class:`ValueError` says so.
MAX_PIXELS = 64_000_000
#: Pixels of the geometry computed at once (bounds the float64 temporaries, ~100 B per pixel).
BLOCK_PIXELS = 1 << 20
#: Overview levels are added until the smaller one's longer side is at most this (pixels).
OVERVIEW_MIN_PX = 128


@dataclass(frozen=True)
class OrthoGrid:
    """A north-up map grid of square pixels in a projected CRS of a body.

    Attributes
    ----------
    crs : the CRS code (``IAU_2015:19915`` ...)
    kind : the :meth:`Body.crs` kind of ``crs`` (``equirectangular``, ``equirectangular_180``,
        ``north_polar``, ``south_polar``)
    west_m, north_m : map coordinates of the grid's outer north-west corner (pixel edge), metres
    pixel_m : pixel size, metres (x and y)
    width, height : pixels
    """

    crs: str
    kind: str
    west_m: float
    north_m: float
    pixel_m: float
    width: int
    height: int

    @property
    def transform(self) -> Any:
        """The affine geotransform (rasterio/GDAL), exact: ``pixel_m`` on both axes."""
        return pixel_transform(self.west_m, self.north_m, self.pixel_m)

    def centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pixel-centre map coordinates: x (width,) west to east, y (height,) north to south, metres."""
        x = self.west_m + (np.arange(self.width, dtype=np.float64) + 0.5) * self.pixel_m
        y = self.north_m - (np.arange(self.height, dtype=np.float64) + 0.5) * self.pixel_m
        return np.asarray(x, np.float64), np.asarray(y, np.float64)

    def lat_lon(self, body: Body, rows: slice | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Planetocentric latitude and east longitude (degrees) of the pixel centres, (rows, width)."""
        x, y = self.centres()
        if rows is not None:
            y = y[rows]
        xx, yy = np.meshgrid(x, y)
        lon, lat = _to_geographic(self.crs, body).transform(xx, yy)
        return np.asarray(lat, np.float64), np.asarray(lon, np.float64)


@dataclass(frozen=True)
class Orthoimage:
    """One image on a map grid.

    Attributes
    ----------
    values : ndarray (height, width) float32, the image's values (DN), NaN = no data
    gsd_m : ndarray (height, width) float32, effective ground pixel scale IFOV x range / cos(emission)
        at each pixel's ground point, metres; NaN where ``values`` is
    grid : the map grid
    """

    values: NDArray[np.float32]
    gsd_m: NDArray[np.float32]
    grid: OrthoGrid

    @property
    def valid_fraction(self) -> float:
        """Share of the grid's pixels holding a value."""
        return float(np.isfinite(self.values).mean()) if self.values.size else 0.0


def _to_geographic(crs: str, body: Body) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(crs, body.crs("geographic"), always_xy=True)


def _from_geographic(crs: str, body: Body) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(body.crs("geographic"), crs, always_xy=True)


def native_pixel_scale_m(camera: FramingCamera, position: ArrayLike, rotation: ArrayLike, *,
                         datum_radius_m: float) -> float:
    """The image's native ground pixel scale: IFOV x slant range to the datum at its centre pixel, metres.

    Rounded to 3 significant digits (a grid of 1790 m pixels rather than 1793.37 m). Where the centre
    ray misses the datum sphere (the limb in the middle of the image) the median range of the rays
    of its edge pixels that hit it is used; :class:`ValueError` when none does.
    """
    centre = np.array([[(camera.samples - 1) / 2.0, (camera.lines - 1) / 2.0]])
    px = np.concatenate([centre, camera.edge_pixels(8)])
    o, d = pixel_rays(camera, position, rotation, px)
    pts, hit = intersect_sphere(o, d, datum_radius_m)
    if not hit.any():
        raise ValueError("the image does not see the body (no ray of its centre or edge meets the datum sphere)")
    rng = np.linalg.norm(pts - o, axis=-1)
    r = float(rng[0]) if hit[0] else float(np.median(rng[hit]))
    s = r * camera.ifov_rad
    return float(f"{s:.3g}")


def image_footprint(camera: FramingCamera, position: ArrayLike, rotation: ArrayLike, *, datum_radius_m: float,
                    height_range_m: tuple[float, float], per_side: int = 16
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Latitudes and longitudes (degrees) bounding what an image can see on a surface within a height range.

    The rays of the image's edge pixels (``per_side`` per side) and centre, intersected with the
    spheres of radius datum + lowest and datum + highest height: the ground the image sees lies in
    the region they enclose. Rays that miss are dropped (an image that sees the limb gets the part
    of its footprint inside it). :class:`ValueError` when fewer than 3 rays meet the surface.
    """
    px = np.concatenate([camera.edge_pixels(per_side), [[(camera.samples - 1) / 2.0, (camera.lines - 1) / 2.0]]])
    o, d = pixel_rays(camera, position, rotation, px)
    lats, lons = [], []
    for h in height_range_m:
        pts, hit = intersect_sphere(o, d, datum_radius_m + float(h))
        la, lo = xyz_to_lat_lon(pts[hit])
        lats.append(la)
        lons.append(lo)
    lat, lon = np.concatenate(lats), np.concatenate(lons)
    if lat.size < 3:
        raise ValueError("the image does not see the surface (fewer than 3 of its edge rays meet it)")
    return lat, lon


def _unwrapped_lon_range(lon: NDArray[np.float64]) -> tuple[float, float]:
    """(west, east) of a set of longitudes as the shortest arc holding them all (east may pass 360)."""
    s = np.sort(wrap_longitude(lon))
    if s.size == 1:
        return float(s[0]), float(s[0])
    gaps = np.diff(np.append(s, s[0] + 360.0))
    k = int(np.argmax(gaps))  # the arc is the circle minus its largest gap
    west = float(s[(k + 1) % s.size])
    return west, west + 360.0 - float(gaps[k])


def map_kind(lat: ArrayLike, lon: ArrayLike, polar_cut_lat: float) -> str:
    """The :meth:`Body.crs` kind for a region given by points on it: polar stereographic when its
    centre (mean unit vector) is at or beyond ``polar_cut_lat``, else equirectangular with central
    meridian 180 (``equirectangular_180``), or 0 (``equirectangular``) when it crosses 0 deg.
    """
    la = np.asarray(lat, np.float64).ravel()
    lo = np.asarray(lon, np.float64).ravel()
    u = latlon_to_unit(la, lo).mean(axis=0)
    lat_c, _ = xyz_to_lat_lon(u)
    if float(lat_c) >= polar_cut_lat:
        return "north_polar"
    if float(lat_c) <= -polar_cut_lat:
        return "south_polar"
    west, east = _unwrapped_lon_range(lo)
    return "equirectangular" if crosses_zero_meridian(west, east) else "equirectangular_180"


def _projected_bbox(lat: NDArray[np.float64], lon: NDArray[np.float64], crs: str, body: Body
                    ) -> tuple[float, float, float, float]:
    x, y = _from_geographic(crs, body).transform(lon, lat)
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        raise ValueError(f"no point of the region can be projected to {crs}")
    return float(x[ok].min()), float(x[ok].max()), float(y[ok].min()), float(y[ok].max())


def grid_for_points(lat: ArrayLike, lon: ArrayLike, body: Body, pixel_m: float, *, polar_cut_lat: float,
                    kind: str | None = None, clip: tuple[float, float, float, float] | None = None,
                    max_pixels: int = MAX_PIXELS) -> OrthoGrid:
    """The smallest grid of ``pixel_m`` pixels (edges whole multiples of it) enclosing points.

    Parameters
    ----------
    lat, lon : points of the region (e.g. :func:`image_footprint`), degrees
    body : the body whose CRS codes are used
    pixel_m : pixel size, metres
    polar_cut_lat : latitude beyond which the map is polar stereographic (:func:`map_kind`)
    kind : force a CRS kind instead of :func:`map_kind`'s choice
    clip : (x_min, x_max, y_min, y_max) map metres the grid is cut to (a tile's box)
    max_pixels : :class:`ValueError` above this many pixels
    """
    la = np.asarray(lat, np.float64).ravel()
    lo = np.asarray(lon, np.float64).ravel()
    kind = kind or map_kind(la, lo, polar_cut_lat)
    crs = body.crs(kind)
    x0, x1, y0, y1 = _projected_bbox(la, lo, crs, body)
    if clip is not None:
        x0, x1, y0, y1 = max(x0, clip[0]), min(x1, clip[1]), max(y0, clip[2]), min(y1, clip[3])
        if x0 >= x1 or y0 >= y1:
            raise ValueError("the region does not meet the clip box")
    p = float(pixel_m)
    if not p > 0:
        raise ValueError(f"pixel size must be > 0 m, got {pixel_m}")
    west, east = math.floor(x0 / p) * p, math.ceil(x1 / p) * p
    south, north = math.floor(y0 / p) * p, math.ceil(y1 / p) * p
    w, h = max(1, round((east - west) / p)), max(1, round((north - south) / p))
    if w * h > max_pixels:
        raise ValueError(f"a {w} x {h} map at {p:g} m/pixel is over the {max_pixels} pixel limit; "
                         "use a coarser pixel or a smaller region")
    return OrthoGrid(crs, kind, west, north, p, int(w), int(h))


def box_points(lat_min: float, lat_max: float, lon_min: float, lon_max: float, n: int = 64
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points along the edges of a latitude/longitude box (degrees), a hair inside it (1e-7 deg), so
    that an edge on a projection's seam (a tile at 0 deg, central meridian 180) stays on its side.
    """
    e = 1e-7
    t = np.linspace(0.0, 1.0, n)
    a0, a1, o0, o1 = lat_min + e, lat_max - e, lon_min + e, lon_max - e
    lat = np.concatenate([a0 + (a1 - a0) * t, a0 + (a1 - a0) * t, np.full(n, a0), np.full(n, a1)])
    lon = np.concatenate([np.full(n, o0), np.full(n, o1), o0 + (o1 - o0) * t, o0 + (o1 - o0) * t])
    return lat, lon


def tile_grid(bounds: tuple[float, float, float, float], footprints: Iterable[tuple[ArrayLike, ArrayLike]],
              body: Body, pixel_m: float, *, polar_cut_lat: float, max_pixels: int = MAX_PIXELS) -> OrthoGrid:
    """The mosaic grid of a tile: its box (lat_min, lat_max, lon_min, lon_max, degrees) cut to the
    union of the footprints (lat, lon arrays) of its images; CRS kind from the tile's box.
    """
    blat, blon = box_points(*bounds)
    kind = map_kind(blat, blon, polar_cut_lat)
    crs = body.crs(kind)
    clip = _projected_bbox(blat, blon, crs, body)
    fl = [(np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()) for a, b in footprints]
    if not fl:
        raise ValueError("a mosaic needs at least one image")
    lat = np.concatenate([a for a, _ in fl])
    lon = np.concatenate([b for _, b in fl])
    return grid_for_points(lat, lon, body, pixel_m, polar_cut_lat=polar_cut_lat, kind=kind, clip=clip,
                           max_pixels=max_pixels)


def orthorectify(image: ArrayLike, camera: FramingCamera, position: ArrayLike, rotation: ArrayLike,
                 dem: xr.DataArray, grid: OrthoGrid, *, body: Body, psf_sigma_px: float = 0.7) -> Orthoimage:
    """Resample one image onto a map grid through a DEM with its (adjusted) pose.

    Parameters
    ----------
    image : ndarray (lines, samples) of the camera's size, DN (integers or float with NaN = invalid)
    camera : the image's framing camera
    position : (3,) camera position, body-fixed metres
    rotation : (3, 3) body-fixed -> camera rotation (``v_cam = R @ (X - C)``)
    dem : heights above the body's datum, metres, dims (lat, lon), as ``dem.zarr``'s ``elevation``
    grid : the output map (:func:`grid_for_points`, :func:`tile_grid`)
    body : the body of the DEM and the grid (its datum radius turns heights into ground points)
    psf_sigma_px : the image's point-spread sigma (its pixels); the image is low-pass filtered to the
        map's pixel first where that is coarser (:func:`mercury_dem.match.ortho.warp_with_maps`)

    Returns
    -------
    Orthoimage : values and effective ground pixel scale per map pixel, NaN = no data
    """
    img = np.asarray(image)
    if img.shape != (camera.lines, camera.samples):
        raise ValueError(f"image of shape {img.shape} does not match its camera ({camera.lines} lines x "
                         f"{camera.samples} samples)")
    c = np.asarray(position, np.float64).reshape(3)
    r = np.asarray(rotation, np.float64).reshape(3, 3)
    n = grid.width * grid.height
    mx = np.full(n, np.nan, np.float32)
    my = np.full(n, np.nan, np.float32)
    gsd = np.full(n, np.nan, np.float32)
    rows_per_block = max(1, BLOCK_PIXELS // grid.width)
    for r0 in range(0, grid.height, rows_per_block):
        rows = slice(r0, min(grid.height, r0 + rows_per_block))
        lat, lon = grid.lat_lon(body, rows)
        h = sample_reference_dem(dem, lat, lon).ravel()
        ground = latlon_to_xyz(lat.ravel(), lon.ravel(), h, body.datum_radius_m)
        ok = np.isfinite(h)
        q, depth = project(camera, c, r, np.where(ok[:, None], ground, 0.0))
        to_cam = c - ground
        rng = np.linalg.norm(to_cam, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_e = np.sum(ground * to_cam, axis=-1) / (np.linalg.norm(ground, axis=-1) * rng)
            ok &= (depth > 0) & (cos_e > 1e-6) & np.all(np.isfinite(q), axis=-1)
        sl = slice(rows.start * grid.width, rows.stop * grid.width)
        mx[sl] = np.where(ok, q[:, 0], np.nan)
        my[sl] = np.where(ok, q[:, 1], np.nan)
        gsd[sl] = np.where(ok, rng * camera.ifov_rad / np.where(ok, cos_e, 1.0), np.nan)
    shape = (grid.height, grid.width)
    mx2, my2 = mx.reshape(shape), my.reshape(shape)
    inside = np.isfinite(mx2)
    # image pixels per map pixel (the map's pixel over the image's own scale, range x IFOV)
    native = float(np.nanmedian(gsd)) if inside.any() else grid.pixel_m
    values = np.full(shape, np.nan, np.float32)
    if inside.any():
        warped, valid = warp_with_maps(img.astype(np.float32, copy=False), mx2, my2, grid.pixel_m / native,
                                       psf_sigma_px)
        values = np.where(valid, warped, np.nan).astype(np.float32)
    gsd2 = np.where(np.isfinite(values), gsd.reshape(shape), np.nan).astype(np.float32)
    return Orthoimage(values, gsd2, grid)


def orthorectify_native(image: ArrayLike, camera: FramingCamera, position: ArrayLike, rotation: ArrayLike,
                        dem: xr.DataArray, *, body: Body, polar_cut_lat: float, psf_sigma_px: float = 0.7,
                        pixel_m: float | None = None, max_pixels: int = MAX_PIXELS) -> Orthoimage:
    """One image's orthoimage at its native ground pixel scale (:func:`native_pixel_scale_m`, or
    ``pixel_m``) on the grid enclosing its footprint over the DEM's height range.
    """
    p = pixel_m or native_pixel_scale_m(camera, position, rotation, datum_radius_m=body.datum_radius_m)
    lat, lon = image_footprint(camera, position, rotation, datum_radius_m=body.datum_radius_m,
                               height_range_m=dem_height_range(dem))
    grid = grid_for_points(lat, lon, body, p, polar_cut_lat=polar_cut_lat, max_pixels=max_pixels)
    return orthorectify(image, camera, position, rotation, dem, grid, body=body, psf_sigma_px=psf_sigma_px)


def dem_height_range(dem: xr.DataArray) -> tuple[float, float]:
    """(lowest, highest) height of a DEM, metres; (0, 0) when it holds no value."""
    v = np.asarray(dem.values, np.float64)
    if not np.isfinite(v).any():
        return 0.0, 0.0
    return float(np.nanmin(v)), float(np.nanmax(v))


def mosaic_orthos(orthos: Iterable[Orthoimage], grid: OrthoGrid) -> tuple[NDArray[np.float32], NDArray[np.int32]]:
    """The best-pixel mosaic of orthoimages on one grid, and the index of each pixel's source.

    Per pixel the orthoimage with the smallest effective ground pixel scale (``gsd_m``: IFOV x range
    / cos(emission), the finest and least foreshortened view) gives the value; ties go to the earlier
    one. Consumed one orthoimage at a time (an iterator keeps one in memory).

    Returns
    -------
    values : ndarray (height, width) float32, NaN where no image has a value
    index : ndarray (height, width) int32, position of the source in ``orthos``, -1 where none
    """
    shape = (grid.height, grid.width)
    values = np.full(shape, np.nan, np.float32)
    index = np.full(shape, -1, np.int32)
    best = np.full(shape, np.inf, np.float32)
    for k, o in enumerate(orthos):
        if o.grid != grid:
            raise ValueError(f"orthoimage {k} is on another grid than the mosaic's")
        with np.errstate(invalid="ignore"):
            better = np.isfinite(o.values) & (o.gsd_m < best)
        values[better] = o.values[better]
        best[better] = o.gsd_m[better]
        index[better] = k
    return values, index


# --------------------------------------------------------------------------- GeoTIFF / COG writers
def _overview_count(grid: OrthoGrid) -> int:
    """Overview levels (factors 2, 4, ...) until the longer side is at most :data:`OVERVIEW_MIN_PX`; at least 1."""
    side = max(grid.width, grid.height)
    return max(1, math.ceil(math.log2(max(side, 2) / OVERVIEW_MIN_PX)))


def _cog_options(grid: OrthoGrid) -> dict[str, Any]:
    # GDAL's COG driver adds overviews only above its block size (512): small maps get smaller
    # blocks and a forced count, so every orthoimage has internal overviews.
    block = 256 if max(grid.width, grid.height) > 256 else 128
    return {"BLOCKSIZE": block, "OVERVIEW_COUNT": _overview_count(grid), "OVERVIEW_RESAMPLING": "AVERAGE"}


def ortho_tags(body: Body, grid: OrthoGrid, extra: dict[str, str] | None = None) -> dict[str, str]:
    """The metadata tags of an orthoimage file: body, CRS code (IAU codes do not always round-trip
    through GDAL by name), pixel size and the rules that made it.
    """
    return {"BODY": body.name, "CRS_CODE": grid.crs, "PIXEL_M": f"{grid.pixel_m:g}",
            "DATUM_RADIUS_M": f"{body.datum_radius_m:.1f}", **(extra or {})}


def write_orthoimage(ortho: Orthoimage, path: Any, *, body: Body, tags: dict[str, str] | None = None) -> Any:
    """Write an orthoimage (or a mosaic's values) as a COG: float32 DN, NaN nodata, internal overviews."""
    return write_raster(ortho.values, ortho.grid.transform, ortho.grid.crs, path, cog=True,
                        tags=ortho_tags(body, ortho.grid, tags), description="image values (DN) on the DEM",
                        units="DN", creation_options=_cog_options(ortho.grid))


def write_source_index(index: NDArray[np.integer], grid: OrthoGrid, path: Any, *, body: Body,
                       image_ids: list[str]) -> Any:
    """Write a mosaic's source-index layer as a COG: int32, -1 = none; tag ``SOURCE_IMAGES`` lists the
    image ids in index order (JSON).
    """
    import json

    return write_raster(np.asarray(index, np.int32), grid.transform, grid.crs, path, cog=True, dtype="int32",
                        nodata=-1, units="", description="index of the source image (SOURCE_IMAGES tag)",
                        tags=ortho_tags(body, grid, {"SOURCE_IMAGES": json.dumps(list(image_ids))}),
                        creation_options={**_cog_options(grid), "OVERVIEW_RESAMPLING": "NEAREST"})
