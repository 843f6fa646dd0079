"""The bucket index of the gridding search: latitude bands of longitude cells on the datum sphere (numba).

Points are bucketed by their footprint's latitude into bands of height ``band_h``
(radians) and, within a band, by longitude into ``band_ncell[b]`` equal cells, so a
cell is about ``band_h`` wide on the ground at the band's widest latitude. Points are
stored sorted by cell, band after band, so the cells of a band in a longitude interval
are one contiguous run of points. The cell size follows the cloud's density (about
``points_per_cell`` points per cell over the area the cloud occupies). The sort is a
stable counting sort in two levels, by band then by cell within each band
(:func:`_bucket_order`), so that no pass writes points to random places in memory.

Why our own index and not ``scipy.spatial.cKDTree``: see :mod:`mercury_dem.dem.buckets`
(the search is fused with the reduction; a kd-tree cannot do that). The search reads the
index through :class:`SearchTables` (:meth:`SphereBuckets.tables`): one tuple numba takes
as a single argument, instead of eight positional ones.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any, NamedTuple

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray

#: Mean points per cell where the cloud lies, and band height / cell width. A query scans
#: whole bands (one contiguous run of points each) over the cells its cap's longitudes
#: touch: narrow cells cost nothing but the ``cell_start`` entries and trim the overhang.
POINTS_PER_CELL = 1.5
CELL_ASPECT = 2.0

# Concurrent launches of numba's default (workqueue) parallel layer from several threads
# are unsafe: parallel kernels are serialised per process (each uses all its threads).
_PARALLEL_LOCK = threading.Lock()


def run_parallel(kernel: Any, threads: int, *args: Any) -> None:
    """Launch a parallel kernel on ``threads`` threads (-1: all numba's), one launch at a time."""
    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at numba's import
    n = most if threads < 1 else min(threads, most)
    with _PARALLEL_LOCK:
        old = numba.get_num_threads()
        numba.set_num_threads(n)
        try:
            kernel(*args)
        finally:
            numba.set_num_threads(old)


class SearchTables(NamedTuple):
    """The index as the compiled search reads it (one argument of the kernels).

    Attributes
    ----------
    xyz : (N, 3) float64, footprints sorted by cell (m)
    radius : (N,) float64, their points' radii (m)
    lat0 : float, southern edge of band 0 (radians)
    inv_bh : float, 1 / the band height (1/radians)
    lon_span : float, longitudes the cells cover from their origin (radians)
    band_invw : (B,) float64, cells per radian of each band (its cells / lon_span)
    band_first : (B + 1,) int64, each band's first cell
    cell_start : (C + 1,) int64, each cell's first sorted point
    """

    xyz: NDArray[np.float64]
    radius: NDArray[np.float64]
    lat0: float
    inv_bh: float
    lon_span: float
    band_invw: NDArray[np.float64]
    band_first: NDArray[np.int64]
    cell_start: NDArray[np.int64]


@dataclass(frozen=True)
class SphereBuckets:
    """Points of a cloud bucketed on the datum sphere (arrays sorted by cell).

    Attributes
    ----------
    xyz : (N, 3) float64, footprints on the datum sphere, body-fixed metres, sorted by cell
    radius : (N,) float64, the points' radii |p| (m), same order
    order : (N,) int64, original row of each sorted point
    lat0, band_h : float, southern edge of band 0 and band height (radians)
    lon0, lon_span : float, the cells cover east longitudes lon0 .. lon0 + lon_span (radians,
        2 pi for a cloud around the planet; a regional cloud's empty longitudes get no cells)
    band_ncell : (B,) int64, longitude cells of each band
    band_first : (B + 1,) int64, index of each band's first cell
    cell_start : (C + 1,) int64, first sorted point of each cell
    density : float, points per steradian over the area the cloud occupies
    sphere_radius : float, radius of the footprint sphere (m)
    """

    xyz: NDArray[np.float64]
    radius: NDArray[np.float64]
    order: NDArray[np.int64]
    lat0: float
    band_h: float
    lon0: float
    lon_span: float
    band_ncell: NDArray[np.int64]
    band_first: NDArray[np.int64]
    cell_start: NDArray[np.int64]
    density: float
    sphere_radius: float

    @property
    def n_points(self) -> int:
        return int(self.radius.shape[0])

    def tables(self) -> SearchTables:
        """The index as the kernels read it (reciprocals: the search multiplies instead of dividing)."""
        return SearchTables(self.xyz, self.radius, self.lat0, 1.0 / self.band_h, self.lon_span,
                            self.band_ncell / self.lon_span, self.band_first, self.cell_start)

    def start_angle(self, k: int) -> float:
        """Initial search cap (radians) expected to hold about 2k + 4 points."""
        return math.sqrt((2.0 * k + 4.0) / (math.pi * self.density))


@numba.njit(cache=True, nogil=True)
def _occupancy(lat: NDArray[np.float64], lon: NDArray[np.float64], c: float, nlat: int, nlon: int,  # pragma: no cover - compiled
               nbin: int) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64], float, float]:
    """One pass over the footprints: coarse lat/lon cells holding points (``nlat x nlon`` of
    edge c radians), the least and greatest longitude in each 2 pi / nbin longitude bin
    (+inf / -inf where empty), and the latitude range.
    """
    occ = np.zeros(nlat * nlon, dtype=np.bool_)
    bin_lo = np.full(nbin, np.inf)
    bin_hi = np.full(nbin, -np.inf)
    lat_lo = np.inf
    lat_hi = -np.inf
    for p in range(lat.size):
        f = lat[p]
        t = lon[p]
        i = min(max(int((f + math.pi / 2) / c), 0), nlat - 1)
        j = min(max(int(t / c), 0), nlon - 1)
        occ[i * nlon + j] = True
        q = min(int(t / (2 * math.pi) * nbin), nbin - 1)
        bin_lo[q] = min(bin_lo[q], t)
        bin_hi[q] = max(bin_hi[q], t)
        lat_lo = min(lat_lo, f)
        lat_hi = max(lat_hi, f)
    return occ, bin_lo, bin_hi, lat_lo, lat_hi


