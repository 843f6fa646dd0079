"""PDS polar products: the caps beyond +-65 deg reprojected to polar stereographic.

Each cap is a square grid in IAU_2015:19930 (north) / 19935 (south) — polar
stereographic, true scale at the pole, sphere 2440.53 km — centred on the pole and
just enclosing the circle of the cut latitude, with the pixel size of the DEM
(north-south, metres). Every output pixel centre is mapped back to latitude/longitude
with pyproj and the equirectangular DEM is sampled there bilinearly (NaN-aware,
across the 0/360 seam): a reprojection, not a cut. Pixels equatorward of the cut
latitude are NaN.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyproj
from numpy.typing import NDArray

from mercury_dem.geometry.body import Body
from mercury_dem.products.sampling import sample_bilinear


def polar_grid(cut_lat: float, pixel_m: float, radius_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel-centre x (W,) and y (H,, descending) of a square stereographic grid enclosing the cap
    (``radius_m``: the CRS sphere).
    """
    rho = 2.0 * radius_m * math.tan(math.radians(90.0 - cut_lat) / 2.0)
    n = int(math.ceil(2.0 * rho / pixel_m))
    x = (np.arange(n) + 0.5 - n / 2.0) * pixel_m
    return x, x[::-1].copy()


def reproject_polar(
    elevation: NDArray[np.floating],
    lat: NDArray[np.floating],
    lon: NDArray[np.floating],
    north: bool,
    cut_lat: float = 65.0,
    pixel_m: float | None = None,
    *,
    body: Body,
) -> dict[str, Any]:
    """Reproject one polar cap of an equirectangular DEM.

    Parameters
    ----------
    elevation : (H, W) m above the datum, rows north to south
    lat, lon : (H,), (W,) pixel centres, degrees
    north : the north cap (else the south)
    cut_lat : the cap is |lat| >= cut_lat
    pixel_m : output pixel size, m (default: the DEM's north-south pixel size on the CRS sphere)

    Returns
    -------
    dict: ``values`` (Hp, Wp) float32, ``x``, ``y`` (m), ``crs`` (code), ``pixel_m``,
    ``valid_fraction`` (share of the cap's pixels holding a value).
    """
    if pixel_m is None:
        pixel_m = body.radius_m * math.radians(abs(float(lat[1] - lat[0])))
    crs = body.crs("north_polar" if north else "south_polar")
    x, y = polar_grid(cut_lat, pixel_m, body.radius_m)
    tr = pyproj.Transformer.from_crs(crs, body.crs("geographic"), always_xy=True)
    values = np.full((y.size, x.size), np.nan, dtype=np.float32)
    n_cap = 0
    step = max(1, (1 << 20) // max(x.size, 1))
    for r0 in range(0, y.size, step):
        xx, yy = np.meshgrid(x, y[r0 : r0 + step])
        qlon, qlat = tr.transform(xx, yy)
        inside = np.abs(qlat) >= cut_lat
        n_cap += int(inside.sum())
        v = sample_bilinear(elevation, lat, lon, np.where(inside, qlat, np.nan), qlon)
        values[r0 : r0 + step] = np.where(inside, v, np.nan)
    valid = float(np.isfinite(values).sum() / n_cap) if n_cap else float("nan")
    return {"values": values, "x": x, "y": y, "crs": crs, "pixel_m": pixel_m, "valid_fraction": valid}
