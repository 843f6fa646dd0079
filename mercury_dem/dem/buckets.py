"""Neighbour search on the datum sphere for pixel-ordered queries: latitude bands of longitude cells (numba).

Why not only ``scipy.spatial.cKDTree``
--------------------------------------
Gridding asks, for every pixel centre of a map, for the k (11) nearest points or the
points within 1.41 pixel, then reduces them (1-sigma median, Shepard weights). With a
kd-tree that is one generic query returning ``(P, k)`` distance/index arrays, then a
second pass in numpy over those arrays. Profiling the DEM stage showed the query
(about 60 %) and the ``(P, k)`` post-processing dominating; ``cKDTree`` cannot fuse
the reduction into the search. A bucket grid on the sphere, searched and reduced in
one compiled loop per pixel, does both with no ``(P, k)`` arrays at all. The kd-tree
remains the exact fallback for the rare pixels this search gives up on (far from
every point, see ``ang_max``) and for the tests' independent checks.

Structure
---------
Points are bucketed by their footprint's latitude into bands of height ``band_h``
(radians) and, within a band, by longitude into ``band_ncell[b]`` equal cells, so a
cell is about ``band_h`` wide on the ground at the band's widest latitude. Points are
stored sorted by cell, band after band, so the cells of a band in a longitude interval
are one contiguous run of points. The cell size follows the cloud's density (about
``points_per_cell`` points per cell over the area the cloud occupies). The sort is a
stable counting sort in two levels, by band then by cell within each band
(:func:`_bucket_order`), so that no pass writes points to random places in memory.

Search
------
For a query direction at latitude phi and an angular radius a, every point within a
lies in the bands covering [phi - a, phi + a] and, unless the cap reaches a pole,
within longitude +-asin(sin a / cos phi) (the bounding box of a spherical cap). Every
point within the cap is a candidate, so as soon as k candidates lie within it they are
exactly the k nearest. The k-NN search tries a cap slightly above the previous pixel's
k-th distance (``GROW``), then one that surely holds k points (triangle inequality),
else (a block's first pixel) a cap expected to hold ~2k points, and doubles it until
k lie within or the cap exceeds ``ang_max`` (the pixel is marked for the kd-tree).
Distances are chords between footprints on the 2439.4 km datum sphere, metres.

A pixel's result depends only on its own centre and the index (the scan order is
fixed by the index), never on which other pixels are computed with it, so chunked
maps are bit-identical to whole ones.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray

#: Pixels per parallel work item of the kernels (each item allocates its scratch once).
BLOCK = 256

#: Candidates buffered per pixel before ranking (beyond: ranked while scanning).
BUFFER = 2048

#: Mean points per cell where the cloud lies, and band height / cell width. A query scans
#: whole bands (one contiguous run of points each) over the cells its cap's longitudes
#: touch: narrow cells cost nothing but the ``cell_start`` entries and trim the overhang.
POINTS_PER_CELL = 1.5
CELL_ASPECT = 2.0

#: First k-NN cap of a pixel: this factor x the previous pixel's k-th distance (the
#: neighbouring pixel's k-th distance is rarely much shorter); the triangle-inequality
#: bound is the second try, then doubling.
GROW = 1.15

#: Up to this many values, top-k selection and sorting count ranks instead of inserting.
RANK_MAX = 64

#: Below this (radians) the search bounds a cap's sine and angle by cheap series (conservatively).
SMALL_ANGLE = 0.01

#: Status of a pixel in the kernels' output.
OK, NEEDS_FALLBACK = 0, 1

# Concurrent launches of numba's default (workqueue) parallel layer from several threads
# are unsafe: parallel kernels are serialised per process (each uses all its threads).
_PARALLEL_LOCK = threading.Lock()


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

    def start_angle(self, k: int) -> float:
        """Initial search cap (radians) expected to hold about 2k + 4 points."""
        return math.sqrt((2.0 * k + 4.0) / (math.pi * self.density))


@numba.njit(cache=True, nogil=True)
def _occupancy(lat, lon, c, nlat, nlon, nbin):  # pragma: no cover - compiled
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


def _prepare_body(p, r, sine, x_out, y_out, bad):  # pragma: no cover - compiled
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


def _wrap_lon_body(lon):  # pragma: no cover - compiled
    for i in prange(lon.size):
        t = lon[i]
        t = t + 2.0 * math.pi if t < 0.0 else t + 0.0  # Python's t % 2 pi for t in [-pi, pi], -0.0 -> 0.0 included
        lon[i] = 0.0 if t >= 2.0 * math.pi else t


#: Points per work item of the bucketing passes (each counts its points per band).
SORT_CHUNK = 65536


def _band_cell_body(lat, lon, lat0, band_h, lon0, lon_span, band_ncell, band, local, hist):  # pragma: no cover
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


def _band_scatter_body(pts, radius, rs, band, local, offset, xyz_out, r_out, order, local_out):  # pragma: no cover
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


def _cell_sort_body(band_start, band_ncell, band_first, xyz, r, order, local, cell_start):  # pragma: no cover
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


def _bucket_order(pts, radius, lat, lon, rs, lat0, band_h, lon0, lon_span, ncell, band_first):
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
    _run(_band_cell, -1, lat, lon, lat0, band_h, lon0, lon_span, ncell, band, local, hist)
    per_band = hist.sum(axis=0)
    band_start = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(per_band, out=band_start[1:])
    offset = band_start[:-1][None, :] + np.cumsum(hist, axis=0) - hist  # chunk ch's first slot in each band
    xyz, rad = np.empty((n, 3)), np.empty(n)
    order = np.empty(n, dtype=np.int64)
    local_sorted = np.empty(n, dtype=np.int32)
    _run(_band_scatter, -1, pts, radius, float(rs), band, local, offset, xyz, rad, order, local_sorted)
    del band, local
    cell_start = np.empty(int(band_first[-1]) + 1, dtype=np.int64)
    cell_start[-1] = n
    _run(_cell_sort, -1, band_start, ncell, band_first, xyz, rad, order, local_sorted, cell_start)
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
    out = {"radius": np.empty(n), "lat": np.empty(n), "lon": np.empty(n), "bad": np.zeros(n, dtype=np.uint8)}
    y = np.empty(n)
    _run(_prepare, -1, p, out["radius"], out["lat"], out["lon"], y, out["bad"])
    with np.errstate(invalid="ignore"):  # non-finite points give NaN here; they are flagged in ``bad``
        np.arcsin(out["lat"], out=out["lat"])
        np.arctan2(y, out["lon"], out=out["lon"])
    _run(_wrap_lon, -1, out["lon"])
    return out


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


# ----------------------------------------------------------------------------------------------
# compiled search
# ----------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _band_run(lo, hi, iw, last, lon_span, f, cell_start, out, n):  # pragma: no cover
    """Append to ``out`` the run of sorted points in the cells of the band starting at cell f
    (cells 0..last, iw cells per radian) that meet the longitudes [lo, hi]; return the count.
    """
    j0 = 0 if lo <= 0.0 else min(int(math.floor(lo * iw)), last)
    j1 = last if hi >= lon_span else min(int(math.floor(hi * iw)), last)
    out[n, 0] = cell_start[f + j0]
    out[n, 1] = cell_start[f + j1 + 1]
    return n + 1


@numba.njit(cache=True, inline="always")
def _ranges(lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, a, out):  # pragma: no cover
    """Contiguous runs of sorted points that hold every point within angle a of (phi, u).

    ``u`` is the query's east longitude from the cells' origin, in [0, 2 pi) (per column:
    ``(lam - lon0) mod 2 pi``), ``icp`` is ``1 / cos(phi)`` (per row), ``inv_bh`` is 1 / the
    band height and ``band_invw[b]`` the cells per radian of band b (its cells / lon_span):
    reciprocals so the search multiplies instead of dividing. Bands and cells found with
    them are those of the division, or one further out: the cap is widened by 1e-9 of itself
    plus 1e-12 rad, far more than the few ulps the reciprocal can shift a boundary by, so
    the runs still hold the whole cap (a wider run only costs time, never changes a result).
    Writes ``[start, end)`` pairs into ``out`` (at least 2 x bands rows); returns their number.
    """
    nb = band_invw.size
    ae = a * (1.0 + 1e-9) + 1e-12
    b0 = int(math.floor((phi - ae - lat0) * inv_bh))
    b1 = int(math.floor((phi + ae - lat0) * inv_bh))
    if b0 < 0:
        b0 = 0
    if b1 > nb - 1:
        b1 = nb - 1
    full = ae >= math.pi or phi + ae >= 0.5 * math.pi or phi - ae <= -0.5 * math.pi
    dl = math.pi
    if not full:
        # sin(ae) <= ae: for small caps ae itself (a conservative bound, one sine fewer per cap)
        sa = ae if ae < SMALL_ANGLE else math.sin(ae)
        x = sa * icp
        if x >= 1.0:
            full = True
        else:
            # asin(x) = x + x^3/6 + 3 x^5/40 + ... <= x (1 + x^2 / 5) for small x (no arcsine per cap)
            dl = (x * (1.0 + 0.2 * x * x) if x < SMALL_ANGLE else math.asin(x)) * (1.0 + 1e-9) + 1e-12
            full = dl >= math.pi
    n = 0
    if full:
        for b in range(b0, b1 + 1):
            out[n, 0] = cell_start[band_first[b]]
            out[n, 1] = cell_start[band_first[b + 1]]
            n += 1
        return n
    # the interval [u - dl, u + dl] and its copies one turn away, cut to the cells [0, lon_span):
    # shorter than a turn, it meets [0, 2 pi) in at most two pieces, the same for every band
    # (u is in [0, 2 pi): the copy one turn up or down is the only other one that can meet it)
    ua = u - dl
    ub = u + dl
    one = ua < lon_span
    va = vb = 0.0
    two = False
    if ua < 0.0:  # the piece below 0 wraps to the top: [ua + 2 pi, 2 pi)
        va = ua + 2.0 * math.pi
        vb = 2.0 * math.pi
        two = va < lon_span
    elif ub >= 2.0 * math.pi:  # the piece above 2 pi wraps to the bottom: [0, ub - 2 pi]
        vb = ub - 2.0 * math.pi
        two = True
    for b in range(b0, b1 + 1):
        f = band_first[b]
        last = band_first[b + 1] - f - 1
        iw = band_invw[b]
        if one:
            n = _band_run(ua, ub, iw, last, lon_span, f, cell_start, out, n)
        if two:
            n = _band_run(va, vb, iw, last, lon_span, f, cell_start, out, n)
    return n


@numba.njit(cache=True, inline="always")
def _insert(dk2, ik, m, k, d2, i):  # pragma: no cover
    """Insert (d2, i) into the ascending top-k list (ties broken by point index); return its new length."""
    if m < k:
        j = m - 1
        m += 1
    elif d2 < dk2[k - 1] or (d2 == dk2[k - 1] and i < ik[k - 1]):
        j = k - 2
    else:
        return m
    while j >= 0 and (dk2[j] > d2 or (dk2[j] == d2 and ik[j] > i)):
        dk2[j + 1] = dk2[j]
        ik[j + 1] = ik[j]
        j -= 1
    dk2[j + 1] = d2
    ik[j + 1] = i
    return m


@numba.njit(cache=True, inline="always")
def _topk(bd2, bi, m, k, dk2, ik):  # pragma: no cover
    """The min(k, m) smallest (bd2[j], bi[j]) of j < m, ascending, into (dk2, ik); returns how many.

    Same result as inserting them one by one with :func:`_insert`. Up to ``RANK_MAX``
    candidates, each one's rank is counted (an O(m^2) loop without data-dependent
    branches, several times faster than insertion's unpredictable shifts at m ~ 10-30).
    """
    if m > RANK_MAX:
        mk = 0
        for j in range(m):
            mk = _insert(dk2, ik, mk, k, bd2[j], bi[j])
        return mk
    for a in range(m):
        da = bd2[a]
        ia = bi[a]
        r = 0
        for b in range(m):
            db = bd2[b]
            r += (db < da) | ((db == da) & (bi[b] < ia))
        if r < k:
            dk2[r] = da
            ik[r] = ia
    return min(m, k)


@numba.njit(cache=True)
def _scan(xyz, ranges, nr, qx, qy, qz, k, d2max, r2count, dk2, ik):  # pragma: no cover
    """Keep the k smallest squared distances <= d2max (sorted, with indices); count those <= r2count.

    Returns (number kept, number within the count radius).
    """
    m = 0
    cnt = 0
    for t in range(nr):
        for i in range(ranges[t, 0], ranges[t, 1]):
            dx = xyz[i, 0] - qx
            dy = xyz[i, 1] - qy
            dz = xyz[i, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= r2count:
                cnt += 1
            if d2 <= d2max:
                m = _insert(dk2, ik, m, k, d2, i)
    return m, cnt


@numba.njit(cache=True, inline="always")
def _collect(xyz, ranges, nr, qx, qy, qz, cap2, r2count, bd2, bi):  # pragma: no cover
    """Squared distances <= cap2 into (bd2, bi); returns (how many there were, count <= r2count).

    More than ``bd2.size`` means the buffer overflowed (only its first entries are stored).
    When every point of the ranges fits in the buffer, each one is stored and the
    position advanced by the test's 0/1 (no data-dependent branch: about half the
    tests go either way, so a branch is mispredicted about half the time).
    """
    m = 0
    cnt = 0
    nbuf = bd2.size
    tot = 0
    for t in range(nr):
        tot += ranges[t, 1] - ranges[t, 0]
    if tot <= nbuf:
        # Unsigned indices: numba then drops its negative-index wraparound test from every
        # access (measured: the median11 kernel 8 % faster).
        um = numba.uint64(0)
        for t in range(nr):
            for i in range(numba.uint64(ranges[t, 0]), numba.uint64(ranges[t, 1])):
                dx = xyz[i, 0] - qx
                dy = xyz[i, 1] - qy
                dz = xyz[i, 2] - qz
                d2 = dx * dx + dy * dy + dz * dz
                cnt += d2 <= r2count
                bd2[um] = d2
                bi[um] = i
                um += numba.uint64(d2 <= cap2)
        return numba.int64(um), cnt
    for t in range(nr):
        for i in range(ranges[t, 0], ranges[t, 1]):
            dx = xyz[i, 0] - qx
            dy = xyz[i, 1] - qy
            dz = xyz[i, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= r2count:
                cnt += 1
            if d2 <= cap2:
                if m < nbuf:
                    bd2[m] = d2
                    bi[m] = i
                m += 1
    return m, cnt


@numba.njit(cache=True, nogil=True)
def _centres(lat_deg, lon_deg, rs, lon0, phi, c, z, icp, u, cl, sl):  # pragma: no cover
    """Pixel centres on the sphere of radius rs (m) from latitudes and longitudes (degrees).

    Per latitude: phi (radians), c = rs cos(phi), z = rs sin(phi), icp = 1 / cos(phi); per
    longitude: lam in [0, 2 pi), its cosine and sine, and u = (lam - lon0) mod 2 pi, the
    longitude from the cells' origin lon0 (the search's). A centre is (c cos(lam), c sin(lam), z):
    the same operations whether the centres come as a grid (rows x columns) or as a list.
    """
    for i in range(lat_deg.size):
        f = math.radians(lat_deg[i])
        phi[i] = f
        cp = math.cos(f)
        icp[i] = 1.0 / cp
        c[i] = rs * cp
        z[i] = rs * math.sin(f)
    for j in range(lon_deg.size):
        t = math.radians(lon_deg[j]) % (2.0 * math.pi)
        if t >= 2.0 * math.pi:
            t = 0.0
        u[j] = (t - lon0) % (2.0 * math.pi)
        cl[j] = math.cos(t)
        sl[j] = math.sin(t)


@numba.njit(cache=True, inline="always")
def _centre(p, paired, ncol, phi_r, u_c, c_r, cl_c, sl_c, z_r, icp_r):  # pragma: no cover
    """Pixel p's centre: (latitude, longitude from the cells' origin, x, y, z, 1 / cos(latitude)) from
    the per-row/column tables;
    ``paired``: row p with column p (scattered pixels), else p = row * ncol + column (a grid).
    """
    if paired:
        i = p
        j = p
    else:
        i = p // ncol
        j = p - i * ncol
    return phi_r[i], u_c[j], c_r[i] * cl_c[j], c_r[i] * sl_c[j], z_r[i], icp_r[i]


@numba.njit(cache=True, inline="always")
def _cap_chord2(a, rs):  # pragma: no cover
    """Squared chord of a cap of angle ``a`` on the sphere of radius ``rs`` (inf for the whole sphere)."""
    if a >= math.pi:
        return np.inf
    ch = 2.0 * rs * math.sin(0.5 * a)
    return ch * ch


@numba.njit(cache=True, inline="always")
def _within_to_front(bd2, bi, m, t2):  # pragma: no cover
    """Move the candidates j < m with bd2[j] <= t2 to the front (pairs swapped); return how many."""
    ms = 0
    for j in range(m):
        if bd2[j] <= t2:
            d, i = bd2[j], bi[j]
            bd2[j], bi[j] = bd2[ms], bi[ms]
            bd2[ms], bi[ms] = d, i
            ms += 1
    return ms


@numba.njit(cache=True, inline="always")
def _next_cap(a, a_second, ang_max):  # pragma: no cover
    """The cap after ``a`` in the k-NN search: ``a_second``, then doubling up to ``ang_max``."""
    if a < a_second:
        return a_second
    return min(2.0 * a, ang_max)


@numba.njit(cache=True, inline="always")
def _knn(xyz, lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, qx, qy, qz, k, a_first,
         a_second, ang_max, rs,
         r2count, ranges, dk2, ik, bd2, bi, t2):  # pragma: no cover
    """Exact k nearest (ascending in dk2/ik): caps a_first, then a_second, then doubling.

    A cap of angle a is scanned whole (every point within a is a candidate), so as soon
    as k candidates lie within it they are the k nearest: any cap sequence gives the
    same result, only the cost differs. ``t2`` is a guess of the k-th squared distance
    (e.g. 1.5 x the previous pixel's): when at least k candidates lie within it, only
    those are ranked. Returns (done, count within r2count).
    """
    a = a_first
    while True:
        nr = _ranges(lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, a, ranges)
        cap2 = _cap_chord2(a, rs)
        m, cnt = _collect(xyz, ranges, nr, qx, qy, qz, cap2, r2count, bd2, bi)
        if m > bd2.size:
            mk, _ = _scan(xyz, ranges, nr, qx, qy, qz, k, cap2, r2count, dk2, ik)
        else:
            mk = 0
            if t2 < cap2:
                ms = _within_to_front(bd2, bi, m, t2)
                if ms >= k:
                    mk = _topk(bd2, bi, ms, k, dk2, ik)
            if mk < k:
                mk = _topk(bd2, bi, m, k, dk2, ik)
        if mk >= k:
            return True, cnt
        if a >= ang_max:
            return False, cnt
        a = _next_cap(a, a_second, ang_max)


@numba.njit(cache=True, inline="always")
def _smallest_set(bd2, bi, m, k, dk2, ik):  # pragma: no cover
    """The k smallest (bd2[j], bi[j]) of j < m (k <= m) into (dk2[:k], ik[:k]) in any order.

    Returns (smallest, k-th smallest) squared distance. The set is the one :func:`_topk`
    gives (ties by point index). When only a few are in excess, the largest are dropped
    one at a time (m - k passes over m values, without insertion's unpredictable
    shifts); otherwise ranked with :func:`_topk`.
    """
    if m - k > 8:
        _topk(bd2, bi, m, k, dk2, ik)
        return dk2[0], dk2[k - 1]
    m0 = m
    for j in range(m):
        dk2[j] = bd2[j]
        ik[j] = bi[j]
    # Distances alone first: m - k times, the largest is found (a branch-free max pass, then its
    # first position) and dropped. The set is the tie-aware one unless the last value dropped (the
    # smallest dropped) equals a kept one -- a tie at the k-th place, as with duplicated points:
    # then the drops are redone with ties broken by point index.
    dlast = -1.0
    while m > k:
        dmax = dk2[0]
        for j in range(1, m):
            dmax = max(dmax, dk2[j])
        jmax = 0
        while dk2[jmax] != dmax:
            jmax += 1
        m -= 1
        dk2[jmax] = dk2[m]
        ik[jmax] = ik[m]
        dlast = dmax
    tie = False
    for j in range(k):
        tie |= dk2[j] == dlast
    if tie:
        m = m0
        for j in range(m):
            dk2[j] = bd2[j]
            ik[j] = bi[j]
        while m > k:
            jmax = 0
            dmax = dk2[0]
            imax = ik[0]
            for j in range(1, m):
                d = dk2[j]
                i = ik[j]
                if d > dmax or (d == dmax and i > imax):
                    jmax = j
                    dmax = d
                    imax = i
            m -= 1
            dk2[jmax] = dk2[m]
            ik[jmax] = ik[m]
    lo = dk2[0]
    hi = dk2[0]
    for j in range(1, k):
        lo = min(lo, dk2[j])
        hi = max(hi, dk2[j])
    return lo, hi


@numba.njit(cache=True, inline="always")
def _knn_set(xyz, lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, qx, qy, qz, k,
             a_first, cap2_first, a_second, bound, a_min, ang_max, rs, r2count, ranges, dk2, ik, bd2, bi,
             t2):  # pragma: no cover
    """:func:`_knn` when the order of the k nearest does not matter (median11 sorts their radii).

    The first cap's squared chord is ``cap2_first`` when > 0 (a chord the caller knows, saving
    the angle's round trip), else that of ``a_first``. ``a_second`` < 0: the second cap is
    computed only if the first fails, from the chord ``bound`` (>= 0) not below ``a_min`` and
    not above ``a_second``'s absolute value. Any cap scanned whole is exact (only the cost
    differs), so these shortcuts never change the result. ``dk2``/``ik`` need room for
    ``BUFFER`` values. Returns (done, count within r2count, smallest squared distance, k-th
    smallest squared distance).
    """
    a = a_first
    cap2 = cap2_first if cap2_first > 0.0 else _cap_chord2(a, rs)
    while True:
        nr = _ranges(lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, a, ranges)
        m, cnt = _collect(xyz, ranges, nr, qx, qy, qz, cap2, r2count, bd2, bi)
        if m > bd2.size:
            mk, _ = _scan(xyz, ranges, nr, qx, qy, qz, k, cap2, r2count, dk2, ik)
            if mk >= k:
                return True, cnt, dk2[0], dk2[k - 1]
        elif m >= k:
            ms = m
            if t2 < cap2:
                ms = _within_to_front(bd2, bi, m, t2)
                if ms < k:
                    ms = m
            lo, hi = _smallest_set(bd2, bi, ms, k, dk2, ik)
            return True, cnt, lo, hi
        if a >= ang_max:
            return False, cnt, 0.0, 0.0
        if a_second < 0.0:
            a_second = -a_second
            if bound >= 0.0:
                a_second = min(a_second, max(_angle(bound, rs), a_min))
        a = _next_cap(a, a_second, ang_max)
        cap2 = _cap_chord2(a, rs)


@numba.njit(cache=True, inline="always")
def _sort11(r):  # pragma: no cover
    """Sort r[:11] ascending in place with a 35-comparator sorting network (min/max pairs, no
    branches; checked on all 2**11 0/1 inputs in the tests). Same values as any sort.
    """
    v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10]
    v0, v9 = min(v0, v9), max(v0, v9)
    v1, v6 = min(v1, v6), max(v1, v6)
    v2, v4 = min(v2, v4), max(v2, v4)
    v3, v7 = min(v3, v7), max(v3, v7)
    v5, v8 = min(v5, v8), max(v5, v8)
    v0, v1 = min(v0, v1), max(v0, v1)
    v3, v5 = min(v3, v5), max(v3, v5)
    v4, v10 = min(v4, v10), max(v4, v10)
    v6, v9 = min(v6, v9), max(v6, v9)
    v7, v8 = min(v7, v8), max(v7, v8)
    v1, v3 = min(v1, v3), max(v1, v3)
    v2, v5 = min(v2, v5), max(v2, v5)
    v4, v7 = min(v4, v7), max(v4, v7)
    v8, v10 = min(v8, v10), max(v8, v10)
    v0, v4 = min(v0, v4), max(v0, v4)
    v1, v2 = min(v1, v2), max(v1, v2)
    v3, v7 = min(v3, v7), max(v3, v7)
    v5, v9 = min(v5, v9), max(v5, v9)
    v6, v8 = min(v6, v8), max(v6, v8)
    v0, v1 = min(v0, v1), max(v0, v1)
    v2, v6 = min(v2, v6), max(v2, v6)
    v4, v5 = min(v4, v5), max(v4, v5)
    v7, v8 = min(v7, v8), max(v7, v8)
    v9, v10 = min(v9, v10), max(v9, v10)
    v2, v4 = min(v2, v4), max(v2, v4)
    v3, v6 = min(v3, v6), max(v3, v6)
    v5, v7 = min(v5, v7), max(v5, v7)
    v8, v9 = min(v8, v9), max(v8, v9)
    v1, v2 = min(v1, v2), max(v1, v2)
    v3, v4 = min(v3, v4), max(v3, v4)
    v5, v6 = min(v5, v6), max(v5, v6)
    v7, v8 = min(v7, v8), max(v7, v8)
    v2, v3 = min(v2, v3), max(v2, v3)
    v4, v5 = min(v4, v5), max(v4, v5)
    v6, v7 = min(v6, v7), max(v6, v7)
    r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10] = v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10


@numba.njit(cache=True)
def _median_filtered(r, s, n, sigma):  # pragma: no cover
    """1-sigma filtered median of r[:n] (sorted in place; s: scratch of n) and the spread of the kept run."""
    if n == 11:
        _sort11(r)
    elif n <= RANK_MAX:  # sort by counting ranks (no data-dependent branches; ties by position)
        for a in range(n):
            v = r[a]
            q = 0
            for b in range(n):
                w = r[b]
                q += (w < v) | ((w == v) & (b < a))
            s[q] = v
        for a in range(n):
            r[a] = s[a]
    else:
        for i in range(1, n):  # insertion sort
            v = r[i]
            j = i - 1
            while j >= 0 and r[j] > v:
                r[j + 1] = r[j]
                j -= 1
            r[j + 1] = v
    if n % 2:
        med = r[n // 2]
    else:
        med = 0.5 * (r[n // 2 - 1] + r[n // 2])
    s1 = 0.0
    s2 = 0.0
    for i in range(n):
        c = r[i] - med
        s1 += c
        s2 += c * c
    var = s2 / n - (s1 / n) ** 2
    band = sigma * math.sqrt(var) if var > 0 else 0.0
    lo = 0
    hi = 0
    for i in range(n):
        c = r[i] - med
        if c < -band:
            lo += 1
        if c <= band:
            hi += 1
    nk = hi - lo
    if nk <= 0:
        return med, np.nan
    a = lo + (nk - 1) // 2
    b = lo + nk // 2
    value = med + 0.5 * ((r[a] - med) + (r[b] - med))
    if nk < 2:
        return value, np.nan
    t1 = 0.0
    t2 = 0.0
    for i in range(lo, hi):
        c = r[i] - med
        t1 += c
        t2 += c * c
    t1 /= nk
    return value, math.sqrt(max(t2 / nk - t1 * t1, 0.0))


@numba.njit(cache=True, inline="always")
def _angle_up(chord, rs):  # pragma: no cover
    """An upper bound of :func:`_angle` without the arcsine for small caps: with x = chord / 2 rs
    < SMALL_ANGLE, 2 asin(x) = 2 (x + x^3/6 + 3 x^5/40 + ...) <= 2 x (1 + x^2 / 5). A cap at
    least as wide as needed is exact all the same (only its cost differs).
    """
    x = chord / (2.0 * rs)
    if x < SMALL_ANGLE:
        return 2.0 * x * (1.0 + 0.2 * x * x)
    return _angle(chord, rs)


@numba.njit(cache=True, inline="always")
def _angle(chord, rs):  # pragma: no cover
    """Angle (radians) of a chord on the sphere of radius rs; pi when longer than the diameter."""
    if chord >= 2.0 * rs:
        return math.pi
    return 2.0 * math.asin(chord / (2.0 * rs))


def _median11_body(xyz, radius, lat0, inv_bh, lon_span, band_invw, band_first, cell_start,
                   phi_r, c_r, z_r, icp_r, u_c, cl_c, sl_c, paired, k, sigma, search_r,
                   a_min, a0, ang_max, rs, grow, out_r, out_count, out_near, out_spread, status):  # pragma: no cover
    ncol = u_c.size
    P = phi_r.size if paired else phi_r.size * ncol
    nblk = (P + BLOCK - 1) // BLOCK
    r2count = search_r * search_r
    for blk in prange(nblk):
        ranges = np.empty((2 * band_invw.size + 2, 2), dtype=np.int64)
        dk2 = np.empty(max(k, BUFFER))
        ik = np.empty(max(k, BUFFER), dtype=np.int64)
        rr = np.empty(k)
        rs_scratch = np.empty(k)
        bd2 = np.empty(BUFFER)
        bi = np.empty(BUFFER, dtype=np.int64)
        t2 = np.inf
        dprev = -1.0  # k-th distance at the previous pixel of the block (chord, m), -1 = none
        px = py = pz = 0.0
        for p in range(blk * BLOCK, min(P, (blk + 1) * BLOCK)):
            phi, u, qx, qy, qz, icp = _centre(p, paired, ncol, phi_r, u_c, c_r, cl_c, sl_c, z_r, icp_r)
            a_first = a0
            cap2_first = -1.0
            bound = -1.0
            if dprev >= 0.0:
                # The first try is a little above the previous k-th distance: it usually holds k
                # (its squared chord is known: no angle round trip). The previous pixel's k nearest
                # lie within dprev + |q - q_prev| of this one (triangle inequality): a cap that
                # surely holds k points, the second try (its angle computed only if needed).
                g = grow * dprev
                a_first = _angle_up(g, rs)
                if a_first < a_min:
                    a_first = a_min
                elif a_first >= ang_max:  # never beyond the last cap: the kd-tree decision is that cap's
                    a_first = ang_max
                else:
                    cap2_first = g * g
                bound = (dprev + math.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)) * (1.0 + 1e-9)
            done, cnt, d2near, d2k = _knn_set(xyz, lat0, inv_bh, lon_span, band_invw, band_first,
                                              cell_start, phi, icp, u, qx, qy, qz, k, a_first, cap2_first, -a0,
                                              bound, a_min, ang_max, rs, r2count, ranges, dk2, ik, bd2, bi, t2)
            if not done:
                status[p] = NEEDS_FALLBACK
                t2 = np.inf
                dprev = -1.0
                continue
            t2 = 1.5 * d2k
            dprev = math.sqrt(d2k)
            px, py, pz = qx, qy, qz
            status[p] = OK
            for i in range(k):
                rr[i] = radius[ik[i]]
            v, sp = _median_filtered(rr, rs_scratch, k, sigma)
            out_r[p] = v
            out_spread[p] = sp
            out_count[p] = cnt
            out_near[p] = math.sqrt(d2near)


@numba.njit(cache=True)
def _weighted(radius, ik, d, w, n):  # pragma: no cover
    """Weighted mean and weighted std of radius[ik[:n]] (weights w[:n]; a zero distance takes all)."""
    exact = False
    for i in range(n):
        if d[i] == 0.0:
            exact = True
    if exact:
        for i in range(n):
            w[i] = 1.0 if d[i] == 0.0 else 0.0
    ref = radius[ik[0]]
    sw = 0.0
    sm = 0.0
    used = 0
    for i in range(n):
        sw += w[i]
        sm += w[i] * (radius[ik[i]] - ref)
        if w[i] > 0:
            used += 1
    m = sm / sw
    sv = 0.0
    for i in range(n):
        c = radius[ik[i]] - ref - m
        sv += w[i] * c * c
    return ref + m, (math.sqrt(sv / sw) if used >= 2 else np.nan)


def _shepard_body(xyz, radius, lat0, inv_bh, lon_span, band_invw, band_first, cell_start,
                  phi_r, c_r, z_r, icp_r, u_c, cl_c, sl_c, paired, kmax, kfb, search_r,
                  a_r, a0, ang_max, rs, out_r, out_count, out_near, out_spread, status):  # pragma: no cover
    ncol = u_c.size
    P = phi_r.size if paired else phi_r.size * ncol
    nblk = (P + BLOCK - 1) // BLOCK
    r2 = search_r * search_r
    kb = max(kmax, kfb)
    for blk in prange(nblk):
        ranges = np.empty((2 * band_invw.size + 2, 2), dtype=np.int64)
        dk2 = np.empty(kb)
        ik = np.empty(kb, dtype=np.int64)
        d = np.empty(kb)
        w = np.empty(kb)
        bd2 = np.empty(BUFFER)
        bi = np.empty(BUFFER, dtype=np.int64)
        for p in range(blk * BLOCK, min(P, (blk + 1) * BLOCK)):
            phi, u, qx, qy, qz, icp = _centre(p, paired, ncol, phi_r, u_c, c_r, cl_c, sl_c, z_r, icp_r)
            nr = _ranges(lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u, a_r, ranges)
            m, cnt = _collect(xyz, ranges, nr, qx, qy, qz, r2, r2, bd2, bi)
            if m > bd2.size:
                m, cnt = _scan(xyz, ranges, nr, qx, qy, qz, kmax, r2, r2, dk2, ik)
            else:
                m = _topk(bd2, bi, m, kmax, dk2, ik)
            if m > 0:
                for i in range(m):
                    d[i] = math.sqrt(dk2[i])
                    w[i] = ((search_r - d[i]) / (search_r * d[i])) ** 2 if d[i] > 0 else 0.0
            else:
                done, _ = _knn(xyz, lat0, inv_bh, lon_span, band_invw, band_first, cell_start, phi, icp, u,
                               qx, qy, qz, kfb, a0, a0,
                               ang_max, rs, r2, ranges, dk2, ik, bd2, bi, np.inf)
                if not done:
                    status[p] = NEEDS_FALLBACK
                    continue
                m = kfb
                for i in range(m):
                    d[i] = math.sqrt(dk2[i])
                    w[i] = 1.0 / dk2[i] if dk2[i] > 0 else 0.0
            status[p] = OK
            v, sp = _weighted(radius, ik, d, w, m)
            out_r[p] = v
            out_spread[p] = sp
            out_count[p] = cnt
            out_near[p] = d[0]


_median11_kernel = numba.njit(parallel=True, cache=True, nogil=True)(_median11_body)
_shepard_kernel = numba.njit(parallel=True, cache=True, nogil=True)(_shepard_body)


def _run(kernel, threads: int, *args) -> None:
    """Launch a parallel kernel on ``threads`` threads (-1: all numba's), one launch at a time."""
    n = numba.config.NUMBA_NUM_THREADS if threads < 1 else min(threads, numba.config.NUMBA_NUM_THREADS)
    with _PARALLEL_LOCK:
        old = numba.get_num_threads()
        numba.set_num_threads(n)
        try:
            kernel(*args)
        finally:
            numba.set_num_threads(old)


def _outputs(P: int) -> tuple[NDArray[np.float64], NDArray[np.int32], NDArray[np.float64], NDArray[np.float64],
                              NDArray[np.uint8]]:
    return np.empty(P), np.zeros(P, dtype=np.int32), np.empty(P), np.empty(P), np.zeros(P, dtype=np.uint8)


def _pixel_centres(lat_deg: NDArray[np.floating], lon_deg: NDArray[np.floating], b: SphereBuckets, grid: bool
                   ) -> tuple[int, tuple[NDArray[np.float64], ...]]:
    """(number of pixels, the kernels' centre arrays) for a list of centres or a grid of them."""
    lat = np.ascontiguousarray(np.ravel(lat_deg), dtype=np.float64)
    lon = np.ascontiguousarray(np.ravel(lon_deg), dtype=np.float64)
    if not grid and lat.size != lon.size:
        raise ValueError(f"{lat.size} latitudes but {lon.size} longitudes")
    rows = tuple(np.empty(lat.size) for _ in range(4))
    cols = tuple(np.empty(lon.size) for _ in range(3))
    _centres(lat, lon, b.sphere_radius, b.lon0, *rows, *cols)
    return (lat.size * lon.size if grid else lat.size), (*rows, *cols, not grid)


def _search_tables(b: SphereBuckets) -> tuple[Any, ...]:
    """The index as the kernels read it: points, radii, the bands' origin and 1 / height, the
    longitude span, each band's cells per radian, the bands' first cells and the cells' starts.
    """
    return (b.xyz, b.radius, b.lat0, 1.0 / b.band_h, b.lon_span, b.band_ncell / b.lon_span, b.band_first,
            b.cell_start)


def median11_search(
    b: SphereBuckets, lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], k: int, sigma: float,
    search_r: float, ang_max: float, threads: int = -1, *, grid: bool = False,
) -> dict[str, NDArray[np.generic]]:
    """median11 at pixel centres (degrees): k nearest, 1-sigma filter about the median radius.

    The centres are ``(lat_deg[p], lon_deg[p])`` (P,) or, with ``grid=True``, every
    ``(lat_deg[i], lon_deg[j])`` row by row (P = rows x columns; the trigonometry of the
    centres is then done once per row and per column). Returns dict of (P,) arrays:
    ``radius`` (m), ``count`` (points within ``search_r``), ``nearest`` (chord to the
    nearest point, m), ``spread`` (m; NaN under two kept points), ``status`` (``OK`` or
    ``NEEDS_FALLBACK`` where the k nearest are beyond ``ang_max`` radians: the other
    outputs are then undefined).
    """
    P, centres = _pixel_centres(lat_deg, lon_deg, b, grid)
    out = _outputs(P)
    a_r = 2.0 * math.asin(min(1.0, search_r / (2.0 * b.sphere_radius)))
    a_min = min(a_r * (1 + 1e-6), math.pi)
    a0 = min(max(b.start_angle(k), a_min), math.pi)
    _run(_median11_kernel, threads, *_search_tables(b), *centres, int(k), float(sigma), float(search_r), a_min, a0,
         max(a0, min(ang_max, math.pi)), b.sphere_radius, GROW, *out)
    return dict(zip(("radius", "count", "nearest", "spread", "status"), out))


def shepard_search(
    b: SphereBuckets, lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], kmax: int, kfb: int,
    search_r: float, ang_max: float, threads: int = -1, *, grid: bool = False,
) -> dict[str, NDArray[np.generic]]:
    """Modified Shepard at pixel centres (degrees); centres and outputs as :func:`median11_search`.

    Weights ``((R - d) / (R d))**2`` over the (at most ``kmax`` nearest) points within
    ``R = search_r``; where none, the ``kfb`` nearest with weights ``1 / d**2``.
    """
    P, centres = _pixel_centres(lat_deg, lon_deg, b, grid)
    out = _outputs(P)
    a_r = min(2.0 * math.asin(min(1.0, search_r / (2.0 * b.sphere_radius))), math.pi)
    a0 = min(max(b.start_angle(kfb), a_r), math.pi)
    _run(_shepard_kernel, threads, *_search_tables(b), *centres, int(kmax), int(kfb), float(search_r), a_r, a0,
         max(a0, min(ang_max, math.pi)), b.sphere_radius, *out)
    return dict(zip(("radius", "count", "nearest", "spread", "status"), out))
