"""Browse PNGs of the DEM, as PDS "extras" (Mattson et al.): greyscale, shaded relief,
colour-coded elevation over shaded relief with colour ramp and scale bar, and a global
map in Robinson projection (as Becker et al. 2016, Fig. 1), plus the coverage map.

Drawn with matplotlib (Agg); the Robinson map is a raster reprojected here with pyproj
(each output pixel mapped back to latitude/longitude), so no cartopy is needed.
Shaded relief of a whole planet at browse scale is nearly flat at true scale, so the
shading uses a vertical exaggeration chosen from the data (stated on the images).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyproj  # noqa: E402
from matplotlib import colors, ticker  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from mercury_dem.geometry.body import Body  # noqa: E402
from mercury_dem.products.sampling import sample_bilinear  # noqa: E402
from mercury_dem.products.stats import block_centres, block_mean  # noqa: E402

#: Robinson, central meridian 180 (the map runs 0..360 E like the reference's Fig. 1).
CMAP = "turbo"


def browse_grid(elevation: NDArray[np.floating], lat: NDArray[np.floating], lon: NDArray[np.floating],
                width: int) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """Block-mean the DEM down to at most ``width`` columns; returns (h, lat, lon)."""
    f = max(1, int(math.ceil(elevation.shape[1] / width)))
    return block_mean(elevation, f), block_centres(lat, f), block_centres(lon, f)


def _spacing(lat: NDArray[np.float64], lon: NDArray[np.float64]) -> tuple[float, float, bool]:
    dlat = abs(float(lat[1] - lat[0])) if lat.size > 1 else 1.0
    dlon = abs(float(lon[1] - lon[0])) if lon.size > 1 else dlat
    return dlat, dlon, abs(dlon * lon.size - 360.0) < 1e-6


def _gradients(h: NDArray[np.floating], lat: NDArray[np.float64], lon: NDArray[np.float64], radius_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """East and north height gradients (m/m) by central differences; columns wrap on a global grid."""
    dlat, dlon, wrap = _spacing(lat, lon)
    z = np.asarray(h, dtype=np.float64)
    if wrap:
        ex = 0.5 * (np.roll(z, -1, axis=1) - np.roll(z, 1, axis=1))
    else:
        ex = np.gradient(z, axis=1) if z.shape[1] > 1 else np.zeros_like(z)
    ny = -np.gradient(z, axis=0) if z.shape[0] > 1 else np.zeros_like(z)  # rows run north to south
    dx = radius_m * np.maximum(np.cos(np.radians(lat)), 1e-3)[:, None] * math.radians(dlon)
    dy = radius_m * math.radians(dlat)
    return ex / dx, ny / dy


def hillshade(h: NDArray[np.floating], lat: NDArray[np.float64], lon: NDArray[np.float64],
              azimuth_deg: float = 315.0, altitude_deg: float = 45.0, exaggeration: float = 1.0,
              *, radius_m: float) -> NDArray[np.float64]:
    """Lambertian shaded relief in [0, 1] (NaN where no value or next to a gap).

    The surface normal ``(-dz/de, -dz/dn, 1)`` (east, north, up; true metric spacing
    per row, heights times ``exaggeration``) dotted with the unit vector to a sun at
    ``azimuth_deg`` (clockwise from north; 315 = north-west) and ``altitude_deg``.
    """
    ge, gn = _gradients(h, lat, lon, radius_m)
    ge, gn = ge * exaggeration, gn * exaggeration
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun = (math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt))
    shade = (-ge * sun[0] - gn * sun[1] + sun[2]) / np.sqrt(ge * ge + gn * gn + 1.0)
    return np.clip(shade, 0.0, 1.0)


def auto_exaggeration(h: NDArray[np.floating], lat: NDArray[np.float64], lon: NDArray[np.float64],
                      target_deg: float = 12.0, *, radius_m: float) -> float:
    """A vertical exaggeration (1..200) making the 90th-percentile browse slope about ``target_deg``."""
    ge, gn = _gradients(h, lat, lon, radius_m)
    g = np.hypot(ge, gn)[np.abs(lat) < 75.0]
    g = g[np.isfinite(g)]
    if g.size == 0:
        return 1.0
    p90 = float(np.percentile(g, 90))
    if p90 <= 0:
        return 1.0
    return float(np.clip(math.tan(math.radians(target_deg)) / p90, 1.0, 200.0))


def crop_to_data(h: NDArray[np.floating], shade: NDArray[np.floating], lat: NDArray[np.float64],
                 lon: NDArray[np.float64], margin: int = 4
                 ) -> tuple[NDArray[np.floating], NDArray[np.floating], NDArray[np.float64], NDArray[np.float64]]:
    """Crop a browse grid to the rows/columns holding data (plus a margin).

    On a global grid the columns are first rolled so the widest empty band of longitude
    is cut, not the data (a patch across 0/360 stays in one piece); longitudes stay
    continuous and are shifted by -360 when the crop starts past 180 E. Returns the
    inputs unchanged when there is no data.
    """
    ok = np.isfinite(h)
    rows, cols = np.flatnonzero(ok.any(axis=1)), ok.any(axis=0)
    if rows.size == 0:
        return h, shade, lat, lon
    _, dlon, wrap = _spacing(lat, lon)
    lon_c = np.asarray(lon, dtype=np.float64)
    if wrap and not cols.all():
        # Start just after the longest circular run of empty columns.
        empty = ~cols
        n = empty.size
        ext = np.concatenate([empty, empty])
        best_len, best_end, run = 0, 0, 0
        for j in range(2 * n):  # over columns of a browse grid (<= a few thousand), not pixels
            run = run + 1 if ext[j] else 0
            if run > best_len and run <= n:
                best_len, best_end = run, j
        start = (best_end + 1 - min(margin, best_len // 2)) % n  # leave room for the margin
        h, shade = np.roll(h, -start, axis=1), np.roll(shade, -start, axis=1)
        lon_c = np.roll(lon_c, -start)
        lon_c = lon_c + 360.0 * (np.arange(n) >= n - start)
        cols = np.roll(cols, -start)
    c = np.flatnonzero(cols)
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h.shape[0])
    c0, c1 = max(c[0] - margin, 0), min(c[-1] + margin + 1, h.shape[1])
    lon_out = lon_c[c0:c1]
    if lon_out[0] > 180.0:
        lon_out = lon_out - 360.0
    return h[r0:r1, c0:c1], shade[r0:r1, c0:c1], lat[r0:r1], lon_out


def _limits(h: NDArray[np.floating]) -> tuple[float, float]:
    v = h[np.isfinite(h)]
    if v.size == 0:
        return -1.0, 1.0
    lo, hi = np.percentile(v, [1, 99])
    if hi <= lo:
        hi = lo + 1.0
    return float(lo), float(hi)


def colour_relief(h: NDArray[np.floating], shade: NDArray[np.floating], vmin: float, vmax: float
                  ) -> NDArray[np.float64]:
    """RGBA (H, W, 4): colour-coded elevation multiplied by the shaded relief; transparent where no value."""
    rgba = plt.get_cmap(CMAP)(colors.Normalize(vmin, vmax, clip=True)(np.nan_to_num(h, nan=vmin)))
    # Where the shading is unknown (next to a gap) use the flat-ground value, so gap edges are not lit.
    k = 0.35 + 0.65 * np.nan_to_num(shade, nan=math.sin(math.radians(45.0)))
    rgba[..., :3] *= k[..., None]
    rgba[..., 3] = np.isfinite(h)
    return rgba


def write_greyscale_png(h: NDArray[np.floating], path: str | Path) -> Path:
    """Elevation as grey levels stretched over the 1-99 % range; no value = transparent."""
    vmin, vmax = _limits(h)
    cmap = plt.get_cmap("gray").with_extremes(bad=(0, 0, 0, 0))
    plt.imsave(path, np.ma.masked_invalid(h), cmap=cmap, vmin=vmin, vmax=vmax)
    return Path(path)


def write_hillshade_png(shade: NDArray[np.floating], path: str | Path) -> Path:
    """Shaded relief as grey levels; no value = transparent."""
    cmap = plt.get_cmap("gray").with_extremes(bad=(0, 0, 0, 0))
    plt.imsave(path, np.ma.masked_invalid(shade), cmap=cmap, vmin=0.0, vmax=1.0)
    return Path(path)


def _nice_length(x: float) -> float:
    p = 10 ** math.floor(math.log10(x))
    for m in (5, 2, 1):
        if m * p <= x:
            return m * p
    return p


def _map_figure(aspect_hw: float, colorbar: str, labels: bool) -> tuple[Any, Any, Any]:
    """A figure with a map axes of the given height/width and a colour-bar axes, laid out by hand.

    (matplotlib's constrained layout measures every tick label and cost seconds per image.)
    """
    lm, rm = (0.8, 0.2) if labels else (0.3, 0.3)  # inches left/right of the map
    top, bottom = 0.45, (0.7 if labels else 0.2)
    map_w = 12.0 - lm - rm - (1.4 if colorbar == "vertical" else 0.0)
    map_h = map_w * aspect_hw
    cb_h = 0.9 if colorbar == "horizontal" else 0.0
    W, H = 12.0, top + map_h + bottom + cb_h
    fig = plt.figure(figsize=(W, H))
    ax = fig.add_axes((lm / W, (bottom + cb_h) / H, map_w / W, map_h / H))
    if colorbar == "vertical":
        cax = fig.add_axes(((lm + map_w + 0.25) / W, (bottom + 0.1 * map_h) / H, 0.2 / W, 0.8 * map_h / H))
    else:
        cax = fig.add_axes((0.25, 0.45 / H, 0.5, 0.18 / H))
    return fig, ax, cax


def _finish(fig: Any, path: str | Path) -> Path:
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def east_longitude_label(x: float, _pos: object = None) -> str:
    """Tick label of an east longitude axis: a map across the 0/360 seam runs on past 360 (or below
    0) to stay continuous, its labels say the longitude itself (365 -> 5).
    """
    return f"{round(float(x), 6) % 360.0:g}"


def write_colour_png(h: NDArray[np.floating], shade: NDArray[np.floating], lat: NDArray[np.float64],
                     lon: NDArray[np.float64], path: str | Path, title: str, exaggeration: float,
                     radius_m: float) -> Path:
    """Annotated colour-coded elevation over shaded relief: axes in degrees, colour ramp, scale bar."""
    vmin, vmax = _limits(h)
    rgba = colour_relief(h, shade, vmin, vmax)
    dlat, dlon, _ = _spacing(lat, lon)
    extent = (lon[0] - dlon / 2, lon[-1] + dlon / 2, lat[-1] - dlat / 2, lat[0] + dlat / 2)
    aspect_hw = (extent[3] - extent[2]) / (extent[1] - extent[0])
    fig, ax, cax = _map_figure(aspect_hw, "vertical", labels=True)
    ax.set_facecolor("0.85")
    ax.imshow(rgba, extent=extent, interpolation="nearest", aspect="equal")
    ax.xaxis.set_major_formatter(ticker.FuncFormatter(east_longitude_label))
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("planetocentric latitude (deg)")
    ax.set_title(title)
    sm = plt.cm.ScalarMappable(norm=colors.Normalize(vmin, vmax), cmap=CMAP)
    cb = fig.colorbar(sm, cax=cax)
    cb.set_label(f"elevation above {radius_m / 1000:g} km datum (m)")
    # Scale bar: equirectangular is true to scale along the parallel of the map's latitude nearest
    # the equator; the bar is drawn in the lower left and says which latitude it holds for.
    lat_ref = float(np.clip(0.0, extent[2], extent[3]))
    km_per_deg = radius_m * math.radians(1.0) / 1000.0 * max(math.cos(math.radians(lat_ref)), 1e-3)
    span_km = (extent[1] - extent[0]) * km_per_deg
    length_km = _nice_length(span_km / 5.0)
    y_bar = extent[2] + 0.07 * (extent[3] - extent[2])
    x0 = extent[0] + 0.04 * (extent[1] - extent[0])
    x1 = x0 + length_km / km_per_deg
    ax.plot([x0, x1], [y_bar, y_bar], color="black", lw=5, solid_capstyle="butt")
    ax.plot([x0, x1], [y_bar, y_bar], color="white", lw=2.5, solid_capstyle="butt")
    where = "at the equator" if lat_ref == 0.0 else f"along {lat_ref:.0f}°"
    ax.text((x0 + x1) / 2, y_bar + 0.025 * (extent[3] - extent[2]), f"{length_km:g} km {where}",
            ha="center", va="bottom", fontsize=9, bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax.text(0.99, 0.01, f"shaded relief x{exaggeration:.0f} vertical exaggeration, sun from NW 45°",
            transform=ax.transAxes, ha="right", va="bottom", fontsize=8,
            bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none"})
    return _finish(fig, path)


def write_hillshade_pair_png(left: NDArray[np.floating], right: NDArray[np.floating], lat: NDArray[np.float64],
                            lon: NDArray[np.float64], path: str | Path, titles: tuple[str, str], suptitle: str,
                            *, radius_m: float) -> dict[str, Any]:
    """Two DEMs on the same grid as shaded relief side by side, cropped to where ``right`` has values, with the
    same vertical exaggeration (from ``right``) and sun; grey where a map has no value. Returns the
    exaggeration and the crop's extent (degrees: west, east, south, north).
    """
    ex = auto_exaggeration(right, lat, lon, radius_m=radius_m)
    shades = [hillshade(h, lat, lon, exaggeration=ex, radius_m=radius_m) for h in (left, right)]
    crops = [crop_to_data(right, sh, lat, lon) for sh in shades]
    _, s_left, clat, clon = crops[0]
    s_right = crops[1][1]
    dlat, dlon, _ = _spacing(clat, clon)
    extent = (clon[0] - dlon / 2, clon[-1] + dlon / 2, clat[-1] - dlat / 2, clat[0] + dlat / 2)
    aspect_hw = (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9)
    panel_w = 5.6
    fig = plt.figure(figsize=(12.0, min(panel_w * aspect_hw, 12.0) + 1.2))
    cmap = plt.get_cmap("gray").with_extremes(bad=(0.55, 0.45, 0.45, 1.0))
    for k, (sh, title) in enumerate(zip((s_left, s_right), titles)):
        ax = fig.add_axes((0.09 + 0.48 * k, 0.08, 0.41, 0.8))
        ax.imshow(np.ma.masked_invalid(sh), cmap=cmap, vmin=0.0, vmax=1.0, extent=extent, interpolation="nearest",
                  aspect="equal")
        ax.xaxis.set_major_formatter(ticker.FuncFormatter(east_longitude_label))
        ax.set_xlabel("east longitude (deg)")
        if k == 0:
            ax.set_ylabel("planetocentric latitude (deg)")
        ax.set_title(title, fontsize=10)
    fig.suptitle(f"{suptitle}; shaded relief x{ex:.0f} vertical exaggeration, sun from NW 45°; "
                 "reddish grey: no value", fontsize=10)
    _finish(fig, path)
    return {"path": str(path), "exaggeration": ex, "extent_deg": [float(e) for e in extent]}


def write_error_png(error: NDArray[np.floating], lat: NDArray[np.float64], lon: NDArray[np.float64],
                    path: str | Path, title: str) -> Path:
    """DEM minus truth on the map (degrees, diverging colours symmetric about 0 at the 98th percentile
    of |error|), with the bias and RMSE in a corner: where the DEM is high, low, or without value.
    """
    v = error[np.isfinite(error)]
    lim = float(np.percentile(np.abs(v), 98)) if v.size else 1.0
    lim = lim if lim > 0 else 1.0
    rgba = plt.get_cmap("RdBu_r")(colors.Normalize(-lim, lim)(np.where(np.isfinite(error), error, 0.0)))
    rgba[~np.isfinite(error)] = (0.85, 0.85, 0.85, 1.0)
    dlat, dlon, _ = _spacing(lat, lon)
    extent = (lon[0] - dlon / 2, lon[-1] + dlon / 2, lat[-1] - dlat / 2, lat[0] + dlat / 2)
    fig, ax, cax = _map_figure((extent[3] - extent[2]) / (extent[1] - extent[0]), "vertical", labels=True)
    ax.imshow(rgba, extent=extent, interpolation="nearest", aspect="equal")
    ax.xaxis.set_major_formatter(ticker.FuncFormatter(east_longitude_label))
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("planetocentric latitude (deg)")
    ax.set_title(title)
    sm = plt.cm.ScalarMappable(norm=colors.Normalize(-lim, lim), cmap="RdBu_r")
    fig.colorbar(sm, cax=cax).set_label("DEM minus truth (m); grey: no value")
    if v.size:
        ax.text(0.99, 0.01, f"bias {v.mean():.0f} m, RMSE {np.sqrt(np.mean(v ** 2)):.0f} m (unweighted, this grid)",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none"})
    return _finish(fig, path)


def robinson_central_meridian(h: NDArray[np.floating], lon: NDArray[np.float64]) -> float:
    """Central meridian of the global map: 180 (the reference's 0-360 E map) when the data span
    most longitudes, else the middle of the longitudes holding data (a regional DEM across
    0/360 would otherwise be split between both edges of the map).
    """
    has = np.isfinite(h).any(axis=0)
    if not has.any():
        return 180.0
    lons = np.mod(np.asarray(lon, np.float64)[has], 360.0)
    # The data's span is the complement of the largest empty gap between occupied longitudes.
    u = np.unique(np.round(lons, 6))
    gaps = np.diff(np.r_[u, u[0] + 360.0])
    k = int(np.argmax(gaps))
    if gaps[k] < 60.0:  # data nearly all round: keep the reference's map
        return 180.0
    start, span = u[(k + 1) % u.size], 360.0 - gaps[k]
    return float(np.mod(round(start + span / 2.0), 360.0))  # a whole degree


def robinson_crs(central_meridian: float, body: Body) -> str:
    """Robinson on the body's IAU sphere: the IAU code for a central meridian of 180, else a PROJ string."""
    if central_meridian == 180.0:
        return body.crs("robinson_180")
    return f"+proj=robin +lon_0={central_meridian:g} +R={body.radius_m:g} +units=m +no_defs +type=crs"


def write_robinson_png(h: NDArray[np.floating], shade: NDArray[np.floating], lat: NDArray[np.float64],
                       lon: NDArray[np.float64], path: str | Path, width: int, title: str | None = None,
                       central_meridian: float | None = None, *, body: Body) -> Path:
    """Global colour-coded shaded relief in Robinson projection with graticule.

    The central meridian is 180 (0-360 E) unless the data are regional
    (:func:`robinson_central_meridian`); the title says which.
    """
    vmin, vmax = _limits(h)
    lon0 = robinson_central_meridian(h, lon) if central_meridian is None else float(central_meridian) % 360.0
    lon0 = lon0 - 360.0 if lon0 > 180.0 else lon0  # PROJ's range; 180 stays 180
    if title is None:
        name = body.name.title()
        title = (f"{name} DEM, Robinson projection (0-360°E, centred on 180°E)" if lon0 == 180.0
                 else f"{name} DEM, Robinson projection centred on {lon0 % 360.0:g}°E (the data's longitudes)")
    geographic = body.crs("geographic")
    fwd = pyproj.Transformer.from_crs(geographic, robinson_crs(lon0, body), always_xy=True)
    inv = pyproj.Transformer.from_crs(robinson_crs(lon0, body), geographic, always_xy=True)
    xmax = abs(fwd.transform(lon0 + 180.0, 0.0)[0])  # the antimeridian of the centre
    ymax = abs(fwd.transform(lon0, 90.0)[1])
    nx = int(width)
    ny = int(round(nx * ymax / xmax))
    xs = np.linspace(-xmax, xmax, nx)
    ys = np.linspace(ymax, -ymax, ny)
    xx, yy = np.meshgrid(xs, ys)
    qlon, qlat = inv.transform(xx, yy)
    bx, by = fwd.transform(qlon, qlat)
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(qlon) & (np.hypot(bx - xx, by - yy) < 1e-3 * xmax) & (np.abs(qlat) <= 90)
    qlat = np.where(inside, qlat, np.nan)
    qlon = np.where(inside, qlon, np.nan)
    hs = sample_bilinear(h, lat, lon, qlat, qlon)
    sh = sample_bilinear(shade, lat, lon, qlat, qlon)
    rgba = colour_relief(hs, sh, vmin, vmax)
    rgba[~inside] = (1.0, 1.0, 1.0, 1.0)
    nodata = inside & ~np.isfinite(hs)
    rgba[nodata] = (0.75, 0.75, 0.75, 1.0)
    fig, ax, cax = _map_figure(1.02 * ymax / (1.01 * xmax), "horizontal", labels=False)
    ax.imshow(rgba, extent=(-xmax, xmax, -ymax, ymax), interpolation="nearest")
    west, east = lon0 - 180.0 + 1e-4, lon0 + 180.0 - 1e-4  # the map's two edges
    for g in range(-60, 61, 30):  # parallels
        px, py = fwd.transform(np.linspace(west, east, 361), np.full(361, float(g)))
        ax.plot(px, py, color="k", lw=0.4, alpha=0.5)
    # The outline: both poles' lines and the antimeridian on either side.
    edge_lat = np.linspace(-90, 90, 181)
    for lon_e in (west, east):
        px, py = fwd.transform(np.full(181, lon_e), edge_lat)
        ax.plot(px, py, color="k", lw=0.8)
    for lat_e in (-90.0, 90.0):
        px, py = fwd.transform(np.linspace(west, east, 361), np.full(361, lat_e))
        ax.plot(px, py, color="k", lw=0.8)
    for g in range(0, 360, 30):  # meridians (not the map's edges)
        if abs((g - lon0 + 180.0) % 360.0 - 180.0) > 179.0:
            continue
        px, py = fwd.transform(np.full(181, float(g)), np.linspace(-90, 90, 181))
        ax.plot(px, py, color="k", lw=0.4, alpha=0.5)
        if g % 60 == 0:
            tx, ty = fwd.transform(float(g), 0.0)
            ax.text(tx, ty, f"{g}°E", fontsize=7, ha="center", va="top", alpha=0.8)
    ax.set_xlim(-1.01 * xmax, 1.01 * xmax)
    ax.set_ylim(-1.02 * ymax, 1.02 * ymax)
    ax.set_axis_off()
    ax.set_title(title)
    sm = plt.cm.ScalarMappable(norm=colors.Normalize(vmin, vmax), cmap=CMAP)
    cb = fig.colorbar(sm, cax=cax, orientation="horizontal")
    cb.set_label("elevation above 2439.4 km datum (m); grey: no data")
    return _finish(fig, path)


def write_coverage_png(nearest_km: NDArray[np.floating], x_km: NDArray[np.floating], y_km: NDArray[np.floating],
                       path: str | Path, width: int, title: str) -> Path:
    """Distance from each map pixel to its nearest control point (reference 001, Fig. 2)."""
    f = max(1, int(math.ceil(nearest_km.shape[1] / width)))
    d = block_mean(nearest_km, f)
    vmax = float(np.nanpercentile(d, 99)) if np.isfinite(d).any() else 1.0
    fig, ax, cax = _map_figure(d.shape[0] / d.shape[1], "horizontal", labels=True)
    cmap = plt.get_cmap("viridis").with_extremes(bad=(1, 1, 1, 1))
    im = ax.imshow(np.ma.masked_invalid(d), cmap=cmap, vmin=0.0, vmax=max(vmax, 1e-6), interpolation="nearest",
                   extent=(x_km[0], x_km[-1], y_km[-1], y_km[0]))
    ax.set_xlabel("sinusoidal x (km)")
    ax.set_ylabel("y (km)")
    ax.set_title(title)
    cb = fig.colorbar(im, cax=cax, orientation="horizontal")
    cb.set_label("distance to nearest control point (km)")
    return _finish(fig, path)
