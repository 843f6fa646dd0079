"""NaN-aware bilinear sampling of an equirectangular grid at arbitrary latitude/longitude.

Used to reproject the DEM (polar stereographic caps, the Robinson browse map) and to
sample elevation profiles. Written here rather than with
``scipy.ndimage.map_coordinates`` because that propagates one NaN corner to the whole
result and knows nothing of the 0/360 seam; here missing corners are dropped and their
weight renormalised (a result needs at least half the weight), and columns wrap on a
global grid.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Output samples handled per block (bounds the temporaries).
BLOCK = 1 << 20


def sample_bilinear(
    grid: NDArray[np.floating],
    lat_centres: NDArray[np.floating],
    lon_centres: NDArray[np.floating],
    qlat: NDArray[np.floating],
    qlon: NDArray[np.floating],
) -> NDArray[np.float32]:
    """Bilinear values of ``grid`` at (qlat, qlon), degrees; NaN where unknown.

    Parameters
    ----------
    grid : (H, W) values on an equirectangular grid, rows north to south
    lat_centres, lon_centres : (H,), (W,) regularly spaced pixel centres, degrees
    qlat, qlon : query coordinates of any (same) shape, degrees (NaN allowed)

    Returns
    -------
    float32 array of the queries' shape.
    """
    H, W = grid.shape
    lat0, lon0 = float(lat_centres[0]), float(lon_centres[0])
    dlat = float(lat_centres[1] - lat_centres[0]) if H > 1 else -1.0  # negative: north to south
    dlon = float(lon_centres[1] - lon_centres[0]) if W > 1 else 1.0
    wrap = abs(abs(dlon) * W - 360.0) < 1e-6
    shape = np.shape(qlat)
    ql = np.asarray(qlat, dtype=np.float64).ravel()
    qo = np.asarray(qlon, dtype=np.float64).ravel()
    out = np.full(ql.size, np.nan, dtype=np.float32)
    for s in range(0, ql.size, BLOCK):
        la, lo = ql[s : s + BLOCK], qo[s : s + BLOCK]
        fi = (la - lat0) / dlat
        with np.errstate(invalid="ignore"):
            dl = np.mod(lo - lon0, 360.0)
        if not wrap:  # just west of the first column: a small negative offset
            dl = np.where(dl > 360.0 - dlon, dl - 360.0, dl)
        fj = dl / dlon
        fi = np.clip(fi, 0.0, H - 1)  # within half a pixel of the first/last row: the edge row
        good = np.isfinite(fi) & np.isfinite(fj)
        fi = np.where(good, fi, 0.0)
        fj = np.where(good, fj, 0.0)
        i0 = np.minimum(np.floor(fi).astype(np.int64), max(H - 2, 0))
        j0 = np.floor(fj).astype(np.int64)
        t = fi - i0
        u = fj - j0
        acc = np.zeros(la.size)
        wsum = np.zeros(la.size)
        for di, dj, w in ((0, 0, (1 - t) * (1 - u)), (1, 0, t * (1 - u)), (0, 1, (1 - t) * u), (1, 1, t * u)):
            ii = np.minimum(i0 + di, H - 1)
            jj = j0 + dj
            if wrap:
                jj = np.mod(jj, W)
                inside = good.copy()
            else:
                inside = good & (jj >= 0) & (jj < W)
                jj = np.clip(jj, 0, W - 1)
            v = grid[ii, jj].astype(np.float64)
            ok = inside & np.isfinite(v)
            acc += np.where(ok, w * np.where(ok, v, 0.0), 0.0)
            wsum += np.where(ok, w, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[s : s + BLOCK] = np.where(wsum >= 0.5, acc / wsum, np.nan)
    return out.reshape(shape)