def _max_from(bin_lo: NDArray[np.float64], bin_hi: NDArray[np.float64], origin: float) -> float:
    """max over the points of (lon - origin) mod 2 pi (numpy's floored modulo), from each
    longitude bin's least and greatest longitude (:func:`_occupancy`; no pass over the points).

    The modulo increases with lon on either side of ``origin``, so a bin whose points are all
    on one side reaches its maximum at its greatest longitude: the exact value of a pass over
    the points. A bin with points on both sides (only by rounding at a bin edge) would need
    the greatest point below ``origin``: then 2 pi, a span that surely holds every point.
    """
    occupied = np.isfinite(bin_hi)
    lo, hi = bin_lo[occupied], bin_hi[occupied]
    if np.any((lo < origin) & (hi >= origin)):
        return 2 * math.pi
    return float(np.max(np.mod(hi - origin, 2 * math.pi)))


#: Longitude bins (0.5 degree) of :func:`_lon_extent`.
LON_BINS = 720


def _coarse_edge(n: int) -> float:
    """Edge (radians) of :func:`_occupied_density`'s coarse cells: ~20 points per cell for a global cloud."""
    return math.radians(min(15.0, max(0.5, math.sqrt(41253.0 / max(n / 20.0, 1.0)))))


def _occupied_density(occ: NDArray[np.bool_], c: float, n: int) -> float:
    """Points per steradian over the area of the coarse lat/lon cells holding points.

    ``occ``: the (nlat x nlon) occupancy of cells of edge ``c`` (:func:`_occupancy`), so a
    regional cloud is not diluted over the whole sphere.
    """
    nlat = int(math.ceil(math.pi / c))
    nlon = int(math.ceil(2 * math.pi / c))
    edges = np.minimum(-math.pi / 2 + np.arange(nlat + 1) * c, math.pi / 2)
    band_area = (np.sin(edges[1:]) - np.sin(edges[:-1])) * c  # last lon cell may be narrower: ignored
    area = float((occ.reshape(nlat, nlon).sum(axis=1) * band_area).sum())
    return n / max(area, 1e-30)


def _prepare_body(p: NDArray[np.float64], r: NDArray[np.float64], sine: NDArray[np.float64], x_out: NDArray[np.float64], y_out: NDArray[np.float64],  # pragma: no cover - compiled
                  bad: NDArray[np.uint8]) -> None:
    for i in prange(p.shape[0]):
        x = p[i, 0]
        y = p[i, 1]
        z = p[i, 2]
        x_out[i] = x  # contiguous copies for numpy's arctan2 (SIMD only on contiguous input)
        y_out[i] = y
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            bad[i] = 1
            continue
        rr = math.sqrt((x * x + z * z) + y * y)  # numpy's einsum('ij,ij->i') order: the same bits
        r[i] = rr
        if not rr > 0.0:
            bad[i] = 2
            continue
        sine[i] = min(1.0, max(-1.0, z / rr))  # its arcsine is taken by numpy


def _wrap_lon_body(lon: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    for i in prange(lon.size):
        t = lon[i]
        t = t + 2.0 * math.pi if t < 0.0 else t + 0.0  # Python's t % 2 pi for t in [-pi, pi], -0.0 -> 0.0 included
        lon[i] = 0.0 if t >= 2.0 * math.pi else t


#: Points per work item of the bucketing passes (each counts its points per band).
SORT_CHUNK = 65536


def _band_cell_body(lat: NDArray[np.float64], lon: NDArray[np.float64], lat0: float, band_h: float, lon0: float,  # pragma: no cover
                    lon_span: float, band_ncell: NDArray[np.int64], band: NDArray[np.int32], local: NDArray[np.int32], hist: NDArray[np.int64]) -> None:
    """Pass 1 of bucketing: each point's band and cell within its band; points per band in each chunk."""
    nb = band_ncell.size
    n = lat.size
    for ch in prange(hist.shape[0]):
        for p in range(ch * SORT_CHUNK, min(n, (ch + 1) * SORT_CHUNK)):
            b = int(math.floor((lat[p] - lat0) / band_h))
            b = min(max(b, 0), nb - 1)
            nc = band_ncell[b]
            u = (lon[p] - lon0) % (2.0 * math.pi)
            j = int(math.floor(u / (lon_span / nc)))
            band[p] = b
            local[p] = min(max(j, 0), nc - 1)
            hist[ch, b] += 1


def _band_scatter_body(pts: NDArray[np.float64], radius: NDArray[np.float64], rs: float, band: NDArray[np.int32], local: NDArray[np.int32],  # pragma: no cover
                       offset: NDArray[np.int64], xyz_out: NDArray[np.float64], r_out: NDArray[np.float64], order: NDArray[np.int64], local_out: NDArray[np.int32]) -> None:
    """Pass 2: points into band order (stable), each chunk from its own offsets; footprints made here."""
    n = band.size
    for ch in prange(offset.shape[0]):
        pos = offset[ch].copy()
        for p in range(ch * SORT_CHUNK, min(n, (ch + 1) * SORT_CHUNK)):
            b = band[p]
            d = pos[b]
            pos[b] = d + 1
            r = radius[p]
            f = rs / r  # footprint = point x (rs / |p|)
            xyz_out[d, 0] = pts[p, 0] * f
            xyz_out[d, 1] = pts[p, 1] * f
            xyz_out[d, 2] = pts[p, 2] * f
            r_out[d] = r
            order[d] = p
            local_out[d] = local[p]


def _cell_sort_body(band_start: NDArray[np.int64], band_ncell: NDArray[np.int64], band_first: NDArray[np.int64], xyz: NDArray[np.float64], r: NDArray[np.float64],  # pragma: no cover
                    order: NDArray[np.int64], local: NDArray[np.int32], cell_start: NDArray[np.int64]) -> None:
    """Pass 3: within each band (a contiguous run after pass 2), a stable counting sort by cell."""
    for b in prange(band_ncell.size):
        s = band_start[b]
        m = band_start[b + 1] - s
        nc = band_ncell[b]
        f = band_first[b]
        pos = np.zeros(nc + 1, dtype=np.int64)
        for t in range(m):
            pos[local[s + t] + 1] += 1
        for j in range(nc):
            pos[j + 1] += pos[j]
        for j in range(nc):
            cell_start[f + j] = s + pos[j]
        xs = xyz[s:s + m].copy()
        rs_ = r[s:s + m].copy()
        os_ = order[s:s + m].copy()
        ls = local[s:s + m].copy()
        for t in range(m):
            j = ls[t]
            d = s + pos[j]
            pos[j] += 1
            xyz[d, 0] = xs[t, 0]
            xyz[d, 1] = xs[t, 1]
            xyz[d, 2] = xs[t, 2]
            r[d] = rs_[t]
            order[d] = os_[t]


_prepare = numba.njit(parallel=True, cache=True, nogil=True)(_prepare_body)
_wrap_lon = numba.njit(parallel=True, cache=True, nogil=True)(_wrap_lon_body)
_band_cell = numba.njit(parallel=True, cache=True, nogil=True)(_band_cell_body)
_band_scatter = numba.njit(parallel=True, cache=True, nogil=True)(_band_scatter_body)
_cell_sort = numba.njit(parallel=True, cache=True, nogil=True)(_cell_sort_body)


def _bucket_order(pts: NDArray[np.float64], radius: NDArray[np.float64], lat: NDArray[np.float64], lon: NDArray[np.float64], rs: float, lat0: float, band_h: float, lon0: float,
                  lon_span: float, ncell: NDArray[np.int64], band_first: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Points sorted by cell (stable): footprints, radii, input rows and the cells' starts.

    Why three passes and not one counting sort by cell: a single sort writes (or gathers)
    each point at a random place in arrays of tens of MB, one cache miss per point, which
    made it most of the index's time. Sorting by band first (a few hundred to a few
    thousand runs written in sequence), then by cell inside each band (a run small enough
    for the cache, bands in parallel) gives the same stable order for a fraction of it.
    """
    n = lat.size
    nb = ncell.size
    nch = max(1, -(-n // SORT_CHUNK))
    band = np.empty(n, dtype=np.int32)
    local = np.empty(n, dtype=np.int32)
    hist = np.zeros((nch, nb), dtype=np.int64)
    run_parallel(_band_cell, -1, lat, lon, lat0, band_h, lon0, lon_span, ncell, band, local, hist)
    per_band = hist.sum(axis=0)
    band_start = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(per_band, out=band_start[1:])
    offset = band_start[:-1][None, :] + np.cumsum(hist, axis=0) - hist  # chunk ch's first slot in each band
    xyz, rad = np.empty((n, 3)), np.empty(n)
    order = np.empty(n, dtype=np.int64)
    local_sorted = np.empty(n, dtype=np.int32)
    run_parallel(_band_scatter, -1, pts, radius, float(rs), band, local, offset, xyz, rad, order, local_sorted)
    del band, local
    cell_start = np.empty(int(band_first[-1]) + 1, dtype=np.int64)
    cell_start[-1] = n
    run_parallel(_cell_sort, -1, band_start, ncell, band_first, xyz, rad, order, local_sorted, cell_start)
    return xyz, rad, order, cell_start


def _lon_extent(bin_lo: NDArray[np.float64], bin_hi: NDArray[np.float64]) -> tuple[float, float]:
    """(origin, span) in radians of the smallest longitude interval holding every point.

    The complement of the widest empty gap of the 0.5-degree longitude bins (their least and
    greatest longitudes from :func:`_occupancy`); the whole circle (origin 0) when no gap is
    wider than 5 degrees.
    """
    occ = np.isfinite(bin_hi)
    nbin = occ.size
    if occ.all():
        return 0.0, 2 * math.pi
    # widest circular run of empty bins
    occ2 = np.concatenate([occ, occ])
    idx = np.flatnonzero(occ2)
    gaps = np.diff(idx) - 1
    g = int(np.argmax(gaps))
    if gaps[g] * 360.0 / nbin < 5.0:
        return 0.0, 2 * math.pi
    origin = (idx[g + 1] % nbin) * 2 * math.pi / nbin
    return float(origin), float(min(2 * math.pi, _max_from(bin_lo, bin_hi, origin) * (1 + 1e-12) + 1e-12))


def footprints(points: NDArray[np.float64], sphere_radius: float) -> dict[str, NDArray[Any]]:
    """Radii of the points and the latitude/longitude of their footprints.

    Returns dict: ``radius`` (N,) = |p| (m), ``lat`` (N,) and ``lon`` (N,) of the footprints
    ``p / |p| x sphere_radius`` (radians, lon in [0, 2 pi)), ``bad`` (N,) uint8: 0 valid, 1
    non-finite coordinate, 2 at the centre (the other outputs of a bad point are undefined).
    The radius is the same arithmetic (and bits) as ``np.sqrt(np.einsum('ij,ij->i', p, p))``,
    in one compiled pass without the numpy version's temporaries. The arcsine and arctangent
    are numpy's: on CPUs with AVX-512 numpy evaluates them with SIMD, 3-5 times faster than
    the scalar libm calls of a compiled loop (they were most of this function's time). The
    footprints themselves are only written once, in bucket order (:func:`build_buckets`).
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    n = p.shape[0]
    radius, lat, lon, y = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    bad = np.zeros(n, dtype=np.uint8)
    run_parallel(_prepare, -1, p, radius, lat, lon, y, bad)
    with np.errstate(invalid="ignore"):  # non-finite points give NaN here; they are flagged in ``bad``
        np.arcsin(lat, out=lat)
        np.arctan2(y, lon, out=lon)
    run_parallel(_wrap_lon, -1, lon)
    return {"radius": radius, "lat": lat, "lon": lon, "bad": bad}


def build_buckets(
    points: NDArray[np.float64], sphere_radius: float,
    points_per_cell: float = POINTS_PER_CELL, aspect: float = CELL_ASPECT,
    prepared: dict[str, NDArray[Any]] | None = None,
) -> SphereBuckets:
    """Bucket a validated cloud (finite points, none at the centre).

    Parameters
    ----------
    points : (N, 3) float64, body-fixed points (m); they are bucketed by their footprints
        ``p / |p| x sphere_radius``
    sphere_radius : float, m
    points_per_cell : target mean occupancy of a cell where the cloud lies
    aspect : band height / cell width (a band's cells are ``aspect`` times narrower than it is high)
    prepared : :func:`footprints` of ``points`` if already computed (radius, lat, lon)
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = pts.shape[0]
    f = footprints(pts, sphere_radius) if prepared is None else prepared
    lat, lon, radius = f["lat"], f["lon"], f["radius"]
    c = _coarse_edge(n)
    occ, bin_lo, bin_hi, lat_lo, lat_hi = _occupancy(lat, lon, c, int(math.ceil(math.pi / c)),
                                                     int(math.ceil(2 * math.pi / c)), LON_BINS)
    lat_lo, lat_hi = float(lat_lo), float(lat_hi)
    density = _occupied_density(occ, c, n)
    lon0, lon_span = _lon_extent(bin_lo, bin_hi)
    s = math.sqrt(points_per_cell / density)  # cell edge (radians) of a square cell
    for _ in range(8):  # grow cells until their count is at most ~4 per point
        sh = s * math.sqrt(aspect)
        nb = max(1, int(math.ceil((lat_hi - lat_lo) / sh)))
        band_h = (lat_hi - lat_lo) / nb if lat_hi > lat_lo else sh
        lo_edge = lat_lo + band_h * np.arange(nb)
        hi_edge = lo_edge + band_h
        cosmax = np.where((lo_edge <= 0) & (hi_edge >= 0), 1.0, np.maximum(np.cos(lo_edge), np.cos(hi_edge)))
        ncell = np.clip(np.floor(lon_span * cosmax / (s / math.sqrt(aspect))), 1, None).astype(np.int64)
        if ncell.sum() <= 4 * n + 1024:
            break
        s *= math.sqrt(ncell.sum() / (4 * n + 1024))
    band_first = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(ncell, out=band_first[1:])
    xyz, rad, order, cell_start = _bucket_order(pts, radius, lat, lon, sphere_radius, lat_lo, band_h, lon0, lon_span,
                                                ncell, band_first)
    return SphereBuckets(
        xyz=xyz,
        radius=rad,
        order=order,
        lat0=lat_lo,
        band_h=float(band_h),
        lon0=lon0,
        lon_span=lon_span,
        band_ncell=ncell,
        band_first=band_first,
        cell_start=cell_start,
        density=density,
        sphere_radius=float(sphere_radius),
    )
